"""The controller manager: ros2_control's update loop, and the fault-table interpreter.

Each tick: read the driver, turn the load cell into a stress (sigma = -F / A_rod), run the law's
`update`, apply the current and slew limits, write the command, tell the law how the tick went,
and hand the tick to every broadcaster (telemetry, status, any part plugged in). The hot path
allocates nothing, does no I/O of its own besides the driver's, and logs nothing.

Faults take one path, which executes the fault table (`safety.FAULT_ACTIONS`, resolved from the
config when the setup is built): how the output goes safe, what follows, whether learning
freezes, and the state the run ends in. Every exit from `run` - normal end, stop request, fault,
exception - writes the safe current through the driver BEFORE the driver and the telemetry close.

The parts come from the builder (`builder.build`): the law (the *controller*), the driver
supervisor (resource manager), the telemetry recorder and the state broadcaster.

    ctrl = ControllerManager(cfg)               # builds model, driver, law, telemetry
    summary = ctrl.run(stop_event, duration_s)  # blocking; the safe current on every way out
    ctrl.status()                               # thread-safe snapshot; ctrl.request_stop(reason)
    ctrl.reload(load_config(path))              # bumpless; the old config is kept on error
"""

from __future__ import annotations

import math
import threading
import time
from enum import Enum
from typing import Any, Mapping

from ..drivers import DriverError, DriverProtocol
from ..drivers.base import CURRENT
from ..errors import GmaError
from ..protocols import Model
from . import safety
from .builder import build, build_reload
from .config import ControllerConfig
from .device_claim import DeviceClaim
from .faults import TickFault, classify, driver_fault
from .law import FeedforwardController
from .learned_file import save_if_learned
from .realtime import realtime
from .safety import RAMP
from .scheduler import Scheduler
from .setup import Setup
from .tick import OUTSIDE_DRIVE, OUTSIDE_STRESS, Broadcaster

RUNNING, STOPPING = 0, 1      # the loop's own mode within State.RUNNING / State.STOPPING
FLAGGED, RAMPING, RESUME, EXIT = 0, 1, 2, 3    # what the loop does after `_execute` ran a fault's row


class State(str, Enum):
    """The controller's lifecycle state; a str so status and JSON read as plain words."""

    IDLE = "idle"
    STARTING = "starting"
    RUNNING = "running"
    RECONNECTING = "reconnecting"
    STOPPING = "stopping"
    STOPPED = "stopped"
    FAULT = "fault"

    def __str__(self) -> str:
        return self.value


class ControllerManager:
    """Runs the law at the configured rate; `run` returns a summary (`summary["ok"]` False on a fault).

    `model`, `driver` and `clock` may be given (tests, the demo); by default they are built from
    the config. `attach` plugs in another broadcaster (a model-fit monitor, say) before `run`.
    """

    def __init__(self, cfg: ControllerConfig, *, model: Model | None = None, driver: DriverProtocol | None = None,
                 clock: Any = None) -> None:
        parts = build(cfg, model=model, driver=driver, clock=clock)
        self.clock, self.period_s, self.setup = parts.clock, cfg.period_s, parts.setup
        self.stats, self.faults, self.watchdog = parts.stats, parts.faults, parts.watchdog
        self.hardware, self.recorder, self.state_broadcaster = parts.hardware, parts.recorder, parts.state
        self.driver: DriverProtocol = parts.hardware.driver
        self.amplifier_claim = DeviceClaim(getattr(type(self.driver), "amplifiers", lambda _cfg: [])(cfg.driver))
        self.broadcasters: list[Broadcaster] = [*parts.plugins, parts.recorder]   # plugins fill the row's columns
        self.tick, self.inputs = parts.tick, parts.tick.inputs
        self.state = State.IDLE
        self.exit_reason = ""
        self.started_unix_s: float | None = None
        self._lock = threading.Lock()
        self._pending: Setup | None = None
        self._stop_reason: str | None = None
        self._stop_event = threading.Event()
        self._mode = RUNNING
        self._stop_started = 0.0
        self._read_ok = False
        self._stress_out = False
        self._has_current = CURRENT in self.driver.channels   # the driver's word before it opens; read again at start
        self._relapses = 0          # reconnects since the last tick whose command got through
        self.setup.law.activate(self.setup.safe_A)
        for b in self.broadcasters:
            b.on_setup(self.setup)

    def attach(self, broadcaster: Broadcaster) -> None:
        """Plug in a part that watches the loop: it gets the setup now and after every reload,
        and every tick (between runs only: the list is not locked against the loop)."""
        broadcaster.on_setup(self.setup)
        self.broadcasters.append(broadcaster)

    # ---- requests from other threads -----------------------------------------------------
    def request_stop(self, reason: str = "stop requested") -> None:
        """Ask the loop to ramp to the safe current and stop (thread-safe, signal-safe)."""
        if self._stop_reason is None:
            self._stop_reason = reason

    def reload(self, new_cfg: ControllerConfig, model: Model | None = None) -> None:
        """Swap model, reference, limits and sensor settings at the next tick, bumplessly.

        Everything is built and validated here, in the caller's thread (`builder.build_reload`);
        on any error the old configuration keeps running and the error propagates.
        """
        setup = build_reload(self.setup.cfg, new_cfg, model)
        for b in self.broadcasters:           # their slow part of the reload, here (any may refuse it)
            b.prepare(setup)
        with self._lock:
            self._pending = setup
        if self.state in (State.IDLE, State.STOPPED, State.FAULT):
            self._apply_pending()

    @property
    def reads_current(self) -> bool:
        """Does the driver read the coil current, as the loop takes it (from the driver's channels at
        start; before a run, as the driver gives them)? The current tracking runs on it; the status says it."""
        return self._has_current

    def status(self) -> dict[str, Any]:
        """Thread-safe snapshot for the service, the CLI and tests (`state_broadcaster`)."""
        snap = self.state_broadcaster.status(self.setup, self.state.value, self.exit_reason, self.started_unix_s,
                                             self.reads_current)
        for b in self.broadcasters:
            snap.update(b.status_fields())
        return snap

    def summary(self) -> dict[str, Any]:
        snap = self.status()
        snap["ok"] = snap["state"] != "fault"
        return snap

    # ---- lifecycle -------------------------------------------------------------------------
    def claim_outputs(self) -> None:
        """Take what this run writes exclusively (the telemetry file's lock) before the driver is
        opened; ConfigError when another controller holds it. `run` calls it; the service calls it
        first, so that refusal is exit 2 with the amplifier untouched. The amplifier itself is claimed
        first (`device_claim`): another controller driving it refuses this one."""
        self.amplifier_claim.acquire()
        try:
            self.recorder.claim()
        except BaseException:
            self.amplifier_claim.release()
            raise

    def release_outputs(self) -> None:
        """Give back a claim when the run will not happen (the service failed to start)."""
        self.recorder.release()
        self.amplifier_claim.release()

    def run(self, stop_event: threading.Event | None = None, duration_s: float | None = None) -> dict[str, Any]:
        """Blocking fixed-rate loop; the safe current is written on every way out."""
        self._stop_event = stop_event or threading.Event()
        self.state = State.STARTING
        self.hardware.at_safe = False
        self.exit_reason = ""
        self.started_unix_s = time.time()
        opened = False
        try:
            if not self.setup.law.active:         # every run starts from the safe current
                self.setup.law.activate(self.setup.safe_A)
            self.claim_outputs()                  # refused here, the driver was never opened
            opened = self._open()
            if opened:
                self._start_and_loop(duration_s)
            else:
                self.exit_reason = "driver could not be opened"
        except GmaError as exc:
            self.faults.raise_fault(driver_fault(exc) if isinstance(exc, DriverError) else safety.EXCEPTION, str(exc))
            self.exit_reason = str(exc)
        except BaseException as exc:  # anything at all: safe current first, then report
            self.faults.raise_fault(safety.EXCEPTION, f"{type(exc).__name__}: {exc}")
            self.exit_reason = f"{type(exc).__name__}: {exc}"
        finally:
            self._finish(opened)
        return self.summary()

    def _open(self) -> bool:
        """Open (configure) the driver, reconnecting with backoff when the table says so."""
        name = self.hardware.open()
        if not name:
            return True
        return self.setup.fault_table[name].then == "reconnect" and self._reconnect()

    def _start_and_loop(self, duration_s: float | None) -> None:
        channels = self.driver.channels
        self._has_current = CURRENT in channels
        self.recorder.start(channels, self.setup, self.started_unix_s or time.time())
        for b in self.broadcasters:
            b.on_start(self.setup)
        if self.clock.simulated:
            self.hardware.activate()      # output on just before the first command, never by a write
            self._loop(duration_s)
            return
        self.watchdog.start()
        self.hardware.activate()
        with realtime(self.setup.cfg.scheduler,
                      lambda message: self.faults.raise_fault(safety.REALTIME_REFUSED, message)):
            self._loop(duration_s)

    def _finish(self, opened: bool) -> None:
        """Safe current and output off (deactivate) first, then join the watchdog, keep what was
        learned, flush telemetry and close the driver."""
        self.watchdog.stop()
        if opened and not self.hardware.at_safe:
            self._go_safe()
        if opened:
            self.hardware.deactivate()
        self.setup.law.deactivate(0.0, "the run ended", freeze_learning=False)
        self.watchdog.join()
        error = save_if_learned(self.setup.law.learner, self.setup.cfg.learning.file,
                                self.setup.cfg.output_dirs)
        if error:
            self.faults.raise_fault(safety.LEARNING_SAVE_FAILED, error)
        error = self.recorder.close()
        if error:
            self.faults.raise_fault(safety.TELEMETRY, error)
        self.recorder.release()              # a claim no writer took over (the driver never opened)
        self.hardware.close()
        self.amplifier_claim.release()               # only once the driver has let go of the amplifier
        hard = [f for f in self.faults.active if exit_state(self.setup.fault_table, f) == "fault"]
        self.state = State.FAULT if hard else State.STOPPED

    def _go_safe(self) -> None:
        """The safe current through the supervisor (with its retries); the limiter starts from it."""
        s = self.setup
        if self.hardware.write_safe(s.safe_A):
            self.tick.command_A = s.safe_A     # the amplifier's last command, for the status
        s.limiter.force(s.safe_A)

    def _reconnect(self, safe_A: float | None = None) -> bool:
        """Reconnect with backoff; the amplifier is already safe, so the watchdog pauses. With
        `safe_A` (after a fault) a safe write that failed is made good before the output goes on."""
        self.state = State.RECONNECTING
        self.watchdog.pause()
        return self.hardware.reconnect(self._wait, safe_A)

    def _wait(self, delay: float) -> bool:
        """Sleep `delay` on the controller's clock; True if a stop came meanwhile."""
        if self.clock.simulated:
            self.clock.advance(delay)          # type: ignore[attr-defined]  # a SimulatedClock
        else:
            self._stop_event.wait(delay)
        return self._stop_event.is_set() or self._stop_reason is not None

    def _apply_pending(self) -> None:
        """Swap in a reload's setup between two ticks: the new law takes over the old one's
        hysteresis memory at the command the amplifier holds, and the limits start from it."""
        with self._lock:
            new, self._pending = self._pending, None
        if new is None:
            return
        old = self.setup
        last = old.limiter.last
        new.law.take_over(old.law, last)
        new.monitor.continue_from(old.monitor)
        new.tracking.continue_from(old.tracking)
        new.limiter.continue_from(old.limiter)   # new limits approached within the slew limit
        self.hardware.comms = new.cfg.comms
        self.setup = new
        for b in self.broadcasters:
            b.on_setup(new)

    # ---- the loop ----------------------------------------------------------------------------
    def _loop(self, duration_s: float | None) -> None:
        clock, stats, tick = self.clock, self.stats, self.tick
        broadcasters = [b for b in self.broadcasters if b.on_the_loop]
        watchdog, stop_event = self.watchdog, self._stop_event
        sched, t0 = self._start_schedule()
        end_t = math.inf if duration_s is None else duration_s
        watchdog_s = self.setup.cfg.watchdog_s
        stall_s = self.setup.cfg.period_s + watchdog_s      # two ticks' starts are a period apart when all is well
        while True:
            deadline = sched.wait()
            t_start = clock.now()
            t = deadline - t0
            if t_start - watchdog.heartbeat > stall_s and self._stalled(t_start - watchdog.heartbeat,
                                                                            t_start - t0, t):
                return                              # NaN (paused: a fault, a reconnect) never is
            watchdog.heartbeat = t_start
            if self._mode == RUNNING and (t >= end_t or stop_event.is_set() or self._stop_reason is not None):
                if self._execute(safety.STOP, t, self._stop_reason or (
                        "stop requested" if stop_event.is_set() else "duration reached")) == EXIT:
                    return
            if self._pending is not None:
                self._apply_pending()
            try:
                self._tick(t, t_start - t0)
            except Exception as exc:   # the one fault path: the table says what happens
                if self._on_fault(exc, t) == RESUME:
                    sched.next_deadline = clock.now()
                    continue
                return
            for b in broadcasters:
                b.on_tick(tick)
            compute = clock.now() - t_start
            stats.record(t_start, compute)
            stats.overruns = sched.overruns
            stats.missed = sched.missed
            if compute > watchdog_s:
                self.faults.raise_fault(safety.WATCHDOG, f"a tick took {compute:.3f} s (watchdog {watchdog_s:g} s)")
                if self._execute(safety.WATCHDOG, t, "watchdog") != RESUME:
                    return
            if self._mode == STOPPING and tick.command_A == self.setup.safe_A:
                return
            if self._mode == STOPPING and t - self._stop_started >= self.setup.cfg.limits["stop_ramp_max_s"]:
                self._ramp_cut(tick.command_A)
                return

    def _ramp_cut(self, command_A: float) -> None:
        """The stop's ramp ran out of `stop_ramp_max_s` short of the safe current (the config checks
        make it fit at the nominal rate: a loop slower than its rate): the safe current is written
        next in one step, and the exit reason says so."""
        left = abs(command_A - self.setup.safe_A)
        self.exit_reason += (f"; the stop's ramp was cut at limits.stop_ramp_max_s "
                             f"({self.setup.cfg.limits['stop_ramp_max_s']:g} s) {left:.4g} A from the safe "
                             "current, which was then written in one step (the loop ran slower than its rate)")

    def _stalled(self, gap_s: float, until_s: float, t: float) -> bool:
        """The loop did not run for `gap_s` > watchdog_s between two ticks, until `until_s` of
        run time (the whole process stopped or starved: SIGSTOP, swapping, a paused VM), holding
        the command unwatched. As `watchdog_s` promises, that is the watchdog fault: the safe
        current at once, then the row's stop. True when the loop must end."""
        self.faults.raise_fault(safety.WATCHDOG, (
            f"the loop stalled for {gap_s:.3f} s, until t={until_s:.3f} s (a period and watchdog_s: "
            f"{self.setup.cfg.period_s + self.setup.cfg.watchdog_s:g} s): "
            "the process was stopped or starved, the command held meanwhile"))
        return self._execute(safety.WATCHDOG, t, "watchdog: the loop stalled") != RESUME

    def _start_schedule(self) -> tuple[Scheduler, float]:
        """The first deadline, and the wall-clock time of t = 0 from one reading of both clocks,
        so a row's unix time is start_unix_s + time_s to well within a millisecond."""
        sched = Scheduler(self.clock, self.period_s)
        t0 = sched.start()
        wall, mono = time.time(), self.clock.now()
        self.started_unix_s = wall - (mono - t0) if not self.clock.simulated else wall
        self.recorder.stamp_start(self.started_unix_s)
        self._mode = RUNNING
        self._read_ok = False
        self.setup.tracking.restart()
        self.watchdog.heartbeat = math.nan      # a stall is measured from this run's first tick
        self._relapses = 0
        self.state = State.RUNNING
        return sched, t0

    def _tick(self, t: float, time_s: float) -> None:
        """One tick, up to the law's observation; the loop broadcasts it. A fault raises."""
        s, tick, inputs = self.setup, self.tick, self.inputs
        tick.t = t
        tick.time_s = time_s
        tick.outside_model = 0
        if self.watchdog.tripped:
            raise TickFault(safety.WATCHDOG, self.faults.active.get(safety.WATCHDOG, "watchdog"))
        self._read_ok = False
        inputs.clear()
        self.driver.read(inputs)
        self._read_ok = True
        bad = s.monitor.update(inputs.force_N, inputs.stress_MPa)
        if bad:
            raise TickFault(bad, s.monitor.message(bad, inputs.force_N if s.monitor.source_force else inputs.stress_MPa))
        if self._has_current and s.tracking.enabled:    # the reading against the command held since the last tick
            bad = s.tracking.update(inputs.current_A, s.limiter.last)
            if bad:
                message = s.tracking.message()
                raise TickFault(bad, message, f"{bad}: {message}")
        stress = s.monitor.stress
        ref_now = s.reference_now.value(t)
        law = s.law
        if self._mode != RUNNING or stress != stress:
            u = s.safe_A                        # stopping, or before the first good stress
        else:
            u = self._law_drive(law, t, stress)
        cmd = s.limiter.apply(u)
        self.hardware.at_safe = False
        self.driver.write(cmd)
        self._relapses = 0
        limited = RAMP if self._mode != RUNNING else s.limiter.clipped
        if law.learner is not None:         # the tick's outcome, to the law's learner
            law.observe(t, ref_now, inputs.displacement_um, stress, limited, cmd)
        tick.reference_um = ref_now
        tick.command_A = cmd
        meas = inputs.current_A
        tick.current_read = read = self._has_current and meas == meas
        tick.current_A = meas if read else cmd   # commanded where unmeasured
        tick.stress_MPa = stress
        tick.displacement_um = inputs.displacement_um
        tick.correction_um = law.correction
        tick.limited_by = limited
        tick.faulted = False

    def _law_drive(self, law: FeedforwardController, t: float, stress: float) -> float:
        """The law's drive with the model's envelope checked (the safe current if that stops the run)."""
        rng = self.setup.stress_range
        if stress < rng.lo or stress > rng.hi:         # the tick's one test of the stress range
            self.tick.outside_model = OUTSIDE_STRESS
            self.state_broadcaster.count_outside(OUTSIDE_STRESS)
            self._stress_out = True
            self._envelope_fault(safety.STRESS_RANGE, stress, t)
            if self._mode != RUNNING:
                return self.setup.safe_A
        elif self._stress_out:
            self._stress_out = False
            self.faults.clear(safety.STRESS_RANGE)
        u = law.update(t, stress)
        if u != u:
            raise TickFault(safety.EXCEPTION, "the inverse model returned NaN")
        if law.beyond:
            self.tick.outside_model |= OUTSIDE_DRIVE
            self.state_broadcaster.count_outside(OUTSIDE_DRIVE)
            self._envelope_fault(safety.DRIVE_RANGE, law.raw, t)
            if self._mode != RUNNING:
                return self.setup.safe_A
        return u

    # ---- faults: the table's interpreter ---------------------------------------------------------
    def _envelope_fault(self, name: str, value: float, t: float) -> None:
        """A stress or drive beyond the model: raised once while it lasts (its message built only
        then), its row executed every tick it lasts; an immediate row leaves by the fault path."""
        immediate = self.setup.fault_table[name].output == "immediate"
        if immediate or name not in self.faults.active:
            s = self.setup
            message = (s.stress_range.message(value) if name == safety.STRESS_RANGE
                       else s.law.drive.message(value, s.limiter.lo, s.limiter.hi))
            if immediate:
                raise TickFault(name, message)
            self.faults.raise_fault(name, message)
        self._execute(name, t)

    def _on_fault(self, exc: Exception, t: float) -> int:
        """A tick that raised: its row (the safe current as command) if it read, then the table's row."""
        name, message, reason = classify(exc)
        if self._read_ok:   # a tick whose read failed has no data to log
            s, tick = self.setup, self.tick
            meas = self.inputs.current_A
            tick.current_read = read = self._has_current and meas == meas
            tick.current_A = meas if read else s.safe_A
            tick.stress_MPa = s.monitor.stress
            tick.displacement_um = self.inputs.displacement_um
            tick.correction_um = 0.0
            tick.faulted = True        # its row records the safe current; reference_um stays the last good
            for b in self.broadcasters:
                if b.on_the_loop:
                    b.on_tick(tick)
        self.faults.raise_fault(name, message)
        return self._execute(name, t, reason)

    def _relapsed_too_often(self, why: str) -> bool:
        """A link that comes back and fails again before any command gets through (a device that
        answers a connect and refuses every write) would be reconnected forever, the coil going
        between the safe current and the first command: after comms.max_attempts such relapses in a
        row (0: forever, as for failed connects) that is reconnect_failed. True when it is."""
        self._relapses += 1
        limit = self.hardware.comms["max_attempts"]
        if limit == 0 or self._relapses <= limit:
            return False
        self.faults.raise_fault(safety.RECONNECT_FAILED, (
            f"gave up after {self._relapses - 1} reconnects in a row that failed again before a command got "
            f"through (the last: {why})"))
        return True

    def _execute(self, name: str, t: float, reason: str | None = None) -> int:
        """Execute the fault table's row for `name` (already raised, or a stop request); returns
        FLAGGED (the tick goes on), RAMPING (the loop heads for the safe current within the slew
        limit), RESUME (reconnected: next tick) or EXIT. `reason` (default: the fault's message)
        becomes the exit reason when the row stops the run. Only ever called on a fault."""
        action = self.setup.fault_table[name]
        if action.output == "none":
            return FLAGGED
        if reason is None:
            reason = self.faults.active.get(name, name)
        if action.output == "ramp":      # stopping ticks are not the law's: they teach nothing
            self.exit_reason = reason
            self.state = State.STOPPING
            if self._mode == RUNNING:
                self._mode, self._stop_started = STOPPING, t
            return RAMPING
        # immediate. Fault handling is bounded (comms timeouts, safe_retry_s, the reconnect
        # policy): the watchdog, which guards against a loop that hangs, pauses until the next tick.
        self.watchdog.pause()
        self._go_safe()
        coil_path = self.hardware.coil_path_at_safe(self.setup.safe_A)     # before a reconnect's safe write
        reconnect = action.then == "reconnect" and self._mode == RUNNING
        self.setup.law.deactivate(t, f"{name}: at the safe current" + (", reconnecting" if reconnect else ""),
                                  action.freeze_learning)
        if reconnect and self._relapsed_too_often(reason):
            reconnect, reason = False, self.faults.active[safety.RECONNECT_FAILED]
        if reconnect and self._reconnect(self.setup.safe_A):
            self.setup.law.resume(self.setup.safe_A, coil_path)
            self.setup.monitor.restart()
            self.setup.tracking.restart()
            self.state = State.RUNNING
            return RESUME
        self.exit_reason = reason
        return EXIT


def exit_state(fault_table: Mapping[str, safety.FaultAction], name: str) -> str:
    """The state a run ending with fault `name` active ends in (unknown names: fault)."""
    action = fault_table.get(name)
    if action is not None:
        return action.exit_state
    return "stopped" if name in safety.WARNINGS else "fault"
