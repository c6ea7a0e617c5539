"""Current tracking: does the amplifier's measured current follow the command?

An amplifier switched off or tripped by another program, a broken coil wire, or an amplifier at
its own current limit carries nothing (or less) while the controller goes on writing commands.
Where the driver reads the coil current, `CurrentTracker` compares it, each tick, with the
*expected* current: the command passed through a first-order lag standing for the amplifier's
current loop (`current_tracking.lag_s`). A measured current further than `tolerance_A` from the
expected one (or missing: NaN) for `hold_s` is the fault `current_not_following`; its row in the
fault table writes the safe current at once and stops the run.

The comparison is lag-aware, so a slew-limited step or a fast reference does not depart: the
expected current lags the command as the amplifier does. The tick reads before it writes, so the
reading of tick k is compared with the expected current after the command of tick k-1.

    tracker = CurrentTracker(tolerance_A=0.3, lag_s=1.6e-4, hold_s=0.05, period_s=1e-3)
    fault = tracker.update(measured_A, last_command_A)     # '' or CURRENT_NOT_FOLLOWING
    if fault: raise TickFault(fault, tracker.message())     # the message is built only then

`update` is on the hot path: floats only, no allocation kept, nothing logged.
"""

from __future__ import annotations

import math
from typing import Any

from .safety import CURRENT_NOT_FOLLOWING

MIN_HOLD_TICKS = 2      # one late or glitched reading never trips it alone


def hold_ticks(hold_s: float, period_s: float) -> int:
    """Consecutive departing ticks that trip the fault: a departure lasting `hold_s` or longer
    trips, a shorter one never (at least MIN_HOLD_TICKS)."""
    return max(MIN_HOLD_TICKS, int(math.ceil(hold_s / period_s - 1e-9)))


class CurrentTracker:
    """The expected current (the command through a first-order lag) against the measured one.

    `tolerance_A` None switches it off (`enabled` False: `update` is never called). The expected
    current starts at the first reading after a start or a reconnect (`restart`): the lag starts
    from where the amplifier is, not from where it should be.
    """

    __slots__ = ("tolerance", "lag_s", "hold_s", "period_s", "alpha", "hold_ticks", "enabled", "expected",
                 "run", "measured", "command")

    def __init__(self, tolerance_A: float | None, lag_s: float, hold_s: float, period_s: float) -> None:
        self.enabled = tolerance_A is not None
        self.tolerance = math.inf if tolerance_A is None else float(tolerance_A)
        self.lag_s = float(lag_s)
        self.hold_s = float(hold_s)
        self.period_s = float(period_s)
        # exact for a command held over the period (a zero-order hold into a first-order lag)
        self.alpha = 1.0 if self.lag_s <= 0.0 else -math.expm1(-self.period_s / self.lag_s)
        self.hold_ticks = hold_ticks(self.hold_s, self.period_s)
        self.expected = math.nan
        self.run = 0                    # consecutive ticks departing
        self.measured = math.nan        # the last departing tick's reading and the command behind it
        self.command = math.nan

    def update(self, measured_A: float, command_A: float) -> str:
        """One tick's reading against the command the amplifier held since the last one; returns
        '' or CURRENT_NOT_FOLLOWING when the departure has lasted `hold_ticks` ticks."""
        e = self.expected
        if e != e:                      # first reading: the lag starts where the amplifier is
            e = measured_A if measured_A == measured_A else command_A
        else:
            e += (command_A - e) * self.alpha
        self.expected = e
        if abs(measured_A - e) <= self.tolerance:      # NaN compares False: a missing reading departs
            self.run = 0
            return ""
        self.run += 1
        self.measured = measured_A
        self.command = command_A
        return CURRENT_NOT_FOLLOWING if self.run >= self.hold_ticks else ""

    def restart(self) -> None:
        """After a start or a reconnect: the amplifier was put at the safe current outside the loop."""
        self.expected = math.nan
        self.run = 0

    def continue_from(self, other: CurrentTracker) -> None:
        """A reload: the amplifier's current did not change; the lag goes on from where it was."""
        self.expected = other.expected
        self.run = other.run

    def message(self) -> str:
        """The fault's message (the fault path only: it allocates)."""
        held = f"{self.run} ticks ({self.run * self.period_s:.3g} s; current_tracking.hold_s {self.hold_s:g} s)"
        if self.measured != self.measured:
            what = f"the amplifier's measured current was missing (NaN) for {held}, while {self.expected:.4g} A was expected"
        else:
            what = (f"the amplifier's measured current {self.measured:.4g} A departed from the expected "
                    f"{self.expected:.4g} A by {abs(self.measured - self.expected):.4g} A, more than "
                    f"current_tracking.tolerance_A ({self.tolerance:g} A), for {held}")
        return (f"{what} (commanded {self.command:.4g} A, expected through current_tracking.lag_s "
                f"{self.lag_s * 1e3:.3g} ms). Check that the amplifier is enabled and not tripped, that the coil "
                "is wired (a broken wire carries nothing) and that the amplifier is not at its own current limit; "
                "if its current loop is slower, set current_tracking.lag_s to its time constant (or raise "
                "current_tracking.tolerance_A)")

    def status(self, reads_current: bool) -> dict[str, Any]:
        """What the status says of it: on, or off and why."""
        if not self.enabled:
            return {"enabled": False, "why": "current_tracking.tolerance_A is null"}
        if not reads_current:
            return {"enabled": False, "why": "the driver reads no current"}
        return {"enabled": True, "tolerance_A": self.tolerance, "lag_s": self.lag_s, "hold_s": self.hold_s}
