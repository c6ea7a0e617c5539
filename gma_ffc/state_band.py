"""What the drive alone tells of a model's output: the band the unknown initial state leaves.

A recording starts in the middle of a history the file does not show, so each play's output at
the first sample is unknown. This module bounds it and carries the bounds through the model, so
a sample can be scored as soon as the unknown start no longer matters there, rather than only
after the drive has swept the whole loop. Pure maths: no I/O.

The bounds. A history that stayed within the drive range [a, b] leaves a play of threshold r
between a + r and b - r (an invariant of eq. (2): a clamp to [x - r, x + r] with a <= x <= b
keeps it there), and eq. (2) keeps it within r of the first drive value x0. So each play starts
in [lo_i, hi_i] = [clip(x0 - r, a + r, b - r), clip(x0 + r, a + r, b - r)]: the states a drive
that came up to x0 (or down to it) leaves (`initial_state.monotone_play_state`). The range is the
model's, widened to hold the recording's own drive (the rig went there, so its history may have).
A state the run is actually started from (an estimate fitted to the measurement, a relaxed
start) widens the box to hold it too, so the prediction that is scored lies in the band.

Carried through the model, exactly. Each play is order-preserving in its initial value and moves
continuously with it, so from a box of starts it spans the interval between the runs from the
box's two corners; the play weights are >= 0, so the play sum spans the interval between the
corners' sums; and every dead-zone superposition that satisfies Proposition 3.1 rises with the
sum at every stress. So the output band at each sample is the two corner runs' outputs, and both
ends are reached by real histories. A play is determined (its two runs meet exactly) once the
drive has moved monotonically by 2r since the start, or has reached an end of the range; the
band collapses to zero width once every play with a weight is.

The assumption is stated where it is used: the history since the actuator was last demagnetised
or depoled stayed inside the range. A freshly demagnetised actuator starts below the band (its
first rise is a virgin curve); a run started from a state fitted to its measurement then widens
the band by itself.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .initial_state import centred_range, monotone_play_state


@dataclass(frozen=True)
class OutputBand:
    """Per sample, the least and greatest output any admissible initial state gives."""

    lower: np.ndarray
    upper: np.ndarray

    @property
    def width(self) -> np.ndarray:
        return self.upper - self.lower

    def known(self, tolerance: float) -> np.ndarray:
        """Samples where the unknown start moves the output by at most `tolerance` (bool)."""
        return self.width <= max(float(tolerance), 0.0)


def history_range(model: Any, drive: np.ndarray) -> tuple[float, float]:
    """The drive range (about the model's input offset) a history is assumed to have stayed in:
    the model's, widened to hold the recording's drive."""
    x = np.asarray(drive, dtype=float) - float(model.input_offset)
    lo, hi = centred_range(model)
    return min(lo, float(x.min())), max(hi, float(x.max()))


def admissible_corners(model: Any, drive: np.ndarray, also: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """The lowest and highest play states at the first sample (module doc), the box widened to
    hold the state `also` when one is given."""
    x = np.asarray(drive, dtype=float)
    r = np.asarray(model.play_thresholds, dtype=float)
    v0 = float(x[0]) - float(model.input_offset)
    a, b = history_range(model, x)
    low = monotone_play_state(r, v0, 1, a, b)       # came up to x0: every play as low as it can be
    high = monotone_play_state(r, v0, -1, a, b)     # came down to it: as high
    if also is not None:
        s = np.clip(np.asarray(also, dtype=float), v0 - r, v0 + r)   # eq. (2) at the first sample
        low, high = np.minimum(low, s), np.maximum(high, s)
    return low, high


def output_band(model: Any, drive: np.ndarray, stress_MPa: Any = None, also: Any = None) -> OutputBand:
    """The output band of an SDPI/MPI `model` on `drive` over every admissible initial state
    (module doc): the model run from the box's two corners, sample by sample."""
    x = np.ascontiguousarray(drive, dtype=float)
    low, high = admissible_corners(model, x, also)
    y_low = np.asarray(model.simulate(None, x, stress_MPa, initial_play_state=low), dtype=float)
    y_high = np.asarray(model.simulate(None, x, stress_MPa, initial_play_state=high), dtype=float)
    return OutputBand(np.minimum(y_low, y_high), np.maximum(y_low, y_high))
