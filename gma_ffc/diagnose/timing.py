"""Does the measured displacement run ahead of the model? Then the columns' timing is wrong, not the physics.

Every effect in the vocabulary (eddy currents, a delay, inertia, creep, heat) makes the
displacement lag its drive. A displacement that leads it has no physical cause: the drive column
is late (a current measured through a filter, or sampled later than the displacement), or the
time columns are misaligned. Such a recording must not be explained by effects, so `diagnose`
looks for a lead before trusting a verdict, and says what to fix. Pure maths: no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .data import RecData

LEAD_MIN_SAMPLES = 2
"""A lead of one sample is within what interpolation and a sample-and-hold leave."""
LEAD_MAX_S = 0.02
"""Longest lead searched: above the group delay of any current sensor's or DAQ's filter (a few ms)."""
LEAD_SHARE = 0.5
"""A lead is reported when shifting the model by it removes at least this share of the residual's
mean square: the timing fault is then most of what is wrong, not a detail of it. It must also remove
this share of what the best lag (or no shift) leaves: on a periodic drive a lag of d and a lead of
one period minus d fit alike (a 100 Hz sine lagging 1.1 ms through a delay and eddy currents was
called 18.9 ms ahead, and the whole diagnosis a column fault)."""


@dataclass(frozen=True)
class Lead:
    recording: str
    lead_s: float
    share_removed: float   # of the base model's residual mean square, over the scored samples

    def words(self) -> str:
        return (f"{self.recording}: the measured displacement runs {self.lead_s * 1e3:.3g} ms ahead of the model "
                f"(shifting the model by that removes {self.share_removed:.0%} of its residual). No physical effect "
                "makes a displacement lead its drive: the drive column is probably late (a current measured "
                "through a filter, or sampled after the displacement) or the time columns are misaligned; align "
                "them and run again")


def displacement_lead(data: Sequence[RecData], predictions: Sequence[np.ndarray]) -> Lead | None:
    """The recording whose displacement leads the model's prediction the most clearly, or None.

    For each shift k of up to LEAD_MAX_S, the mean square of y[t] - p[t + k] over the same scored
    samples; k > 0 (the measurement ahead) by LEAD_MIN_SAMPLES or more that removes LEAD_SHARE of
    the unshifted residual, and of the best lag's, is a lead."""
    best: Lead | None = None
    for d, p in zip(data, predictions):
        y = np.asarray(d.y, dtype=float)
        p = np.asarray(p, dtype=float)
        start = int(d.settled)
        k_max = int(min(round(LEAD_MAX_S / d.dt_med), (y.size - start) // 10))
        if k_max < LEAD_MIN_SAMPLES:
            continue
        lo, hi = start + k_max, y.size - k_max          # the same samples for every shift
        target = y[lo:hi]
        mse = np.array([float(np.mean((target - p[lo + k: hi + k]) ** 2)) for k in range(-k_max, k_max + 1)])
        k = int(np.argmin(mse)) - k_max
        base = mse[k_max]
        if k < LEAD_MIN_SAMPLES or base <= 0:
            continue
        share = 1.0 - float(mse[k + k_max]) / base
        beyond_lags = 1.0 - float(mse[k + k_max]) / max(float(mse[:k_max + 1].min()), 1e-300)
        if share >= LEAD_SHARE and beyond_lags >= LEAD_SHARE and (best is None or share > best.share_removed):
            best = Lead(d.name, k * d.dt_med, share)
    return best
