"""Safety: current and slew limits, sensor plausibility, and the fault vocabulary.

Which faults go to the safe current at once and which ramp there within the slew limit:

* IMMEDIATE (the loop can no longer be trusted, or the device is not answering, so the safe
  current is written in one step, ignoring the slew limit): comms timeout / comms error,
  an exception anywhere in the tick, watchdog expiry, and a bad load-cell reading (NaN,
  missing, absurd or stuck for the configured number of ticks) - the inverse model would be
  fed a wrong stress.
* RAMPED (the loop is healthy; the command goes to the safe current within the slew limit,
  for at most `limits.stop_ramp_max_s`, then the safe current is written): a stop request
  (signal, control socket), the end of `--duration`, and stress outside the model's range
  when `stress.out_of_range: fault`.
"""

from __future__ import annotations

import math

# Fault names (status and telemetry metadata use these words).
COMMS_TIMEOUT = "comms_timeout"
COMMS_ERROR = "comms_error"
EXCEPTION = "exception"
WATCHDOG = "watchdog"
SENSOR_NAN = "sensor_nan"          # NaN or missing
SENSOR_ABSURD = "sensor_absurd"    # outside the plausible range
SENSOR_STALE = "sensor_stale"      # unchanged for stale_ticks ticks
STRESS_RANGE = "stress_out_of_model_range"
DRIVE_RANGE = "drive_out_of_model_range"   # the inverse asks for a drive the model was not identified on
STOP = "stop_requested"

IMMEDIATE = frozenset({COMMS_TIMEOUT, COMMS_ERROR, EXCEPTION, WATCHDOG, SENSOR_NAN, SENSOR_ABSURD, SENSOR_STALE})


class Limiter:
    """Clamp to [lo, hi] and limit the step per tick to slew*dt; NaN commands hold the last."""

    __slots__ = ("lo", "hi", "max_step", "last")

    def __init__(self, lo: float, hi: float, slew_A_per_s: float, period_s: float, initial: float) -> None:
        self.lo = lo
        self.hi = hi
        self.max_step = slew_A_per_s * period_s
        self.last = min(max(initial, lo), hi)

    def apply(self, target: float) -> float:
        if target != target:            # NaN: hold (the caller raises the fault)
            target = self.last
        if target > self.hi:
            target = self.hi
        elif target < self.lo:
            target = self.lo
        step = target - self.last
        if step > self.max_step:
            target = self.last + self.max_step
        elif step < -self.max_step:
            target = self.last - self.max_step
        # Rounding can put last+max_step a hair outside the box when last sits on a bound.
        if target > self.hi:
            target = self.hi
        elif target < self.lo:
            target = self.lo
        self.last = target
        return target

    def force(self, value: float) -> None:
        """The amplifier was put at `value` outside the limiter (a safe-current write)."""
        self.last = min(max(value, self.lo), self.hi)


class SensorMonitor:
    """Turns raw load-cell readings into a stress, holding the last good one through short glitches.

    A reading is bad when NaN/missing, beyond the force limit, or gives a stress outside the
    plausible range; `bad_ticks` bad readings in a row raise the fault. A reading unchanged
    for `stale_ticks` ticks (0 = off) means a stuck sensor.
    """

    __slots__ = ("source_force", "area", "lo", "hi", "force_limit", "bad_ticks", "stale_ticks",
                 "bad_run", "stale_run", "last_raw", "stress", "bad_kind")

    def __init__(self, source: str, area_mm2: float, valid_range: tuple[float, float],
                 force_limit_N: float, bad_ticks: int, stale_ticks: int) -> None:
        self.source_force = source == "force"
        self.area = area_mm2
        self.lo, self.hi = valid_range
        self.force_limit = force_limit_N
        self.bad_ticks = bad_ticks
        self.stale_ticks = stale_ticks
        self.bad_run = 0
        self.stale_run = 0
        self.last_raw = math.nan
        self.stress = math.nan          # last good stress (MPa)
        self.bad_kind = ""

    def update(self, force_N: float, stress_MPa: float) -> str:
        """Feed one reading; returns '' or the name of the fault that is now due."""
        raw = force_N if self.source_force else stress_MPa
        if raw != raw or math.isinf(raw):
            return self._bad(SENSOR_NAN)
        if self.source_force:
            if abs(raw) > self.force_limit:
                return self._bad(SENSOR_ABSURD)
            stress = -raw / self.area
        else:
            stress = raw
        if stress < self.lo or stress > self.hi:
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
        self.stress = stress
        return ""

    def _bad(self, kind: str) -> str:
        self.bad_run += 1
        self.bad_kind = kind
        return kind if self.bad_run >= self.bad_ticks else ""
