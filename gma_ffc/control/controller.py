"""The controller: a fixed-rate inverse-SDPI feedforward loop with safety and telemetry.

Each tick: read the load cell and scale it to stress (sigma = -F / A_rod), take the reference
sample, step the inverse model, apply current and slew limits, write the command, and push a
telemetry row. The hot path allocates no containers, does no I/O of its own besides the
driver's, and logs nothing; faults are recorded in preallocated state and reported by
`status()`. Faults go through one path that executes the fault table (`safety.FAULT_ACTIONS`,
resolved from the config by `safety.fault_actions` at configure and reload time): how the output
goes safe, what follows, whether learning freezes, and the state the run ends in.

Every exit from `run` - normal end, stop request, fault, exception - writes the safe current
through the driver BEFORE the driver and the telemetry file are closed.
"""

from __future__ import annotations

import collections
import contextlib
import gc
import math
import os
import sys
import threading
import time
from enum import Enum
from typing import Any, Iterator

import numpy as np

from ..drivers import Driver, DriverError, DriverProtocol, Inputs, driver_class
from ..drivers.base import CURRENT, DISPLACEMENT, FORCE, INSTANCE_MEMBERS, STRESS, missing_members
from ..errors import ConfigError, GmaError
from ..model import InverseStepper as SDPIInverseStepper
from ..protocols import InverseStepper, Model
from . import safety
from .law import FeedforwardController
from .learning import RepetitiveLearner, model_gain_table, reference_period_s
from .config import ControllerConfig
from .model_watch import COLUMNS as WATCH_COLUMNS, ModelWatch
from .reference import Reference, build_reference
from .scheduler import MonotonicClock, Scheduler, SimulatedClock, TickStats
from .telemetry import Telemetry

RUNNING, STOPPING = 0, 1      # the loop's own mode within State.RUNNING / State.STOPPING
FLAGGED, RAMP, RESUME, EXIT = 0, 1, 2, 3    # what the loop does after `_execute` ran a fault's row


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
FAULT_HISTORY = 200     # most recent faults kept for the status (bounded for long service lives)
_RESTART_KEYS = ("rate_hz", "clock", "driver", "telemetry", "scheduler")


class _TickFault(Exception):
    """Raised inside a tick to leave it for the fault path (only on the rare fault branch)."""

    def __init__(self, name: str, message: str) -> None:
        super().__init__(message)
        self.name = name


class Controller:
    """Builds the model, driver, reference and telemetry from a validated config and runs the loop.

    `model`, `driver` and `clock` may be given (tests, the demo); by default they are built from
    the config. `run` returns a summary dict; `summary["ok"]` is False when it ended on a fault.
    """

    def __init__(self, cfg: ControllerConfig, *, model: Model | None = None, driver: DriverProtocol | None = None,
                 clock: Any = None) -> None:
        self.cfg = cfg
        self.period_s = cfg.period_s
        if model is None:
            from ..modelio import load_model

            model = load_model(cfg.model)
        self.model: Model = model
        if clock is None:
            # Spin at most half a period: a loop that never sleeps at SCHED_FIFO would hit the
            # kernel's RT throttling (50 ms stalls per second) and starve everything else.
            clock = SimulatedClock() if cfg.clock == "simulated" else \
                MonotonicClock(min(cfg.scheduler["spin_us"] * 1e-6, 0.5 * self.period_s))
        self.clock = clock
        self.driver: DriverProtocol = driver if driver is not None else \
            driver_class(cfg.driver["kind"])(cfg.driver, self.period_s)
        if not isinstance(self.driver, Driver) and missing_members(self.driver, INSTANCE_MEMBERS):
            raise ConfigError(f"driver '{cfg.driver['kind']}' lacks the driver contract's "
                              f"{', '.join(missing_members(self.driver, INSTANCE_MEMBERS))}")
        want = FORCE if cfg.stress["source"] == "force" else STRESS
        if self.driver.channels and want not in self.driver.channels:
            raise ConfigError(f"config key 'stress.source' is {cfg.stress['source']!r} but driver "
                              f"'{cfg.driver['kind']}' provides no '{want}' channel (it has: "
                              f"{', '.join(self.driver.channels)})")
        # The command uses the reference `lead` ahead (configured latency + the model's delay
        # preview); telemetry records the reference for *now*, so tracking error is y(t) - r(t).
        self.reference: Reference = build_reference(cfg.reference, model.preview_s)
        self.reference_now: Reference = build_reference({**cfg.reference, "lead_s": 0.0})
        lim = cfg.limits
        self.safe_A = lim["safe_current_A"]
        self.limiter = safety.Limiter(lim["current_min_A"], lim["current_max_A"], lim["slew_A_per_s"],
                                      self.period_s, self.safe_A)
        self.monitor = self._make_monitor(cfg)
        self.stepper: InverseStepper = model.inverse_stepper(self.period_s, initial_drive=self.safe_A)
        self.initial_state = start_stepper(self.stepper, model, self.safe_A)
        self.learner = make_learner(cfg, model, self.reference)
        self._set_stress_range(model)
        _warm_up(model, self.period_s, self.stress_lo, self.stress_hi)
        self.stats = TickStats(self.period_s)
        self.inputs = Inputs()
        self.telemetry: Telemetry | None = None
        self._lock = threading.Lock()
        self._pending: tuple | None = None
        self._stop_reason: str | None = None
        self.state = State.IDLE
        self.active_faults: dict[str, str] = {}
        self.fault_history: collections.deque[dict[str, Any]] = collections.deque(maxlen=FAULT_HISTORY)
        self.stress_clamped_ticks = 0
        self.drive_outside_ticks = 0
        self._outside = 0
        self.limits_beyond = cfg.limits["beyond_model"]
        self.law = self._make_law()
        self.reconnects = 0
        self.exit_reason = ""
        self.started_unix_s: float | None = None
        self.last_reference_um = math.nan
        self.last_cmd_A = math.nan
        self.last_current_A = math.nan
        self.last_stress_MPa = math.nan
        self.last_displacement_um = math.nan
        self._heartbeat = math.nan
        self._watchdog_tripped = False
        self._at_safe = False
        self.fault_counts: collections.Counter[str] = collections.Counter()
        self.watch: ModelWatch | None = None       # the model-fit monitor's part, built with the run's columns

    # ---- construction helpers ------------------------------------------------------------
    @staticmethod
    def _make_monitor(cfg: ControllerConfig) -> safety.SensorMonitor:
        return safety.SensorMonitor(cfg.stress["source"], cfg.rod_area_mm2, tuple(cfg.stress["valid_range_MPa"]),
                                    cfg.sensor["force_limit_N"], cfg.sensor["bad_ticks"], cfg.sensor["stale_ticks"])

    def _make_law(self) -> FeedforwardController:
        """The tick's control law from the current reference, stepper, learner and model range."""
        return FeedforwardController(self.reference, self.stepper, self.learner, (self.drive_lo, self.drive_hi),
                                     self.limits_beyond)

    def _set_drive_range(self, model: Model) -> None:
        lo, hi = model.drive_range
        pad = 0.01 * (hi - lo) if math.isfinite(hi - lo) else 0.0    # rounding at the identified extremes
        self.drive_lo, self.drive_hi = float(lo) - pad, float(hi) + pad

    def _set_stress_range(self, model: Model) -> None:
        rng = model.stress_range_MPa
        self.stress_lo, self.stress_hi = (float(rng[0]), float(rng[1])) if rng is not None else (-math.inf, math.inf)
        self.stress_policy_fault = self.cfg.stress["out_of_range"] == "fault"
        self.fault_table = safety.fault_actions(self.cfg)     # configure time, never per tick
        self._set_drive_range(model)

    # ---- requests from other threads -----------------------------------------------------
    def request_stop(self, reason: str = "stop requested") -> None:
        """Ask the loop to ramp to the safe current and stop (thread-safe, signal-safe)."""
        if self._stop_reason is None:
            self._stop_reason = reason

    def reload(self, new_cfg: ControllerConfig, model: Model | None = None) -> None:
        """Swap model, reference, limits and sensor settings at the next tick, bumplessly.

        Everything is built and validated here, in the caller's thread; on any error the old
        configuration keeps running and the error propagates. Rate, clock, driver, telemetry
        and scheduler changes need a restart and are refused.
        """
        for key in _RESTART_KEYS:
            if getattr(new_cfg, key) != getattr(self.cfg, key):
                raise ConfigError(f"config key '{key}' changed: that needs a restart, not a reload "
                                  f"(the running configuration is kept)")
        if model is None:
            from ..modelio import load_model

            model = load_model(new_cfg.model)
        watched = self.watch.prepare(model, new_cfg.model, new_cfg.monitor) if self.watch is not None else None
        reference = (build_reference(new_cfg.reference, model.preview_s),
                     build_reference({**new_cfg.reference, "lead_s": 0.0}))
        rng = model.stress_range_MPa
        _warm_up(model, self.period_s, *(rng if rng is not None else (-11.3, -11.3)))
        last = self.limiter.last
        stepper = model.inverse_stepper(self.period_s, initial_drive=last)
        monitor = self._make_monitor(new_cfg)
        learner = make_learner(new_cfg, model, reference[0])
        if learner is not None:
            learner.last_event = "reset: configuration reloaded"
        with self._lock:
            self._pending = (new_cfg, model, reference, stepper, monitor, learner, watched)
        if self.state in (State.IDLE, State.STOPPED, State.FAULT):
            self._apply_pending()

    def _apply_pending(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, None
        if pending is None:
            return
        cfg, model, reference, stepper, monitor, learner, watched = pending
        lim = cfg.limits
        last = self.limiter.last
        # Bumpless: the new inverse starts relaxed at the current command; limits keep `last`.
        stepper.reset(last)
        monitor.stress = self.monitor.stress
        monitor.last_raw = self.monitor.last_raw
        self.limiter = safety.Limiter(lim["current_min_A"], lim["current_max_A"], lim["slew_A_per_s"],
                                      self.period_s, last)
        self.safe_A = lim["safe_current_A"]
        self.limits_beyond = lim["beyond_model"]
        self.cfg, self.model, (self.reference, self.reference_now), self.stepper, self.monitor = \
            cfg, model, reference, stepper, monitor
        self.learner = learner
        self._set_stress_range(model)
        self.law = self._make_law()
        if self.watch is not None:
            self.watch.adopt(watched)

    # ---- faults ----------------------------------------------------------------------------
    def _raise_fault(self, name: str, message: str) -> None:
        with self._lock:
            self.active_faults[name] = message
            self.fault_counts[name] += 1
            self.fault_history.append({"fault": name, "message": message, "at_unix_s": time.time(),
                                       "tick": self.stats.count})

    def _clear_fault(self, name: str) -> None:
        with self._lock:
            self.active_faults.pop(name, None)

    def _write_safe(self) -> None:
        """The safe current, at once, outside the limiter. On a failing link keep retrying (with
        a reconnect between tries) for `comms.safe_retry_s` of real time; a final failure is
        recorded as the fault `safe_write_failed`, never raised."""
        retry_s = 0.0 if self.clock.simulated else self.cfg.comms["safe_retry_s"]
        give_up = time.monotonic() + retry_s
        while True:
            try:
                self.driver.safe(self.safe_A)
                self.last_cmd_A = self.safe_A
                self._at_safe = True
                self._clear_fault(safety.SAFE_WRITE_FAILED)
                break
            except Exception as exc:  # the device may be gone; keep trying for a while
                if time.monotonic() >= give_up:
                    self._raise_fault(safety.SAFE_WRITE_FAILED,
                                      f"could not write the safe current: {type(exc).__name__}: {exc}")
                    break
            time.sleep(0.05)
            try:
                self.driver.reconnect()
            except Exception:
                pass
        self.limiter.force(self.safe_A)

    # ---- the loop ----------------------------------------------------------------------------
    def _columns(self) -> list[str]:
        cols = ["time_s", "reference_um", "current_cmd_A", "current_A", "stress_MPa"]
        ch = self.driver.channels
        if DISPLACEMENT in ch:
            cols.append(DISPLACEMENT)
            if self.cfg.monitor["enabled"]:
                cols += WATCH_COLUMNS          # right after the displacement they are about
        if FORCE in ch:
            cols.append(FORCE)
        if self.learner is not None:
            cols.append("correction_um")
        cols.append("outside_model")       # 1: drive beyond the identified range, 2: stress beyond it, 3: both
        return cols

    def _open_driver(self, stop_event: threading.Event) -> bool:
        """Open (configure), retrying with backoff when the policy says reconnect; False when it gave up."""
        try:
            self.driver.open()
            return True
        except DriverError as exc:
            name = safety.COMMS_ERROR if exc.reason != "timeout" else safety.COMMS_TIMEOUT
            self._raise_fault(name, f"cannot open the driver: {exc}")
            if self.fault_table[name].then != "reconnect":
                return False
            return self._reconnect(stop_event)

    def _reconnect(self, stop_event: threading.Event) -> bool:
        """Reconnect with exponential backoff; True when the driver answers again. The amplifier
        is already at its safe current, so the watchdog is paused while waiting."""
        self.state = State.RECONNECTING
        self._heartbeat = math.nan
        comms = self.cfg.comms
        delay = comms["backoff_initial_s"]
        attempt = 0
        while comms["max_attempts"] == 0 or attempt < comms["max_attempts"]:
            attempt += 1
            if self._wait(delay, stop_event):
                return False
            try:
                self.driver.reconnect()
                self.driver.activate()         # safe() may have switched the output off
            except DriverError as exc:
                self.driver.last_error = str(exc)
                delay = min(delay * 2.0, comms["backoff_max_s"])
                continue
            except Exception as exc:
                self._raise_fault(safety.EXCEPTION, f"reconnect raised {type(exc).__name__}: {exc}")
                return False
            self.reconnects += 1
            self._clear_fault(safety.COMMS_ERROR)
            self._clear_fault(safety.COMMS_TIMEOUT)
            return True
        self._raise_fault(safety.RECONNECT_FAILED, f"gave up after {attempt} reconnect attempts")
        return False

    def _wait(self, delay: float, stop_event: threading.Event) -> bool:
        """Sleep `delay` on the controller's clock; True if a stop came meanwhile."""
        if self.clock.simulated:
            self.clock.advance(delay)
        else:
            stop_event.wait(delay)
        return stop_event.is_set() or self._stop_reason is not None

    def run(self, stop_event: threading.Event | None = None, duration_s: float | None = None) -> dict[str, Any]:
        """Blocking fixed-rate loop; the safe current is written on every way out."""
        stop_event = stop_event or threading.Event()
        self.state = State.STARTING
        self._at_safe = False
        self.exit_reason = ""
        self.started_unix_s = time.time()
        watchdog: threading.Thread | None = None
        wd_stop = threading.Event()
        opened = False
        try:
            opened = self._open_driver(stop_event)
            if not opened:
                self.exit_reason = "driver could not be opened"
                return self._finish(opened, None, wd_stop)
            cols = self._columns()
            tcfg = self.cfg.telemetry
            self.telemetry = Telemetry(
                tcfg["path"], cols,
                {"source": "gma-ffc controller", "start_unix_s": self.started_unix_s,
                 "sample_rate_hz": self.cfg.rate_hz, "driver": self.cfg.driver["kind"],
                 "command_lead_s": self.reference.lead_s,
                 "model_kind": self.model.kind, "config": self.cfg.source,
                 "current_A_is": "measured (commanded where a reading is missing)"
                 if CURRENT in self.driver.channels else "commanded"},
                capacity=int(tcfg["buffer_s"] * self.cfg.rate_hz), flush_interval_s=tcfg["flush_interval_s"],
                block_when_full=self.clock.simulated)
            self.watch = ModelWatch(self.cfg.monitor, self.driver.channels, cols, self.period_s)
            self.watch.metadata = self.telemetry.metadata
            self.watch.start(self.model, self.safe_A, initial_play_state(self.stepper, self.model, self.safe_A))
            if not self.clock.simulated and self.cfg.scheduler["realtime_priority"] > 1:
                self.telemetry.realtime_priority = self.cfg.scheduler["realtime_priority"] - 1
            self.telemetry.start()
            if not self.clock.simulated:
                watchdog = threading.Thread(target=self._watchdog, args=(wd_stop,), name="gma-ffc-watchdog",
                                            daemon=True)
                watchdog.start()
            self.driver.activate()        # output on just before the first command, never by a write
            with _realtime(self):
                self._loop(stop_event, duration_s)
        except GmaError as exc:
            self._raise_fault(safety.EXCEPTION if not isinstance(exc, DriverError) else safety.COMMS_ERROR, str(exc))
            self.exit_reason = str(exc)
        except BaseException as exc:  # anything at all: safe current first, then report
            self._raise_fault(safety.EXCEPTION, f"{type(exc).__name__}: {exc}")
            self.exit_reason = f"{type(exc).__name__}: {exc}"
        finally:
            if self.state not in (State.STOPPED, State.FAULT):
                self._finish(opened, watchdog, wd_stop)
        return self._summary()

    def _finish(self, opened: bool, watchdog: threading.Thread | None, wd_stop: threading.Event) -> dict[str, Any]:
        """Safe current and output off (deactivate) first, then stop the watchdog, flush telemetry
        and close the driver."""
        wd_stop.set()
        if opened and not self._at_safe:
            self._write_safe()
        if opened:
            try:
                self.driver.deactivate()
            except Exception as exc:   # after the safe current: the output may still be on, say so
                self._raise_fault(safety.DEACTIVATE_FAILED, f"output not switched off: {type(exc).__name__}: {exc}")
        if watchdog is not None:
            watchdog.join(timeout=2.0)
        self._save_learned()
        if self.telemetry is not None:
            self.telemetry.close()
            if self.telemetry.error:
                self._raise_fault(safety.TELEMETRY, self.telemetry.error)
        try:
            self.driver.close()
        except Exception as exc:
            self._raise_fault(safety.CLOSE_FAILED, f"{type(exc).__name__}: {exc}")
        hard = [f for f in self.active_faults if self._exit_state(f) == "fault"]
        self.state = State.FAULT if hard else State.STOPPED
        return self._summary()

    def _save_learned(self) -> None:
        """Keep what was learned for the next run (`learning.file`, `gma-ffc run --learned`)."""
        path = self.cfg.learning.file
        if self.learner is None or path is None or self.learner.learned_periods == 0:
            return
        try:
            save_learned(self.learner, path)
        except OSError as exc:
            self._raise_fault(safety.LEARNING_SAVE_FAILED, f"could not save the learned correction to {path}: {exc}")

    def _watchdog(self, stop: threading.Event) -> None:
        """Trip when the loop makes no progress for watchdog_s (a hung driver call, a stall)."""
        limit = self.cfg.watchdog_s
        prio = self.cfg.scheduler["realtime_priority"]
        if prio > 1:
            # A normal-priority thread preempted while it holds the GIL would stall an RT loop.
            with contextlib.suppress(OSError, AttributeError):
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio - 1))
        while not stop.wait(limit / 4.0):
            hb = self._heartbeat
            if hb == hb and self.clock.now() - hb > limit and not self._watchdog_tripped:
                self._watchdog_tripped = True
                self._raise_fault(safety.WATCHDOG, f"the loop made no progress for over {limit:g} s")

    def _loop(self, stop_event: threading.Event, duration_s: float | None) -> None:
        clock, stats, inputs, driver = self.clock, self.stats, self.inputs, self.driver
        tel = self.telemetry
        assert tel is not None
        ncols = len(tel.columns)
        row = np.zeros(ncols)
        has_current = CURRENT in driver.channels
        disp_col = tel.columns.index(DISPLACEMENT) if DISPLACEMENT in tel.columns else -1
        watch = self.watch
        assert watch is not None
        force_col = tel.columns.index(FORCE) if FORCE in tel.columns else -1
        self.law = self._make_law()          # configure: the law from what the controller holds now
        sched = Scheduler(clock, self.period_s)
        t0 = sched.start()
        # Wall-clock time of t = 0 (the first deadline), from one reading of both clocks, so a
        # row's unix time is start_unix_s + time_s to well within a millisecond.
        wall, mono = time.time(), clock.now()
        self.started_unix_s = wall - (mono - t0) if not clock.simulated else wall
        tel.metadata["start_unix_s"] = self.started_unix_s
        tel.metadata["unix_time_of_a_row"] = "start_unix_s + time_s"
        mode = RUNNING
        stop_started = 0.0
        end_t = math.inf if duration_s is None else duration_s
        watchdog_s = self.cfg.watchdog_s
        self.state = State.RUNNING
        read_ok = False
        while True:
            deadline = sched.wait()
            t_start = clock.now()
            self._heartbeat = t_start
            t = deadline - t0
            if mode == RUNNING and (t >= end_t or stop_event.is_set() or self._stop_reason is not None):
                self._execute(safety.STOP, t, mode, stop_event,
                              self._stop_reason or ("stop requested" if stop_event.is_set() else "duration reached"))
                mode = STOPPING                # the STOP row ramps
                stop_started = t
            if self._pending is not None:
                self._apply_pending()
            try:
                if self._watchdog_tripped:
                    raise _TickFault(safety.WATCHDOG, self.active_faults.get(safety.WATCHDOG, "watchdog"))
                read_ok = False
                inputs.clear()
                driver.read(inputs)
                read_ok = True
                bad = self.monitor.update(inputs.force_N, inputs.stress_MPa)
                if bad:
                    raise _TickFault(bad, self._sensor_message(bad, inputs))
                stress = self.monitor.stress
                ref_now = self.reference_now.value(t)
                learner = self.learner
                if mode == RUNNING and stress == stress:
                    if stress < self.stress_lo or stress > self.stress_hi:
                        self._stress_out_of_range(stress)
                        if self._execute(safety.STRESS_RANGE, t, mode, stop_event) == RAMP:
                            mode = STOPPING
                            stop_started = t
                    elif self.stress_clamped_ticks and safety.STRESS_RANGE in self.active_faults:
                        self._clear_fault(safety.STRESS_RANGE)
                if mode == RUNNING and stress == stress:
                    u = self.law.update(t, stress)
                    if u != u:
                        raise _TickFault(safety.EXCEPTION, "the inverse model returned NaN")
                    if self.law.beyond:
                        self._outside = 1
                        self._beyond_drive(self.law.raw)
                        if self._execute(safety.DRIVE_RANGE, t, mode, stop_event) == RAMP:
                            mode = STOPPING
                            stop_started = t
                            u = self.safe_A
                    else:
                        self._outside = 0
                    if stress < self.stress_lo or stress > self.stress_hi:
                        self._outside += 2
                else:
                    u = self.safe_A      # stopping, or no good stress yet: head for the safe current
                cmd = self.limiter.apply(u)
                self._at_safe = False
                driver.write(cmd)
                if learner is not None:
                    if mode != RUNNING:
                        learner.observe(t, ref_now, inputs.displacement_um, stress, False, "stopping")
                    elif stress != stress:
                        learner.observe(t, ref_now, inputs.displacement_um, stress, False, "no valid stress yet")
                    elif cmd != u:
                        learner.observe(t, ref_now, inputs.displacement_um, stress, False,
                                        "command limited (ramp, slew or current limit)")
                    else:
                        learner.observe(t, ref_now, inputs.displacement_um, stress, True)
                watch.on_tick(t, inputs.displacement_um, ref_now, cmd, stress, mode == RUNNING)
            except Exception as exc:   # the one fault path: the table says what happens
                name, message, reason = _classify(exc)
                watch.interrupt(self.safe_A, self.monitor.stress)
                if read_ok:   # a tick whose read failed has no data to log
                    self._record_row(row, t_start - t0, ref_or_nan(self), self.limiter.last, inputs, has_current,
                                     disp_col, force_col, tel, safe=True)
                self._raise_fault(name, message)
                if self._execute(name, t, mode, stop_event, reason) == RESUME:
                    sched.next_deadline = clock.now()
                    continue
                return
            self.last_reference_um = ref_now
            self.last_cmd_A = cmd
            self.last_stress_MPa = stress
            self._record_row(row, t_start - t0, ref_now, cmd, inputs, has_current, disp_col, force_col, tel)
            compute = clock.now() - t_start
            stats.record(t_start, compute)
            stats.overruns = sched.overruns
            stats.missed = sched.missed
            if compute > watchdog_s:
                self._raise_fault(safety.WATCHDOG, f"a tick took {compute:.3f} s (watchdog {watchdog_s:g} s)")
                if self._execute(safety.WATCHDOG, t, mode, stop_event, "watchdog") != RESUME:
                    return
            if mode == STOPPING and (cmd == self.safe_A or t - stop_started >= self.cfg.limits["stop_ramp_max_s"]):
                return

    def _execute(self, name: str, t: float, mode: int, stop_event: threading.Event, reason: str | None = None) -> int:
        """Execute the fault table's row for `name` (already raised, or a stop request); returns
        FLAGGED (the tick goes on), RAMP (the loop heads for the safe current within the slew
        limit), RESUME (reconnected: next tick) or EXIT. `reason` (default: the fault's message)
        becomes the exit reason when the row stops the run. Only ever called on a fault."""
        action = self.fault_table[name]
        if action.output == "none":
            return FLAGGED
        if reason is None:
            reason = self.active_faults.get(name, name)
        if action.output == "ramp":      # the stopping ticks observe with ok=False: learning frozen
            self.exit_reason = reason
            self.state = State.STOPPING
            return RAMP
        # immediate. Fault handling is bounded (comms timeouts, safe_retry_s, the reconnect
        # policy): the watchdog, which guards against a loop that hangs, pauses until the next tick.
        self._heartbeat = math.nan
        self._write_safe()
        reconnect = action.then == "reconnect" and mode == RUNNING
        if action.freeze_learning and self.learner is not None:
            self.learner.freeze(t, f"{name}: at the safe current" + (", reconnecting" if reconnect else ""))
        if reconnect and self._reconnect(stop_event):
            start_stepper(self.stepper, self.model, self.safe_A)
            self.monitor.bad_run = 0
            self.monitor.stale_run = 0
            self.state = State.RUNNING
            return RESUME
        self.exit_reason = reason
        return EXIT

    def _exit_state(self, name: str) -> str:
        """The state a run ending with fault `name` active ends in (unknown names: fault)."""
        action = self.fault_table.get(name)
        if action is not None:
            return action.exit_state
        return "stopped" if name in safety.WARNINGS else "fault"

    def _record_row(self, row: np.ndarray, t: float, ref: float, cmd: float, inputs: Inputs, has_current: bool,
                    disp_col: int, force_col: int, tel: Telemetry, safe: bool = False) -> None:
        """One telemetry row; on a fault tick the command recorded is the safe current."""
        if safe:
            cmd = self.safe_A
        row[0] = t
        row[1] = ref
        row[2] = cmd
        meas = inputs.current_A
        row[3] = meas if has_current and meas == meas else cmd   # commanded where unmeasured
        row[4] = self.monitor.stress
        if disp_col >= 0:
            row[disp_col] = inputs.displacement_um
            if self.watch is not None and self.watch.enabled:
                row[disp_col + 1] = self.watch.predicted_um
                row[disp_col + 2] = self.watch.residual_um
        if force_col >= 0:
            row[force_col] = inputs.force_N
        if self.learner is not None:
            row[-2] = 0.0 if safe else self.law.correction
        row[-1] = self._outside
        self.last_current_A = row[3]
        self.last_displacement_um = inputs.displacement_um
        tel.push(row)
        if self.watch is not None:
            self.watch.push(row)

    def _beyond_drive(self, u: float) -> None:
        """Flag a command outside the model's identified drive range (the law clamps it if configured)."""
        self.drive_outside_ticks += 1
        if safety.DRIVE_RANGE not in self.active_faults:
            verb = {"warn": "commanded anyway (limits.beyond_model: warn)",
                    "clamp": "clamped to the identified range (limits.beyond_model: clamp)",
                    "fault": "fault (limits.beyond_model: fault)"}[self.limits_beyond]
            self._raise_fault(safety.DRIVE_RANGE, f"the inverse asks for {u:.4g} outside the drive range the model "
                                                  f"was identified on [{self.drive_lo:.4g}, {self.drive_hi:.4g}]: {verb}")

    def _stress_out_of_range(self, stress: float) -> None:
        self.stress_clamped_ticks += 1
        if safety.STRESS_RANGE not in self.active_faults:
            verb = "fault (stress.out_of_range: fault)" if self.stress_policy_fault else "clamped to the model's range"
            self._raise_fault(safety.STRESS_RANGE, f"stress {stress:.2f} MPa outside the model's range "
                                                   f"[{self.stress_lo:.2f}, {self.stress_hi:.2f}] MPa: {verb}")

    def _sensor_message(self, bad: str, inputs: Inputs) -> str:
        n = self.monitor.stale_ticks if bad == safety.SENSOR_STALE else self.monitor.bad_ticks
        what = {safety.SENSOR_NAN: "missing or NaN", safety.SENSOR_ABSURD: "absurd (outside the plausible range)",
                safety.SENSOR_STALE: "stuck (unchanged)"}[bad]
        raw = inputs.force_N if self.monitor.source_force else inputs.stress_MPa
        return f"load-cell reading {what} for {n} ticks (last value {raw!r})"

    # ---- reporting -----------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """Thread-safe snapshot for the service, the CLI and tests."""
        s = self.stats.summary()
        with self._lock:
            faults = dict(self.active_faults)
            history = list(self.fault_history)
        tel = self.telemetry
        return {
            "state": self.state.value,
            "target_rate_hz": self.cfg.rate_hz,
            **s,
            "stress_MPa": _finite(self.last_stress_MPa),
            "current_cmd_A": _finite(self.last_cmd_A),
            "current_A": _finite(self.last_current_A),
            "reference_um": _finite(self.last_reference_um),
            "displacement_um": _finite(self.last_displacement_um),
            "faults": sorted(faults),
            "fault_messages": faults,
            "fault_counts": dict(self.fault_counts),
            "fault_history": history,
            "stress_clamped_ticks": self.stress_clamped_ticks,
            "outside_model": {"drive_ticks": self.drive_outside_ticks, "stress_ticks": self.stress_clamped_ticks,
                              "policy": self.limits_beyond,
                              "drive_range": [_finite(self.drive_lo), _finite(self.drive_hi)]},
            "reconnects": self.reconnects,
            "exit_reason": self.exit_reason,
            "started_unix_s": self.started_unix_s,
            "model_kind": self.model.kind,
            "initial_state": self.initial_state,
            "learning": {"enabled": False} if self.learner is None else self.learner.status(),
            **({} if self.watch is None else {"monitor": self.watch.status()}),
            "driver": self.driver.health(),
            "telemetry": None if tel is None else {"path": str(tel.path) if tel.path else None,
                                                   "rows": tel.head, "rows_written": tel.rows_written,
                                                   "dropped": tel.dropped},
        }

    def model_window(self, seconds: float) -> tuple[Any, Model]:
        """The last `seconds` of telemetry as a recording, and the model running now (for the
        service's background diagnosis; off the loop)."""
        if self.watch is None:
            raise GmaError("the controller has not started: there is no telemetry to take")
        return self.watch.window(seconds)

    def _summary(self) -> dict[str, Any]:
        snap = self.status()
        snap["ok"] = snap["state"] != "fault"
        return snap


@contextlib.contextmanager
def _realtime(ctrl: Controller) -> Iterator[None]:
    """Real clock only: a short GIL switch interval (the loop gets the GIL back quickly from the
    telemetry and service threads), garbage collector frozen (no long collections of start-up
    objects), and SCHED_FIFO for the loop thread when configured. All restored afterwards."""
    if ctrl.clock.simulated:
        yield
        return
    sched = ctrl.cfg.scheduler
    old_interval = sys.getswitchinterval()
    sys.setswitchinterval(min(old_interval, sched["gil_switch_interval_us"] * 1e-6))
    gc.collect()
    gc.freeze()
    prio = sched["realtime_priority"]
    old_policy = None
    if prio > 0:
        try:
            old_policy = (os.sched_getscheduler(0), os.sched_getparam(0))
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
        except (OSError, AttributeError) as exc:
            old_policy = None
            ctrl._raise_fault(safety.REALTIME_REFUSED, f"SCHED_FIFO {prio} not permitted ({exc}); running "
                                                          f"with normal scheduling")
    try:
        yield
    finally:
        if old_policy is not None:
            with contextlib.suppress(OSError):
                os.sched_setscheduler(0, old_policy[0], old_policy[1])
        gc.unfreeze()
        sys.setswitchinterval(old_interval)


def _warm_up(model: Model, dt: float, lo: float, hi: float) -> None:
    """Call a throwaway stepper once so JIT compilation / cache loading happens before tick 1."""
    mid = 0.5 * (lo + hi) if math.isfinite(lo) and math.isfinite(hi) else -11.3
    model.inverse_stepper(dt, initial_drive=0.0).step(0.0, mid)


def initial_play_state(stepper: InverseStepper, model: Model, safe_A: float) -> Any:
    """The play state `start_stepper` starts an SDPI/MPI inverse in (None for other steppers):
    the forward prediction starts in the same one."""
    if not isinstance(stepper, SDPIInverseStepper):
        return None
    lo, hi = model.drive_range
    target = 0.5 * (lo + hi) if math.isfinite(lo) and math.isfinite(hi) else safe_A + 1.0
    return model.resolve_initial_state(np.array([safe_A, target if target != safe_A else safe_A + 1.0])).play_state


def start_stepper(stepper: InverseStepper, model: Model, safe_A: float) -> str:
    """Put the inverse stepper in the shared default start (`gma_ffc.initial_state`): the loop
    starts at the safe current and its drive first moves towards the middle of the identified
    range, so the plays start consistent with that first monotone stretch. Returns how."""
    if not isinstance(stepper, SDPIInverseStepper):       # only the SDPI/MPI stepper takes a play state
        stepper.reset(safe_A)
        return f"relaxed at the safe current ({safe_A:g}), the {model.kind} model's own start"
    lo, hi = model.drive_range
    target = 0.5 * (lo + hi) if math.isfinite(lo) and math.isfinite(hi) else safe_A + 1.0
    start = model.resolve_initial_state(np.array([safe_A, target if target != safe_A else safe_A + 1.0]))
    stepper.reset(safe_A, start.play_state)
    return f"{start.how.split(';')[0]}, from the safe current {safe_A:g}"


def make_learner(cfg: ControllerConfig, model: Model, reference: Reference) -> RepetitiveLearner | None:
    """The repetitive learner the config asks for (None when learning is off), with the saved
    correction of an earlier run when `learning.file` holds one learned for this model."""
    lc = cfg.learning
    if not lc.enabled:
        return None
    period = lc.period_s or reference_period_s(cfg.reference) or getattr(reference, "duration", None)
    if not period:
        raise ConfigError("config key 'learning.period_s' is required: the reference is not periodic")
    learner = RepetitiveLearner(lc, cfg.rate_hz, period, model_gain_table(model), model_fingerprint(model))
    if lc.file is not None and os.path.exists(lc.file):
        from ..yamlfile import read_yaml

        learner.load_dict(read_yaml(lc.file, "learned-correction file", ConfigError), lc.file)
    return learner


def model_fingerprint(model: Model) -> str:
    """A short hash of the model's data: a learned correction belongs to the model it was learned through."""
    import hashlib
    import json

    return hashlib.sha256(json.dumps(model.to_dict(), sort_keys=True, default=str).encode()).hexdigest()[:16]


def save_learned(learner: RepetitiveLearner, path: str) -> None:
    import yaml

    from ..atomic import atomic_write

    with atomic_write(path) as fh:
        fh.write("# gma-ffc learned feedforward correction: loaded by `gma-ffc run --learned FILE`\n")
        yaml.safe_dump(learner.to_dict(), fh, sort_keys=False)


def _classify(exc: Exception) -> tuple[str, str, str]:
    """A tick's exception as (fault name, fault message, exit reason)."""
    if isinstance(exc, _TickFault):
        return exc.name, str(exc), str(exc)
    if isinstance(exc, DriverError):
        return (safety.COMMS_TIMEOUT if exc.reason == "timeout" else safety.COMMS_ERROR), str(exc), str(exc)
    message = f"{type(exc).__name__}: {exc}"
    return safety.EXCEPTION, message, f"exception in the tick: {message}"


def ref_or_nan(ctrl: Controller) -> float:
    return ctrl.last_reference_um


def _finite(x: float) -> float | None:
    return x if x == x and not math.isinf(x) else None
