"""The model's prediction beside the command: what the next displacement reading should be.

A driver's `read` comes before its `write` in a tick, so the displacement read at tick k answers
the drives written up to tick k-1. After each write the model's forward stepper takes the drive
actually written (limits, slew and any learned correction included: what the amplifier was told)
and the stress read, and `next_um` is the displacement the next reading should show. The
residual of that reading is `measured - next_um`.

The forward stepper is the model's own (`Model.forward_stepper`), preallocated; a step allocates
nothing, like the inverse (tests/test_step_allocation.py).
"""

from __future__ import annotations

import math
from typing import Any

from ..protocols import ForwardStepper, Model


class Prediction:
    """`after_write(drive, stress)` steps the model; `next_um` is the prediction for the next tick."""

    __slots__ = ("stepper", "next_um")

    def __init__(self, model: Model, period_s: float, drive: float, play_state: Any = None) -> None:
        self.stepper: ForwardStepper = model.forward_stepper(period_s, initial_drive=drive)
        self.next_um = math.nan
        self.start(drive, play_state)

    def start(self, drive: float, play_state: Any = None) -> None:
        """Back to the state the loop starts its inverse in: the play state given (an SDPI/MPI core
        takes one), else the model's own relaxed start at `drive`. No prediction until a write."""
        if play_state is not None:
            self.stepper.reset(drive, play_state)        # type: ignore[call-arg]
        else:
            self.stepper.reset(drive)
        self.next_um = math.nan

    def after_write(self, drive: float, stress_MPa: float) -> None:
        """The drive just written and the stress it was written under (hot path)."""
        self.next_um = self.stepper.step(drive, stress_MPa)

    def forget(self) -> None:
        """The next reading cannot be predicted (the output went safe outside the loop's writes)."""
        self.next_um = math.nan
