"""The state broadcaster: the one place the controller's status is assembled.

On the hot path it keeps the tick's last values and counts the ticks outside the model (a
broadcaster: a few stores per tick). `status()` builds the snapshot the service, the CLI and the
tests read, from any thread: the keys are the controller contract's (docs/ARCHITECTURE.md).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from .tick import OUTSIDE_DRIVE, OUTSIDE_STRESS, Broadcaster, Tick

if TYPE_CHECKING:
    from .faults import FaultLog
    from .hardware import DriverSupervisor
    from .recorder import TelemetryRecorder
    from .scheduler import TickStats
    from .setup import Setup


class StateBroadcaster(Broadcaster):
    """Last values of the run and the status snapshot."""

    def __init__(self, rate_hz: float, stats: TickStats, faults: FaultLog, hardware: DriverSupervisor,
                 recorder: TelemetryRecorder) -> None:
        self.rate_hz = rate_hz
        self.stats, self.faults, self.hardware, self.recorder = stats, faults, hardware, recorder
        self.setup: Setup | None = None
        self.last_reference_um = math.nan
        self.last_cmd_A = math.nan
        self.last_current_A = math.nan
        self.last_stress_MPa = math.nan
        self.last_displacement_um = math.nan
        self.drive_outside_ticks = 0
        self.stress_outside_ticks = 0

    def on_setup(self, setup: Setup) -> None:
        self.setup = setup

    def on_tick(self, tick: Tick) -> None:
        if not tick.faulted:      # a fault tick's command is the safe current, its reference the last good
            self.last_reference_um = tick.reference_um
            self.last_cmd_A = tick.command_A
            self.last_stress_MPa = tick.stress_MPa
        self.last_current_A = tick.current_A
        self.last_displacement_um = tick.inputs.displacement_um
        outside = tick.outside_model
        if outside:
            if outside & OUTSIDE_DRIVE:
                self.drive_outside_ticks += 1
            if outside & OUTSIDE_STRESS:
                self.stress_outside_ticks += 1

    def status(self, state: str, exit_reason: str, started_unix_s: float | None) -> dict[str, Any]:
        """Thread-safe snapshot (the runner passes its own lifecycle: state, exit reason, start)."""
        setup = self.setup
        assert setup is not None, "status before the first setup"
        faults, history = self.faults.snapshot()
        law = setup.law
        return {
            "state": state,
            "target_rate_hz": self.rate_hz,
            **self.stats.summary(),
            "stress_MPa": _finite(self.last_stress_MPa),
            "current_cmd_A": _finite(self.last_cmd_A),
            "current_A": _finite(self.last_current_A),
            "reference_um": _finite(self.last_reference_um),
            "displacement_um": _finite(self.last_displacement_um),
            "faults": sorted(faults),
            "fault_messages": faults,
            "fault_history": history,
            "stress_clamped_ticks": self.stress_outside_ticks,
            "outside_model": {"drive_ticks": self.drive_outside_ticks, "stress_ticks": self.stress_outside_ticks,
                              "policy": law.drive.policy, "drive_range": [_finite(law.lo), _finite(law.hi)]},
            "reconnects": self.hardware.reconnects,
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
