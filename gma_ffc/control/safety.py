"""Safety: current and slew limits, sensor plausibility, and the fault vocabulary.

The fault vocabulary is a table of data, `FAULT_ACTIONS`: fault name -> `FaultAction`, which the
runner (`manager.ControllerManager`) executes on its one fault path. A row says

* `output` - how the output goes safe: "immediate" (the safe current written in one step,
  ignoring the slew limit: the loop can no longer be trusted, or the device is not answering),
  "ramp" (the loop is healthy: the command goes to the safe current within the slew limit, for
  at most `limits.stop_ramp_max_s`, then the safe current is written) or "none" (keep running,
  the fault is a flag in the status and telemetry);
* `then` - what follows: "stop", "reconnect" (with backoff, per `comms`) or "continue";
* `freeze_learning` - whether the repetitive learner learns nothing from the current period;
* `exit_state` - the state the run ends in when this fault ends it: "fault" or "stopped".

Three rows depend on the config (`stress.out_of_range`, `limits.beyond_model`, `comms.on_fault`);
`fault_actions(cfg)` resolves them once, at configure (and reload) time, into the runner's table.
`FAULT_ACTIONS` holds the defaults. `EXIT_FAULTS` are raised on the way out (after the safe
current is written) and end the run in "fault"; `WARNINGS` never do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Mapping

# Fault names (status and telemetry metadata use these words).
COMMS_TIMEOUT = "comms_timeout"
COMMS_ERROR = "comms_error"
REGISTER_REFUSED = "register_refused"   # the device has no such register/function: a config fact, no reconnect
EXCEPTION = "exception"
WATCHDOG = "watchdog"
SENSOR_NAN = "sensor_nan"          # NaN or missing
SENSOR_ABSURD = "sensor_absurd"    # outside the plausible range
SENSOR_STALE = "sensor_stale"      # unchanged for stale_ticks ticks
# the amplifier's measured current left the command (through its lag) for current_tracking.hold_s:
# switched off or tripped, a broken coil wire, or at its own current limit (control/current_tracking.py)
CURRENT_NOT_FOLLOWING = "current_not_following"
STRESS_RANGE = "stress_out_of_model_range"
DRIVE_RANGE = "drive_out_of_model_range"   # the inverse asks for a drive the model was not identified on
STOP = "stop_requested"

# Raised on the way out, at lifecycle edges, after the safe current was written (or tried).
SAFE_WRITE_FAILED = "safe_write_failed"
RECONNECT_FAILED = "reconnect_failed"
DEACTIVATE_FAILED = "deactivate_failed"
CLOSE_FAILED = "close_failed"
TELEMETRY = "telemetry"
LEARNING_SAVE_FAILED = "learning_save_failed"
EXIT_FAULTS = frozenset({SAFE_WRITE_FAILED, RECONNECT_FAILED, DEACTIVATE_FAILED, CLOSE_FAILED, TELEMETRY,
                         LEARNING_SAVE_FAILED})
REALTIME_REFUSED = "realtime_priority_refused"
WARNINGS = frozenset({REALTIME_REFUSED})      # reported, never a fault exit

OUTPUTS = ("immediate", "ramp", "none")
THENS = ("stop", "reconnect", "continue")
EXIT_STATES = ("fault", "stopped")


@dataclass(frozen=True)
class FaultAction:
    """What the runner does on a fault (see the module docstring)."""

    output: str            # "immediate" | "ramp" | "none"
    then: str              # "stop" | "reconnect" | "continue"
    freeze_learning: bool
    exit_state: str        # "fault" | "stopped"

    def __post_init__(self) -> None:
        ok = self.output in OUTPUTS and self.then in THENS and self.exit_state in EXIT_STATES and {
            "immediate": self.then in ("stop", "reconnect"),
            "ramp": self.then == "stop" and self.freeze_learning,   # stopping ticks teach nothing
            "none": self.then == "continue"}[self.output]
        if not ok:
            raise ValueError(f"not a fault action: {self}")


_IMMEDIATE_STOP = FaultAction("immediate", "stop", True, "fault")
_RAMP_FAULT = FaultAction("ramp", "stop", True, "fault")
_FLAG_ONLY = FaultAction("none", "continue", False, "stopped")
_RECONNECT = FaultAction("immediate", "reconnect", True, "fault")

FAULT_ACTIONS: Mapping[str, FaultAction] = MappingProxyType({
    COMMS_TIMEOUT: _RECONNECT,                  # comms.on_fault: reconnect (stop: _IMMEDIATE_STOP)
    COMMS_ERROR: _RECONNECT,
    REGISTER_REFUSED: _IMMEDIATE_STOP,          # reconnecting cannot add a register: 10 reconnects said so
    EXCEPTION: _IMMEDIATE_STOP,
    WATCHDOG: _IMMEDIATE_STOP,
    SENSOR_NAN: _IMMEDIATE_STOP,
    SENSOR_ABSURD: _IMMEDIATE_STOP,
    SENSOR_STALE: _IMMEDIATE_STOP,
    CURRENT_NOT_FOLLOWING: _IMMEDIATE_STOP,     # no command reaches the coil: ramping it is pointless, and an
                                                # amplifier switched back on must find the safe current waiting
    STRESS_RANGE: _FLAG_ONLY,                   # stress.out_of_range: clamp (fault: _RAMP_FAULT)
    DRIVE_RANGE: _FLAG_ONLY,                    # limits.beyond_model: warn | clamp (fault: _RAMP_FAULT)
    STOP: FaultAction("ramp", "stop", True, "stopped"),   # a stop request, the end of --duration
})

# The config choice that selects each config-dependent row: (section, key) -> {choice: action}.
CONFIGURED: Mapping[str, tuple[str, str, Mapping[str, FaultAction]]] = MappingProxyType({
    COMMS_TIMEOUT: ("comms", "on_fault", {"reconnect": _RECONNECT, "stop": _IMMEDIATE_STOP}),
    COMMS_ERROR: ("comms", "on_fault", {"reconnect": _RECONNECT, "stop": _IMMEDIATE_STOP}),
    STRESS_RANGE: ("stress", "out_of_range", {"clamp": _FLAG_ONLY, "fault": _RAMP_FAULT}),
    DRIVE_RANGE: ("limits", "beyond_model", {"warn": _FLAG_ONLY, "clamp": _FLAG_ONLY, "fault": _RAMP_FAULT}),
})


def fault_actions(cfg: Any) -> dict[str, FaultAction]:
    """The runner's table for this config: `FAULT_ACTIONS` with the config-dependent rows resolved."""
    table = dict(FAULT_ACTIONS)
    for name, (section, key, choices) in CONFIGURED.items():
        table[name] = choices[getattr(cfg, section)[key]]
    return table


# Which limit changed the tick's command (`Limiter.clipped`, `Tick.limited_by`, the learner's
# status). RAMP is the command heading for, or coming from, the safe current rather than following
# the law: set by the runner while it stops, and by the limiter for the slew ramp after a start or
# a reconnect. MODEL_RANGE is the law's clamp to the model's drive range (`limits.beyond_model:
# clamp`). Interned strings: recording one allocates nothing.
NOT_LIMITED = ""
CURRENT_MIN = "current_min"
CURRENT_MAX = "current_max"
SLEW = "slew"
RAMP = "ramp"
MODEL_RANGE = "model_range"
LIMITS = (CURRENT_MIN, CURRENT_MAX, SLEW, RAMP, MODEL_RANGE)


class Limiter:
    """Clamp to [lo, hi] and limit the step per tick to slew*dt; NaN commands hold the last.

    After each `apply`, `clipped` names the limit that changed the command (the last one to
    bind: a target beyond `hi` that the slew limit then holds back is SLEW), or NOT_LIMITED.
    From construction and from `force` (a safe-current write) the command ramps: slew clipping
    counts as RAMP until the first tick it does not clip, or at the latest after the time the
    slew limit needs to cross the whole current range (after that, what clips is the target,
    not the start).
    """

    __slots__ = ("lo", "hi", "max_step", "last", "clipped", "_ramp_ticks", "_max_ramp_ticks")

    def __init__(self, lo: float, hi: float, slew_A_per_s: float, period_s: float, initial: float) -> None:
        self.lo = lo
        self.hi = hi
        self.max_step = slew_A_per_s * period_s
        self.last = min(max(initial, lo), hi)
        self.clipped = NOT_LIMITED
        span = (hi - lo) / self.max_step if self.max_step > 0 else 0.0
        self._max_ramp_ticks = int(math.ceil(span)) if math.isfinite(span) else 0
        self._ramp_ticks = self._max_ramp_ticks

    def apply(self, target: float) -> float:
        clipped = NOT_LIMITED
        if target != target:            # NaN: hold (the caller raises the fault)
            target = self.last
        if target > self.hi:
            target = self.hi
            clipped = CURRENT_MAX
        elif target < self.lo:
            target = self.lo
            clipped = CURRENT_MIN
        step = target - self.last
        if step > self.max_step or step < -self.max_step:
            stepped = self.last + (self.max_step if step > 0 else -self.max_step)
            if stepped != target:       # a step one rounding over max_step lands on the target: not limited
                target = stepped
                clipped = RAMP if self._ramp_ticks > 0 else SLEW
        if clipped != RAMP:
            self._ramp_ticks = 0
        elif self._ramp_ticks > 0:
            self._ramp_ticks -= 1
        # Rounding can put last+max_step a hair outside the box when last sits on a bound; a
        # last outside the box (a reload moved it) is approached within the slew limit instead.
        if target > self.hi and self.last <= self.hi:
            target = self.hi
        elif target < self.lo and self.last >= self.lo:
            target = self.lo
        self.last = target
        self.clipped = clipped
        return target

    def continue_from(self, old: Limiter) -> None:
        """A reload: the amplifier holds `old.last`. Limits that moved past it are approached
        from there within the (new) slew limit, never in a jump; that approach counts as RAMP."""
        self.last = old.last
        outside = max(self.lo - old.last, old.last - self.hi, 0.0)
        steps = outside / self.max_step if self.max_step > 0 else 0.0
        if outside > 0.0 and math.isfinite(steps):
            self._ramp_ticks = self._max_ramp_ticks + int(math.ceil(steps))
        else:
            self._ramp_ticks = old._ramp_ticks

    def force(self, value: float) -> None:
        """The amplifier was put at `value` outside the limiter (a safe-current write); the next
        commands ramp from there."""
        self.last = min(max(value, self.lo), self.hi)
        self._ramp_ticks = self._max_ramp_ticks


class SensorMonitor:
    """Turns raw load-cell readings into a stress, holding the last good one through short glitches.

    A reading is bad when NaN/missing or implausible; `bad_ticks` bad readings in a row raise the
    fault. Plausible is one interval on the raw reading, fixed at configure time: the stress
    range `valid_range`, and for a load cell (source "force") also |F| <= `force_limit_N` when
    set (its rated capacity: it holds whatever rod diameter was configured), so a tick makes
    one comparison pair. A reading unchanged for `stale_ticks` ticks (0 = off) is a stuck sensor.
    """

    __slots__ = ("source_force", "area", "lo", "hi", "force_limit", "raw_lo", "raw_hi", "bad_ticks",
                 "stale_ticks", "bad_run", "stale_run", "last_raw", "stress", "bad_kind")

    def __init__(self, source: str, area_mm2: float, valid_range: tuple[float, float],
                 force_limit_N: float | None, bad_ticks: int, stale_ticks: int) -> None:
        self.source_force = source == "force"
        self.area = area_mm2
        self.lo, self.hi = valid_range
        self.force_limit = math.inf if force_limit_N is None else force_limit_N
        self.raw_lo, self.raw_hi = self.plausible_raw()
        self.bad_ticks = bad_ticks
        self.stale_ticks = stale_ticks
        self.bad_run = 0
        self.stale_run = 0
        self.last_raw = math.nan
        self.stress = math.nan          # last good stress (MPa)
        self.bad_kind = ""

    def plausible_raw(self) -> tuple[float, float]:
        """The plausible interval of the raw reading (N for a load cell: sigma = -F / A)."""
        if not self.source_force:
            return self.lo, self.hi
        return max(-self.hi * self.area, -self.force_limit), min(-self.lo * self.area, self.force_limit)

    def update(self, force_N: float, stress_MPa: float) -> str:
        """Feed one reading; returns '' or the name of the fault that is now due."""
        raw = force_N if self.source_force else stress_MPa
        if raw != raw or math.isinf(raw):
            return self._bad(SENSOR_NAN)
        if raw < self.raw_lo or raw > self.raw_hi:
            return self._bad(SENSOR_ABSURD)
        if self.stale_ticks:
            if raw == self.last_raw:
                self.stale_run += 1
                if self.stale_run >= self.stale_ticks:
                    return SENSOR_STALE
            else:
                self.stale_run = 0
        self.last_raw = raw
        self.bad_run = 0
        self.stress = -raw / self.area if self.source_force else raw
        return ""

    def _bad(self, kind: str) -> str:
        self.bad_run += 1
        self.bad_kind = kind
        return kind if self.bad_run >= self.bad_ticks else ""

    def restart(self) -> None:
        """After a reconnect: the runs of bad and unchanged readings start afresh."""
        self.bad_run = 0
        self.stale_run = 0

    def continue_from(self, other: SensorMonitor) -> None:
        """A reload: keep the last good stress and the stuck-sensor reference of the monitor replaced."""
        self.stress = other.stress
        self.last_raw = other.last_raw

    def message(self, fault: str, raw: float) -> str:
        """The fault's message (the fault path only: it allocates)."""
        n = self.stale_ticks if fault == SENSOR_STALE else self.bad_ticks
        what = {SENSOR_NAN: "missing or NaN", SENSOR_STALE: "stuck (unchanged)",
                SENSOR_ABSURD: f"absurd (outside the plausible {self.raw_lo:.4g} .. {self.raw_hi:.4g} "
                               f"{'N' if self.source_force else 'MPa'})"}[fault]
        text = f"load-cell reading {what} for {n} ticks (last value {raw!r})"
        return text + self._absurd_advice(raw) if fault == SENSOR_ABSURD else text

    def _absurd_advice(self, raw: float) -> str:
        """Where the plausible range comes from, and the sign slip when the reading negated is plausible:
        a load cell reading compression as a negative force (or a transmitter giving compression as a
        positive stress) has every reading outside the range, and the bare numbers did not say why."""
        if self.source_force:
            diameter_mm = 2.0 * math.sqrt(self.area / math.pi)
            words = (f": {raw:.6g} N is {-raw / self.area:.4g} MPa on the {diameter_mm:.4g} mm rod "
                     f"(stress.rod_diameter_mm), against stress.valid_range_MPa [{self.lo:g}, {self.hi:g}]"
                     + ("" if math.isinf(self.force_limit) else f" and sensor.force_limit_N {self.force_limit:g}"))
            flip = (f"{-raw:.6g} N would be plausible: if the load cell reads compression as a negative "
                    "force, negate its scale (stress = -force / rod area)")
            check = "check the load cell's scale and unit (N) and stress.rod_diameter_mm (millimetres)"
        else:
            words = f": stress.valid_range_MPa is [{self.lo:g}, {self.hi:g}]"
            flip = (f"{-raw:.6g} MPa would be plausible: if the transmitter gives compression as a positive "
                    "stress, negate its scale")
            check = "check the transmitter's scale and unit (MPa)"
        if raw != 0.0 and self.raw_lo <= -raw <= self.raw_hi:
            return f"{words}; compression is negative stress, and {flip}"
        return f"{words}; {check}"
