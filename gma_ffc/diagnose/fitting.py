"""Fit extension blocks around a fixed core and score them on held-out blocks.

A model under test is a `Spec`: the nonlinear parameters of its blocks (time constants, delay,
resonance). Given a spec, every linear parameter (static gain/offset/curvature, stress gain,
creep and heating gains, stress-play weights) follows by least squares, because each block is
linear in them once the nonlinear parameters are fixed (the resonance filter is linear, so it can
be applied to each regressor). Nonlinear parameters are searched on a grid refined locally,
separately for each fold using only that fold's training samples.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from . import kernels as K
from .data import RecData, mean_stress, stress_span
from .extended import CREEP_SPREAD, MIN_FAST_HEAT_S, THERMAL_FAST_RATIO, widened_core


@dataclass(frozen=True)
class Spec:
    """Nonlinear parameters of the blocks in a model under test (None: block absent)."""

    saturation: bool = False                        # hinge correction beyond the identified drive range
    eddy_tau: float | None = None                   # s
    delay_s: float | None = None                    # s
    stress_play: float = 0.0                        # != 0: play weights and loop width vary with stress;
                                                    # the value is the threshold step of the width's chord
    creep_tau: float | None = None                  # s
    dynamics: tuple[float, float, float] | None = None  # (f_ref_hz, zeta, beta_per_MPa)
    thermal_tau: float | None = None                # s

    def with_(self, **kw: Any) -> "Spec":
        return dataclasses.replace(self, **kw)

    def input_key(self) -> tuple:
        return (self.eddy_tau, self.delay_s)


@dataclass
class Score:
    """Results of one spec: per-fold train/test loss (Huber when set, else squared error), the
    test folds' plain squared error, and the all-data fit."""

    sse_train: tuple[float, float]
    sse_test: tuple[float, float]
    n_train: tuple[int, int]
    n_test: tuple[int, int]
    sse_all: float
    n_all: int
    coef_all: np.ndarray | None
    names: list[str]
    sq_test: tuple[float, float] = (math.nan, math.nan)   # plain squared error on the test folds

    def train_mse(self, fold: int) -> float:
        return self.sse_train[fold] / max(self.n_train[fold], 1)

    @property
    def all_mse(self) -> float:
        return self.sse_all / max(self.n_all, 1)


class Fitter:
    """Builds regressors for specs over the prepared recordings (with caches) and solves them."""

    def __init__(self, model: Any, data: Sequence[RecData]) -> None:
        self.model = model
        self.data = list(data)
        lo, hi = model.drive_range
        u_all = np.concatenate([d.u for d in self.data])
        if not (math.isfinite(lo) and math.isfinite(hi)):
            lo, hi = float(u_all.min()), float(u_all.max())
        self.drive_lo, self.drive_hi = float(lo), float(hi)
        self.drive_span = max(self.drive_hi - self.drive_lo, 1e-12)
        self.stress_ref = mean_stress(self.data)
        self.stress_top = max(float(d.s.max()) for d in self.data)
        self.stress_varies = model.stress_range_MPa is not None and stress_span(self.data) >= 1.0
        self.play_thresholds = np.array([0.1, 0.25, 0.45]) * self.drive_span
        self._core_cache: dict[tuple, list[tuple[np.ndarray, np.ndarray]]] = {}
        self._yc0: float | None = None
        self._width_cache: dict[tuple, np.ndarray] = {}
        self.dt_min = min(d.dt_med for d in self.data)
        self.duration_max = max(d.duration_s for d in self.data)
        self.duration_total = sum(d.duration_s for d in self.data)
        # least-squares rows, fold A's (of every recording) first, then fold B's: folds are slices
        self._rows_ab = [(d.rows[d.fold[d.rows] == 0], d.rows[d.fold[d.rows] == 1]) for d in self.data]
        ya = [d.y[ra] for d, (ra, _) in zip(self.data, self._rows_ab)]
        yb = [d.y[rb] for d, (_, rb) in zip(self.data, self._rows_ab)]
        self.n_a = int(sum(a.size for a in ya))
        self.y_rows = np.concatenate(ya + yb)
        self.segment_lengths = [a.size for a in ya] + [b.size for b in yb]
        rates = [np.abs(np.gradient(d.u, d.t)) if d.t.size > 1 else np.zeros(d.t.size) for d in self.data]
        self.rate_rows = np.concatenate([r[ra] for r, (ra, _) in zip(rates, self._rows_ab)] +
                                        [r[rb] for r, (_, rb) in zip(rates, self._rows_ab)])
        self.evaluations = 0
        self.delta: float | None = None   # Huber scale of the loss (None: plain least squares)

    # ------------------------------------------------------------------ the core
    def core(self, spec: Spec) -> list[tuple[np.ndarray, np.ndarray]]:
        """(core input u3, core output y_c) per recording for the spec's input-side blocks."""
        key = spec.input_key()
        hit = self._core_cache.get(key)
        if hit is not None:
            return hit
        out = []
        for d in self.data:
            u3 = self.core_input(d, spec)
            s = d.s if self.model.stress_range_MPa is not None else None
            yc = np.asarray(self.model.simulate(d.t, u3, s, initial_state=d.start), dtype=float)
            out.append((u3, yc))
        if len(self._core_cache) > 64:
            self._core_cache.clear()
        self._core_cache[key] = out
        return out

    def core_input(self, d: RecData, spec: Spec) -> np.ndarray:
        u = d.u
        if spec.eddy_tau:
            u = K.lag_filter(u, d.dt, spec.eddy_tau, float(u[0]))
        if spec.delay_s:
            u = K.delay_filter(u, spec.delay_s / d.dt_med, float(u[0]))
        return np.ascontiguousarray(u)

    def width_derivative(self, d: RecData, u3: np.ndarray, yc: np.ndarray, spec: Spec) -> np.ndarray:
        """(y_c with play thresholds x (1 + eps) - y_c) / eps: how the core's output moves as its loop widens."""
        eps = float(spec.stress_play)
        key = (id(d), spec.input_key(), eps)
        hit = self._width_cache.get(key)
        if hit is not None:
            return hit
        wide = widened_core(self.model, eps)
        s = d.s if self.model.stress_range_MPa is not None else None
        out = (np.asarray(wide.simulate(d.t, u3, s, initial_play_state=d.start.play_state), dtype=float) - yc) / eps
        if len(self._width_cache) > 64:
            self._width_cache.clear()
        self._width_cache[key] = out
        return out

    @property
    def yc_center(self) -> float:
        if self._yc0 is None:
            base = self.core(Spec())
            self._yc0 = float(np.mean(np.concatenate([yc for _, yc in base])))
        return self._yc0

    # ------------------------------------------------------------------ regressors
    def columns(self, d: RecData, u3: np.ndarray, yc: np.ndarray, spec: Spec) -> tuple[list[np.ndarray], list[str]]:
        """Full-length regressors of one recording (before row selection)."""
        ds = d.s - self.stress_ref
        cols = [yc, (yc - self.yc_center) ** 2, np.ones_like(yc)]
        names = ["gain", "quadratic", "offset"]
        if self.stress_varies:
            cols.append(ds * yc)
            names.append("stress_gain")
        plays = K.play_bank(u3, self.play_thresholds, float(u3[0]))
        for j in range(self.play_thresholds.size):
            cols.append(plays[:, j] - u3)
            names.append(f"play_{j}")
        if spec.stress_play:
            # each play's weight may change linearly with stress (loop shape), and the core's loop may
            # widen with stress (its play thresholds - the coercive current - scaled by 1 + k (s - s_ref))
            for j in range(self.play_thresholds.size):
                cols.append(ds * (plays[:, j] - u3))
                names.append(f"stress_play_{j}")
            cols.append(ds * self.width_derivative(d, u3, yc, spec))
            names.append("stress_width")
        if spec.saturation:
            above = np.maximum(d.u - self.drive_hi, 0.0)
            below = np.maximum(self.drive_lo - d.u, 0.0)
            for side, h in (("hi", above), ("lo", below)):
                if np.any(h > 0.02 * self.drive_span):
                    cols += [h, h * h]
                    names += [f"sat_lin_{side}", f"sat_quad_{side}"]
        if spec.creep_tau:
            acc = np.zeros_like(yc)
            for k in CREEP_SPREAD:
                acc += K.lag_filter(yc, d.dt, spec.creep_tau * k, float(yc[0])) - yc
            cols.append(acc / len(CREEP_SPREAD))
            names.append("creep_gain")
        if spec.dynamics is not None:
            f, zeta, beta = spec.dynamics
            idx = [j for j, name in enumerate(names) if name != "offset"]
            filt = K.msd_filter_columns(np.column_stack([cols[j] for j in idx]), d.dt, d.s, 2 * math.pi * f,
                                        zeta, beta, self.stress_top)
            for k, j in enumerate(idx):
                cols[j] = filt[:, k]
        if spec.thermal_tau:
            cols.append(K.lag_filter(d.u * d.u, d.dt, spec.thermal_tau, 0.0))
            names.append("thermal_gain")
            # coil and rod heat with different time constants: a faster part with its own gain, where it
            # is still slow enough to be thermal. On a one-sided drive the drive squared and the core
            # output rise and fall together, so that fast part and creep are look-alikes: a model with
            # creep keeps the single heating time constant, and creep is judged as the fast part's rival
            if spec.thermal_tau * THERMAL_FAST_RATIO >= MIN_FAST_HEAT_S and not spec.creep_tau:
                cols.append(K.lag_filter(d.u * d.u, d.dt, spec.thermal_tau * THERMAL_FAST_RATIO, 0.0))
                names.append("thermal_fast_gain")
        return cols, names

    def design(self, spec: Spec) -> tuple[np.ndarray, list[str]]:
        """Regressors at the least-squares rows: fold A rows of every recording, then fold B rows."""
        part_a, part_b = [], []
        names: list[str] = []
        for d, (u3, yc), (ra, rb) in zip(self.data, self.core(spec), self._rows_ab):
            cols, names = self.columns(d, u3, yc, spec)
            part_a.append(np.column_stack([c[ra] for c in cols]))
            part_b.append(np.column_stack([c[rb] for c in cols]))
        return np.vstack(part_a + part_b), names

    def predict_full(self, spec: Spec, coef: np.ndarray) -> list[np.ndarray]:
        """Full-rate prediction per recording for a spec and its linear coefficients."""
        out = []
        for d, (u3, yc) in zip(self.data, self.core(spec)):
            cols, _ = self.columns(d, u3, yc, spec)
            out.append(np.column_stack(cols) @ coef)
        return out

    # ------------------------------------------------------------------ solving
    def loss(self, r: np.ndarray) -> float:
        """Sum of 2 x Huber loss (equal to the squared error for residuals within delta)."""
        if self.delta is None:
            return float(r @ r)
        a = np.abs(r)
        d = self.delta
        return float(np.sum(np.where(a <= d, a * a, 2 * d * a - d * d)))

    def _solve(self, X: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Least squares; with a Huber scale, two reweighting passes so a few bursts (a load change
        the core cannot follow) do not steer the fit."""
        scale = np.sqrt(np.mean(X * X, axis=0))
        scale[scale == 0] = 1.0
        Xs = X / scale
        w = None
        c = np.zeros(X.shape[1])
        for _ in range(1 if self.delta is None else 3):
            Xw = Xs if w is None else Xs * w[:, None]
            G = Xw.T @ Xs
            G[np.diag_indices_from(G)] += 1e-10 * max(float(np.trace(G)), 1.0) / G.shape[0]
            try:
                c = np.linalg.solve(G, Xw.T @ y)
            except np.linalg.LinAlgError:
                c = np.linalg.lstsq(Xs, y, rcond=None)[0]
            if self.delta is not None:
                a = np.abs(y - Xs @ c)
                w = np.where(a <= self.delta, 1.0, self.delta / np.maximum(a, 1e-300))
        return c / scale

    def score(self, specs: tuple[Spec, Spec, Spec], want_coef: bool = False) -> Score:
        """Fit fold A's spec on A, fold B's on B (each tested on the other), and the all-data spec."""
        self.evaluations += 1
        y = self.y_rows
        designs: dict[Spec, np.ndarray] = {}
        names: list[str] = []

        def X_for(spec: Spec) -> np.ndarray:
            nonlocal names
            if spec not in designs:
                designs[spec], names = self.design(spec)
            return designs[spec]

        sse_train, sse_test, n_train, n_test, sq_test = [], [], [], [], []
        na = self.n_a
        for f in (0, 1):
            X = X_for(specs[f])
            tr = slice(0, na) if f == 0 else slice(na, None)
            te = slice(na, None) if f == 0 else slice(0, na)
            c = self._solve(X[tr], y[tr])
            r_tr = y[tr] - X[tr] @ c
            r_te = y[te] - X[te] @ c
            sse_train.append(self.loss(r_tr))
            sse_test.append(self.loss(r_te))
            sq_test.append(float(r_te @ r_te))
            n_train.append(int(r_tr.size))
            n_test.append(int(r_te.size))
        X = X_for(specs[2])
        c_all = self._solve(X, y)
        r = y - X @ c_all
        return Score(tuple(sse_train), tuple(sse_test), tuple(n_train), tuple(n_test),  # type: ignore[arg-type]
                     self.loss(r), int(y.size), c_all if want_coef else None, names, tuple(sq_test))  # type: ignore[arg-type]

    @property
    def rows_ab(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per recording, its least-squares rows in fold A and in fold B (sample indices)."""
        return self._rows_ab

    def row_blocks(self) -> list[np.ndarray]:
        """Per recording, where its fold A rows and then its fold B rows sit in `y_rows`."""
        a_sizes = [ra.size for ra, _ in self._rows_ab]
        b_sizes = [rb.size for _, rb in self._rows_ab]
        a_start = np.concatenate([[0], np.cumsum(a_sizes)])
        b_start = self.n_a + np.concatenate([[0], np.cumsum(b_sizes)])
        return [np.concatenate([np.arange(a_start[k], a_start[k] + a_sizes[k]),
                                np.arange(b_start[k], b_start[k] + b_sizes[k])]) for k in range(len(a_sizes))]

    def test_residuals(self, specs: tuple[Spec, Spec, Spec]) -> np.ndarray:
        """Held-out residuals at the least-squares rows (each fold predicted by the other fold's fit)."""
        y = self.y_rows
        na = self.n_a
        out = np.empty_like(y)
        for f in (0, 1):
            X, _ = self.design(specs[f])
            tr = slice(0, na) if f == 0 else slice(na, None)
            te = slice(na, None) if f == 0 else slice(0, na)
            c = self._solve(X[tr], y[tr])
            out[te] = y[te] - X[te] @ c
        return out


# ---------------------------------------------------------------------- searching one block

ZOOM_LEVELS = 3


@dataclass
class SearchResult:
    specs: tuple[Spec, Spec, Spec]      # fold A, fold B, all data (each with the block's best parameters)
    cv_loss: float                      # held-out loss per sample (selection)
    cv_mse: float                       # held-out mean squared error (reported)
    all_mse: float
    n_test: int
    coef_all: np.ndarray
    names: list[str]
    evaluated: int


def search(fitter: Fitter, base: tuple[Spec, Spec, Spec], make: Callable[[Spec, Any], Spec],
           grid: Sequence[Any], refine: Callable[[Fitter, Any], Sequence[Any]] | None = None) -> SearchResult:
    """Grid (plus local refinement) over one block's parameters; per-fold choice by training error."""
    results: dict[Any, Score] = {}

    def run(points: Sequence[Any]) -> None:
        for p in points:
            if p in results:
                continue
            results[p] = fitter.score((make(base[0], p), make(base[1], p), make(base[2], p)))

    run(grid)
    if refine is not None:
        for level in range(1, ZOOM_LEVELS + 1):
            best_points = {min(results, key=lambda p: results[p].train_mse(0)),
                           min(results, key=lambda p: results[p].train_mse(1)),
                           min(results, key=lambda p: results[p].all_mse)}
            for bp in best_points:
                run(refine(fitter, bp, level))
    pa = min(results, key=lambda p: results[p].train_mse(0))
    pb = min(results, key=lambda p: results[p].train_mse(1))
    pall = min(results, key=lambda p: results[p].all_mse)
    ra, rb = results[pa], results[pb]
    n_test = ra.n_test[0] + rb.n_test[1]
    cv = (ra.sse_test[0] + rb.sse_test[1]) / max(n_test, 1)
    mse = (ra.sq_test[0] + rb.sq_test[1]) / max(n_test, 1)
    specs = (make(base[0], pa), make(base[1], pb), make(base[2], pall))
    final = fitter.score(specs, want_coef=True)
    return SearchResult(specs, cv, mse, final.all_mse, n_test, final.coef_all, final.names, len(results))


def geom_refine(p: float, ratio: float, level: int = 1) -> list[float]:
    """Points around p on a log scale for zoom level 1, 2, ... of a grid of spacing `ratio`."""
    step = 3.0 ** -level
    return [p * ratio ** (e * step) for e in (-2.0, -1.0, 1.0, 2.0)]
