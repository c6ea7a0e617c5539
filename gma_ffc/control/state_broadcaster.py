"""The state broadcaster: the one place the controller's status is assembled.

It reads the loop's state when a status is asked for, from any thread: the last tick's record
(`tick.Tick`, which the loop keeps current), the tick statistics, the faults, the driver's
health and the telemetry's counts. So it costs the loop nothing per tick; the loop only tells
it when a tick was outside the model (`count_outside`, on those ticks alone). The keys are the
controller contract's (docs/ARCHITECTURE.md).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from .tick import OUTSIDE_DRIVE, OUTSIDE_STRESS, Tick

if TYPE_CHECKING:
    from .faults import FaultLog
    from .hardware import DriverSupervisor
    from .recorder import TelemetryRecorder
    from .scheduler import TickStats
    from .setup import Setup


class StateBroadcaster:
    """The status snapshot, from the parts that hold the state."""

    def __init__(self, rate_hz: float, tick: Tick, stats: TickStats, faults: FaultLog,
                 hardware: DriverSupervisor, recorder: TelemetryRecorder) -> None:
        self.rate_hz = rate_hz
        self.tick, self.stats, self.faults, self.hardware, self.recorder = tick, stats, faults, hardware, recorder
        self.drive_outside_ticks = 0
        self.stress_outside_ticks = 0

    def count_outside(self, which: int) -> None:
        """A tick beyond the model's drive range (OUTSIDE_DRIVE) or stress range (OUTSIDE_STRESS)."""
        if which & OUTSIDE_DRIVE:
            self.drive_outside_ticks += 1
        if which & OUTSIDE_STRESS:
            self.stress_outside_ticks += 1

    def status(self, setup: Setup, state: str, exit_reason: str, started_unix_s: float | None,
               reads_current: bool) -> dict[str, Any]:
        """Thread-safe snapshot (the runner passes its setup, its lifecycle: state, exit reason, start, and
        whether the loop reads the coil current: `ControllerManager.reads_current`, its one source)."""
        faults, history = self.faults.snapshot()
        law, tick = setup.law, self.tick
        return {
            "state": state,
            "target_rate_hz": self.rate_hz,
            **self.stats.summary(),
            "stress_MPa": _finite(tick.stress_MPa),
            "current_cmd_A": _finite(tick.command_A),
            "current_A": _finite(tick.current_A),
            "current_measured": bool(tick.current_read),     # False: current_A is the command standing in
            "reference_um": _finite(tick.reference_um),
            "displacement_um": _finite(tick.displacement_um),
            "faults": sorted(faults),
            "fault_messages": faults,
            "fault_counts": self.faults.counted(),
            "fault_history": history,
            "stress_clamped_ticks": self.stress_outside_ticks,
            "outside_model": {"drive_ticks": self.drive_outside_ticks, "stress_ticks": self.stress_outside_ticks,
                              "policy": law.drive.policy, "drive_range": [_finite(law.lo), _finite(law.hi)]},
            "reconnects": self.hardware.reconnects,
            "at_safe_current": self.hardware.at_safe,     # the last write was the safe current
            "safe_current_A": setup.safe_A,
            "current_tracking": setup.tracking.status(reads_current),
            "exit_reason": exit_reason,
            "started_unix_s": started_unix_s,
            "model_kind": setup.model.kind,
            "initial_state": law.initial_state or None,
            "learning": {"enabled": False} if law.learner is None else law.learner.status(),
            "driver": self.hardware.driver.health(),
            "telemetry": self.recorder.status(),
        }


def _finite(x: float) -> float | None:
    return x if x == x and not math.isinf(x) else None
