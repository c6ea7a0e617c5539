"""Numba kernels of the diagnosis' weighted least squares (pure maths, no I/O; used by `fitting`).

A fit's design X is tall and narrow (thousands of rows, a few columns), and each fit solves the
normal equations of its columns scaled to unit RMS, with Huber weights in two reweighting passes.
numpy built a scaled copy of X, a weighted copy per pass, and the residual: three passes over X
and three temporaries per reweighting. These kernels read X once per quantity and allocate nothing.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, fastmath=True)
def weighted_normal(X: np.ndarray, inv_scale: np.ndarray, w: np.ndarray, y: np.ndarray,
                    G: np.ndarray, b: np.ndarray) -> None:
    """G = Xs' W Xs and b = Xs' W y into G and b, for Xs = X with column j times inv_scale[j] and
    W = diag(w). Column pairs outermost: each inner sum runs down contiguous columns of an
    F-ordered X (`fastmath` lets it vectorise; sums reassociate at rounding level)."""
    n, m = X.shape
    for j in range(m):
        s = 0.0
        for i in range(n):
            s += w[i] * X[i, j] * y[i]
        b[j] = s * inv_scale[j]
        for k in range(j, m):
            s = 0.0
            for i in range(n):
                s += w[i] * X[i, j] * X[i, k]
            G[j, k] = s * inv_scale[j] * inv_scale[k]
            G[k, j] = G[j, k]


@njit(cache=True, nogil=True, fastmath=True)
def huber_weights(X: np.ndarray, c: np.ndarray, y: np.ndarray, delta: float, r: np.ndarray,
                  w: np.ndarray) -> None:
    """The residual r = y - X c, and into w the Huber weights of scale delta: 1 within delta,
    delta / |r| beyond (the reweighting that turns least squares into the Huber loss)."""
    n, m = X.shape
    for i in range(n):
        r[i] = y[i]
    for j in range(m):
        cj = c[j]
        for i in range(n):
            r[i] -= X[i, j] * cj
    for i in range(n):
        a = abs(r[i])
        w[i] = 1.0 if a <= delta else delta / max(a, 1e-300)
