"""Numba kernels of the rod + load-mass dynamics (pure maths, no I/O; physics in `rod_load`).

State (x, v): the load's position (um) and velocity (um/s), driven by the free stroke u::

    x' = v,   v' = w^2 (u - x) - 2 zeta w v

discretised exactly for an input held over each sample interval (zero-order hold, the input of
sample k acting over (t[k-1], t[k]]):  [x, v]_k = Phi(dt_k) [x, v]_{k-1} + Gamma(dt_k) u_k with
Phi = exp(A dt) and Gamma = (I - Phi) e1 (unity static gain). The state form keeps position and
velocity continuous when w changes with the load and is exact for uneven sampling too.

The inverse is exact: u_k = (y_k - Phi11 x - Phi12 v) / (1 - Phi11); its own pole is the
sampling zero of the forward model, inside the unit circle for zeta > 0 (tested), so it is
stable (lightly damped near Nyquist at fast sampling).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

MIN_MASS_FACTOR = 0.05     # (m_eff / m_eff,ref) floor: keeps w finite for stresses far outside the data


@njit(cache=True, nogil=True)
def phi(dt: float, omega: float, zeta: float) -> tuple:
    """(Phi11, Phi12, Phi21, Phi22) of the damped oscillator over dt (any zeta > 0)."""
    sg = zeta * omega
    e = math.exp(-sg * dt)
    if zeta < 1.0 - 1e-9:
        wd = omega * math.sqrt(1.0 - zeta * zeta)
        c = math.cos(wd * dt)
        s = math.sin(wd * dt) / wd
    elif zeta > 1.0 + 1e-9:
        mu = omega * math.sqrt(zeta * zeta - 1.0)
        c = math.cosh(mu * dt)
        s = math.sinh(mu * dt) / mu
    else:
        c = 1.0
        s = dt
    return e * (c + sg * s), e * s, -omega * omega * e * s, e * (c - sg * s)


@njit(cache=True, nogil=True)
def omega_at(omega_ref: float, beta: float, s_static: float, s_ref: float) -> float:
    """Natural frequency with the load the static stress implies: m_eff / m_eff,ref = 1 + beta (s_ref - s)."""
    m = 1.0 + beta * (s_ref - s_static)
    if m < MIN_MASS_FACTOR:
        m = MIN_MASS_FACTOR
    return omega_ref / math.sqrt(m)


@njit(cache=True, nogil=True)
def static_stress(s: np.ndarray, dt: np.ndarray, fc_hz: float, s0: float) -> np.ndarray:
    """The load's static stress: two cascaded first-order lags at fc_hz (critically damped, exact
    exponentials), relaxed at s0. Removes the inertial force that rides on the load-cell reading."""
    n = s.shape[0]
    out = np.empty(n)
    z1 = s0
    z2 = s0
    tau = 1.0 / (2.0 * math.pi * fc_hz)
    last_dt = -1.0
    a = 0.0
    for k in range(n):
        if dt[k] != last_dt:
            a = math.exp(-dt[k] / tau)
            last_dt = dt[k]
        z1 = a * z1 + (1.0 - a) * s[k]
        z2 = a * z2 + (1.0 - a) * z1
        out[k] = z2
    return out


@njit(cache=True, nogil=True)
def transitions(dt: np.ndarray, s_static: np.ndarray, omega_ref: float, zeta: float, beta: float,
                s_ref: float) -> np.ndarray:
    """Phi(dt_k) per sample, as rows (Phi11, Phi12, Phi21, Phi22) of a (4, n) array."""
    n = dt.shape[0]
    out = np.empty((4, n))
    last_dt = -1.0
    last_w = -1.0
    p11, p12, p21, p22 = 1.0, 0.0, 0.0, 1.0
    for k in range(n):
        w = omega_at(omega_ref, beta, s_static[k], s_ref)
        if dt[k] != last_dt or w != last_w:
            p11, p12, p21, p22 = phi(dt[k], w, zeta)
            last_dt = dt[k]
            last_w = w
        out[0, k] = p11
        out[1, k] = p12
        out[2, k] = p21
        out[3, k] = p22
    return out


@njit(cache=True, nogil=True)
def forward_rows(X: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Load position for every row of X taken as the free stroke (each at rest at its first value),
    through the per-sample transitions P (`transitions`: computed once for every row, and by the
    caller once for every set of rows through the same dynamics; they cost more than the rows).
    The rows advance together sample by sample, so their independent recurrences overlap (a row at
    a time waits on each step's result: 25 % slower on 20 rows)."""
    m, n = X.shape
    out = np.empty((m, n))
    x = np.empty(m)
    v = np.zeros(m)
    for j in range(m):
        x[j] = X[j, 0]
    for k in range(n):
        p11 = P[0, k]
        p12 = P[1, k]
        p21 = P[2, k]
        p22 = P[3, k]
        g1 = 1.0 - p11
        for j in range(m):
            u = X[j, k]
            xn = p11 * x[j] + p12 * v[j] + g1 * u
            v[j] = p21 * x[j] + p22 * v[j] - p21 * u
            x[j] = xn
            out[j, k] = xn
    return out


@njit(cache=True, nogil=True)
def forward(u: np.ndarray, dt: np.ndarray, s_static: np.ndarray, omega_ref: float, zeta: float,
            beta: float, s_ref: float, x0: float) -> np.ndarray:
    """Load position for the free stroke u, at rest at x0 before the first sample."""
    n = u.shape[0]
    out = np.empty(n)
    x = x0
    v = 0.0
    for k in range(n):
        w = omega_at(omega_ref, beta, s_static[k], s_ref)
        p11, p12, p21, p22 = phi(dt[k], w, zeta)
        xn = p11 * x + p12 * v + (1.0 - p11) * u[k]
        v = p21 * x + p22 * v - p21 * u[k]
        x = xn
        out[k] = x
    return out


@njit(cache=True, nogil=True)
def inverse(y: np.ndarray, dt: np.ndarray, s_static: np.ndarray, omega_ref: float, zeta: float,
            beta: float, s_ref: float, x0: float) -> np.ndarray:
    """Exact inverse of `forward`: the free stroke that puts the load at y (at rest at x0 before)."""
    n = y.shape[0]
    out = np.empty(n)
    x = x0
    v = 0.0
    for k in range(n):
        w = omega_at(omega_ref, beta, s_static[k], s_ref)
        p11, p12, p21, p22 = phi(dt[k], w, zeta)
        u = (y[k] - p11 * x - p12 * v) / (1.0 - p11)
        v = p21 * x + p22 * v - p21 * u
        x = y[k]
        out[k] = u
    return out
