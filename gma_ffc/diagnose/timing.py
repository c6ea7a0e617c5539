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

from ..drive import loop_frequency_hz
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


@dataclass(frozen=True)
class _Shift:
    """The shift of the model that fits a recording best: k samples (> 0: the measurement ahead)."""
    k: int
    share: float          # of the unshifted residual's mean square that the shift removes
    beyond_other: float   # of what the best shift the other way (or none) leaves, that it removes

    @property
    def clear(self) -> bool:
        return abs(self.k) >= LEAD_MIN_SAMPLES and min(self.share, self.beyond_other) >= LEAD_SHARE


def displacement_lead(data: Sequence[RecData], predictions: Sequence[np.ndarray]) -> Lead | None:
    """The recording whose displacement leads the model's prediction the most clearly, or None.

    For each shift k of up to LEAD_MAX_S, the mean square of y[t] - p[t + k] over the same scored
    samples; k > 0 (the measurement ahead) by LEAD_MIN_SAMPLES or more that removes LEAD_SHARE of
    the unshifted residual, and of the best lag's, is a lead. It is not a column fault where a
    recording with a faster drive clearly lags (`_lag_grows_with_rate`)."""
    shifts = [(d, _best_shift(d, np.asarray(p, dtype=float))) for d, p in zip(data, predictions)]
    clear = [(d, sh) for d, sh in shifts if sh is not None and sh.clear]
    leads = [(d, sh) for d, sh in clear if sh.k > 0]
    if not leads:
        return None
    lag_rates = [loop_frequency_hz(d.t, d.u) for d, sh in clear if sh.k < 0]
    if lag_rates:
        leads = [(d, sh) for d, sh in leads if not _lag_grows_with_rate(loop_frequency_hz(d.t, d.u), lag_rates)]
    if not leads:
        return None
    d, sh = max(leads, key=lambda pair: pair[1].share)
    return Lead(d.name, sh.k * d.dt_med, sh.share)


def _lag_grows_with_rate(rate: float, lag_rates: Sequence[float]) -> bool:
    """Whether a faster drive than `rate` clearly lags the model. A lag that grows with the drive rate
    (eddy currents, a delay) is read as loop width by an identification at one rate: recordings
    slower than the loops then lead the model, faster ones lag it (hil_sim's eddy currents and 1 ms
    delay, identified at 3 Hz: 1 Hz 1.9 ms ahead, 10-50 Hz 0.8-1 ms behind). A late drive column
    shifts every recording the same way, so a lead beside faster lags is not one. Rates are loops a
    second (`drive.loop_frequency_hz`); a NaN one (fewer than two turns) is neither faster nor slower."""
    return any(r > rate for r in lag_rates)


def _best_shift(d: RecData, p: np.ndarray) -> _Shift | None:
    """The best shift of `p` against d.y over the same scored samples for every shift, or None when
    the recording is too short to shift."""
    y = np.asarray(d.y, dtype=float)
    start = int(d.settled)
    k_max = int(min(round(LEAD_MAX_S / d.dt_med), (y.size - start) // 10))
    if k_max < LEAD_MIN_SAMPLES:
        return None
    lo, hi = start + k_max, y.size - k_max          # the same samples for every shift
    target = y[lo:hi]
    mse = np.array([float(np.mean((target - p[lo + k: hi + k]) ** 2)) for k in range(-k_max, k_max + 1)])
    i = int(np.argmin(mse))
    base = mse[k_max]
    if base <= 0:
        return None
    other = mse[:k_max + 1] if i > k_max else mse[k_max:]   # the other side's shifts, and none
    return _Shift(i - k_max, 1.0 - float(mse[i]) / base, 1.0 - float(mse[i]) / max(float(other.min()), 1e-300))
