"""Compiled kernels of the repetitive learner: in place on preallocated buffers, no allocation.

They run once per period, inside a tick (docs/learning.md has the law and its derivation).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def lowpass_circular(x: np.ndarray, a: float, zero_phase: bool) -> None:
    """First-order low-pass y[k] = y[k-1] + a (x[k] - y[k-1]) over a circular buffer, in place.

    One lap settles the filter's state on the periodic signal (its memory is ~1/a samples, and
    a lap is longer); the second lap writes. Zero-phase runs the same filter backwards too, so
    the overall response is |H|^2 with no phase lag.
    """
    n = x.shape[0]
    y = x[n - 1]
    for k in range(n):                       # settle, forwards
        y += a * (x[k] - y)
    for k in range(n):
        y += a * (x[k] - y)
        x[k] = y
    if zero_phase:
        y = x[0]
        for k in range(n - 1, -1, -1):       # settle, backwards
            y += a * (x[k] - y)
        for k in range(n - 1, -1, -1):
            y += a * (x[k] - y)
            x[k] = y


@njit(cache=True, nogil=True)
def learn_period(c: np.ndarray, e: np.ndarray, seen: np.ndarray, push: np.ndarray, gain: float,
                 forgetting: float, lead: int, a: float, zero_phase: bool, bound: float) -> None:
    """c <- clip(Q{f c + L e[. + lead]}, +-bound) in place, with two exceptions per phase j:

    * the error at phase j + lead was not observed (`seen` False): no update at j;
    * the command for phase j was limited (`push[j]` != 0, the sign of limited - asked):
      no update that would ask for more of what the limit refused (anti-windup). The inverse
      model is increasing, so a command raised by a limit (push > 0) lets c only grow, a
      command cut by one (push < 0) lets it only shrink.
    """
    n = c.shape[0]
    for j in range(n):
        k = (j + lead) % n
        d = gain * e[k] if seen[k] else 0.0
        if (push[j] > 0 and d < 0.0) or (push[j] < 0 and d > 0.0):
            d = 0.0
        c[j] = forgetting * c[j] + d
    if a < 1.0:
        lowpass_circular(c, a, zero_phase)
    for j in range(n):
        if c[j] > bound:
            c[j] = bound
        elif c[j] < -bound:
            c[j] = -bound


@njit(cache=True, nogil=True)
def period_difference(err: np.ndarray, seen: np.ndarray, prev: np.ndarray, prev_seen: np.ndarray,
                      out: np.ndarray) -> int:
    """out = err - prev where both periods saw the phase, else 0; returns how many phases did."""
    both = 0
    for j in range(err.shape[0]):
        if seen[j] and prev_seen[j]:
            out[j] = err[j] - prev[j]
            both += 1
        else:
            out[j] = 0.0
    return both


def filter_coefficient(cutoff_hz: float, rate_hz: float, zero_phase: bool) -> float:
    """Smoothing factor `a` of the first-order filter whose overall -3 dB point is `cutoff_hz`.

    The zero-phase pair squares the magnitude, so each pass is placed where |H| = 2^-1/4.
    """
    wc = 2.0 * math.pi * cutoff_hz / rate_hz
    if zero_phase:
        wc /= math.sqrt(math.sqrt(2.0) - 1.0)     # 1 / (1 + (w/wp)^2) = 1/sqrt(2) at w = wc
    if wc >= math.pi:
        return 1.0
    return 1.0 - math.exp(-wc)


@njit(cache=True, nogil=True)
def highpass_change(err: np.ndarray, seen: np.ndarray, a: float, zero_phase: bool, hp: np.ndarray,
                    prev_hp: np.ndarray, prev_seen: np.ndarray, scratch: np.ndarray) -> tuple[float, int]:
    """The error above the robustness filter's band (err - Q err), against the previous period's:
    returns the sum of squared differences over the phases both saw, and how many there were;
    keeps this period's for the next call. Unseen phases hold the last seen value first.

    Above the band the learning does not act, and what repeats cancels in the difference: what is
    left is the non-repeatable error there, whatever the learning does below it."""
    n = err.shape[0]
    last = 0.0
    for j in range(n):                       # the value a circular hold starts from
        if seen[j]:
            last = err[j]
    for j in range(n):
        if seen[j]:
            last = err[j]
        hp[j] = last
        scratch[j] = last
    if a < 1.0:
        lowpass_circular(scratch, a, zero_phase)
    total = 0.0
    both = 0
    for j in range(n):
        hp[j] -= scratch[j]
        if seen[j] and prev_seen[j]:
            d = hp[j] - prev_hp[j]
            total += d * d
            both += 1
        prev_hp[j] = hp[j]
        prev_seen[j] = seen[j]
    return total, both
