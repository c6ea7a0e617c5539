"""Fit effects around a fixed core and score them on held-out blocks.

A model under test is a `Spec`: effect name -> the effect's nonlinear parameter (time constant,
delay, resonance). Given a spec, every linear parameter (static gain/offset/curvature, stress
gain, creep and heating gains, stress-play weights) follows by least squares, because each
effect is linear in them once its nonlinear parameter is fixed (the resonance filter is linear,
so it can be applied to each regressor). Each effect class builds its own regressors
(`gma_ffc.effects`); input-side effects change the core's input instead, and core runs are
cached by them. Nonlinear parameters are searched on a grid refined locally,
separately for each fold using only that fold's training samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

import numpy as np

from ..effects import path_order
from ..effects.base import Effect, Regressors
from ..effects.static import StaticMap
from .data import RecData, mean_stress, stress_levels, stress_span


def _plain(p: Any) -> Any:
    """A parameter as plain Python (grid points may be numpy scalars): equal values, equal specs."""
    if isinstance(p, (bool, np.bool_)):
        return bool(p)
    if isinstance(p, (tuple, list, np.ndarray)):
        return tuple(float(v) for v in p)
    return float(p)


class Spec(Mapping[str, Any]):
    """A model under test: effect name -> its nonlinear parameter (time constant, delay, resonance
    (f_ref_hz, zeta, beta_per_MPa), width chord step, True). An effect not in it is absent.
    Hashable and order-free, so fits and core runs are cached by spec."""

    __slots__ = ("_items",)

    def __init__(self, items: Mapping[str, Any] | Iterable[tuple[str, Any]] = ()) -> None:
        self._items = tuple(sorted((k, _plain(v)) for k, v in dict(items).items()))

    def __getitem__(self, name: str) -> Any:
        for k, v in self._items:
            if k == name:
                return v
        raise KeyError(name)

    def __iter__(self) -> Iterator[str]:
        return (k for k, _ in self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __hash__(self) -> int:
        return hash(self._items)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Spec) and self._items == other._items

    def __repr__(self) -> str:
        return f"Spec({dict(self._items)!r})"

    def with_(self, name: str, p: Any) -> "Spec":
        return Spec({**dict(self._items), name: p})

    def without(self, name: str) -> "Spec":
        return Spec({k: v for k, v in self._items if k != name})


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
        self.stress_varies = model.stress_range_MPa is not None and stress_span(self.data) >= 1.0
        self.play_thresholds = np.array([0.1, 0.25, 0.45]) * self.drive_span
        # the effects as registered now, in signal-path order: input-side ones change the core input
        self.effects: list[type[Effect]] = [c for c in path_order() if c.candidate]
        self._inputs = [c for c in self.effects if c.stage == "input"]
        self._core_fx = [c for c in self.effects if c.shapes_core]     # effects that reshape the core
        # an effect that supplies the stress the model sees (the rod_load dynamics: the load's static
        # stress, the load cell's inertial force filtered out); per recording raw (it sets the
        # resonance) and clamped (the core's)
        self._stress_fx = [c for c in self.effects if getattr(c, "transforms_stress", False)][:1]
        rng = model.stress_range_MPa
        self._static = {id(d): (self._stress_fx[0].fit_stress(d) if self._stress_fx else d.s) for d in self.data}
        self._static_clamped = {id(d): np.ascontiguousarray(np.clip(self._static[id(d)], *rng))
                                if rng is not None else d.s for d in self.data}
        # the loads' static stress range: the resonance's reference (least compressive) and extent
        self.stress_top = max(float(s.max()) for s in self._static.values())
        self.stress_bottom = min(float(s.min()) for s in self._static.values())
        self._core_cache: dict[tuple, list[tuple[np.ndarray, np.ndarray]]] = {}
        self._yc0: float | None = None
        self._cache: dict[tuple, np.ndarray] = {}
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
    def input_key(self, spec: Spec) -> tuple:
        """What the core's run depends on: the spec's input-side effects, the parameters of those
        that reshape the core, and whether a stress transform is present (the core then sees the
        load's static stress)."""
        return (tuple(spec.get(c.name) for c in self._inputs) + tuple(spec.get(c.name) for c in self._core_fx)
                + tuple(c.name in spec for c in self._stress_fx))

    def static_stress(self, d: RecData, clamped: bool = False) -> np.ndarray:
        """The stress-transforming effect's stress of a recording (the load's static stress), raw
        or clamped to the model's range (as recorded without such an effect)."""
        return self._static_clamped[id(d)] if clamped else self._static[id(d)]

    def stress(self, d: RecData, spec: Spec) -> np.ndarray:
        """The stress the model under `spec` sees: as recorded (clamped), or the transformed one."""
        return self._static_clamped[id(d)] if any(c.name in spec for c in self._stress_fx) else d.s

    def core(self, spec: Spec) -> list[tuple[np.ndarray, np.ndarray]]:
        """(core input u3, core output y_c) per recording for the spec's input-side effects."""
        key = self.input_key(spec)
        hit = self._core_cache.get(key)
        if hit is not None:
            return hit
        out = []
        core = self.model
        for c in self._core_fx:
            if c.name in spec:
                core = c.fit_core(self, core, spec[c.name])
        for d in self.data:
            u3 = self.core_input(d, spec)
            s = self.stress(d, spec) if self.model.stress_range_MPa is not None else None
            yc = np.asarray(core.simulate(d.t, u3, s, initial_state=d.start), dtype=float)
            out.append((u3, yc))
        if len(self._core_cache) > 64:
            self._core_cache.clear()
        self._core_cache[key] = out
        return out

    def core_input(self, d: RecData, spec: Spec) -> np.ndarray:
        u = d.u
        for c in self._inputs:
            if c.name in spec:
                u = c.filter_input(u, d, spec[c.name])
        return np.ascontiguousarray(u)

    def cached(self, key: tuple, compute: Callable[[], np.ndarray]) -> np.ndarray:
        """compute() once per key (e.g. a re-run of the core an effect's regressor needs)."""
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        out = compute()
        if len(self._cache) > 64:
            self._cache.clear()
        self._cache[key] = out
        return out

    def stress_levels(self) -> list[float]:
        return stress_levels(self.data)

    @property
    def yc_center(self) -> float:
        if self._yc0 is None:
            base = self.core(Spec())
            self._yc0 = float(np.mean(np.concatenate([yc for _, yc in base])))
        return self._yc0

    # ------------------------------------------------------------------ regressors
    def columns(self, d: RecData, u3: np.ndarray, yc: np.ndarray, spec: Spec) -> tuple[list[np.ndarray], list[str]]:
        """Full-length regressors of one recording (before row selection): the static map's, then
        each effect's in signal-path order (a filter effect transforms those before it)."""
        r = Regressors(d, u3, yc, self.input_key(spec), spec, [], [], {})
        StaticMap.columns(self, r, None)
        for c in self.effects:
            if c.stage != "input" and c.name in spec:
                c.columns(self, r, spec[c.name])
        return r.cols, r.names

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
           grid: Iterable[Any], refine: Callable[[Fitter, Any, int], Sequence[Any] | None] | None = None,
           zoom_levels: int = ZOOM_LEVELS) -> SearchResult:
    """Grid (plus local refinement) over one block's parameters; per-fold choice by training error."""
    results: dict[Any, Score] = {}

    def run(points: Iterable[Any]) -> None:
        for p in points:
            if p in results:
                continue
            results[p] = fitter.score((make(base[0], p), make(base[1], p), make(base[2], p)))

    run(grid)
    if refine is not None:
        for level in range(1, zoom_levels + 1):
            best_points = {min(results, key=lambda p: results[p].train_mse(0)),
                           min(results, key=lambda p: results[p].train_mse(1)),
                           min(results, key=lambda p: results[p].all_mse)}
            for bp in best_points:
                run(refine(fitter, bp, level) or [])
    pa = min(results, key=lambda p: results[p].train_mse(0))
    pb = min(results, key=lambda p: results[p].train_mse(1))
    pall = min(results, key=lambda p: results[p].all_mse)
    ra, rb = results[pa], results[pb]
    n_test = ra.n_test[0] + rb.n_test[1]
    cv = (ra.sse_test[0] + rb.sse_test[1]) / max(n_test, 1)
    mse = (ra.sq_test[0] + rb.sq_test[1]) / max(n_test, 1)
    specs = (make(base[0], pa), make(base[1], pb), make(base[2], pall))
    final = fitter.score(specs, want_coef=True)
    assert final.coef_all is not None
    return SearchResult(specs, cv, mse, final.all_mse, n_test, final.coef_all, final.names, len(results))
