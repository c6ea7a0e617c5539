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
WIDTH_SLOPE = -0.5
"""Leads at several drive rates: the slope of log(lead) against log(rate). A late column leads every
run by the same time (slope 0); a loop narrower than the model's leads each by the same share of its
period (slope -1: hil_sim's stress-dependent play, 0.1 of a period at 1, 3, 10 and 30 Hz, was called
2.9 ms ahead at 3 Hz). Halfway between decides."""
WIDTH_RATE_SPAN = 3.0
"""The slope is read only over rates this far apart: a lead is known to one sample, so two runs
2 samples ahead and 3 ahead read as a slope of log(1.5) / log(3) = 0.37 at most, short of WIDTH_SLOPE."""


@dataclass(frozen=True)
class Lead:
    recording: str
    lead_s: float
    share_removed: float   # of the base model's residual mean square, over the scored samples
    rates_agree: bool = False   # runs at drive rates WIDTH_RATE_SPAN apart lead by the same time

    def words(self) -> str:
        said = (f"{self.recording}: the measured displacement runs {self.lead_s * 1e3:.3g} ms ahead of the model "
                f"(shifting the model by that removes {self.share_removed:.0%} of its residual). No physical effect "
                "makes a displacement lead its drive: the drive column is probably late (a current measured "
                "through a filter, or sampled after the displacement) or the time columns are misaligned; align "
                "them and run again")
        if self.rates_agree:
            return said
        return (said + ". A loop narrower than the model's also leads, by the same share of each period: a run at "
                "a drive rate three times faster or slower tells the two apart (a late column leads it by the same "
                "time)")


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
    recording with a faster drive clearly lags (`_lag_grows_with_rate`), nor where runs at rates apart
    lead by the same share of a period, not the same time (`WIDTH_SLOPE`)."""
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
    slope = _lead_rate_slope([(loop_frequency_hz(d.t, d.u), sh.k * d.dt_med) for d, sh in leads]) \
        if len(leads) > 1 else None
    if slope is not None and slope < WIDTH_SLOPE:
        return None              # the same share of each period: a loop width, not the columns' timing
    d, sh = max(leads, key=lambda pair: pair[1].share)
    return Lead(d.name, sh.k * d.dt_med, sh.share, rates_agree=slope is not None)


def _lead_rate_slope(rate_leads: Sequence[tuple[float, float]]) -> float | None:
    """The least-squares slope of log(lead) against log(drive rate) over the leading runs, or None
    when their rates (loops a second) do not span WIDTH_RATE_SPAN."""
    pairs = np.array([(r, lead) for r, lead in rate_leads if np.isfinite(r) and r > 0])
    if len(pairs) < 2 or pairs[:, 0].max() < WIDTH_RATE_SPAN * pairs[:, 0].min():
        return None
    return float(np.polyfit(np.log(pairs[:, 0]), np.log(pairs[:, 1]), 1)[0])


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
