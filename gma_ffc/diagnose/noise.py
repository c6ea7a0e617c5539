"""The measurement noise a recording shows, from its second differences. Pure maths: no I/O."""

from __future__ import annotations

import numpy as np

MAD_TO_SIGMA = 1.4826       # a normal distribution's standard deviation per median absolute deviation


def mad_sigma(x: np.ndarray) -> float:
    """A normal sample's standard deviation from its median absolute deviation: what most samples
    spread by, whatever a few outliers (bursts, steps) do."""
    return MAD_TO_SIGMA * float(np.median(np.abs(x - np.median(x))))


def second_difference_sigma(y: np.ndarray) -> float:
    """The white noise's std in y: the robust spread (MAD) of its second differences, whose variance
    is 6 sigma^2 for white noise. Slow signal content hardly reaches a second difference at kHz
    rates, and the median ignores the few samples where the signal itself turns fast. 0 for a
    constant or quantised, nearly constant signal (the caller decides the fallback), and for fewer
    than three samples."""
    if y.size < 3:
        return 0.0
    return mad_sigma(np.diff(y, 2)) / float(np.sqrt(6.0))
