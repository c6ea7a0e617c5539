"""Fit effects around a fixed core and score them on held-out blocks.

A model under test is a `Spec` (`specs.py`): effect name -> the effect's nonlinear parameter (time constant,
delay, resonance). Given a spec, every linear parameter (static gain/offset/curvature, stress
gain, creep and heating gains, stress-play weights) follows by least squares, because each
effect is linear in them once its nonlinear parameter is fixed (the resonance filter is linear,
so it can be applied to each regressor). Each effect class builds its own regressors
(`gma_ffc.effects`); input-side effects change the core's input instead, and core runs are
cached by them. The nonlinear parameters are searched in `search.py`, on the scores this
module gives, separately for each fold using only that fold's training samples.
"""

from __future__ import annotations

import functools
import math
import threading
from dataclasses import dataclass
from typing import Any, Callable, Sequence, TypeVar

import numpy as np
from scipy.linalg import lapack

from ..drive import held
from ..effects import path_order
from ..effects.base import CoreAround, Effect, Regressors
from ..effects.static import StaticMap
from . import lsq_kernels as LK
from .cache import BoundedCache
from .data import RecData, mean_stress, stress_levels, stress_span
from .jumps import Jump
from .rebase import identify_on
from .specs import LeftOut, Score, Spec

# the caches' byte budgets: each entry is as long as the recordings, so without them memory grows
# with the recording (64 core runs of an hour at 1 kHz are 3.7 GB); within them a long recording
# re-runs the core more often, with the same results. Up to a few minutes at kHz rates every entry fits.
CORE_CACHE_BYTES = 192 * 2 ** 20
REGRESSOR_CACHE_BYTES = 128 * 2 ** 20
STATIC_CACHE_BYTES = 32 * 2 ** 20
ANCHOR_CACHE_BYTES = 96 * 2 ** 20
TABLE_CACHE_BYTES = 32 * 2 ** 20   # per-sample tables (`cached_table`): a resonance's for an hour at 1 kHz is 115 MB,
                                   # so long recordings keep the newest only; a recording of minutes keeps dozens
SEARCHES_KEPT = 256              # searches' results kept per fitter (`searched`): a few kilobytes each (the specs and
                                 # one coefficient per column); a diagnosis makes 20-60, so a diagnosis keeps every one
_T = TypeVar("_T")               # what an effect keeps in the fitter's cache (`Fitter.cached`)


@dataclass(frozen=True)
class FitSettings:
    """The fitter's settings (`EffectSelector`'s constructor documents each one's reason)."""

    min_stress_span_MPa: float = 1.0
    recalibration_plays: tuple[float, ...] = (0.1, 0.25, 0.45)
    range_margin: float = 0.02
    drive_limits: tuple[float, float] | None = None     # the controller's (`diagnose --drive-limits`), or none


class Fitter:
    """Builds regressors for specs over the prepared recordings (with caches) and solves them."""

    def __init__(self, model: Any, data: Sequence[RecData], anchor: Sequence[RecData] = (),
                 settings: FitSettings = FitSettings()) -> None:
        self.model = model
        self.settings = settings
        self.data = list(data)
        # train-only pseudo-recordings (`anchor.py`), never scored. A loop without a row holds nothing
        # (a drive sampled too coarsely for a loop after its first: a 1 s step against a 0.2 Hz
        # identification rate), and its tolerance would be divided by its zero rows
        self.anchor = [d for d in anchor if d.rows.size]
        self._init_ranges()
        # the effects as registered now, in signal-path order: input-side ones change the core input
        self.effects: list[type[Effect]] = [c for c in path_order() if c.candidate]
        self._inputs = [c for c in self.effects if c.stage == "input"]
        # the identification loops first: an effect may reshape the core only where they are given
        self.identification = [d for d in self.anchor if d.extra.get("anchor_rule") == "estimate"]
        self._init_stress()
        self._init_caches()
        # effects that reshape the core (after the caches: creep asks the loops whether they show it)
        self._core_fx = [c for c in self.effects if c.reshapes(self)]
        self._init_rows()
        self.evaluations = 0
        self.delta: float | None = None   # Huber scale of the loss (None: plain least squares)
        self._init_anchor()
        self._identified: dict[Any, Any] = {}
        self.static_off: frozenset[str] = frozenset()   # recalibration columns left out (`drop_static`)
        self._identify_lock = threading.Lock()

    def _init_ranges(self) -> None:
        """The model's drive range (the data's where it has none), the mean stress, the recalibration's plays."""
        lo, hi = self.model.drive_range
        if not (math.isfinite(lo) and math.isfinite(hi)):
            u_all = np.concatenate([d.u for d in self.data])
            lo, hi = float(u_all.min()), float(u_all.max())
        self.drive_lo, self.drive_hi = float(lo), float(hi)
        self.drive_span = max(self.drive_hi - self.drive_lo, 1e-12)
        self.drive_margin = self.settings.range_margin * self.drive_span   # beyond it: beyond the range
        self.drive_limits = self.settings.drive_limits
        self.stress_ref = mean_stress(self.data)
        self.stress_varies = (self.model.stress_range_MPa is not None
                              and stress_span(self.data) >= self.settings.min_stress_span_MPa)
        self.play_thresholds = np.array(self.settings.recalibration_plays, dtype=float) * self.drive_span
        self.dt_min = min(d.dt_med for d in self.data)
        self.duration_max = max(d.duration_s for d in self.data)
        self.duration_total = sum(d.duration_s for d in self.data)

    def _init_stress(self) -> None:
        """An effect that supplies the stress the model sees (the rod_load dynamics: the load's static
        stress, the load cell's inertial force filtered out); per recording raw (it sets the
        resonance) and clamped (the core's); the loads' static stress range (the resonance's
        reference, the least compressive, and its extent)."""
        self._stress_fx = [c for c in self.effects if getattr(c, "transforms_stress", False)][:1]
        rng = self.model.stress_range_MPa
        self._static = {id(d): (self._stress_fx[0].fit_stress(d) if self._stress_fx else d.s)
                        for d in self.data + self.anchor}
        self._static_clamped = {id(d): np.ascontiguousarray(np.clip(self._static[id(d)], *rng))
                                if rng is not None else d.s for d in self.data + self.anchor}
        self.stress_top = max(float(self._static[id(d)].max()) for d in self.data)
        self.stress_bottom = min(float(self._static[id(d)].min()) for d in self.data)

    def _init_caches(self) -> None:
        """Core runs, regressors, static columns, per-sample tables and anchor designs, each bounded in bytes (`cache.py`)."""
        self._anchor_cache: BoundedCache[np.ndarray] = BoundedCache(max_bytes=ANCHOR_CACHE_BYTES)
        self._gram_cache: BoundedCache[tuple[list[np.ndarray], list[float]]] = BoundedCache()
        self._core_cache: BoundedCache[list[tuple[np.ndarray, np.ndarray]]] = BoundedCache(max_bytes=CORE_CACHE_BYTES)
        self._anchor_core_cache: BoundedCache[list[tuple[np.ndarray, np.ndarray]]] = \
            BoundedCache(max_bytes=ANCHOR_CACHE_BYTES)
        self._yc0: float | None = None
        self._cache: BoundedCache[Any] = BoundedCache(max_bytes=REGRESSOR_CACHE_BYTES)
        self._static_cache: BoundedCache[tuple[list[np.ndarray], list[str], dict[str, np.ndarray]]] = \
            BoundedCache(max_bytes=STATIC_CACHE_BYTES)
        self._table_cache: BoundedCache[np.ndarray] = BoundedCache(max_bytes=TABLE_CACHE_BYTES)
        self._search_cache: BoundedCache[Any] = BoundedCache(max_entries=SEARCHES_KEPT)

    def _init_rows(self) -> None:
        """The least-squares rows, fold A's (of every recording) first, then fold B's (folds are
        slices), with their displacement and drive rate."""
        self._rows_ab = [(d.rows[d.fold[d.rows] == 0], d.rows[d.fold[d.rows] == 1]) for d in self.data]
        ya = [d.y[ra] for d, (ra, _) in zip(self.data, self._rows_ab)]
        yb = [d.y[rb] for d, (_, rb) in zip(self.data, self._rows_ab)]
        self.n_a = int(sum(a.size for a in ya))
        self.y_rows = np.concatenate(ya + yb)
        self.segment_lengths = [a.size for a in ya] + [b.size for b in yb]
        rates = [np.abs(np.gradient(d.u, d.t)) if d.t.size > 1 else np.zeros(d.t.size) for d in self.data]
        self.rate_rows = np.concatenate([r[ra] for r, (ra, _) in zip(rates, self._rows_ab)] +
                                        [r[rb] for r, (_, rb) in zip(rates, self._rows_ab)])

    def _init_anchor(self) -> None:
        """The anchor (off until `use_anchor`): a constraint, not data. Each loop has its own free
        offset and scale, projected out: the sensor's zero and gain, the slow states and the rod's
        calibration on the day of identification are not this recording's, and a static
        recalibration is the diagnosis data's to learn. What is held is the shape of the base's
        loops (the base's own output projects to zero), to within its identification error there."""
        self._anchor_free = [_affine_basis(d.y[d.rows]) for d in self.anchor]
        edges = np.cumsum([0] + [d.rows.size for d in self.anchor])
        self._anchor_slices = [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]   # per loop, in its rows
        self.anchor_on = False
        self._anchor_tol = np.full(len(self.anchor), math.nan)

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
        return self._core_cache.get_or_compute(self.input_key(spec), lambda: self._run_core(spec, self.data))

    def anchor_core(self, spec: Spec) -> list[tuple[np.ndarray, np.ndarray]]:
        """The same per identification loop of the anchor: shared by every spec with the same input
        key (a resonance's grid runs the core on the loops once, not once per point)."""
        return self._anchor_core_cache.get_or_compute(self.input_key(spec), lambda: self._run_core(spec, self.anchor))

    def _run_core(self, spec: Spec, data: Sequence[RecData]) -> list[tuple[np.ndarray, np.ndarray]]:
        core = self.model
        for c in self._core_fx:
            if c.name in spec:
                core = c.fit_core(self, core, spec[c.name])
        out = []
        for d in data:
            u3 = self.core_input(d, spec)
            s = self.stress(d, spec) if self.model.stress_range_MPa is not None else None
            yc = np.asarray(core.simulate(d.t, u3, s, initial_state=d.start), dtype=float)
            out.append((u3, yc))
        return out

    def identification_levels(self) -> list[float]:
        return stress_levels(self.identification, gap_MPa=self.settings.min_stress_span_MPa)

    def identified_core(self, loop_width: tuple[float, float] | None = None,
                        creep: tuple[float, float] | None = None) -> Any:
        """The base identified again on the measured identification loops by its own settings (with
        a loop width that follows stress, or through a creep, when given), once per setting; None
        without those loops (`diagnose --ident`) or when the fit fails."""
        if not self.identification:
            return None
        width = None if loop_width is None else (float(loop_width[0]), float(loop_width[1]))
        through = None if creep is None else (float(creep[0]), float(creep[1]))
        with self._identify_lock:
            if (width, through) not in self._identified:
                self._identified[(width, through)] = identify_on(self.model, self.identification,
                                                                 loop_width=width, creep=through)
            return self._identified[(width, through)]

    def plain_core(self, spec: Spec) -> Any:
        """The core the spec's extended model is built on: the given one, or the one an effect that
        reshapes the core identified again, as the diagnosis ran it (`_run_core`) with what each
        effect put around it taken off (the widening, the creep: those are the effects' blocks)."""
        core = self.model
        for c in self._core_fx:
            if c.name in spec:
                core = c.fit_core(self, core, spec[c.name])
        while isinstance(core, CoreAround):
            core = core.base
        return core

    def core_input(self, d: RecData, spec: Spec) -> np.ndarray:
        u = d.u
        for c in self._inputs:
            if c.name in spec:
                u = c.filter_input(u, d, spec[c.name])
        return np.ascontiguousarray(u)

    def cached(self, key: tuple, compute: Callable[[], _T]) -> _T:
        """compute() once per key (e.g. a re-run of the core an effect's regressor needs)."""
        return self._cache.get_or_compute(key, compute)

    def searched(self, key: tuple, compute: Callable[[], _T]) -> _T:
        """compute() once per key and the fitter's loss and designs (its Huber scale, whether the anchor
        holds, the recalibration columns left out): a search's result is a function of these, its
        base and the effect searched alone (`scoring.search_all`)."""
        return self._search_cache.get_or_compute((self.delta, self.anchor_on, self.static_off) + key, compute)

    def cached_table(self, d: RecData, key: tuple, compute: Callable[[], np.ndarray]) -> np.ndarray:
        """compute() once per recording (or anchor loop) and key: a per-sample table that an effect's
        columns share across specs. Its own cache, so the many tables a search makes do not push
        `cached`'s entries out."""
        return self._table_cache.get_or_compute((id(d),) + key, compute)

    def stress_levels(self) -> list[float]:
        return stress_levels(self.data, gap_MPa=self.settings.min_stress_span_MPa)

    @property
    def yc_center(self) -> float:
        if self._yc0 is None:
            base = self.core(Spec())
            self._yc0 = float(np.mean(np.concatenate([yc for _, yc in base])))
        return self._yc0

    # ------------------------------------------------------------------ regressors
    def columns(self, d: RecData, u3: np.ndarray, yc: np.ndarray, spec: Spec,
                steady: bool = False) -> tuple[list[np.ndarray], list[str]]:
        """Full-length regressors of one recording (before row selection): the static map's, then
        each effect's in signal-path order (a filter effect transforms those before it). `steady`
        (the anchor's loops): effects that do not follow the drive loop (`follows_drive = False`:
        heating, a plugin's pickup) stay at their reference state, as the base absorbed whatever state
        its loops were recorded in; creep follows the drive (a loss of gain at the loops' rate)."""
        r = Regressors(d, u3, yc, self.input_key(spec), spec, [], [], {})
        # the static map's columns follow from the core's run alone (its input key): computed once
        # per recording and run, shared by every spec on that run (no effect changes an array in place)
        cols, names, shared = self._static_cache.get_or_compute((id(d), r.input_key),
                                                                lambda: self._static_columns(r))
        r.cols += cols
        r.names += names
        r.shared.update(shared)
        for c in self.effects:
            if c.stage != "input" and c.name in spec:
                first = len(r.cols)
                c.columns(self, r, spec[c.name])
                if steady and not c.follows_drive:   # a disturbance or slow state: at its reference there
                    r.cols[first:] = [np.zeros_like(col) for col in r.cols[first:]]
        self._sensor_zero_columns(r)                 # last: the sensor's zero passes through no effect's filter
        return r.cols, r.names

    def _static_columns(self, r: Regressors) -> tuple[list[np.ndarray], list[str], dict[str, np.ndarray]]:
        """The static map's columns (and its play bank) for r's recording and core run alone."""
        own = Regressors(r.d, r.u3, r.yc, r.input_key, r.spec, [], [], {})
        StaticMap.columns(self, own, None)
        return own.cols, own.names, own.shared

    @property
    def sensor_jumps(self) -> list[tuple[RecData, Jump]]:
        """Every recording's jumps of the sensor's zero, with the recording each belongs to."""
        return [(d, j) for d in self.data for j in d.jumps.found]

    def _sensor_zero_columns(self, r: Regressors) -> None:
        """The displacement sensor's zero, in every spec and no effect's: each recording after the
        first has its own (a sensor is often zeroed again between runs, and a constant difference
        between recordings is no evidence of heating or creep), and each jump within a recording
        (`jumps.py`) moves it from that sample on. Zero on rows of other recordings and on the anchor's."""
        n = r.d.t.size
        for i, owner in enumerate(self.data[1:], 1):
            r.cols.append(np.full(n, 1.0 if owner is r.d else 0.0))
            r.names.append(f"{SENSOR_ZERO}{i}")
        for i, (owner, jump) in enumerate(self.sensor_jumps):
            r.cols.append((np.arange(n) >= jump.index).astype(float) if owner is r.d else np.zeros(n))
            r.names.append(f"{SENSOR_JUMP}{i}")

    def design(self, spec: Spec) -> tuple[np.ndarray, list[str]]:
        """Regressors at the least-squares rows: fold A rows of every recording, then fold B rows."""
        X = np.empty((0, 0))
        names: list[str] = []
        a_at, b_at = 0, self.n_a
        for d, (u3, yc), (ra, rb) in zip(self.data, self.core(spec), self._rows_ab):
            cols, names = self.columns(d, u3, yc, spec)
            if X.size == 0:
                X = np.empty((self.y_rows.size, len(cols)), order="F")     # filled and solved by column
            a_at = _put_rows(X, a_at, cols, ra)
            b_at = _put_rows(X, b_at, cols, rb)
        return X, names

    def use_anchor(self, on: bool = True, fallback_tolerance_um: float = math.nan) -> None:
        """Hold every fit from now on within the base's identification error on its own loops
        (`anchor.py`); a loop without a recorded error gets `fallback_tolerance_um` (e.g. the
        data's noise floor: the base is not known better than a measurement)."""
        tol = np.array([float(d.extra.get("anchor_tolerance_um", math.nan)) for d in self.anchor])
        tol[~(tol > 0)] = fallback_tolerance_um
        self._anchor_tol = tol
        self.anchor_on = bool(on and self.anchor and np.all(tol > 0))

    def anchor_design(self, spec: Spec) -> np.ndarray:
        """Regressors at the anchor's rows, each loop's offset and base output projected out."""
        def compute() -> np.ndarray:
            X = np.empty((0, 0))
            for q, d, (u3, yc), k in zip(self._anchor_free, self.anchor, self.anchor_core(spec), self._anchor_slices):
                cols = self.columns(d, u3, yc, spec, steady=True)[0]
                if X.size == 0:
                    X = np.empty((self._anchor_slices[-1].stop, len(cols)), order="F")
                _put_rows(X, k.start, cols, d.rows)
                X[k] = _projected(q, X[k])
            return X

        return self._anchor_cache.get_or_compute(spec, compute)

    def _anchor_grams(self, spec: Spec) -> tuple[list[np.ndarray], list[float]]:
        """Per anchor loop, the quadratic form c' A_k c = (its RMS departure / its tolerance)^2, and
        what each loop may reach: 1 plus the departure the spec brings by itself (`_fit`). That is
        the larger of two: the least departure at gain 1 over all loops together, and the loop's own
        lag that stays (`_lag_that_stays`). The second matters for a law in stress: a resonance that
        moves with the load lags the heaviest loop most, and the least departure over all loops takes
        it from that loop to spread it. A loop held below its own lag drags the fit away from the law
        the data show (a resonance law that cut a probe at another load from 3.6 to 0.14 um lost to a
        load-independent one). Cached per spec."""
        def compute() -> tuple[list[np.ndarray], list[float]]:
            Xa = self.anchor_design(spec)
            grams = [Xa[k].T @ Xa[k] / ((k.stop - k.start) * t * t)
                     for k, t in zip(self._anchor_slices, self._anchor_tol)]
            least = _least_departure(np.sum(grams, axis=0))
            stays = self._lag_that_stays(spec)
            return grams, [1.0 + max(float(least @ A @ least), s) for A, s in zip(grams, stays)]

        return self._gram_cache.get_or_compute(spec, compute)

    def _lag_that_stays(self, spec: Spec) -> list[float]:
        """Per anchor loop, (departure / tolerance)^2 of the core's output at gain 1 through the spec's
        effects that no rebase takes back out: all but the input-side ones, whose lag the core
        identified again through them gives back (`rebase.py`). Zero without such an effect."""
        rebased = {c.name for c in self._inputs}
        kept = Spec((name, p) for name, p in spec.items() if name not in rebased)
        if not any(c.stage == "filter" and c.name in kept for c in self.effects):
            return [0.0] * len(self.anchor)
        gain = self.anchor_design(kept)[:, 0]
        return [float(np.mean(gain[k] ** 2)) / (t * t) for k, t in zip(self._anchor_slices, self._anchor_tol)]

    def anchor_deviation(self, spec: Spec, coef: np.ndarray) -> list[float]:
        """Per anchor loop, the RMS by which the model (spec, coefficients) departs from the base's
        loop, offset and scale aside."""
        if not self.anchor:
            return []
        r = self.anchor_design(spec) @ coef
        return [float(np.sqrt(np.mean(r[k] ** 2))) for k in self._anchor_slices]

    def loops_misfit(self, spec: Spec, coef: np.ndarray, shared_scale: bool = True) -> float:
        """RMS by which the model (spec, coefficients) misses the measured identification loops
        (`diagnose --ident`), each loop's offset free, and with `shared_scale` one scale shared by
        them all: one day, one sensor calibration. The anchor frees each loop's scale too, so it
        cannot see how the gain changes from one load to another; this can. Without the shared
        scale, the model's own gain is judged too. NaN without measured loops at two or more loads
        (`min_stress_span_MPa` apart)."""
        measured = {id(d) for d in self.identification}
        loops = [(d, run) for d, run in zip(self.anchor, self.anchor_core(spec)) if id(d) in measured]
        stresses = [float(np.median(d.s[d.rows])) for d, _ in loops]
        if len(loops) < 2 or np.ptp(stresses) < self.settings.min_stress_span_MPa:
            return math.nan
        predicted, offsets, ys = [], [], []
        for k, (d, (u3, yc)) in enumerate(loops):
            cols = self.columns(d, u3, yc, spec, steady=True)[0]
            predicted.append(np.column_stack(cols)[d.rows] @ coef)
            ys.append(d.y[d.rows])
            offsets.append(np.full(d.rows.size, k))
        y = np.concatenate(ys)
        zeros = [np.concatenate(offsets) == k for k in range(len(loops))]
        # the prediction against the measurement, each loop's zero (and the shared scale) fitted
        p = np.concatenate(predicted)
        free, miss = (np.column_stack(zeros + [y]), p) if shared_scale else (np.column_stack(zeros), p - y)
        free = free.astype(float)
        return float(np.sqrt(np.mean((miss - free @ np.linalg.lstsq(free, miss, rcond=None)[0]) ** 2)))

    def score_identity_map(self, specs: tuple[Spec, Spec, Spec]) -> Score:
        """`score` with the static map held at the identity: gain 1, and no curvature, stress gain
        or loop-width plays. Only each recording's own zero (the offset, the later recordings'
        sensor zeros, the jumps) is fitted, by least squares, on each fold and on all rows. For a
        model whose law and core are the identification loops' own (`fitted_on_loops`): it has no
        column of its own, so nothing else is fitted on these recordings."""
        y = self.y_rows
        na = self.n_a
        folds = ((slice(0, na), slice(na, None)), (slice(na, None), slice(0, na)))
        designs = {spec: self.design(spec) for spec in dict.fromkeys(specs)}    # the folds' specs are often one
        sse_train, sse_test, n_train, n_test, sq_test = [], [], [], [], []
        for f, (tr, te) in enumerate(folds):
            X, names = designs[specs[f]]
            c = self._identity_map_coef(X, names, tr)
            r_tr, r_te = y[tr] - X[tr] @ c, y[te] - X[te] @ c
            sse_train.append(self.loss(r_tr))
            sse_test.append(self.loss(r_te))
            sq_test.append(float(r_te @ r_te))
            n_train.append(int(r_tr.size))
            n_test.append(int(r_te.size))
        X, names = designs[specs[2]]
        c_all = self._identity_map_coef(X, names, slice(None))
        r_all = y - X @ c_all
        return Score(tuple(sse_train), tuple(sse_test), tuple(n_train), tuple(n_test),  # type: ignore[arg-type]
                     self.loss(r_all), int(r_all.size), c_all, names, tuple(sq_test))  # type: ignore[arg-type]

    def identity_map_coef(self, spec: Spec) -> np.ndarray:
        """The coefficients of `score_identity_map` on all rows: gain 1, each recording's zero fitted."""
        X, names = self.design(spec)
        return self._identity_map_coef(X, names, slice(None))

    def identity_map_left_out(self, spec: Spec) -> list["LeftOut"]:
        """`left_out` with the static map held at the identity (`score_identity_map`): each recording
        predicted with gain 1, its own zero fitted on it."""
        X, names = self.design(spec)
        y = self.y_rows
        out = []
        blocks = self.row_blocks()
        for k, test in enumerate(blocks):
            train = np.concatenate([b for j, b in enumerate(blocks) if j != k])
            c = self._identity_map_coef(X, names, train)
            out.append(self._left_out_score(X, y, train, test, c, self.loss(y[train] - X[train] @ c), int(train.size)))
        return out

    def _identity_map_coef(self, X: np.ndarray, names: Sequence[str], rows: slice | np.ndarray) -> np.ndarray:
        """The coefficients of `score_identity_map` fitted on `rows` of the design X: gain 1, the zeros free."""
        zero = np.array([n == "offset" or n.startswith((SENSOR_ZERO, SENSOR_JUMP)) for n in names])
        gain = names.index("gain")
        c = np.zeros(len(names))
        c[gain] = 1.0
        c[zero] = np.linalg.lstsq(X[rows][:, zero], self.y_rows[rows] - X[rows, gain], rcond=None)[0]
        return c

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

    def _solve(self, X: np.ndarray, y: np.ndarray, penalty: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Least squares (plus c' penalty c); with a Huber scale, two reweighting passes so a few
        bursts (a load change the core cannot follow) do not steer the fit. Returns the coefficients
        and the last pass's scaled normal equations (G, b, column scale) for cheap re-solves."""
        X = np.asfortranarray(X)     # a fold's rows of the design: the kernels run down whole columns
        m = X.shape[1]
        scale = np.sqrt(np.einsum("ij,ij->j", X, X) / X.shape[0])   # the columns' RMS; np.mean(X * X, axis=0)
        scale[scale == 0] = 1.0                                       # took 3x as long (a strided reduction)
        inv = 1.0 / scale
        P = np.zeros((m, m)) if penalty is None else penalty / np.outer(scale, scale)
        G, b, c = np.empty((m, m)), np.empty(m), np.zeros(m)
        w, r = np.ones(X.shape[0]), np.empty(X.shape[0])
        for _ in range(1 if self.delta is None else 3):
            LK.weighted_normal(X, inv, w, y, G, b)
            G.flat[:: m + 1] += 1e-10 * max(float(np.trace(G)), 1.0) / m   # its diagonal
            c, info = _gesv(G + P, b)[2:]
            if info != 0:                   # singular: least squares on the scaled rows
                c = np.linalg.lstsq(X * inv, y, rcond=None)[0]
            if self.delta is not None:
                LK.huber_weights(X, c * inv, y, self.delta, r, w)
        return c * inv, G, b, scale

    def _fit(self, X: np.ndarray, y: np.ndarray, spec: Spec) -> tuple[np.ndarray, float, int]:
        """Coefficients on data rows (X, y), held near the base on the anchor's loops; the training
        loss on the data rows and their count.

        The discrepancy principle, per loop: the least anchor weight (each loop's scaled by its
        1/tolerance^2) that brings every loop within its tolerance, beyond the departure the spec
        brings by itself (a resonance's lag on the 3 Hz loops, say, which the base absorbed into its
        loops and no static term undoes: it is added to the tolerance in quadrature, see
        `_anchor_grams`), so an effect is never distorted into the data fit to chase it."""
        c, G, b, scale = self._solve(X, y)
        if self.anchor_on:
            grams, allowed = self._anchor_grams(spec)
            scaled = np.asarray(grams) / np.outer(scale, scale)     # (loops, terms, terms)
            reach = np.asarray(allowed)

            def worst(cs: np.ndarray) -> float:
                return float(np.max((scaled @ cs) @ cs / reach))     # every loop's c' A c at once

            if worst(c * scale) > 1.0:
                total = np.sum(scaled, axis=0)
                lam0 = float(np.trace(G)) / max(float(np.trace(total)), 1e-300)
                lo, hi = -8.0, 8.0          # the departures fall as the weight grows; bisect on its log
                best = _solve_normal(G + lam0 * 1e8 * total, b)
                for _ in range(ANCHOR_BISECTIONS):
                    mid = 0.5 * (lo + hi)
                    cs = _solve_normal(G + lam0 * 10.0 ** mid * total, b)
                    if worst(cs) > 1.0:
                        lo = mid
                    else:
                        hi, best = mid, cs
                c = best / scale            # the unconstrained fit's robust weights kept
        r = y - X @ c
        return c, self.loss(r), int(r.size)

    def score(self, specs: tuple[Spec, Spec, Spec], want_coef: bool = False) -> Score:
        """Fit fold A's spec on A, fold B's on B (each tested on the other), and the all-data spec;
        every fit is held by the anchor, no test sees it."""
        self.evaluations += 1
        y = self.y_rows
        designs: dict[Spec, np.ndarray] = {}
        names: list[str] = []

        def X_for(f: int) -> np.ndarray:
            """Fold f's design, kept only while a later fold shares its spec (each is rows x columns)."""
            nonlocal names
            spec = specs[f]
            X = designs.get(spec)
            if X is None:
                X, names = self.design(spec)
            if spec in specs[f + 1:]:
                designs[spec] = X
            else:
                designs.pop(spec, None)
            return X

        sse_train, sse_test, n_train, n_test, sq_test = [], [], [], [], []
        na = self.n_a
        for f in (0, 1):
            X = X_for(f)
            tr = slice(0, na) if f == 0 else slice(na, None)
            te = slice(na, None) if f == 0 else slice(0, na)
            c, loss_tr, n_tr = self._fit(X[tr], y[tr], specs[f])
            r_te = y[te] - X[te] @ c
            sse_train.append(loss_tr)
            sse_test.append(self.loss(r_te))
            sq_test.append(float(r_te @ r_te))
            n_train.append(n_tr)
            n_test.append(int(r_te.size))
            del X                       # before the next fold's design is built
        X = X_for(2)
        c_all, loss_all, n_all = self._fit(X, y, specs[2])
        return Score(tuple(sse_train), tuple(sse_test), tuple(n_train), tuple(n_test),  # type: ignore[arg-type]
                     loss_all, n_all, c_all if want_coef else None, names, tuple(sq_test))  # type: ignore[arg-type]

    @functools.cached_property
    def held_rows(self) -> np.ndarray:
        """At the least-squares rows, whether the drive holds there (`drive.held`; found when first
        asked, as only stress-dependent play's signature asks)."""
        still = [held(d.t, d.u) for d in self.data]
        return np.concatenate([h[ra] for h, (ra, _) in zip(still, self._rows_ab)] +
                              [h[rb] for h, (_, rb) in zip(still, self._rows_ab)])

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

    def left_out(self, spec: Spec) -> list["LeftOut"]:
        """Each recording predicted by the spec fitted on the other recordings alone (gains only: its
        nonlinear parameters as given), its own nuisance (its sensor zero and jumps: columns no
        other recording has, and a constant) fitted on it. Held by the anchor like every fit."""
        return self.left_out_blocks(spec, self.row_blocks())

    def level_blocks(self) -> list[np.ndarray]:
        """Where the rows of each (recording, stress level) sit in `y_rows`: each recording's rows split
        by the stress level (`stress_levels`) nearest their stress. A load-change recording gives a
        block per load; a recording at one load, one block."""
        levels = np.array(self.stress_levels() or [0.0])
        stress = self._row_stress()
        out = []
        for idx in self.row_blocks():
            near = np.argmin(np.abs(stress[idx][:, None] - levels[None, :]), axis=1)
            out += [idx[near == k] for k in range(levels.size) if np.any(near == k)]
        return out

    def left_out_blocks(self, spec: Spec, blocks: Sequence[np.ndarray], off: Sequence[str] = ()) -> list["LeftOut"]:
        """Each of the row `blocks` (a recording's rows: `row_blocks`; a stress level's: `level_blocks`)
        predicted by the spec fitted on the others, with the columns named in `off` left out of every
        fit; a column the training rows do not determine (a stress gain over one stress) is left out too."""
        X, names = self.design(spec)
        y = self.y_rows
        stress = self._row_stress()
        out = []
        for k, test in enumerate(blocks):
            train = np.concatenate([b for j, b in enumerate(blocks) if j != k])
            span = float(np.ptp(stress[train])) if train.size else 0.0
            keep = self._identifiable(X[train], names, span) & ~np.isin(np.array(names), list(off))
            Xk = np.where(keep, X, 0.0)
            c, loss_tr, n_tr = self._fit(Xk[train], y[train], spec)
            out.append(self._left_out_score(Xk, y, train, test, np.where(keep, c, 0.0), loss_tr, n_tr))
        return out

    def _row_stress(self) -> np.ndarray:
        """The recorded stress at each of `y_rows` (0 without stress)."""
        s = np.zeros(self.y_rows.size)
        for d, idx, (ra, rb) in zip(self.data, self.row_blocks(), self._rows_ab):
            if d.s is not None:
                s[idx] = np.concatenate([d.s[ra], d.s[rb]])
        return s

    def drop_static(self, names: Sequence[str]) -> None:
        """Leave the static recalibration's columns `names` out of every design from now on (the
        caches holding them emptied)."""
        self.static_off = frozenset(names)
        for cache in (self._static_cache, self._anchor_cache, self._gram_cache):
            cache.clear()

    def _identifiable(self, X: np.ndarray, names: Sequence[str], stress_span: float) -> np.ndarray:
        """Which columns the training rows X determine, in design order (a column that the earlier
        ones already span is left at zero: on one recording its sensor zero is the offset), and no
        stress term (`stress_*`) when the training stresses span less than the fitter's
        `min_stress_span_MPa`: a recording at one load says nothing of how gains change with load,
        and a split of its gain into a gain and a stress gain would be extrapolated to the load left out."""
        keep = np.zeros(X.shape[1], dtype=bool)
        basis = np.zeros((X.shape[0], 0))
        for j in range(X.shape[1]):
            col = X[:, j]
            norm = float(np.linalg.norm(col))
            if norm == 0.0 or (names[j].startswith("stress_") and stress_span < self.settings.min_stress_span_MPa):
                continue
            r = col - basis @ (basis.T @ col)
            r = r - basis @ (basis.T @ r)            # twice: Gram-Schmidt keeps its orthogonality
            rn = float(np.linalg.norm(r))
            if rn <= RANK_TOL * norm:
                continue
            basis = np.column_stack([basis, r / rn])
            keep[j] = True
        return keep

    def _left_out_score(self, X: np.ndarray, y: np.ndarray, train: np.ndarray, test: np.ndarray, c: np.ndarray,
                        loss_tr: float, n_tr: int) -> "LeftOut":
        r = y[test] - X[test] @ c
        own = ~np.any(X[train] != 0.0, axis=0)          # columns only the left-out recording has
        nuis = np.column_stack([np.ones(test.size), X[test][:, own]])
        r = r - nuis @ np.linalg.lstsq(nuis, r, rcond=None)[0]
        return LeftOut(loss_tr / max(n_tr, 1), self.loss(r), float(r @ r), int(r.size))

    def test_residuals(self, specs: tuple[Spec, Spec, Spec]) -> np.ndarray:
        """Held-out residuals at the least-squares rows (each fold predicted by the other fold's fit)."""
        y = self.y_rows
        na = self.n_a
        out = np.empty_like(y)
        for f in (0, 1):
            X, _ = self.design(specs[f])
            tr = slice(0, na) if f == 0 else slice(na, None)
            te = slice(na, None) if f == 0 else slice(0, na)
            c = self._fit(X[tr], y[tr], specs[f])[0]
            out[te] = y[te] - X[te] @ c
        return out


SENSOR_ZERO = "sensor_zero_"   # the columns' name prefixes of each later recording's sensor zero and of each
SENSOR_JUMP = "sensor_jump_"   # jump of it: a recording's own zero, fitted even where the static map is held
RANK_TOL = 1e-9         # a column whose part outside the earlier ones is below this share of its norm adds
                        # nothing the rows can tell (double precision's rounding on ~1e4 rows is ~1e-12)
ANCHOR_BISECTIONS = 16   # on the log of the anchor weight over 16 decades: 2.4e-4 of a decade
def _affine_basis(y: np.ndarray) -> np.ndarray:
    """Orthonormal basis of {constant, y}: an anchor loop's free offset and scale."""
    q, _ = np.linalg.qr(np.column_stack([np.ones(y.size), y]))
    return q


def _least_departure(T: np.ndarray) -> np.ndarray:
    """The coefficients of least anchor departure c'Tc at gain 1 (the static map's first column,
    the core's output, held: a model may not escape the anchor by shrinking to nothing)."""
    c = np.zeros(T.shape[0])
    c[0] = 1.0
    if T.shape[0] > 1:
        c[1:] = -np.linalg.lstsq(T[1:, 1:], T[1:, 0], rcond=None)[0]
    return c


_gesv = lapack.dgesv     # (lu, piv, x, info); info > 0: singular


def _solve_normal(G: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve G c = b (least squares on G if it is singular). LAPACK's gesv, as numpy.linalg.solve
    calls it, without numpy's wrapping: the anchor's bisection solves a small system half a
    million times in a diagnosis, and the wrapping was four fifths of each."""
    c, info = _gesv(G, b)[2:]
    return c if info == 0 else np.linalg.lstsq(G, b, rcond=None)[0]


def _put_rows(X: np.ndarray, at: int, cols: list[np.ndarray], rows: np.ndarray) -> int:
    """Write the columns' values at `rows` into X's rows from `at` on, column by column (no block
    per recording to stack after); returns the row after the last written."""
    end = at + rows.size
    for j, c in enumerate(cols):
        X[at:end, j] = c[rows]
    return end


def _projected(q: np.ndarray, a: np.ndarray) -> np.ndarray:
    """`a` (a vector or the columns of a matrix) with its components along the basis `q` removed."""
    return a - q @ (q.T @ a)
