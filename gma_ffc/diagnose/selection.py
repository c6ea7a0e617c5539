"""Which effects the recordings show: a forward selection on held-out blocks, as an estimator.

    sel = EffectSelector().fit(model, recordings)
    sel.outcome_, sel.verdict_, sel.candidates_, sel.extended_model_, sel.diagnosis_

Selection is greedy and forward: each round fits every untried effect of the registry
(`gma_ffc.effects`) on top of what is already accepted and scores it on held-out time blocks.
The best is accepted only if it (1) lowers the held-out loss by a clear margin, (2) wins a
penalised held-out likelihood test with the residual's effective sample count, (3) removes a
residual above the noise floor measured from the data, and (4) passes its own signature check.
The null model every effect must beat is the base model with a static recalibration (gain,
offset, curvature, stress gain, loop width): ordinary model error of that kind is never called
an effect. With two or more accepted, a swap pass asks whether each is still the best choice for
its slot with the others in place. Final guards then refuse anything that is worse than the base
as given, or fitted to a drive the model's class cannot follow.
"""

from __future__ import annotations

import dataclasses
import math
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable, Sequence

import numpy as np

from .. import effects as effect_registry
from ..effects import REGISTRY
from ..effects.base import SignatureCheck, geom_refine
from ..effects.static import StaticMap
from ..errors import InputError
from ..extended import ExtendedModel
from ..recordings import Recording
from ..drive import reversals
from .checks import check_overlap
from .anchor import anchor_data, anchor_words
from .rebase import reidentify_through
from .data import N_BLOCKS, RecData, noise_floor, prepare, unscored_note
from .noise import mad_sigma
from .jumps import jump_words, sensor_jumps
from .explain import decider, drive_unit, explain, identification_rms, runner_up_note, validation_words
from .fitting import ZOOM_LEVELS, Fitter, SearchResult, Spec, search
from .locate import locate
from .results import Candidate, Diagnosis
from .timing import displacement_lead

Specs = tuple[Spec, Spec, Spec]          # fold A's, fold B's and the all-data spec

MIN_REVERSALS = 2 * N_BLOCKS   # drive turning points in all: on average a full drive cycle per time block, or a
                               # held-out block is a piece of one branch that the neighbouring training blocks
                               # interpolate, and blocked cross-validation tests interpolation, not prediction


class EffectSelector:
    """Select the physical effects missing from a model, scikit-learn style.

    Parameters (each threshold with its reason; `tests/test_diagnose_thresholds.py` moves every
    one by 30 % either way and the verdicts of a benchmark subset must not flip):

    max_effects
        Rounds of forward selection: at most this many effects are named.
    min_mse_ratio (0.75)
        An accepted effect cuts the held-out loss to at most this fraction (RMS by ~13 %): a
        smaller gain is within what a more flexible model buys on any data.
    min_loglik_gain (6.0 nats)
        Penalised held-out log-likelihood gain an effect must win by (one nat per parameter
        already subtracted): with the effective sample count of the residual, about the evidence
        of a likelihood-ratio test at p ~ 0.001 per added parameter group.
    noise_factor (1.5)
        A held-out residual within 1.5x the noise floor estimated from the data is "within
        noise": the floor itself is estimated to ~20 %, and sensor noise is all that is left.
    model_error_factor (3.0)
        Below 3x the noise floor, what a recalibrated core leaves is ordinary identification
        error (a core fitted to similar data reaches 2-3x its sensor noise): nothing to explain.
        Also the tolerance of saturation's "the curve turns round" check.
    slow_ratio_max (0.8)
        Play weights are rate-independent, so stress_dependent_play must also cut the error on
        the slowest 40 % of samples, by 20 %: a gain from the fast parts is another effect's leftover.
    ambiguous_nats (3.0)
        A runner-up within 3 nats of the winner (likelihood ratio ~20) is a look-alike the data
        do not tell apart: the outcome is inconclusive, with the experiment that would decide.
    huber_k (3.0)
        The Huber scale in robust standard deviations of the recalibrated residual: bursts no
        model can follow (a load change) weigh in linearly, Gaussian noise never reaches it.
    min_samples (400)
        Scored samples needed at all; below, any effect is fitted to the loops it is judged on.
    workers (2)
        Candidate searches in parallel threads (numba kernels and BLAS release the GIL).
    initial_state ("estimate")
        The core's hysteresis state at each recording's first sample, by the rule every model run
        shares (`gma_ffc.initial_state`): estimated from the measured displacement by default;
        whatever the rule, nothing before the state has settled is scored.

    Attributes after `fit`: `outcome_`, `verdict_`, `candidates_`, `extended_model_` and the whole
    `diagnosis_` (`gma_ffc.diagnose.results.Diagnosis`, what the report shows).
    """

    def __init__(self, max_effects: int = 3, *, min_mse_ratio: float = 0.75, min_loglik_gain: float = 6.0,
                 noise_factor: float = 1.5, model_error_factor: float = 3.0, slow_ratio_max: float = 0.8,
                 ambiguous_nats: float = 3.0, huber_k: float = 3.0, min_samples: int = 400,
                 workers: int = 2, initial_state: Any = "estimate") -> None:
        self.max_effects = max_effects
        self.min_mse_ratio = min_mse_ratio
        self.min_loglik_gain = min_loglik_gain
        self.noise_factor = noise_factor
        self.model_error_factor = model_error_factor
        self.slow_ratio_max = slow_ratio_max
        self.ambiguous_nats = ambiguous_nats
        self.huber_k = huber_k
        self.min_samples = min_samples
        self.workers = workers
        self.initial_state = initial_state

    def fit(self, model: Any, recordings: Sequence[Recording],
            progress: Callable[[str], None] | None = None) -> "EffectSelector":
        """Run the whole diagnosis (no I/O) and keep its results in the trailing-underscore attributes."""
        run = _Run(self, model, recordings, progress)
        run.precheck()
        run.null_model()
        run.open_candidates()
        run.forward_rounds()
        run.swap_pass()
        run.rebase()
        run.final_guards()
        dg = run.outcome()
        self.diagnosis_ = dg
        self.outcome_ = dg.outcome
        self.verdict_ = list(dg.verdict)
        self.candidates_ = list(dg.candidates)
        self.extended_model_ = dg.extended
        return self

    def accepts(self, best: Candidate, cur_loss: float, noise: float) -> bool:
        """The acceptance rule of one round (before the winner's signature check)."""
        return self.earns_place(best.cv_loss, best.loglik_gain, cur_loss, noise)

    def earns_place(self, loss: float, loglik_gain: float, loss_without: float, noise: float) -> bool:
        """Does an effect that takes the held-out loss from `loss_without` to `loss` (with that
        log-likelihood gain, its parameters paid for) earn its place in the model?"""
        return (loss < self.min_mse_ratio * loss_without and loglik_gain > self.min_loglik_gain
                and math.sqrt(loss_without) - math.sqrt(loss) > 0.5 * noise)


def loglik_gain(n_eff: float, loss_without: float, loss: float, n_params: int) -> float:
    """Penalised held-out log-likelihood gain (nats) of a model that takes the loss per sample from
    `loss_without` to `loss` on n_eff effectively independent samples, one nat per parameter."""
    return 0.5 * n_eff * math.log(loss_without / max(loss, 1e-300)) - n_params


def effective_samples(resid: np.ndarray, lengths: Sequence[int]) -> float:
    """Independent samples in a residual (per recording: length / integrated correlation time)."""
    total = 0.0
    start = 0
    for n in lengths:
        r = resid[start:start + n]
        start += n
        if r.size < 8:
            total += r.size
            continue
        r = r - r.mean()
        var = float(r @ r) / r.size
        if var <= 0:
            total += r.size
            continue
        tau = 1.0
        for lag in range(1, min(r.size // 4, 2000)):
            rho = float(r[:-lag] @ r[lag:]) / (r.size * var)
            if rho < 0.05:
                break
            tau += 2 * rho
        total += r.size / tau
    return max(total, 1.0)


def params_of(fitter: Fitter, effect: str, spec: Spec, coef: np.ndarray, names: list[str]) -> dict[str, float]:
    """An effect's reported parameters for a spec and its all-data coefficients."""
    return REGISTRY[effect].fitted_params(fitter, spec[effect], dict(zip(names, coef)))


def build_extended(model: Any, fitter: Fitter, spec: Spec, coef: np.ndarray, names: list[str],
                   effects: list[str]) -> ExtendedModel:
    """The extended model for a spec and its all-data coefficients (through the file form, so it is validated)."""
    c = dict(zip(names, (float(v) for v in coef)))
    blocks = StaticMap.fitted_blocks(fitter, None, c)
    for cls in fitter.effects:
        if cls.name in spec:
            blocks.update(cls.fitted_blocks(fitter, spec[cls.name], c))
    return ExtendedModel(model, blocks, effects)


def _restarted(core: Any, data: Sequence[RecData], rule: Any) -> list[RecData]:
    """The recordings as they are (rows, folds, what is not scored), each with `core`'s own initial
    state by `rule`."""
    return [dataclasses.replace(d, start=core.resolve_initial_state(
        d.u, d.s if core.stress_range_MPa is not None else None, rule, d.y, d.t)) for d in data]


def _scored(d: RecData, r: np.ndarray) -> np.ndarray:
    """The residual with the samples that are not scored set to zero (`data.known_samples`)."""
    return d.scored_only(r)


class _Run:
    """One fit of the selector: the named steps share this state (nothing outlives `fit`)."""

    def __init__(self, sel: EffectSelector, model: Any, recordings: Sequence[Recording],
                 progress: Callable[[str], None] | None) -> None:
        self.sel = sel
        self.model = model
        self.recordings = recordings
        self.say = progress or (lambda _msg: None)
        self.cannot: list[str] = []
        self.accepted: list[str] = []
        self.rounds: list[dict] = []
        self.runner_note = ""
        self.ambiguous_pairs: list[tuple[str, str]] = []
        self.swapped: list[tuple[str, str, float, float]] = []
        self.outside_class = ""
        self.base_kept = False
        self.ext_core: Any = model          # the core the extended model is built on (`rebase`)
        self.rebase_note = ""

    # ------------------------------------------------------------------ step 1: pre-checks
    def precheck(self) -> None:
        """Overlap with the model's ranges, enough samples and loops, what is not scored."""
        sel, recordings = self.sel, self.recordings
        if not recordings:
            raise InputError("give at least one recording to compare with the model")
        check_overlap(self.model, recordings)
        self.data = data = prepare(recordings, self.model, sel.initial_state)
        self.fitter = Fitter(self.model, data, anchor_data(self.model, min(d.dt_med for d in data)))
        self.n_samples = sum(d.n_scored for d in data)   # samples scored: where the initial state is known
        n_rev = sum(reversals(d.u[run]) for d in data for run in d.scored_runs())
        for d in data:
            note = unscored_note(d)
            if d.n_scored == 0:
                self.cannot.append(note)
            elif note:
                d.extra["settled_note"] = note
        # each fold needs scored rows to fit on: a fold without any would be fitted to nothing
        self.too_little = (self.n_samples < sel.min_samples or n_rev < MIN_REVERSALS
                           or min(self.fitter.n_a, self.fitter.y_rows.size - self.fitter.n_a) == 0)
        if self.too_little:
            self.cannot.append(
                f"too little data to tell effects apart ({self.n_samples} samples, {n_rev} drive reversals in all): "
                "any effect would be fitted to the same few loops it is judged on; record at least a few cycles "
                f"(>= {MIN_REVERSALS // 2} full loops, >= {sel.min_samples} samples) at two or more drive frequencies")
        for d in data:
            if d.clamped_fraction > 0.01:
                self.cannot.append(f"{d.name}: {d.clamped_fraction:.0%} of the samples are at stresses outside the "
                                   "model's range; they were compared at the nearest stress of the range")
        self.noise = float(np.median([noise_floor(d.y) for d in data]))
        self.fitter.use_anchor(fallback_tolerance_um=self.noise)

    # ------------------------------------------------------------------ step 2: the null model
    def null_model(self) -> None:
        """The base as given (rms_before) and recalibrated (the null every effect must beat)."""
        fitter, data = self.fitter, self.data
        self.say("simulating the base model")
        base_core = fitter.core(Spec())
        _ = fitter.yc_center          # computed once, before any threads share the fitter
        self.base_pred = [yc for _, yc in base_core]
        for d, yc in zip(data, self.base_pred):     # before any fit: each jump is a column of every design
            d.jumps = sensor_jumps(d.y, yc, d.u, d.recorded_stress, d.t, d.dt_med, d.settled)
            if d.jumps.excess:
                self.cannot.append(f"{d.name}: {jump_words(d.jumps)}")
        # over the scored samples; over all of them when none is (the figure then says how far off the
        # transient is, and cannot_conclude says that nothing was scored)
        judged = [d.mask if self.n_samples else np.ones(d.t.size, bool) for d in data]
        self.rms_before = float(np.sqrt(sum(float(np.sum((d.y - yc)[m] ** 2)) for d, yc, m
                                            in zip(data, self.base_pred, judged)) / max(sum(map(np.sum, judged)), 1)))
        if self.too_little:
            self._nothing_to_fit()
            return
        null_specs = (Spec(), Spec(), Spec())
        # Huber scale from the recalibrated base's held-out residual: bursts the core cannot follow at all
        # (e.g. a load change) then weigh in linearly, not quadratically, in fits and in the selection
        r0 = fitter.test_residuals(null_specs)
        fitter.delta = max(self.sel.huber_k * mad_sigma(r0), 2.0 * self.noise, 1e-12)
        null = fitter.score(null_specs, want_coef=True)
        assert null.coef_all is not None
        self.null_loss, self.null_cv = null.held_out_loss, null.held_out_mse
        self.null_pred = fitter.predict_full(Spec(), null.coef_all)
        self.located = [locate(d, _scored(d, d.y - yb), _scored(d, d.y - yn))
                        for d, yb, yn in zip(data, self.base_pred, self.null_pred)]
        self.current: Specs = null_specs
        self.cur_cv = self.null_cv
        self.cur_loss = self.null_loss
        self.final = SearchResult(null_specs, self.null_loss, self.null_cv, null.all_mse,
                                  null.n_held_out, null.coef_all, null.names, 1)

    def _nothing_to_fit(self) -> None:
        """Too little scored data to fit anything and judge it on other blocks: the base as given is
        the null and stays the model (a fit to a fold without rows has no coefficients, and one to a
        few loops would be judged on the loops it was fitted to)."""
        self.fitter.delta = max(2.0 * self.noise, 1e-12)
        self.null_loss = self.null_cv = self.rms_before ** 2
        self.null_pred = list(self.base_pred)
        self.located = [locate(d, _scored(d, d.y - yb), _scored(d, d.y - yb)) for d, yb in zip(self.data, self.base_pred)]
        self.current = (Spec(), Spec(), Spec())
        self.cur_cv = self.cur_loss = self.null_cv
        self.final = SearchResult(self.current, self.null_loss, self.null_cv, self.null_cv, 0, np.zeros(0), [], 0)

    # ------------------------------------------------------------------ step 3: what can be tested
    def open_candidates(self) -> None:
        fitter = self.fitter
        self.candidates = {cls.name: Candidate(cls.name, *cls.testable(fitter))
                           for cls in effect_registry.candidates()}
        if self.too_little:
            for c in self.candidates.values():
                c.testable, c.reason = False, c.reason or "too little data"
        if fitter.duration_max < 20.0:
            for name, c in self.candidates.items():
                if REGISTRY[name].slow and c.testable:
                    c.reason = (f"the longest recording lasts {fitter.duration_max:.3g} s: slow effects "
                                "(heating, creep) with time constants beyond it are hard to separate; "
                                "a run of several minutes with drive on/off phases would decide")
        for c in self.candidates.values():
            if not c.testable and c.reason and c.reason not in self.cannot and not self.too_little:
                self.cannot.append(f"{c.effect}: {c.reason}")

    # ------------------------------------------------------------------ step 4: forward rounds
    def forward_rounds(self) -> None:
        sel = self.sel
        for rnd in range(1, sel.max_effects + 1):
            if math.sqrt(self.cur_cv) <= sel.noise_factor * self.noise:
                break
            if not self._round(rnd):
                break

    def _round(self, rnd: int) -> bool:
        """One round; False when selection stops here."""
        sel, fitter = self.sel, self.fitter
        todo = [c for c in self.candidates.values() if c.testable and not c.accepted]
        self.say(f"round {rnd}: fitting {', '.join(c.effect for c in todo)}")
        results = self.search_all(self.current, [c.effect for c in todo])
        tried: list[Candidate] = []
        for c in todo:
            res = results[c.effect]
            c.result = res
            c.cv_mse = res.cv_mse
            c.cv_loss = res.cv_loss
            c.params = params_of(fitter, c.effect, res.specs[2], res.coef_all, res.names)
            c.round = rnd
            tried.append(c)
        if not tried:
            return False
        # effective sample count of the noise, from the best candidate's held-out residual
        leader = min(tried, key=lambda c: c.cv_loss)
        assert leader.result is not None
        n_eff = effective_samples(fitter.test_residuals(leader.result.specs), fitter.segment_lengths)
        for c in tried:
            c.loglik_gain = loglik_gain(n_eff, self.cur_loss, c.cv_loss, REGISTRY[c.effect].n_params)
        gains = np.array([c.loglik_gain for c in tried])
        top = max(0.0, float(gains.max()))
        weights = np.exp(np.clip(gains - top, -700, 0))
        norm = math.exp(-top) + float(weights.sum())
        for c, w in zip(tried, weights):
            c.evidence = float(w / norm)
        tried.sort(key=lambda c: c.cv_loss)
        best = tried[0]
        ok = sel.accepts(best, self.cur_loss, self.noise)
        # signature checks: a winner without its effect's signature is dropped, and the next one checked
        while ok:
            assert best.result is not None
            failure = REGISTRY[best.effect].signature(
                SignatureCheck(fitter, self.model, self.current, best.result, best.params, self.noise,
                               sel.slow_ratio_max, sel.model_error_factor))
            if failure is None:
                break
            best.testable, best.reason = False, failure.reason
            if failure.outside_class:
                self.outside_class = failure.reason
            tried = tried[1:]
            if not tried:
                return False
            best = tried[0]
            ok = sel.accepts(best, self.cur_loss, self.noise)
        self.rounds.append({"round": rnd, "n_eff": n_eff, "current_rms_um": math.sqrt(self.cur_cv),
                            "table": [(c.effect, math.sqrt(c.cv_mse), c.loglik_gain) for c in tried],
                            "accepted": best.effect if ok else None})
        if not ok:
            return False
        if len(tried) > 1 and tried[1].loglik_gain > sel.min_loglik_gain and \
                best.loglik_gain - tried[1].loglik_gain < sel.ambiguous_nats:
            self.ambiguous_pairs.append((best.effect, tried[1].effect))
        if rnd == 1 and len(tried) > 1:
            self.runner_note = runner_up_note(best, tried[1])
        assert best.result is not None
        best.accepted = True
        self.accepted.append(best.effect)
        self._take(best.result)
        return True

    def _take(self, res: SearchResult) -> None:
        self.current, self.cur_cv, self.cur_loss, self.final = res.specs, res.cv_mse, res.cv_loss, res

    def search_all(self, base: Specs, names: list[str]) -> dict[str, SearchResult]:
        """Search several effects on top of `base`, in parallel threads (the kernels release the GIL)."""
        fitter = self.fitter

        def one(name: str) -> SearchResult:
            cls = REGISTRY[name]

            def make(s: Spec, p: Any) -> Spec:
                return s.with_(name, p)

            partner = cls.joint_with
            if partner is None or partner not in base[2]:
                return search(fitter, base, make, cls.grid(fitter), cls.refine, getattr(cls, "zoom_levels", ZOOM_LEVELS),
                              cls.polish)

            # look-alikes trade off against each other: re-search the accepted one's value with the new one
            def make_joint(s: Spec, p: Any) -> Spec:
                return s.with_(name, p[0]).with_(partner, s[partner] * p[1])

            def refine(f: Fitter, p: Any, level: int) -> list:
                own = cls.refine(f, p[0], level)
                out = [(q, p[1]) for q in own] if own is not None else []
                return out + [(p[0], min(p[1] * m, 1.5)) for m in geom_refine(1.0, 1.6, level)]

            grid = [(p, k) for p in cls.grid(fitter) for k in (0.3, 0.55, 0.8, 1.0)]
            return search(fitter, base, make_joint, grid, refine)

        workers = min(self.sel.workers, max(len(names), 1))
        if workers <= 1:
            return {n: one(n) for n in names}
        with ThreadPoolExecutor(max_workers=workers) as pool:
            return dict(zip(names, pool.map(one, names)))

    # ------------------------------------------------------------------ step 5: swap pass
    def swap_pass(self) -> None:
        """With the other accepted effects in place, is each one still the best choice for its slot?
        (the first rounds judge look-alikes against a residual dominated by the biggest effect)"""
        if len(self.accepted) < 2:
            return
        fitter, candidates = self.fitter, self.candidates
        importance: dict[str, float] = {}
        self.ambiguous_pairs = []
        n_eff_last = self.rounds[-1]["n_eff"] if self.rounds else 1.0
        for name in list(self.accepted):
            if name not in self.accepted:
                continue
            others: Specs = tuple(s.without(name) for s in self.current)  # type: ignore[assignment]
            o = fitter.score(others)
            o_cv = o.held_out_loss
            best_name, best_res = name, None
            slot: list[tuple[float, str]] = []
            rivals = [c.effect for c in candidates.values() if c.testable and not (c.accepted and c.effect != name)]
            self.say(f"checking {name} against the others with the other effects in place")
            found = self.search_all(others, rivals)
            for cand_name in rivals:
                res = found[cand_name]
                slot.append((res.cv_loss, cand_name))
                if best_res is None or res.cv_loss < best_res.cv_loss:
                    best_name, best_res = cand_name, res
            if best_res is None:
                continue
            slot.sort()
            if len(slot) > 1 and \
                    0.5 * n_eff_last * math.log(slot[1][0] / max(slot[0][0], 1e-300)) < self.sel.ambiguous_nats:
                self.ambiguous_pairs.append((slot[0][1], slot[1][1]))
            if best_name != name and best_res.cv_loss < self.cur_loss:
                swap = candidates[best_name]
                candidates[name].accepted = False
                swap.accepted = True
                swap.result = best_res
                swap.cv_mse = best_res.cv_mse
                swap.cv_loss = best_res.cv_loss
                swap.params = params_of(fitter, best_name, best_res.specs[2], best_res.coef_all, best_res.names)
                self.swapped.append((name, best_name, math.sqrt(candidates[name].cv_mse), math.sqrt(best_res.cv_mse)))
                self.accepted[self.accepted.index(name)] = best_name
                self._take(best_res)
                name = best_name
            importance[name] = o_cv - self.cur_loss
        self.accepted.sort(key=lambda n: -importance.get(n, 0.0))

    # ------------------------------------------------------------------ step 5b: the core through the effects
    def rebase(self) -> None:
        """With an input-side effect named (eddy lag, delay), the core identified again through it on
        the base's own loops (`rebase.py`: the base had absorbed the effect's lag there, and the
        effect in front of it would undo that lag twice); kept when the final specs, refitted on it,
        are no worse on held-out blocks."""
        if self.too_little or not self.accepted:
            return
        if not any(REGISTRY[name].stage == "input" for name in self.accepted):
            return
        fitter, final = self.fitter, self.final
        ext = build_extended(self.model, fitter, final.specs[2], final.coef_all, final.names, list(self.accepted))
        inputs = [e for e in ext.chain if e.stage == "input"]
        names = ", ".join(k for e in inputs for k in e.to_blocks())
        self.say(f"identifying the core again through {names}")
        core = reidentify_through(self.model, inputs, fitter.anchor)    # the base's loops, as the anchor holds them
        if core is None:
            return
        # the same recordings and scored rows (the anchor's: the base's loops and tolerances), each
        # with the new core's own initial state
        data = _restarted(core, self.data, self.sel.initial_state)
        refit = Fitter(core, data, _restarted(core, fitter.anchor, "relaxed"))
        refit.use_anchor(fallback_tolerance_um=self.noise)
        refit.delta = fitter.delta
        sc = refit.score(final.specs, want_coef=True)
        assert sc.coef_all is not None
        cv_mse, cv_loss = sc.held_out_mse, sc.held_out_loss
        if cv_mse > self.cur_cv:
            self.rebase_note = (f" The core identified again through {names} on the base's own loops was not "
                                f"kept: held-out {math.sqrt(cv_mse):.4g} um against {math.sqrt(self.cur_cv):.4g} um.")
            return
        self.rebase_note = (f" The core was identified again through {names} on the base's own identification "
                            "loops, so that core and effect together give back the base there (the base had "
                            "absorbed the effect's lag into those loops; in front of the base as it was, the "
                            f"effect would undo that lag twice): held-out {math.sqrt(cv_mse):.4g} um against "
                            f"{math.sqrt(self.cur_cv):.4g} um on the base's core.")
        self.fitter, self.data, self.ext_core = refit, data, core
        self.final = SearchResult(final.specs, cv_loss, cv_mse, sc.all_mse, sc.n_held_out, sc.coef_all, sc.names,
                                  final.evaluated)
        self.cur_cv, self.cur_loss = cv_mse, cv_loss
        self._prune_after_rebase(names)

    def _prune_after_rebase(self, through: str) -> None:
        """Effects accepted later than the input-side one were judged against the residual of the old
        core, part of which was the input-side effect's lag absorbed twice: on the new core each must
        earn its place again, by the rule it was accepted by, or it is dropped."""
        fitter = self.fitter
        n_eff: float | None = None          # of the current final model's residual: found again only after a drop
        for name in [n for n in self.accepted if REGISTRY[n].stage != "input"]:
            final = self.final
            without: Specs = tuple(s.without(name) for s in final.specs)  # type: ignore[assignment]
            sc = fitter.score(without, want_coef=True)
            assert sc.coef_all is not None
            if n_eff is None:
                n_eff = effective_samples(fitter.test_residuals(final.specs), fitter.segment_lengths)
            gain = loglik_gain(n_eff, sc.held_out_loss, self.cur_loss, REGISTRY[name].n_params)
            if self.sel.earns_place(self.cur_loss, gain, sc.held_out_loss, self.noise):
                continue
            cand = self.candidates[name]
            cand.accepted = False
            cand.reason = (f"named against the core before it was identified again through {through}; on the new "
                           f"core it no longer earns its place (held-out {math.sqrt(self.cur_cv):.4g} um with it, "
                           f"{math.sqrt(sc.held_out_mse):.4g} um without)")
            self.accepted.remove(name)
            self.ambiguous_pairs = [p for p in self.ambiguous_pairs if name not in p]
            self.rebase_note += f" {name} was dropped: {cand.reason}."
            self.final = SearchResult(without, sc.held_out_loss, sc.held_out_mse, sc.all_mse, sc.n_held_out,
                                      sc.coef_all, sc.names, final.evaluated)
            self.cur_cv, self.cur_loss = sc.held_out_mse, sc.held_out_loss
            n_eff = None

    # ------------------------------------------------------------------ step 6: final guards
    def final_guards(self) -> None:
        """The extended model, unless it is worse than the base as given, does not generalise, or is
        fitted to a drive outside the model's class."""
        fitter, final, candidates = self.fitter, self.final, self.candidates
        if self.too_little:              # nothing was fitted: the base as given
            self._keep_base()
            return
        # parameters of the accepted effects as they stand in the final model (later rounds may retune them)
        for name in self.accepted:
            candidates[name].params = params_of(fitter, name, final.specs[2], final.coef_all, final.names)
        self.ext = build_extended(self.ext_core, fitter, final.specs[2], final.coef_all, final.names,
                                  list(self.accepted))
        self.final_pred = fitter.predict_full(final.specs[2], final.coef_all)
        if self.cur_cv > self.rms_before ** 2:
            # Worse than the base model as given, on held-out data: never the verdict. The extended
            # model is the base as it was, and nothing is named.
            if self.accepted:
                self.cannot.append(
                    f"{', '.join(self.accepted)} improved on the recalibrated model but not on the base model "
                    f"itself on held-out data ({math.sqrt(self.cur_cv):.4g} um against {self.rms_before:.4g} um), "
                    "so nothing is named: longer recordings, or several at different drive frequencies, "
                    "would let the fit be judged on more than the blocks it was chosen on")
                self._name_nothing()
            self._keep_base()
        for a, b in self.ambiguous_pairs:
            self.cannot.append(f"{a} and {b} explain the held-out data almost equally well; " + decider(a, b))
        if not self.accepted and self.cur_cv < self.rms_before ** 2:
            # nothing named: the static recalibration alone is kept only where it generalises, i.e. it
            # beats the base model on the held-out blocks of every recording (on data with nothing
            # missing, a recalibration fitted to one recording's quirks makes the next one worse)
            worse = self._recalibration_hurts(final.specs)
            if worse:
                self.cannot.append(f"the static recalibration was left out of the extended model: on held-out "
                                   f"blocks it is worse than the base model on {', '.join(worse)}")
                self._keep_base()
        if self.outside_class and not self.too_little:
            # the residual is dominated by drive the model's class cannot follow: whatever else fits it, a
            # recalibration too, is fitted to that, so nothing is named and nothing is written over the base
            # until the core is identified over the drive range used
            if self.accepted:
                self.cannot.append(f"{', '.join(self.accepted)} would be fitted to the part of the residual the "
                                   "model's class cannot follow, so nothing is named")
            self._name_nothing()
            self._keep_base()
        if self.outside_class:
            self.cannot.insert(0, f"outside the model's class: {self.outside_class}")

    def _name_nothing(self) -> None:
        for name in self.accepted:
            self.candidates[name].accepted = False
        self.accepted, self.ambiguous_pairs = [], []

    def _keep_base(self) -> None:
        self.base_kept = True
        self.ext = ExtendedModel(self.model, {}, [])
        self.final_pred = list(self.base_pred)
        self.cur_cv = self.rms_before ** 2

    def _recalibration_hurts(self, specs: Specs) -> list[str]:
        """Recordings on whose held-out blocks the selected (recalibrated) model does worse than the base."""
        fitter = self.fitter
        held_out = fitter.test_residuals(specs)
        rows = fitter.row_blocks()                      # per recording: (fold A rows, fold B rows) in held_out
        worse = []
        for d, yb, idx, (ra, rb) in zip(fitter.data, self.base_pred, rows, fitter.rows_ab):
            base_r = np.concatenate([(d.y - yb)[ra], (d.y - yb)[rb]])
            if float(held_out[idx] @ held_out[idx]) > float(base_r @ base_r):
                worse.append(d.name)
        return worse

    # ------------------------------------------------------------------ step 7: the outcome
    def outcome(self) -> Diagnosis:
        sel = self.sel
        verdict = [] if self.too_little else list(self.accepted)
        conclusive = not self.too_little and not self.ambiguous_pairs
        well_above = math.sqrt(self.cur_cv) > sel.model_error_factor * self.noise
        if self.too_little or self.ambiguous_pairs:
            outcome = "inconclusive"     # too little data, or look-alikes the data cannot tell apart
        elif verdict:
            outcome = "effects_named"
        elif not well_above and not self.outside_class:
            outcome = "within_noise"
        else:
            outcome = "unexplained"
        self.cannot.extend(d.extra["settled_note"] for d in self.data if "settled_note" in d.extra)
        lead = displacement_lead(self.data, self.base_pred)
        if lead is not None:     # a column-timing fault: effects fitted to it would be confidently wrong
            self.cannot.append(lead.words())
            if outcome != "unexplained":
                outcome, conclusive = "inconclusive", False
        for old_name, new_name, old_rms, new_rms in self.swapped:
            self.runner_note += (f" {old_name} was first chosen while a larger effect dominated the residual; with the "
                                 f"other effects in place {new_name} explains the held-out data better ({new_rms:.4g} "
                                 f"um against {old_rms:.4g} um), so it replaced {old_name}.")
        # where the named effects leave residual: located on the final model's, as the base's was
        left = [_scored(d, d.y - yf) for d, yf in zip(self.data, self.final_pred)] if outcome == "effects_named" else []
        after = [locate(d, r, r) for d, r in zip(self.data, left)]     # nothing recalibrated away: raw = residual
        explanation = explain(verdict, self.candidates, self.located, self.rms_before, math.sqrt(self.null_cv),
                              math.sqrt(self.cur_cv), self.noise, self.too_little, self.runner_note.strip(), outcome,
                              drive_unit(self.model), sel.noise_factor, identification_rms(self.model),
                              after, sel.model_error_factor, any(d.s_raw is not None for d in self.data))
        if lead is not None:     # the fault to fix first, so it comes first
            explanation = (f"First, a fault in the columns: {lead.words()}"
                           + ("." if outcome == "unexplained" else "; what is named below may only compensate it.")
                           + " " + explanation)
        validation = validation_words(self.fitter, self.null_cv, sel.min_mse_ratio, sel.min_loglik_gain)
        if not self.base_kept:
            validation += self.rebase_note
        if self.fitter.anchor_on:
            validation += anchor_words(self.model, [] if self.base_kept else
                                       self.fitter.anchor_deviation(self.final.specs[2], self.final.coef_all))
        ordered = sorted(self.candidates.values(), key=lambda c: (not c.accepted, not c.testable,
                                                                 c.cv_mse if math.isfinite(c.cv_mse) else math.inf))
        return Diagnosis(outcome, verdict, explanation, self.located, ordered, self.rms_before,
                         math.sqrt(self.null_cv), math.sqrt(self.cur_cv), self.noise, validation, conclusive,
                         self.cannot, self.ext, self.data, self.base_pred, self.null_pred, self.final_pred,
                         self.rounds, self.rounds[0]["n_eff"] if self.rounds else float("nan"),
                         str(self.sel.initial_state), after)
