"""The model's prediction beside the command: what each displacement reading should have been.

A driver's `read` comes before its `write` in a tick, so the displacement read at tick k answers
the drives written up to tick k-1. The model's forward stepper takes each drive actually written
(limits, slew and any learned correction included: what the amplifier was told) with the stress
read, and `next_um` is the displacement the next reading should show. The residual of that
reading is `measured - next_um`.

This runs off the loop, on blocks of telemetry rows (`predict_block`, in the telemetry writer's
thread): the loop only packs its row. An SDPI core steps a block in one compiled call that
releases the GIL (`operators.forward_batch`); other models step row by row.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .. import operators as ops
from ..model import ForwardStepper as SDPIForwardStepper
from ..protocols import ForwardStepper, Model

# Bits of the telemetry ring's hidden flags column (never written to the file).
FAULTED = 1     # the tick ended on the fault path: the amplifier got the safe current, the reading is not judged
RAMPING = 2     # the command ramped to or from the safe current: stepped, the reading not judged


class Prediction:
    """The forward model stepped with the drives written; `next_um` is the prediction for the next reading."""

    __slots__ = ("stepper", "next_um", "last_t")

    def __init__(self, model: Model, period_s: float, drive: float, play_state: Any = None) -> None:
        self.stepper: ForwardStepper = model.forward_stepper(period_s, initial_drive=drive)
        self.next_um = math.nan
        self.last_t = -math.inf          # the time of the last judged (not faulted) row
        self.start(drive, play_state)

    def start(self, drive: float, play_state: Any = None) -> None:
        """Back to the state the loop starts its inverse in: the play state given (an SDPI/MPI core
        takes one), else the model's own relaxed start at `drive`. No prediction until a write."""
        if play_state is not None:
            self.stepper.reset(drive, play_state)        # type: ignore[call-arg]
        else:
            self.stepper.reset(drive)
        self.next_um = math.nan
        self.last_t = -math.inf

    def run(self, drive: np.ndarray, stress_MPa: np.ndarray) -> np.ndarray:
        """The outputs after each of these writes (all finite), the state moved past them."""
        out = np.empty(drive.size)
        stepper = self.stepper
        if type(stepper) is SDPIForwardStepper:
            ops.forward_batch(np.ascontiguousarray(drive), np.ascontiguousarray(stress_MPa), stepper._p,
                              stepper._state, out)
            out *= stepper._sign
        else:
            for k, (u, s) in enumerate(zip(drive.tolist(), stress_MPa.tolist())):
                out[k] = stepper.step(u, s)
        if out.size:
            self.next_um = float(out[-1])
        return out


def predict_block(prediction: Prediction, t: np.ndarray, drive: np.ndarray, stress: np.ndarray,
                  flags: np.ndarray, gap_s: float) -> np.ndarray:
    """Each row's prediction of its own reading (NaN where it is not judged), the state moved past
    the block. Row by row this is:

        if faulted: step with the drive (the safe current) if the stress is valid; forget
        else:       forget if over `gap_s` passed since the last judged row;
                    predicted = next_um; then step (stress valid) or forget (stress invalid)
    """
    n = t.size
    faulted = (flags.astype(np.int64) & FAULTED) != 0
    stepped = np.isfinite(stress) & np.isfinite(drive)
    after = np.full(n, math.nan)              # the prediction each row leaves for the next one
    carried = prediction.next_um
    idx = np.flatnonzero(stepped)
    if idx.size:
        after[idx] = prediction.run(drive[idx], stress[idx])
    after[faulted] = math.nan
    predicted = np.empty(n)
    if n:
        predicted[0] = carried
        predicted[1:] = after[:-1]
        judged_t = np.where(faulted, -math.inf, t)
        since = np.maximum.accumulate(np.concatenate([[prediction.last_t], judged_t]))
        predicted[(t - since[:-1]) > gap_s] = math.nan      # after a gap in the ticks: not judged
        predicted[faulted] = math.nan
        prediction.last_t = float(since[-1])
        prediction.next_um = float(after[-1])
    return predicted
