"""How far a model reaches: a full sweep of its drive range (the drive the controller's reach check,
`invert`'s and the learner's gain table all put through the model, so they measure one thing), and
the largest displacement that sweep gives."""

from __future__ import annotations

import math

import numpy as np

from .protocols import Model

# A reference this many times the largest displacement the model gives over its identified drive range
# is nothing the actuator can follow, and most likely a unit slip (nanometres typed as micrometres are
# 1000x); the controller ran one with every tick at a current limit and exit 0, and `invert` wrote a
# drive of 174-1570 A for one 500x the reach. A reference a little past the stroke is extrapolation:
# the controller's limits.beyond_model and invert's warning handle that.
REFERENCE_BEYOND_REACH_FACTOR = 10.0
SWEEP_POINTS = 200      # each way: the loop's two branches at 0.5 % of the drive range a step


def full_range_sweep(model: Model) -> tuple[np.ndarray, np.ndarray] | None:
    """Times and drive of a 1 s sweep up the model's drive range and back; None when the range is not finite.

    1 s: an extended model's effects are functions of time (a lag, heating), and at 1 Hz they leave
    the stroke as the quasi-static core gives it; the plain model ignores the times."""
    lo, hi = (float(v) for v in model.drive_range)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return None
    sweep = np.concatenate([np.linspace(lo, hi, SWEEP_POINTS), np.linspace(hi, lo, SWEEP_POINTS)])
    return np.arange(sweep.size) * (1.0 / sweep.size), sweep


def model_reach_um(model: Model) -> float:
    """The largest |displacement| of a full sweep of the model's drive range, at each end of its
    stresses; NaN when the range is not finite."""
    drive = full_range_sweep(model)
    if drive is None:
        return math.nan
    stresses = [None] if model.stress_range_MPa is None else [float(s) for s in model.stress_range_MPa]
    return max(float(np.max(np.abs(model.simulate(*drive, s)))) for s in stresses)


def reach_exceeded(model: Model, peak_um: float) -> float | None:
    """The model's reach (`model_reach_um`) when a reference peaking at |peak_um| is over
    REFERENCE_BEYOND_REACH_FACTOR times it; None when it is not (or the reach is unknown)."""
    reach = model_reach_um(model)
    if not (math.isfinite(reach) and reach > 0.0) or abs(peak_um) <= REFERENCE_BEYOND_REACH_FACTOR * reach:
        return None
    return reach
