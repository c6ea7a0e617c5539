"""Analytic inverse parameters of the PI and dead-zone superpositions (seed paper (8)-(14), (18)-(22)).

Derivation (why the signs differ from the paper's (19) and (22)):

A dead-zone superposition S(z) = sum_j w_j S_{r_j}(z) with thresholds r_{-l} < ... < r_0 = 0 < ... < r_l
is piecewise linear. On the positive side its slope right of r_i is the cumulative weight
c_i = w_0 + ... + w_i; on the negative side left of r_i it is c_i = w_i + ... + w_0. Its inverse is
again piecewise linear, with breakpoints at the images r'_i = S(r_i) and slopes 1/c_i. A one-sided
dead-zone in the inverse superposition adds its weight to the slope beyond its threshold, so

    w'_0 = 1/c_0,   w'_i = 1/c_i - 1/c_{i-1} = -w_i / (c_i c_{i-1})           (i = 1..l)
    w'_i = 1/c_i - 1/c_{i+1} = -w_i / (c_i c_{i+1})                         (i = -l..-1)

with a MINUS sign, as in (12) and (14); the paper's (19) and (22) drop it (a typo). The images are
r'_i = sum_{j=0}^{i} w_j (r_i - r_j) for i >= 0 and sum_{j=i}^{0} w_j (r_i - r_j) for i <= 0,
equations (11)/(18) and (13)/(20).

For the play superposition P[x] = sum_i w_i H_{r_i}[x] with r_0 = 0 the same argument on the
loading curve gives (8) and (9), and the inverse's initial play states follow (10). All of this is
proved numerically in tests/test_inverse.py (inverse after forward returns the input to rounding).

Arrays here hold dead-zone operators in ascending threshold order; the centre operator (r = 0) sits
at index `center = (len - 1) // 2`.
"""

from __future__ import annotations

import numpy as np
from numba import njit


def play_inverse(r_h: np.ndarray, w_h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Thresholds (8) and weights (9) of the inverse PI operator."""
    r_h = np.asarray(r_h, dtype=float)
    w_h = np.asarray(w_h, dtype=float)
    n = len(r_h)
    # A model that violates Proposition 3.1 (w_h0 = 0, a partial sum at 0) or whose weights overflow
    # gets inf/NaN here quietly: the caller's check refuses it in one line, numpy's warnings would
    # come before that line.
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        r_inv = np.array([np.sum(w_h[: i + 1] * (r_h[i] - r_h[: i + 1])) for i in range(n)])
        cum = np.cumsum(w_h)
        w_inv = np.empty(n)
        w_inv[0] = 1.0 / w_h[0]
        w_inv[1:] = -w_h[1:] / (cum[1:] * cum[:-1])
    return r_inv, w_inv


def play_inverse_initial_state(w_h: np.ndarray, y0: np.ndarray) -> np.ndarray:
    """Initial states (10) of the inverse PI's plays from the forward plays' states y0."""
    w_h = np.asarray(w_h, dtype=float)
    y0 = np.asarray(y0, dtype=float)
    n = len(w_h)
    cum = np.cumsum(w_h)
    tail = np.concatenate([np.cumsum((w_h * y0)[::-1])[::-1][1:], [0.0]])  # sum_{j>i} w_j y0_j
    return cum * y0 + tail if n else y0.copy()


def play_forward_state(w_h: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The forward plays' states from the inverse PI's plays `q`: (10) solved back, bottom up.

    (10) ties the two sets of plays at every sample, not only the first (the inverse's plays move
    with the forward ones), so this reads the hysteresis memory out of a running inverse.
    """
    w_h = np.asarray(w_h, dtype=float)
    cum = np.cumsum(w_h)
    y0 = np.empty(len(w_h))
    tail = 0.0                                  # sum_{j>i} w_j y0_j
    for i in range(len(w_h) - 1, -1, -1):
        y0[i] = (float(q[i]) - tail) / cum[i]
        tail += w_h[i] * y0[i]
    return y0


def deadzone_inverse(r_s: np.ndarray, w_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Thresholds (11)/(13) and weights (12)/(14) of the inverse dead-zone superposition.

    Written as the paper's explicit sums so the kernel's incremental form can be checked against it.
    """
    r_s = np.asarray(r_s, dtype=float)
    w_s = np.asarray(w_s, dtype=float)
    m = len(r_s)
    c = (m - 1) // 2
    r_inv = np.empty(m)
    w_inv = np.empty(m)
    w_inv[c] = 1.0 / w_s[c]
    r_inv[c] = 0.0
    for i in range(c + 1, m):  # positive side, paper's i = 1..l
        r_inv[i] = np.sum(w_s[c: i + 1] * (r_s[i] - r_s[c: i + 1]))
        cum_i, cum_prev = np.sum(w_s[c: i + 1]), np.sum(w_s[c:i])
        w_inv[i] = -w_s[i] / (cum_i * cum_prev)
    for i in range(c - 1, -1, -1):  # negative side, paper's i = -1..-l
        r_inv[i] = np.sum(w_s[i: c + 1] * (r_s[i] - r_s[i: c + 1]))
        cum_i, cum_next = np.sum(w_s[i: c + 1]), np.sum(w_s[i + 1: c + 1])
        w_inv[i] = -w_s[i] / (cum_i * cum_next)
    return r_inv, w_inv


@njit(cache=True, nogil=True)
def deadzone_inverse_into(r_s: np.ndarray, w_s: np.ndarray, r_out: np.ndarray, w_out: np.ndarray) -> None:
    """Same as `deadzone_inverse`, O(l), writing into preallocated arrays (control-loop form).

    Uses r'_i = r'_{i-1} + c_{i-1} (r_i - r_{i-1}), the telescoped form of (11)/(13).
    """
    m = r_s.shape[0]
    c = (m - 1) // 2
    cum = w_s[c]
    r_out[c] = 0.0
    w_out[c] = 1.0 / cum
    for i in range(c + 1, m):
        prev = cum
        cum = prev + w_s[i]
        r_out[i] = r_out[i - 1] + prev * (r_s[i] - r_s[i - 1])
        w_out[i] = -w_s[i] / (cum * prev)
    cum = w_s[c]
    for i in range(c - 1, -1, -1):
        nxt = cum
        cum = nxt + w_s[i]
        r_out[i] = r_out[i + 1] + nxt * (r_s[i] - r_s[i + 1])
        w_out[i] = -w_s[i] / (cum * nxt)
