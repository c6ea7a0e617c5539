"""The diagnosis' least-squares kernels (`gma_ffc.diagnose.lsq_kernels`) against numpy's algebra,
on designs of any layout, scale and weight: they replace it in every fit, so they must agree with
it to rounding."""

from __future__ import annotations

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from gma_ffc.diagnose import lsq_kernels as LK


def a_design(seed: int, rows: int, cols: int, layout: str) -> tuple[np.ndarray, np.ndarray]:
    """A design with columns of very different sizes (as a fit's are: gain, offset, curvature) and a
    target, in the layout asked: F, C, or a fold's rows of an F-ordered design (neither)."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(2 * rows, cols)) * 10.0 ** rng.uniform(-3, 3, cols)
    y = X @ rng.normal(size=cols) + rng.standard_cauchy(2 * rows)       # outliers for the Huber weights
    if layout == "F":
        return np.asfortranarray(X[:rows]), y[:rows]
    if layout == "C":
        return np.ascontiguousarray(X[:rows]), y[:rows]
    return np.asfortranarray(X)[rows:], y[rows:]


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), rows=st.integers(1, 400), cols=st.integers(1, 12),
       layout=st.sampled_from(["F", "C", "fold"]))
@example(seed=33, rows=33, cols=1, layout="fold")    # drawn in a full run on 2026-11-30: b off by 5e-12 of itself
def test_weighted_normal_equations_are_numpys(seed, rows, cols, layout):
    X, y = a_design(seed, rows, cols, layout)
    rng = np.random.default_rng(seed + 1)
    inv = 1.0 / np.sqrt(np.mean(X * X, axis=0))
    w = rng.uniform(0.0, 1.0, rows)
    G, b = np.empty((cols, cols)), np.empty(cols)
    LK.weighted_normal(X, inv, w, y, G, b)
    Xs = X * inv
    G_np, b_np = (Xs * w[:, None]).T @ Xs, (Xs * w[:, None]).T @ y
    assert np.array_equal(G, G.T)
    np.testing.assert_allclose(G, G_np, rtol=1e-12, atol=1e-12 * np.abs(G_np).max())
    # each b_j is a sum whose terms (a Cauchy target's outliers) may cancel: its rounding is bounded by
    # the sum of the terms' sizes, not by the result (seed 33, 33 rows: b = -3.5e-4, off by 1.8e-15)
    terms = np.abs(Xs * w[:, None]).T @ np.abs(y)
    assert np.all(np.abs(b - b_np) <= 1e-12 * terms + 1e-300), (b, b_np, terms)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), rows=st.integers(1, 400), cols=st.integers(1, 12),
       layout=st.sampled_from(["F", "C", "fold"]), delta=st.floats(1e-3, 1e3))
def test_huber_weights_are_the_residuals(seed, rows, cols, layout, delta):
    X, y = a_design(seed, rows, cols, layout)
    c = np.random.default_rng(seed + 2).normal(size=cols)
    r, w = np.empty(rows), np.empty(rows)
    LK.huber_weights(X, c, y, delta, r, w)
    r_np = y - X @ c
    np.testing.assert_allclose(r, r_np, rtol=1e-12, atol=1e-12 * (np.abs(X) @ np.abs(c) + np.abs(y)).max())
    a = np.abs(r)
    assert np.all(w[a <= delta] == 1.0)
    np.testing.assert_allclose(w[a > delta], delta / a[a > delta], rtol=1e-15)
    assert np.all((w > 0) & (w <= 1))
