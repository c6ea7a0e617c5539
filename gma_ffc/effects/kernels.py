"""Numba kernels of the effect blocks (pure maths, no I/O), shared by the extended model and the diagnosis.

Each forward block has an exact discrete inverse, so the extended model can be inverted sample by
sample: the first-order lag (eddy currents, heating, creep) uses the ZOH form
``z_k = a z_{k-1} + (1-a) x_k`` and the mass-spring-damper uses matched poles with a unity-DC
numerator ``y_k = K x_k - a1 y_{k-1} - a2 y_{k-2}`` whose inverse is a 3-tap FIR (always stable).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def lag_coeff(dt: float, tau: float) -> float:
    """Pole of the ZOH-discretised first-order lag (0 when tau is 0: no lag)."""
    if tau <= 0.0:
        return 0.0
    return math.exp(-dt / tau)


@njit(cache=True, nogil=True)
def lag_filter(x: np.ndarray, dt: np.ndarray, tau: float, z0: float) -> np.ndarray:
    """First-order lag of x with time constant tau, relaxed at z0; dt[k] is the step into sample k."""
    n = x.shape[0]
    out = np.empty(n)
    z = z0
    last_dt = math.nan          # the pole is computed again only where the step changes (`lag_coeff` is
    a = 0.0                     # an exp, most of the loop's cost; an even step gives the same value each time)
    for k in range(n):
        if dt[k] != last_dt:
            a = lag_coeff(dt[k], tau)
            last_dt = dt[k]
        z = a * z + (1.0 - a) * x[k]
        out[k] = z
    return out


@njit(cache=True, nogil=True)
def lag_inverse(z: np.ndarray, dt: np.ndarray, tau: float, z0: float) -> np.ndarray:
    """Exact inverse of `lag_filter`: the input that makes the lag output equal z."""
    n = z.shape[0]
    out = np.empty(n)
    prev = z0
    last_dt = math.nan          # as in `lag_filter`: the pole once per step length
    a = 0.0
    for k in range(n):
        if dt[k] != last_dt:
            a = lag_coeff(dt[k], tau)
            last_dt = dt[k]
        out[k] = (z[k] - a * prev) / (1.0 - a)
        prev = z[k]
    return out


@njit(cache=True, nogil=True)
def creep_inverse(y: np.ndarray, dt: np.ndarray, gain: float, taus: np.ndarray) -> np.ndarray:
    """Exact inverse of creep, y = y_c + gain mean_k (lag(y_c, tau_k) - y_c) with every lag relaxed at
    y_c[0]: the core output y_c that gives y. Each sample's y_c is the root of a linear equation in it."""
    n = y.shape[0]
    m = taus.shape[0]
    out = np.empty(n)
    z = np.full(m, y[0])
    a = np.empty(m)             # each lag's pole, computed again only where the step changes (as `lag_filter`)
    last_dt = math.nan
    for k in range(n):
        if k == 0:
            out[0] = y[0]                       # every lag starts at y_c[0]: no creep term yet
            continue
        if dt[k] != last_dt:
            for j in range(m):
                a[j] = lag_coeff(dt[k], taus[j])
            last_dt = dt[k]
        held = 0.0
        fresh = 0.0
        for j in range(m):
            held += a[j] * z[j]
            fresh += 1.0 - a[j]
        yc = (y[k] - gain * held / m) / (1.0 - gain + gain * fresh / m)
        for j in range(m):
            z[j] = a[j] * z[j] + (1.0 - a[j]) * yc
        out[k] = yc
    return out


@njit(cache=True, nogil=True)
def delay_filter(x: np.ndarray, delay_samples: float, x0: float) -> np.ndarray:
    """Fractional delay by linear interpolation; samples before the start hold x0."""
    n = x.shape[0]
    out = np.empty(n)
    whole = int(math.floor(delay_samples))
    frac = delay_samples - whole
    for k in range(n):
        i0 = k - whole
        i1 = i0 - 1
        v0 = x[i0] if i0 >= 0 else x0
        v1 = x[i1] if i1 >= 0 else x0
        out[k] = (1.0 - frac) * v0 + frac * v1
    return out


@njit(cache=True, nogil=True)
def msd_coeffs(dt: float, omega: float, zeta: float) -> tuple:
    """(a1, a2, K) of the matched-pole second-order low-pass (poles exp(s dt), DC gain 1)."""
    if zeta < 1.0:
        wd = omega * math.sqrt(1.0 - zeta * zeta)
        e = math.exp(-zeta * omega * dt)
        a1 = -2.0 * e * math.cos(wd * dt)
        a2 = e * e
    else:
        r = math.sqrt(zeta * zeta - 1.0)
        p1 = math.exp((-zeta + r) * omega * dt)
        p2 = math.exp((-zeta - r) * omega * dt)
        a1 = -(p1 + p2)
        a2 = p1 * p2
    return a1, a2, 1.0 + a1 + a2


@njit(cache=True, nogil=True)
def msd_omega(omega_ref: float, beta: float, stress: float, stress_ref: float) -> float:
    """Natural frequency with the load mass that the stress implies (more compression, more mass)."""
    m = 1.0 + beta * (stress_ref - stress)
    if m < 0.05:
        m = 0.05
    return omega_ref / math.sqrt(m)


@njit(cache=True, nogil=True)
def msd_filter(x: np.ndarray, dt: np.ndarray, stress: np.ndarray, omega_ref: float, zeta: float,
               beta: float, stress_ref: float, y0: float) -> np.ndarray:
    """Mass-spring-damper response to the quasi-static displacement x, relaxed at y0."""
    n = x.shape[0]
    out = np.empty(n)
    y1 = y0
    y2 = y0
    for k in range(n):
        w = msd_omega(omega_ref, beta, stress[k], stress_ref)
        a1, a2, kk = msd_coeffs(dt[k], w, zeta)
        y = kk * x[k] - a1 * y1 - a2 * y2
        out[k] = y
        y2 = y1
        y1 = y
    return out


@njit(cache=True, nogil=True)
def msd_inverse(y: np.ndarray, dt: np.ndarray, stress: np.ndarray, omega_ref: float, zeta: float,
                beta: float, stress_ref: float, y0: float) -> np.ndarray:
    """Exact inverse of `msd_filter` (3-tap FIR)."""
    n = y.shape[0]
    out = np.empty(n)
    y1 = y0
    y2 = y0
    for k in range(n):
        w = msd_omega(omega_ref, beta, stress[k], stress_ref)
        a1, a2, kk = msd_coeffs(dt[k], w, zeta)
        out[k] = (y[k] + a1 * y1 + a2 * y2) / kk
        y2 = y1
        y1 = y[k]
    return out


def play_bank(x: np.ndarray, thresholds: np.ndarray, x0: float) -> np.ndarray:
    """Outputs of play operators H_r[x] (one column per threshold), relaxed at x0."""
    return play_bank_from(x, thresholds, np.full(thresholds.shape[0], float(x0)))


@njit(cache=True, nogil=True)
def play_bank_from(x: np.ndarray, thresholds: np.ndarray, p0: np.ndarray) -> np.ndarray:
    """Outputs of play operators H_r[x] (one column per threshold), each starting at p0[j]."""
    n = x.shape[0]
    m = thresholds.shape[0]
    out = np.empty((n, m))
    state = p0.copy()
    for k in range(n):
        for j in range(m):
            r = thresholds[j]
            s = state[j]
            lo = x[k] - r
            hi = x[k] + r
            if s < lo:
                s = lo
            elif s > hi:
                s = hi
            state[j] = s
            out[k, j] = s
    return out
