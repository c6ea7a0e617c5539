"""Hysteresis operators as numba kernels: one implementation of the maths, two ways to run it.

The elementary operators are the play (seed paper (1)-(2)) and the one-sided dead-zone (4). The
SDPI model (16) is  y = c(sigma) + sum_j w_sj(sigma) S_{r_sj}[ sum_i w_hi H_{r_hi}[x - x_c] ],
with w_sj(sigma) and the output offset c(sigma) quadratic in stress; an MPI (6) is the special
case without stress terms. Its analytic inverse (17) runs the inverse dead-zone superposition
(whose parameters depend on stress, so they are recomputed each sample, in place) and then the
inverse PI.

`forward_step`/`inverse_step` advance one sample and are what the control loop calls; the batch
functions loop over them, so batch and step forms agree sample for sample by construction. All
parameters travel in one packed float64 vector and all state in one preallocated state vector, so
a step allocates nothing and crosses the Python/numba boundary with just four arguments.

Packed parameter layout (see `pack`):
    [n_h, n_s, x_c, sigma_lo, sigma_hi, o0, o1, o2,
     r_h(n_h), w_h(n_h), r_h'(n_h), w_h'(n_h), r_s(n_s), C0(n_s), C1(n_s), C2(n_s)]
State layout: [play states (n_h) | scratch w_s (n_s) | scratch r_s' (n_s) | scratch w_s' (n_s)].
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .inverse import deadzone_inverse_into

HEADER = 8


def pack(x_c: float, sigma_range: tuple[float, float], offset_coeffs: np.ndarray,
         r_h: np.ndarray, w_h: np.ndarray, r_h_inv: np.ndarray, w_h_inv: np.ndarray,
         r_s: np.ndarray, coeffs: np.ndarray) -> np.ndarray:
    """Pack model parameters for the kernels; `coeffs` is (3, n_s): w_s(sigma) = C0 + C1 s + C2 s^2."""
    n_h, n_s = len(r_h), len(r_s)
    head = [n_h, n_s, x_c, sigma_range[0], sigma_range[1], *np.asarray(offset_coeffs, float)]
    return np.ascontiguousarray(np.concatenate(
        [np.asarray(head, float), r_h, w_h, r_h_inv, w_h_inv, r_s, coeffs[0], coeffs[1], coeffs[2]]),
        dtype=np.float64)


def state_size(n_h: int, n_s: int) -> int:
    return n_h + 3 * n_s


@njit(cache=True, nogil=True, inline="always")
def play(x: float, r: float, y_prev: float) -> float:
    """Play operator (1): y = max(x - r, min(x + r, y_prev))."""
    return max(x - r, min(x + r, y_prev))


@njit(cache=True, nogil=True, inline="always")
def deadzone(z: float, r: float) -> float:
    """One-sided dead-zone operator (4)."""
    if r > 0.0:
        return max(z - r, 0.0)
    if r < 0.0:
        return min(z - r, 0.0)
    return z


@njit(cache=True, nogil=True, inline="always")
def _clamp(v: float, lo: float, hi: float) -> float:
    return min(max(v, lo), hi)


@njit(cache=True, nogil=True, inline="always")
def _deadzones_out(z: float, s: float, p: np.ndarray, n_h: int, n_s: int) -> float:
    """c(s) + sum_j w_sj(s) S_{r_sj}[z]: the output of the dead-zone superposition at stress s."""
    o_rs = HEADER + 4 * n_h
    o_c0 = o_rs + n_s
    y = p[5] + s * (p[6] + s * p[7])
    for j in range(n_s):
        w = p[o_c0 + j] + s * (p[o_c0 + n_s + j] + s * p[o_c0 + 2 * n_s + j])
        y += w * deadzone(z, p[o_rs + j])
    return y


@njit(cache=True, nogil=True, inline="always")
def _deadzones_inverse(y_ref: float, s: float, p: np.ndarray, state: np.ndarray, n_h: int, n_s: int) -> float:
    """z with _deadzones_out(z, s) = y_ref: the inverse superposition's parameters recomputed
    at this stress into the state's scratch, then applied."""
    o_rs = HEADER + 4 * n_h
    o_c0 = o_rs + n_s
    ws = state[n_h: n_h + n_s]
    rs_inv = state[n_h + n_s: n_h + 2 * n_s]
    ws_inv = state[n_h + 2 * n_s: n_h + 3 * n_s]
    for j in range(n_s):
        ws[j] = p[o_c0 + j] + s * (p[o_c0 + n_s + j] + s * p[o_c0 + 2 * n_s + j])
    deadzone_inverse_into(p[o_rs: o_rs + n_s], ws, rs_inv, ws_inv)
    v = y_ref - (p[5] + s * (p[6] + s * p[7]))
    z = 0.0
    for j in range(n_s):
        z += ws_inv[j] * deadzone(v, rs_inv[j])
    return z


@njit(cache=True, nogil=True, inline="always")
def _forward(x: float, sigma: float, g: float, p: np.ndarray, state: np.ndarray, commit: bool) -> float:
    """The forward model with play thresholds scaled by g; the play states move only if `commit`."""
    n_h = int(p[0])
    n_s = int(p[1])
    s = _clamp(sigma, p[3], p[4])
    o_wh = HEADER + n_h
    v = x - p[2]
    z = 0.0
    for i in range(n_h):
        q = play(v, g * p[HEADER + i], state[i])
        if commit:
            state[i] = q
        z += p[o_wh + i] * q
    return _deadzones_out(z, s, p, n_h, n_s)


@njit(cache=True, nogil=True)
def forward_step(x: float, sigma: float, p: np.ndarray, state: np.ndarray) -> float:
    """One sample of the SDPI forward model; updates the play states in `state`."""
    return _forward(x, sigma, 1.0, p, state, True)


@njit(cache=True, nogil=True)
def forward_peek(x: float, sigma: float, p: np.ndarray, state: np.ndarray) -> float:
    """What forward_step would return, the play states left as they are."""
    return _forward(x, sigma, 1.0, p, state, False)


@njit(cache=True, nogil=True, inline="always")
def _inverse(y_ref: float, sigma: float, p: np.ndarray, state: np.ndarray, commit: bool) -> float:
    n_h = int(p[0])
    n_s = int(p[1])
    s = _clamp(sigma, p[3], p[4])
    o_rhi = HEADER + 2 * n_h
    o_whi = o_rhi + n_h
    z = _deadzones_inverse(y_ref, s, p, state, n_h, n_s)
    x = 0.0
    for i in range(n_h):
        q = play(z, p[o_rhi + i], state[i])
        if commit:
            state[i] = q
        x += p[o_whi + i] * q
    return x + p[2]


@njit(cache=True, nogil=True)
def inverse_step(y_ref: float, sigma: float, p: np.ndarray, state: np.ndarray) -> float:
    """One sample of the analytic inverse (17): inverse dead-zones at this stress, then inverse PI."""
    return _inverse(y_ref, sigma, p, state, True)


@njit(cache=True, nogil=True)
def inverse_peek(y_ref: float, sigma: float, p: np.ndarray, state: np.ndarray) -> float:
    """What inverse_step would return, the play states left as they are (only scratch is written)."""
    return _inverse(y_ref, sigma, p, state, False)


# ---- the core with a loop width that follows stress (the stress_dependent_play effect's loop_width)
#
# Every play threshold is scaled by g(sigma) = max(1 + kappa (sigma_w - sigma), WIDTH_MIN): the
# coercive current grows by kappa per MPa of extra compression. A play with a varying threshold
# stays a play (y = max(x - g r, min(x + g r, y_prev))), so the model stays rate-independent; but
# once g has shrunk, the play states no longer satisfy the inverse PI's consistency conditions,
# and the analytic inverse (17) stops being exact. The widened inverse therefore keeps the FORWARD
# play states and solves sum_i w_i H_i(v) = z for this sample's v exactly: the sum is continuous and
# piecewise linear in v with its kinks at state_i -/+ g r_i, so sorting the kinks and interpolating
# on the segment that brackets z is exact (the leftmost such v, should the sum not be monotone).
# Widened state: [play states (n_h) | dead-zone scratch (3 n_s) | kinks (2 n_h) | sums there (2 n_h)].

WIDTH_MIN = 0.05


@njit(cache=True, nogil=True, inline="always")
def width_factor(s: float, kappa: float, sigma_w: float) -> float:
    return max(1.0 + kappa * (sigma_w - s), WIDTH_MIN)


def widened_state_size(n_h: int, n_s: int) -> int:
    return state_size(n_h, n_s) + 4 * n_h


@njit(cache=True, nogil=True)
def forward_step_widened(x: float, sigma: float, kappa: float, sigma_w: float, p: np.ndarray,
                         state: np.ndarray) -> float:
    """forward_step with every play threshold scaled by width_factor at this sample's stress."""
    return _forward(x, sigma, width_factor(_clamp(sigma, p[3], p[4]), kappa, sigma_w), p, state, True)


@njit(cache=True, nogil=True, inline="always")
def _widened_sum(v: float, g: float, p: np.ndarray, state: np.ndarray, n_h: int) -> float:
    z = 0.0
    for i in range(n_h):
        r = g * p[HEADER + i]
        z += p[HEADER + n_h + i] * max(v - r, min(v + r, state[i]))
    return z


@njit(cache=True, nogil=True)
def inverse_step_widened(y_ref: float, sigma: float, kappa: float, sigma_w: float, p: np.ndarray,
                         state: np.ndarray) -> float:
    """The drive x with forward_step_widened(x) = y_ref from this state (exact), and the step taken."""
    return _inverse_widened(y_ref, sigma, kappa, sigma_w, p, state, True)


@njit(cache=True, nogil=True)
def inverse_peek_widened(y_ref: float, sigma: float, kappa: float, sigma_w: float, p: np.ndarray,
                         state: np.ndarray) -> float:
    """What inverse_step_widened would return, the play states left as they are (only scratch is written)."""
    return _inverse_widened(y_ref, sigma, kappa, sigma_w, p, state, False)


@njit(cache=True, nogil=True, inline="always")
def _inverse_widened(y_ref: float, sigma: float, kappa: float, sigma_w: float, p: np.ndarray,
                     state: np.ndarray, commit: bool) -> float:
    n_h = int(p[0])
    n_s = int(p[1])
    s = _clamp(sigma, p[3], p[4])
    g = width_factor(s, kappa, sigma_w)
    z = _deadzones_inverse(y_ref, s, p, state, n_h, n_s)
    base = n_h + 3 * n_s
    kinks = state[base: base + 2 * n_h]
    sums = state[base + 2 * n_h: base + 4 * n_h]
    m = 2 * n_h
    for i in range(n_h):
        r = g * p[HEADER + i]
        kinks[2 * i] = state[i] - r
        kinks[2 * i + 1] = state[i] + r
    for a in range(1, m):                     # insertion sort: at most 2 x 16 kinks
        k = kinks[a]
        b = a - 1
        while b >= 0 and kinks[b] > k:
            kinks[b + 1] = kinks[b]
            b -= 1
        kinks[b + 1] = k
    w_total = 0.0
    for i in range(n_h):
        w_total += p[HEADER + n_h + i]
    for a in range(m):
        sums[a] = _widened_sum(kinks[a], g, p, state, n_h)
    if z <= sums[0]:                          # below every kink all plays move: slope w_total
        v = kinks[0] + (z - sums[0]) / w_total
    elif z >= sums[m - 1]:
        v = kinks[m - 1] + (z - sums[m - 1]) / w_total
    else:
        v = kinks[m - 1]
        for a in range(m - 1):
            lo, hi = sums[a], sums[a + 1]
            if (lo <= z <= hi) or (hi <= z <= lo):
                v = kinks[a] if hi == lo else kinks[a] + (z - lo) * (kinks[a + 1] - kinks[a]) / (hi - lo)
                break
    if commit:
        for i in range(n_h):
            r = g * p[HEADER + i]
            state[i] = max(v - r, min(v + r, state[i]))
    return v + p[2]


@njit(cache=True, nogil=True)
def forward_batch_widened(x: np.ndarray, sigma: np.ndarray, kappa: float, sigma_w: float, p: np.ndarray,
                          state: np.ndarray, out: np.ndarray) -> None:
    for k in range(x.shape[0]):
        out[k] = forward_step_widened(x[k], sigma[k], kappa, sigma_w, p, state)


@njit(cache=True, nogil=True)
def inverse_batch_widened(y: np.ndarray, sigma: np.ndarray, kappa: float, sigma_w: float, p: np.ndarray,
                          state: np.ndarray, out: np.ndarray) -> None:
    for k in range(y.shape[0]):
        out[k] = inverse_step_widened(y[k], sigma[k], kappa, sigma_w, p, state)


@njit(cache=True, nogil=True)
def forward_batch(x: np.ndarray, sigma: np.ndarray, p: np.ndarray, state: np.ndarray,
                  out: np.ndarray) -> None:
    for k in range(x.shape[0]):
        out[k] = forward_step(x[k], sigma[k], p, state)


@njit(cache=True, nogil=True)
def inverse_batch(y: np.ndarray, sigma: np.ndarray, p: np.ndarray, state: np.ndarray,
                  out: np.ndarray) -> None:
    for k in range(y.shape[0]):
        out[k] = inverse_step(y[k], sigma[k], p, state)


@njit(cache=True, nogil=True)
def play_outputs_scaled(x: np.ndarray, r: np.ndarray, g: np.ndarray, y0: np.ndarray, out: np.ndarray) -> None:
    """play_outputs with every threshold scaled by g[k] at sample k (a loop width that follows
    stress: the widened core's plays, the regressors of its identification)."""
    n = r.shape[0]
    for i in range(n):
        out[0, i] = play(x[0], g[0] * r[i], y0[i])
    for k in range(1, x.shape[0]):
        for i in range(n):
            out[k, i] = play(x[k], g[k] * r[i], out[k - 1, i])


@njit(cache=True, nogil=True)
def play_outputs(x: np.ndarray, r: np.ndarray, y0: np.ndarray, out: np.ndarray) -> None:
    """All play outputs H_{r_i}[x](t_k) into out[k, i]: the regressors of identification."""
    n = r.shape[0]
    for i in range(n):
        out[0, i] = play(x[0], r[i], y0[i])
    for k in range(1, x.shape[0]):
        for i in range(n):
            out[k, i] = play(x[k], r[i], out[k - 1, i])
