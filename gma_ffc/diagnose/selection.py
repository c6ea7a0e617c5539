"""Which effects the recordings show: a forward selection on held-out blocks, as an estimator.

    sel = EffectSelector().fit(model, recordings)
    sel.outcome_, sel.verdict_, sel.candidates_, sel.extended_model_, sel.diagnosis_

Selection is greedy and forward: each round fits every untried effect of the registry
(`gma_ffc.effects`) on top of what is already accepted and scores it on held-out time blocks.
The best is accepted only if it (1) lowers the held-out loss by a clear margin, (2) wins a
penalised held-out likelihood test with the residual's effective sample count, (3) removes a
residual above the noise floor measured from the data, and (4) passes its own signature check.
A winner that fails its signature is set aside, and tried again once another effect is accepted:
a resonance beside eddy currents first fits as a lag, and shows its peak once a lag is in the model.
A round that accepts nothing, whose best is a look-alike of the effect accepted last, tries that
effect's look-alikes together in its place: a delay that won the first round as a stand-in for a
lag and a resonance leaves the resonance too little to gain beside it.
The null model every effect must beat is the base model with a static recalibration (gain,
offset, curvature, stress gain, loop width): ordinary model error of that kind is never called
an effect. With two or more accepted, a swap pass asks whether each is still the best choice for
its slot with the others in place, and a backward pass drops any that no longer earns its place
beside them. Final guards then refuse anything that is worse than the base as given, or fitted
to a drive the model's class cannot follow.

`fit` runs the steps in order, each taking the frozen state of the one before (`state.py`) and
returning a new one: the recordings prepared with the null model (`problem.setup`), the
candidates each round fits and scores (`scoring`) and this module decides on, the swap and
backward passes, the core identified again through input-side effects (`rebase`), the
recalibration's terms kept only where they carry (`recalibration`), the guards, and the outcome in
words (`outcome.assemble`).
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Any, Callable, Mapping, Sequence

from threadpoolctl import threadpool_limits

from .. import effects as effect_registry
from ..effects import REGISTRY, dynamics
from ..effects.base import SignatureCheck, SignatureFailure
from ..drive import dominant_band
from ..errors import InputError
from ..extended import ExtendedModel
from ..initial_state import InitialStateSpec
from ..recordings import Recording
from . import load_law, recalibration
from .explain import decider
from .fitting import Fitter
from .identification import check
from .outcome import assemble
from .problem import setup
from .rebase import reidentify_through
from .results import Diagnosis
from .scoring import (Specs, build_extended, descend, effective_samples, loglik_gain, params_of, rezoom, score_round,
                      search_all, search_variant)
from .search import SearchResult, leave_one_out_search
from .state import LOO_REFUSED, Final, Problem, RoundRecord, Selection, Trial


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
        Play weights are rate-independent, and creep shows most where the drive stops changing, so
        creep must also cut the error on the slowest 40 % of samples (where the drive turns round or
        holds) by 20 %, and stress_dependent_play there or on the slowest 40 % of those where the
        drive moves (its turns: after a step the core's minor loops may miss by more than a width
        law changes): a gain from the fast parts alone is another effect's leftover.
    ambiguous_nats (3.0)
        A runner-up within 3 nats of the winner (likelihood ratio ~20) is a look-alike the data
        do not tell apart: the outcome is inconclusive, with the experiment that would decide.
    huber_k (3.0)
        The Huber scale in robust standard deviations of the recalibrated residual: bursts no
        model can follow (a load change) weigh in linearly, Gaussian noise never reaches it.
    min_samples (400)
        Scored samples needed at all; below, any effect is fitted to the loops it is judged on.
    min_removed_noise (0.5)
        An accepted effect takes at least half the noise floor off the held-out RMS: a smaller gain,
        however significant on many samples, is not a residual anyone could see above the noise.
        With nothing named, the static recalibration alone is kept only on the same terms.
    min_stress_span_MPa (1.0)
        Stress terms (the recalibration's stress gain, stress_dependent_play) are fitted only when
        the recordings' loads span at least this, and loads closer than this count as one level:
        the SDPI loop moves by a few % of its stroke per MPa (the paper's rig: about a micrometre
        over 13 MPa), so across less a stress term fits noise and drift, not the load.
    recalibration_plays ((0.1, 0.25, 0.45))
        The recalibration's own play thresholds, as fractions of the drive span: a narrow, a middle
        and the widest play a 10-play core has (0.45 of the span), so the loop's width can be
        corrected at every scale with three columns.
    range_margin (0.02)
        A drive or stress within 2 % of the model's range counts as inside it: the range was taken
        from noisy recordings, to about that.
    min_overlap (0.05)
        Unless at least 5 % of the samples lie inside the model's drive (and stress) range, nothing
        can be compared and the recordings are refused with the experiment to make instead.
    clamped_share (0.01)
        More than 1 % of samples at stresses outside the model's range is said (they are compared at
        the nearest stress of the range): beyond that the comparison there is an extrapolation.
    slow_duration_s (20.0)
        A longest recording shorter than this gets a caveat on slow effects: heating and creep have
        time constants of tens of seconds, and below that they look alike.
    sample_timing_share (0.5)
        A delay shorter than this share of the sample period, found beside a lag or a resonance, is
        kept in the extended model but not named. Those effects' discrete forms take the drive as
        held over each sample interval (as a DAC holds it); a drive that moves through the interval
        (a current smoothed by the coil, a lagged field) is about half a sample later, and such a
        delay takes that up. On hil_sim's rig, eddy currents before the load's dynamics show as
        0.19-0.22 ms at 0.5 ms sampling (`scripts/lag_before_dynamics.py`).
    one_frequency_share (0.9)
        Drives holding this share of their power within an octave of one frequency are one
        frequency to a phase lag (`drive.dominant_band`): a delay, a lag and a resonance then all
        fit it, and which one it is shows only in how the lag changes with frequency. On the
        twelve rate cases of the development and never-tuned sets, cut to their first 8 s (one
        3-5 Hz sine), 7 named the wrong one of the three, with confidence
        (`scripts/one_frequency.py`). So an effect of that kind (`told_by_frequency`) found on
        such drives is named with its look-alikes, tentatively: the outcome is inconclusive, with
        the frequencies that would decide. A single sine holds 0.97-1.0 (the measured piezo 0.97,
        quantised); a second sine a third of its amplitude takes 10 %; the benchmarks' mixed
        drives hold 0.17-0.44, two short runs at two frequencies about 0.71.
    workers (2)
        Candidate searches in parallel threads (numba kernels and BLAS release the GIL), at most
        one per usable CPU (`usable_cpus`: the environment's `GMA_FFC_CPUS`, else the CPUs this
        process may run on). BLAS gets the usable CPUs shared among them (`_blas_threads_per_worker`).
    initial_state ("estimate")
        The core's hysteresis state at each recording's first sample, by the rule every model run
        shares (`gma_ffc.initial_state`): estimated from the measured displacement by default;
        whatever the rule, nothing before the state has settled is scored.
    drive_limits (None)
        (LO, HI): the drive the rig's controller allows (`diagnose --drive-limits`). Advice on what
        to record asks for no drive beyond it; the model's drive range alone could ask for more.

    Attributes after `fit`: `outcome_`, `verdict_`, `tentative_`, `candidates_`, `extended_model_`, the search
    threads it ran (`threads_`) and the whole `diagnosis_` (`gma_ffc.diagnose.results.Diagnosis`, what the report shows).
    """

    def __init__(self, max_effects: int = 3, *, min_mse_ratio: float = 0.75, min_loglik_gain: float = 6.0,
                 noise_factor: float = 1.5, model_error_factor: float = 3.0, slow_ratio_max: float = 0.8,
                 ambiguous_nats: float = 3.0, huber_k: float = 3.0, min_samples: int = 400,
                 min_removed_noise: float = 0.5, min_stress_span_MPa: float = 1.0,
                 recalibration_plays: tuple[float, ...] = (0.1, 0.25, 0.45), range_margin: float = 0.02,
                 min_overlap: float = 0.05, clamped_share: float = 0.01, slow_duration_s: float = 20.0,
                 sample_timing_share: float = 0.5, one_frequency_share: float = 0.9, workers: int = 2,
                 initial_state: Any = "estimate", drive_limits: tuple[float, float] | None = None) -> None:
        self.max_effects = max_effects
        self.min_mse_ratio = min_mse_ratio
        self.min_loglik_gain = min_loglik_gain
        self.noise_factor = noise_factor
        self.model_error_factor = model_error_factor
        self.slow_ratio_max = slow_ratio_max
        self.ambiguous_nats = ambiguous_nats
        self.huber_k = huber_k
        self.min_samples = min_samples
        self.min_removed_noise = min_removed_noise
        self.min_stress_span_MPa = min_stress_span_MPa
        self.recalibration_plays = recalibration_plays
        self.range_margin = range_margin
        self.min_overlap = min_overlap
        self.clamped_share = clamped_share
        self.slow_duration_s = slow_duration_s
        self.sample_timing_share = sample_timing_share
        self.one_frequency_share = one_frequency_share
        self.workers = workers
        self.initial_state = initial_state
        self.drive_limits = drive_limits

    def fit(self, model: Any, recordings: Sequence[Recording], progress: Callable[[str], None] | None = None,
            identification: Sequence[Recording] = (),
            fingerprints: Sequence[Mapping[str, Any]] | None = None) -> "EffectSelector":
        """Run the whole diagnosis (no I/O) and keep its results in the trailing-underscore attributes.
        `identification`: the recordings the model was identified on (checked against its record, by
        their files' `fingerprints` when given, else by name), which every fit is then held to and on
        which an effect may identify the core again."""
        cpus = usable_cpus()
        self.threads_ = max(1, min(self.workers, cpus))      # at most one search thread per usable CPU
        with _blas_threads_per_worker(self.threads_, cpus):
            dg = self._diagnose(model, recordings, progress or (lambda _msg: None), identification, fingerprints)
        self.diagnosis_ = dg
        self.outcome_ = dg.outcome
        self.verdict_ = list(dg.verdict)
        self.tentative_ = list(dg.tentative)
        self.candidates_ = list(dg.candidates)
        self.extended_model_ = dg.extended
        return self

    def _diagnose(self, model: Any, recordings: Sequence[Recording], say: Callable[[str], None],
                  identification: Sequence[Recording], fingerprints: Sequence[Mapping[str, Any]] | None) -> Diagnosis:
        """Set up, forward rounds, swap and backward passes, rebase, guard: the diagnosis."""
        checked = check(model, [r.name for r in identification], fingerprints)
        problem = setup(self, model, recordings, say, identification, checked)
        sel = self._open(problem)
        for rnd in range(1, self.max_effects + 1):
            if math.sqrt(sel.cur_cv) <= self.noise_factor * problem.noise:
                break
            sel, more = self._round(problem, sel, rnd, say)
            if not more:
                break
        sel = self._prune_after_swap(problem, self._swap_pass(problem, sel, say))
        sel = self._lookalikes_rezoomed(problem, sel)
        problem, sel = self._rebase(problem, sel, say)
        sel = recalibration.on_loops(problem, recalibration.carried(problem, sel))
        final = self._guard(problem, sel)
        return assemble(self, problem, final)

    # ------------------------------------------------------------------ the acceptance rule
    def accepts(self, best: Trial, cur_loss: float, noise: float) -> bool:
        """The acceptance rule of one round (before the winner's signature check)."""
        return self.earns_place(best.cv_loss, best.loglik_gain, cur_loss, noise)

    def earns_place(self, loss: float, loglik_gain: float, loss_without: float, noise: float) -> bool:
        """Does an effect that takes the held-out loss from `loss_without` to `loss` (with that
        log-likelihood gain, its parameters paid for) earn its place in the model?"""
        return not self.shortfall(loss, loglik_gain, loss_without, noise)

    def shortfall(self, loss: float, loglik_gain: float, loss_without: float, noise: float) -> str:
        """'' when such an effect earns its place (`earns_place`), else which of the rule's terms it
        misses, in words (the report's rounds table gives them for a round's best not accepted)."""
        missed = []
        if not loss < self.min_mse_ratio * loss_without:
            share = 1.0 - loss / loss_without if loss_without > 0 else math.nan
            missed.append(f"takes {share:.0%} of the held-out loss, where an effect must take more than "
                          f"{1.0 - self.min_mse_ratio:.0%}")
        if not loglik_gain > self.min_loglik_gain:
            missed.append(f"below the evidence: {loglik_gain:.3g} nats, where more than {self.min_loglik_gain:g} "
                          "are needed")
        removed, needed = math.sqrt(loss_without) - math.sqrt(loss), self.min_removed_noise * noise
        if not removed > needed:
            missed.append(f"takes {removed:.3g} um off the held-out error, where more than {needed:.3g} um "
                          f"({self.min_removed_noise:g} of the noise floor) is needed")
        return "; ".join(missed)

    # ------------------------------------------------------------------ what can be tested
    def _open(self, problem: Problem) -> Selection:
        """The selection before any round: the null model, and which effects the data can test."""
        fitter = problem.fitter
        testable, reasons, cannot = set(), {}, []
        short_for_slow = (f"the longest recording lasts {fitter.duration_max:.3g} s: slow effects (heating, creep) "
                          "with time constants beyond it are hard to separate; a run of several minutes with drive "
                          "on/off phases would decide") if fitter.duration_max < self.slow_duration_s else ""
        for cls in effect_registry.candidates():
            ok, why = cls.testable(fitter)
            loops_untested = problem.slow_only and not cls.slow     # a step test's loop effects: one note, from checks
            if problem.too_little:
                ok, why = False, why or "too little data"
            elif loops_untested:
                ok, why = False, "too few drive reversals to test it: see the note on them for the recording that would"
            elif ok and cls.slow and short_for_slow:
                why = short_for_slow
            if ok:
                testable.add(cls.name)
            elif why and not problem.too_little and not loops_untested:
                cannot.append(f"{cls.name}: {why}")
            reasons[cls.name] = why
        if short_for_slow and any(REGISTRY[name].slow for name in testable):
            cannot.append(short_for_slow)        # once, for both: the caveat holds whether or not one is named
        loo = problem.leave_one_out(problem.null.fit.specs[2])
        return Selection(problem.null.fit, frozenset(testable), reasons, cannot=tuple(cannot), leave_one_out=loo,
                         null_leave_one_out=loo)

    # ------------------------------------------------------------------ one forward round
    def _round(self, problem: Problem, sel: Selection, rnd: int,
               say: Callable[[str], None]) -> tuple[Selection, bool]:
        """One round: every effect not yet accepted fitted and scored, the best decided on; the
        selection after it, and whether selection goes on."""
        todo = [c.name for c in effect_registry.candidates() if c.name in sel.testable and c.name not in sel.accepted]
        say(f"round {rnd}: fitting {', '.join(todo)}")
        trials, n_eff = score_round(problem.fitter, sel.fit.specs, sel.cur_loss, todo, rnd, self.threads_)
        if not trials:
            return sel, False
        trials = sorted((self._start_earned(problem, sel, t, n_eff) for t in trials), key=lambda t: t.cv_loss)
        earlier, scored = sel.trials, tuple(trials)
        sel = dataclasses.replace(sel, trials={**sel.trials, **{t.effect: t for t in trials}})
        best = trials[0]
        ok = self.accepts(best, sel.cur_loss, problem.noise)
        refused: list[Trial] = []      # winners whose law did not carry to a recording left out
        set_aside: dict[str, str] = {}     # the winners set aside, and why: the report lists them
        # signature checks: a winner without its effect's signature is set aside, and the next one checked;
        # once another effect is accepted, it is tried again on top of it
        while ok:
            failure = self.signature_failure(problem, sel.fit.specs, best)
            if failure is not None and failure.variant is not None:     # its fit in another form first
                retried = self._retried(problem, sel, best, failure.variant, n_eff)
                trials = sorted([retried] + trials[1:], key=lambda t: t.cv_loss)
                scored = tuple(sorted((retried if t.effect == retried.effect else t for t in scored),
                                      key=lambda t: t.cv_loss))
                sel = dataclasses.replace(sel, trials={**sel.trials, retried.effect: retried})
                best = trials[0]
                ok = self.accepts(best, sel.cur_loss, problem.noise)
                continue
            if failure is None:
                best, why = self._carries_over(problem, sel, best)
                trials = [best] + trials[1:]
                sel = dataclasses.replace(sel, trials={**sel.trials, best.effect: best})
                if not why:
                    break
                refused.append(best)
                failure = SignatureFailure(why)
            if failure.outside_class:
                sel = dataclasses.replace(sel.with_reason(best.effect, failure.reason, testable=False),
                                          outside_class=failure.reason)
            else:
                sel = sel.aside(best.effect, failure.reason)
            set_aside[best.effect] = _set_aside_words(failure, by_leave_one_out=bool(refused) and refused[-1] is best)
            trials = trials[1:]
            if not trials:
                record = self._round_record(problem, sel, rnd, n_eff, scored, trials, set_aside, None, refused)
                return dataclasses.replace(sel, rounds=sel.rounds + (record,)), False
            best = trials[0]
            ok = self.accepts(best, sel.cur_loss, problem.noise)
        record = self._round_record(problem, sel, rnd, n_eff, scored, trials, set_aside, best if ok else None,
                                    refused)
        sel = dataclasses.replace(sel, rounds=sel.rounds + (record,))
        if not ok:
            return self._look_ahead(problem, sel, earlier, best, n_eff, say)
        ambiguous = sel.ambiguous
        if len(trials) > 1 and self._alike(best, trials[1]):
            ambiguous += ((best.effect, trials[1].effect),)
        return dataclasses.replace(sel.readmitted(), accepted=sel.accepted + (best.effect,), fit=best.result,
                                   ambiguous=ambiguous, undecided=sel.undecided + _undecided(best, refused),
                                   leave_one_out=problem.leave_one_out(best.result.specs[2])), True

    def _start_earned(self, problem: Problem, sel: Selection, trial: Trial, n_eff: float) -> Trial:
        """A trial whose fit holds the effect under way at each recording's start (creep's start
        terms) keeps them only where they earn their place as an effect must (`earns_place`), against
        the same effect from rest (`rest_form`), one parameter a recording. A model file runs from
        rest: start terms that take a little off the held-out error take it from something else.
        hil_sim's creep and eddy currents on multifreq and steps runs: 0.0740 um held out with them,
        0.0752 um from rest; the model file ran at 0.138 um with them, 0.078 um from rest."""
        form = REGISTRY[trial.effect].rest_form
        if form is None:
            return trial
        rest = self._retried(problem, sel, trial, form, n_eff)
        gain = loglik_gain(n_eff, rest.cv_loss, trial.cv_loss, len(problem.data))
        return trial if self.earns_place(trial.cv_loss, gain, rest.cv_loss, problem.noise) else rest

    def _retried(self, problem: Problem, sel: Selection, trial: Trial, variant: Callable[[Any], Any],
                 n_eff: float) -> Trial:
        """A round's trial searched again in another form of its search point, and scored as the
        round scores: creep from rest, where its start terms do not earn their place
        (`_start_earned`) or held a drift its signature refuses (`SignatureFailure.variant`)."""
        fitter = problem.fitter
        result = search_variant(fitter, sel.fit.specs, trial.effect, variant, self.threads_)
        gain = loglik_gain(n_eff, sel.cur_loss, result.cv_loss, REGISTRY[trial.effect].count_params(fitter))
        params = params_of(fitter, trial.effect, result.specs[2], result.coef_all, result.names)
        return Trial(trial.effect, result, params, trial.round, gain)

    def _alike(self, best: Trial, runner_up: Trial) -> bool:
        """Is a round's runner-up significant and within `ambiguous_nats` of its best (a look-alike the
        data do not tell apart)?"""
        return runner_up.loglik_gain > self.min_loglik_gain and \
            best.loglik_gain - runner_up.loglik_gain < self.ambiguous_nats

    def _round_record(self, problem: Problem, sel: Selection, rnd: int, n_eff: float, scored: Sequence[Trial],
                      kept: Sequence[Trial], set_aside: Mapping[str, str], accepted: Trial | None,
                      refused: Sequence[Trial]) -> RoundRecord:
        """What a round tried and decided: the candidates it kept in the running (`kept`, best first),
        and every one it `scored` with its decision (`RoundRecord.scored`): accepted, or why not. Those
        `set_aside` by a check carry its words; a refused look-alike of the accepted one that fitted
        better is left undecided beside it (`_undecided`)."""
        decisions = dict(set_aside)
        if accepted is not None:
            for named, other, _ in _undecided(accepted, refused):
                decisions[other] += (f"; left undecided beside {named}, which fitted worse: these recordings cannot "
                                     "tell the two apart (see what cannot be concluded)")
        for place, trial in enumerate(kept):
            if trial is accepted:
                decisions[trial.effect] = "accepted"
            elif place == 0:
                decisions[trial.effect] = "not accepted: " + self.shortfall(trial.cv_loss, trial.loglik_gain,
                                                                            sel.cur_loss, problem.noise)
            elif place == 1 and accepted is not None and self._alike(accepted, trial):
                decisions[trial.effect] = (f"a look-alike of {accepted.effect}: within {self.ambiguous_nats:g} nats "
                                           "of it, the data do not tell the two apart")
            elif accepted is not None:
                decisions[trial.effect] = f"behind {accepted.effect}, accepted: a round accepts one effect"
            else:
                decisions[trial.effect] = (f"behind {kept[0].effect}, the round's best, not accepted: a round "
                                           "decides on its best alone")
        return RoundRecord(rnd, n_eff, math.sqrt(sel.cur_cv),
                           tuple((t.effect, math.sqrt(t.cv_mse), t.loglik_gain) for t in kept),
                           None if accepted is None else accepted.effect,
                           tuple((t.effect, math.sqrt(t.cv_mse), t.loglik_gain, decisions[t.effect]) for t in scored))

    def _look_ahead(self, problem: Problem, sel: Selection, earlier: Mapping[str, Trial], round_best: Trial,
                    n_eff: float, say: Callable[[str], None]) -> tuple[Selection, bool]:
        """A round that accepted nothing, whose best (`round_best`: none of its checks failed) is a
        look-alike of the effect accepted last (`joint_with`), significant but short of the margin:
        beside it, another look-alike may do better in the last one's place. A delay beside a
        resonance takes the place of an eddy lag and leaves the resonance too little to gain; the
        lag with the resonance may then explain the recordings where the delay with it could not.
        The pair is searched along the signal path, the effect nearer the drive first (a resonance
        searched first takes a lag's phase as damping). The best pair replaces the last effect if
        it earns its place against the model as it stands, by the round's rule, and passes the
        checks a round's winner passes. The selection, and whether selection goes on."""
        last = sel.accepted[-1] if sel.accepted else ""
        alikes = REGISTRY[last].joint_with if last else ()
        if round_best.effect not in alikes or round_best.loglik_gain <= self.min_loglik_gain:
            return sel, False
        listed = {row[0] for row in sel.rounds[-2].table} if len(sel.rounds) > 1 else set()   # none failed a check
        firsts = [n for n in alikes if n in earlier and n in listed and earlier[n].round == round_best.round - 1
                  and earlier[n].loglik_gain > self.min_loglik_gain]
        pairs = [(a, b) for a in firsts for b in alikes           # the one nearer the drive fitted first
                 if REGISTRY[a].position < REGISTRY[b].position and round_best.effect in (a, b)]
        if not pairs:
            return sel, False
        say(f"trying {' and '.join(sorted(set(sum(pairs, ()))))} together in {last}'s place")
        tried = [(earlier[a], score_round(problem.fitter, earlier[a].result.specs, earlier[a].cv_loss, [b],
                                          round_best.round, self.threads_)[0][0]) for a, b in pairs]
        first, second = min(tried, key=lambda fs: fs[1].cv_loss)
        extra = REGISTRY[first.effect].count_params(problem.fitter) + REGISTRY[second.effect].count_params(
            problem.fitter) - REGISTRY[last].count_params(problem.fitter)
        gain = loglik_gain(n_eff, sel.cur_loss, second.cv_loss, extra)
        if not self.earns_place(second.cv_loss, gain, sel.cur_loss, problem.noise):
            return sel, False
        checked = self._pair_checked(problem, sel, first, second)
        if checked is None:
            return sel, False
        first, second = checked
        return dataclasses.replace(
            sel.readmitted(), accepted=sel.accepted[:-1] + (first.effect, second.effect), fit=second.result,
            trials={**sel.trials, first.effect: first, second.effect: second},
            swapped=sel.swapped + ((last, first.effect, math.sqrt(sel.cur_cv), math.sqrt(second.cv_mse)),),
            rounds=sel.rounds[:-1] + (sel.rounds[-1].accepting(second.effect, {
                first.effect: f"accepted in {last}'s place, with {second.effect} (the figures here: beside {last})",
                second.effect: f"accepted with {first.effect} in {last}'s place (the figures here: beside {last})"}),),
            leave_one_out=problem.leave_one_out(second.result.specs[2])), True

    def _pair_checked(self, problem: Problem, sel: Selection, first: Trial,
                      second: Trial) -> tuple[Trial, Trial] | None:
        """A look-ahead's pair with each one's signature checked on the model it was fitted on top
        of, and, with two or more recordings, each one's law carried to the recordings left out (as
        a round's winner is); None when either fails."""
        before: Specs = tuple(s.without(sel.accepted[-1]) for s in sel.fit.specs)  # type: ignore[assignment]
        if self.signature_failure(problem, before, first) is not None or \
                self.signature_failure(problem, first.result.specs, second) is not None:
            return None
        if sel.leave_one_out is None:
            return first, second
        first, why = self._carries_over(problem, dataclasses.replace(
            sel, leave_one_out=problem.leave_one_out(before[2])), first)
        if not why:
            second, why = self._carries_over(problem, dataclasses.replace(
                sel, leave_one_out=problem.leave_one_out(first.result.specs[2])), second)
        return None if why else (first, second)

    def signature_failure(self, problem: Problem, base: Specs, trial: Trial) -> SignatureFailure | None:
        """The trial's effect's signature check, on the model `base` it was fitted on top of."""
        return REGISTRY[trial.effect].signature(
            SignatureCheck(problem.fitter, problem.model, base, trial.result, dict(trial.params),
                           problem.noise, self.slow_ratio_max, self.model_error_factor, self.min_samples))

    def _refit_keeps_signatures(self, problem: Problem, fit: SearchResult, names: Sequence[str]) -> bool:
        """Do `names`, as `fit` has them, each still pass their signature check (each judged on `fit`
        without it)? Every step that searches an accepted effect's parameters again (the swap pass, the
        backward pass's look-alikes zoomed again, the pair's descent after a drop) keeps a new fit only
        then, as a round keeps its winner: a resonance zoomed again without the delay beside it ran to
        the heaviest damping (a lag, docs/cli.md) on the second measured piezo, and was named so."""
        for name in names:
            before: Specs = tuple(s.without(name) for s in fit.specs)  # type: ignore[assignment]
            trial = Trial(name, fit, params_of(problem.fitter, name, fit.specs[2], fit.coef_all, fit.names), 0)
            if self.signature_failure(problem, before, trial) is not None:
                return False
        return True

    def _carries_over(self, problem: Problem, sel: Selection, best: Trial) -> tuple[Trial, str]:
        """With two or more recordings: does the effect's law, fitted on the other recordings,
        improve each recording left out (pooled)? The trial with its leave-one-out figures, and why
        not ('' when it does, or when there is one recording)."""
        if sel.leave_one_out is None:
            return best, ""
        cls = REGISTRY[best.effect]
        # on the round's fit of it: a look-alike it was searched jointly with (`joint_with`) as rescaled there
        loo = leave_one_out_search(problem.fitter, best.result.specs[2], lambda s, p: s.with_(best.effect, p),
                                   cls.grid_like(problem.fitter, best.result.specs[2][best.effect]), cls.refine,
                                   getattr(cls, "zoom_levels", 3))
        without = sel.leave_one_out
        skip = problem.sole_setter(float(best.params.get("tau_s", math.inf))) if cls.slow else None
        if skip is not None:              # that fold extrapolates a time constant; the others test the law
            without, loo = without.without(skip), loo.without(skip)
        best = dataclasses.replace(best, leave_one_out=loo)
        if loo.loss_per_sample < without.loss_per_sample:
            return best, ""
        return best, (f"fitted on the other recordings, it does not improve the one left out (leave-one-recording-"
                      f"out RMS {math.sqrt(loo.mse):.4g} um against {math.sqrt(without.mse):.4g} um "
                      "without it): its law does not carry to the conditions it was not fitted on")

    # ------------------------------------------------------------------ the swap pass
    def _swap_pass(self, problem: Problem, sel: Selection, say: Callable[[str], None]) -> Selection:
        """With the other accepted effects in place, is each one still the best choice for its slot?
        (the first rounds judge look-alikes against a residual dominated by the biggest effect)"""
        if len(sel.accepted) < 2:
            return sel
        fitter = problem.fitter
        importance: dict[str, float] = {}
        sel = dataclasses.replace(sel, ambiguous=())
        # the last round that kept a candidate in the running (one whose every winner was set aside ends the rounds)
        n_eff_last = next((r.n_eff for r in reversed(sel.rounds) if r.table), 1.0)
        for name in list(sel.accepted):
            if name not in sel.accepted:
                continue
            others: Specs = tuple(s.without(name) for s in sel.fit.specs)  # type: ignore[assignment]
            o_cv = fitter.score(others).held_out_loss
            rivals = [c for c in _slot_rivals(name) if c in sel.testable and not (c in sel.accepted and c != name)]
            say(f"checking {name} against the others with the other effects in place")
            found = search_all(fitter, others, rivals, self.threads_)
            if not rivals:
                continue
            slot = sorted((found[cand].cv_loss, cand) for cand in rivals)
            if len(slot) > 1 and \
                    0.5 * n_eff_last * math.log(slot[1][0] / max(slot[0][0], 1e-300)) < self.ambiguous_nats:
                sel = dataclasses.replace(sel, ambiguous=sel.ambiguous + ((slot[0][1], slot[1][1]),))
            # the best of the slot takes it, passed over where its fit fails its own signature check (a
            # round's winner must pass it too); the effect searched again in its own slot ends the walk
            for loss, cand in slot:
                if cand == name or loss >= sel.cur_loss:
                    break
                if self._refit_keeps_signatures(problem, found[cand], [cand]):
                    sel = _swapped(fitter, sel, name, cand, found[cand])
                    name = cand
                    break
            importance[name] = o_cv - sel.cur_loss
        return dataclasses.replace(sel, accepted=tuple(sorted(sel.accepted, key=lambda n: -importance.get(n, 0.0))))

    # ------------------------------------------------------------------ the core through the effects
    def _rebase(self, problem: Problem, sel: Selection, say: Callable[[str], None]) -> tuple[Problem, Selection]:
        """With an input-side effect named (eddy lag, delay), the core identified again through it on
        the base's own loops (`rebase.py`: the base had absorbed the effect's lag there, and the
        effect in front of it would undo that lag twice); kept when the final specs, refitted on it,
        are no worse on held-out blocks."""
        if problem.too_little or not any(REGISTRY[name].stage == "input" for name in sel.accepted):
            return problem, sel
        fitter, final = problem.fitter, sel.fit
        ext = build_extended(problem.model, fitter, final.specs[2], final.coef_all, final.names, list(sel.accepted))
        inputs = [e for e in ext.chain if e.stage == "input"]
        names = ", ".join(k for e in inputs for k in e.to_blocks())
        say(f"identifying the core again through {names}")
        core = reidentify_through(problem.model, inputs, fitter.anchor)    # the base's loops, as the anchor holds them
        if core is None:
            return problem, sel
        # the same recordings and scored rows (the anchor's: the base's loops and tolerances), each
        # with the new core's own initial state
        data = _restarted(core, problem.data, self.initial_state)
        refit = Fitter(core, data, [dataclasses.replace(d, start=core.resolve_initial_state(
            d.u, d.s if core.stress_range_MPa is not None else None, d.extra.get("anchor_rule", "relaxed"), d.y,
            d.t)) for d in fitter.anchor], fitter.settings)
        refit.use_anchor(fallback_tolerance_um=problem.noise)
        refit.delta = fitter.delta
        sc = refit.score(final.specs, want_coef=True)
        assert sc.coef_all is not None
        if sc.held_out_mse > sel.cur_cv:
            return problem, dataclasses.replace(sel, rebase_note=(
                f" The core identified again through {names} on the base's own loops was not "
                f"kept: held-out {math.sqrt(sc.held_out_mse):.4g} um against {math.sqrt(sel.cur_cv):.4g} um."))
        note = (f" The core was identified again through {names} on the base's own identification "
                "loops, so that core and effect together give back the base there (the base had "
                "absorbed the effect's lag into those loops; in front of the base as it was, the "
                f"effect would undo that lag twice): held-out {math.sqrt(sc.held_out_mse):.4g} um against "
                f"{math.sqrt(sel.cur_cv):.4g} um on the base's core.")
        problem = dataclasses.replace(problem, core=core, data=tuple(data), fitter=refit)
        fit = SearchResult(final.specs, sc.held_out_loss, sc.held_out_mse, sc.all_mse, sc.n_held_out, sc.coef_all,
                           sc.names, final.evaluated)
        return problem, self._prune_after_rebase(problem, dataclasses.replace(sel, fit=fit, rebase_note=note), names)

    def _prune_after_rebase(self, problem: Problem, sel: Selection, through: str) -> Selection:
        """Effects accepted later than the input-side one were judged against the residual of the old
        core, part of which was the input-side effect's lag absorbed twice: on the new core each must
        earn its place again, by the rule it was accepted by, or it is dropped."""
        sel, dropped = self._drop_unearned(problem, sel, [n for n in sel.accepted if REGISTRY[n].stage != "input"],
                                           f"named against the core before it was identified again through "
                                           f"{through}; on the new core it no longer earns its place")
        return dataclasses.replace(sel, rebase_note=sel.rebase_note + dropped)

    def _prune_after_swap(self, problem: Problem, sel: Selection) -> Selection:
        """Backward elimination: with every other accepted effect in place, and its look-alikes zoomed
        again without it (`_without_rezoomed`), each must still earn its place by the rule it was
        accepted by, or it is dropped. An effect accepted first takes part of
        what a later one explains better (a delay named before eddy currents and a resonance, which
        then share its phase lag), and forward selection alone never takes it back."""
        if len(sel.accepted) < 2:
            return sel
        came_by_swap = {new: old for old, new, _, _ in sel.swapped}

        def why(name: str) -> str:
            how = (f"put in {came_by_swap[name]}'s place by the swap pass" if name in came_by_swap
                   else "named before the others")
            return f"{how}; with the others in the model it no longer earns its place"

        sel, dropped = self._drop_unearned(problem, sel, list(reversed(sel.accepted)),   # the least important first
                                           why, lookalikes=True)
        return self._refit_after_drop(problem, sel) if dropped else sel

    def _lookalikes_rezoomed(self, problem: Problem, sel: Selection) -> Selection:
        """Each accepted effect with an accepted look-alike beside it (`joint_with`) zoomed and polished
        again (`rezoom`) with every other effect where it ended, and kept where it predicts the held-out
        blocks better and keeps its signature. The joint descent that accepted the second of a pair
        starts from the first's fit beside an earlier partner, and stops in the nearest valley: the
        fifteenth never-tuned draw's resonance, fitted beside a delay in round 2, kept a load law 7x too
        flat beside the eddy lag named in round 3 (held-out 0.0615 um^2); zoomed again beside the lag,
        the law's own sweep found the plant's (170 Hz, mass stress 3.5 MPa; 0.0476 um^2)."""
        for name in sel.accepted:
            if not any(p in sel.accepted for p in REGISTRY[name].joint_with):
                continue
            found = rezoom(problem.fitter, sel.fit.specs, name, self.threads_)
            if found.cv_loss < sel.cur_loss and self._refit_keeps_signatures(problem, found, (name,)):
                sel = dataclasses.replace(sel, fit=found)
        return sel

    def _refit_after_drop(self, problem: Problem, sel: Selection) -> Selection:
        """The look-alikes that stay, fitted again without the one dropped: their parameters were
        searched beside it. A lag searched beside a resonance and an earlier delay came out at 1.22 ms
        (the rig's eddy lag 1.88 ms), the resonance's damping at 0.29 (the rig's 0.10); the delay had
        taken the lag's place. The descent of the joint search (`scoring.descend`) runs again from
        where they are, and is kept when it predicts the held-out blocks better."""
        for name in sel.accepted:
            partner = next((p for p in REGISTRY[name].joint_with if p in sel.accepted and REGISTRY[p].joint_refit),
                           None)
            if partner is None:
                continue
            found = descend(problem.fitter, sel.fit, name, partner, self.threads_)
            if found.cv_loss < sel.cur_loss and self._refit_keeps_signatures(problem, found, (name, partner)):
                sel = dataclasses.replace(sel, fit=found)
        return sel

    def _drop_unearned(self, problem: Problem, sel: Selection, names: Sequence[str],
                       why: str | Callable[[str], str], lookalikes: bool = False) -> tuple[Selection, str]:
        """Each of `names` that no longer earns its place (`earns_place`, with the others as they are
        fitted, or with its look-alikes zoomed again when `lookalikes`) dropped, with `why` as its
        reason; the selection, and a sentence per drop."""
        fitter = problem.fitter
        n_eff: float | None = None          # of the current final model's residual: found again only after a drop
        said = ""
        for name in [n for n in names if n in sel.accepted]:
            without: Specs = tuple(s.without(name) for s in sel.fit.specs)  # type: ignore[assignment]
            sc = fitter.score(without, want_coef=True)
            assert sc.coef_all is not None
            fit = SearchResult(without, sc.held_out_loss, sc.held_out_mse, sc.all_mse, sc.n_held_out,
                               sc.coef_all, sc.names, sel.fit.evaluated)
            if n_eff is None:
                n_eff = effective_samples(fitter.test_residuals(sel.fit.specs), fitter.segment_lengths)
            if lookalikes:
                fit = self._without_rezoomed(problem, sel, name, fit)
            gain = loglik_gain(n_eff, fit.cv_loss, sel.cur_loss, REGISTRY[name].count_params(fitter))
            if self.earns_place(sel.cur_loss, gain, fit.cv_loss, problem.noise):
                continue
            reason = (f"{why(name) if callable(why) else why} (held-out {math.sqrt(sel.cur_cv):.4g} um with it, "
                      f"{math.sqrt(fit.cv_mse):.4g} um without)")
            sel = dataclasses.replace(
                sel.with_reason(name, reason), fit=fit, accepted=tuple(n for n in sel.accepted if n != name),
                ambiguous=tuple(p for p in sel.ambiguous if name not in p))
            said += f" {name} was dropped: {reason}."
            n_eff = None
        return sel, said

    def _without_rezoomed(self, problem: Problem, sel: Selection, name: str, without: SearchResult) -> SearchResult:
        """The model without `name`, its accepted look-alikes (`joint_with`) zoomed again one after the
        other from where they are, each kept where it predicts the held-out blocks better: a look-alike
        searched beside `name` gave it part of its role, and must be let take that part back before
        `name`'s place is judged, and before the model without it is kept. Beside a delay of a sample,
        an eddy lag came out 30 % short and a resonance's load law moved; without the delay and so
        refitted, they explained the recording better than with it (the eleventh never-tuned draw's
        pair: held-out 0.44 -> 0.15 um)."""
        best = without
        for partner in [p for p in REGISTRY[name].joint_with if p in sel.accepted]:
            found = rezoom(problem.fitter, best.specs, partner, self.threads_)
            if found.cv_loss < best.cv_loss and self._refit_keeps_signatures(problem, found, (partner,)):
                best = found
        return best

    # ------------------------------------------------------------------ final guards
    def _guard(self, problem: Problem, sel: Selection) -> Final:
        """The extended model, unless it is worse than the base as given, does not generalise, or is
        fitted to a drive outside the model's class."""
        fitter, fit, null = problem.fitter, sel.fit, problem.null
        if problem.too_little:           # nothing was fitted: the base as given
            return Final(sel, ExtendedModel(problem.model, {}, []), null.base_pred, null.rms_before ** 2, True,
                         tuple(problem.cannot + sel.cannot))
        # parameters of the accepted effects as they stand in the final model (later rounds may retune them)
        trials = dict(sel.trials)
        for name in sel.accepted:
            trials[name] = dataclasses.replace(trials[name], params=params_of(fitter, name, fit.specs[2], fit.coef_all,
                                                                              fit.names))
        sel = _with_undecided(dataclasses.replace(sel, trials=trials))
        cannot = list(problem.cannot + sel.cannot)
        base = Final(sel, ExtendedModel(problem.model, {}, []), null.base_pred, null.rms_before ** 2, True, ())
        final = Final(sel, build_extended(fitter.plain_core(fit.specs[2]), fitter, fit.specs[2], fit.coef_all,
                                          fit.names, list(sel.accepted)),
                      tuple(fitter.predict_full(fit.specs[2], fit.coef_all)), sel.cur_cv, False, ())
        if final.cv_mse > null.rms_before ** 2:
            # Worse than the base model as given, on held-out data: never the verdict. The extended
            # model is the base as it was, and nothing is named.
            if sel.accepted:
                cannot.append(
                    f"{', '.join(sel.accepted)} improved on the recalibrated model but not on the base model "
                    f"itself on held-out data ({math.sqrt(final.cv_mse):.4g} um against {null.rms_before:.4g} um), "
                    "so nothing is named: longer recordings, or several at different drive frequencies, "
                    "would let the fit be judged on more than the blocks it was chosen on")
                sel = _name_nothing(sel, "improved on the recalibrated model but not on the base model itself on "
                                         "held-out data, so nothing is named (see cannot_conclude)")
            final = dataclasses.replace(base, selection=sel)
        for a, b in sel.ambiguous:
            own = [words for x, y, words in sel.undecided if {x, y} == {a, b}]
            cannot.append(own[0] if own else f"{a} and {b} explain the held-out data almost equally well; " + decider(a, b))
        if not sel.accepted and final.cv_mse < null.rms_before ** 2:
            doubt = recalibration.doubt(problem, fit.specs, math.sqrt(final.cv_mse), self.min_removed_noise)
            if doubt:
                cannot.append(f"the static recalibration was left out of the extended model: {doubt}")
                final = dataclasses.replace(base, selection=sel)
        if sel.outside_class and not problem.too_little:
            # the residual is dominated by drive the model's class cannot follow: whatever else fits it, a
            # recalibration too, is fitted to that, so nothing is named and nothing is written over the base
            # until the core is identified over the drive range used
            if sel.accepted:
                cannot.append(f"{', '.join(sel.accepted)} would be fitted to the part of the residual the "
                              "model's class cannot follow, so nothing is named")
            sel = _name_nothing(sel, "would be fitted to the part of the residual the model's class cannot follow, "
                                     "so nothing is named (see cannot_conclude)")
            final = dataclasses.replace(base, selection=sel)
        if not final.base_kept:
            sel, words = self._one_frequency(problem, sel)
            sel, final, law_words = self._law_measured(problem, sel, final)
            cannot += words + law_words
        if sel.outside_class:
            cannot.insert(0, f"outside the model's class: {sel.outside_class}")
        loo = None if final.base_kept else problem.leave_one_out(sel.fit.specs[2])
        return dataclasses.replace(final, selection=sel, cannot=tuple(cannot), leave_one_out=loo)

    def _one_frequency(self, problem: Problem, sel: Selection) -> tuple[Selection, list[str]]:
        """An accepted phase lag (`told_by_frequency`) on drives of one frequency (`one_frequency_share`)
        is ambiguous with the look-alikes this diagnosis tried: the selection with those pairs, and
        what the user is told."""
        if not any(REGISTRY[name].told_by_frequency for name in sel.accepted):
            return sel, []
        f0, share = dominant_band([(d.t, d.u) for d in problem.data])
        if not share >= self.one_frequency_share:
            return sel, []
        pairs, words = [], []
        for name in sel.accepted:
            others = [o for o in sel.trials if o != name and o not in sel.accepted and REGISTRY[o].told_by_frequency]
            if not REGISTRY[name].told_by_frequency or not others:
                continue
            pairs += [(name, o) for o in others]
            words.append(f"{name}: the drives hold one frequency ({f0:.3g} Hz, {share:.0%} of their power within an "
                         f"octave of it), at which {name} and {' and '.join(others)} all fit a phase lag; they "
                         "differ in how the lag changes with frequency, so record at a second frequency, "
                         f"{f0 / 2:.3g} Hz or below or {2 * f0:.3g} Hz or above, to tell which it is")
        return dataclasses.replace(sel, ambiguous=sel.ambiguous + tuple(pairs)), words

    def _law_measured(self, problem: Problem, sel: Selection, final: Final) -> tuple[Selection, Final, list[str]]:
        """A named resonance whose fit improves on the base as given (by `min_mse_ratio`, the rule an
        effect is accepted by) over a narrow band of the loads only: its law beyond them is
        extrapolated from its form, which the user is told with the recording that measures it
        (`load_law`), and the resonance is held beyond that band at its value at the nearer end
        (`_held_law`). The base as given, not the recalibrated one: a recalibration fitted beside an
        unmodelled resonance bends to it at every load (the twenty-third draw's heaviest load: 1.02 um
        recalibrated, 0.19 um as given, where the data show no resonance)."""
        name = "mechanical_dynamics"
        if name not in sel.accepted or not problem.fitter.stress_varies:
            return sel, final, []
        fitter, data = problem.fitter, problem.data
        span = load_law.improved_span([fitter.static_stress(d) for d in data], [d.mask for d in data],
                                      [d.y - p for d, p in zip(data, problem.null.base_pred)],
                                      [d.y - p for d, p in zip(data, final.final_pred)], self.min_mse_ratio)
        words = load_law.extrapolation_words(span, sel.trials[name].params)
        if not words or span is None:
            return sel, final, []
        sel, final, said = self._held_law(problem, sel, final, span)
        return sel, final, [words + said]

    def _held_law(self, problem: Problem, sel: Selection, final: Final,
                  span: tuple[tuple[float, float], tuple[float, float]]) -> tuple[Selection, Final, str]:
        """The resonance held beyond the loads where its law was measured (`rod_load`), on the side
        of that band that has recordings beyond it, or on both, its gains refitted: the hold the
        held-out blocks like best. The law's course there is a claim like an effect's: it is kept
        only when it earns its place by the acceptance rule (held-out loss below `min_mse_ratio` of
        the hold's), and otherwise held (the twenty-third draw: the recordings show no resonance at
        the heavy load, where the course as fitted put a probe at 6.0 um against the base's 2.6)."""
        name, fitter, fit = "mechanical_dynamics", problem.fitter, sel.fit
        (a, b), (lo, hi) = span
        sides = [(a, math.inf)] * (a > lo) + [(-math.inf, b)] * (b < hi)
        holds = sides + [(a, b)] * (len(sides) == 2)
        tried = []
        for band in holds:
            specs = tuple(s.with_(name, dynamics.with_law_held(s[name], band)) for s in fit.specs)
            tried.append((fitter.score((specs[0], specs[1], specs[2]), want_coef=True), specs, band))
        if not tried:
            return sel, final, ""
        sc, specs, band = min(tried, key=lambda x: x[0].held_out_loss)
        assert sc.coef_all is not None
        if fit.cv_loss < self.min_mse_ratio * sc.held_out_loss:
            return sel, final, (f" The law as fitted is kept: holding the resonance beyond them raised the held-out "
                                f"error from {math.sqrt(fit.cv_mse):.4g} to {math.sqrt(sc.held_out_mse):.4g} um.")
        held = SearchResult((specs[0], specs[1], specs[2]), sc.held_out_loss, sc.held_out_mse, sc.all_mse,
                            sc.n_held_out, sc.coef_all, sc.names, fit.evaluated)
        trials = {**sel.trials, name: dataclasses.replace(sel.trials[name], params=params_of(
            fitter, name, specs[2], sc.coef_all, sc.names))}
        sel = dataclasses.replace(sel, fit=held, trials=trials)
        final = dataclasses.replace(final, selection=sel, cv_mse=sc.held_out_mse, final_pred=tuple(
            fitter.predict_full(specs[2], sc.coef_all)), extended=build_extended(
            fitter.plain_core(specs[2]), fitter, specs[2], sc.coef_all, sc.names, list(sel.accepted)))
        where = " and ".join(f"at its frequency at {end:.3g} MPa under {side} compressive loads"
                             for end, side in ((band[0], "more"), (band[1], "less")) if math.isfinite(end))
        return sel, final, (f" Until then, the model holds the resonance {where}. On the recordings' held-out "
                            f"blocks that gives {math.sqrt(sc.held_out_mse):.4g} um, against "
                            f"{math.sqrt(fit.cv_mse):.4g} um with the law's course.")


CPUS_ENV = "GMA_FFC_CPUS"


def usable_cpus() -> int:
    """The CPUs a diagnosis may use: `GMA_FFC_CPUS` when set, else those this process may run on.
    Set it to 1 where other processes already fill the machine (the test suite's workers, a batch
    of diagnoses): threads inside each would only contend for the same cores. On 2 cores under
    3 pytest workers, a resonance diagnosis took 190 s of CPU with two search threads, 113 s with one."""
    text = os.environ.get(CPUS_ENV, "").strip()
    if not text:
        return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if not text.isdigit() or int(text) < 1:
        raise InputError(f"{CPUS_ENV}={text!r} is not a number of CPUs: give a whole number from 1 up, "
                         f"or unset it to use every CPU this process may run on")
    return int(text)


def _blas_threads_per_worker(workers: int, cpus: int) -> Any:
    """A context giving BLAS the usable CPUs (`cpus`), shared among the search threads. With
    OpenBLAS's own threads on top of them, BLAS threads wait (and spin) for CPUs the search threads
    hold: on 2 CPUs with two search threads, one BLAS thread each took a resonance diagnosis with
    its loops from 40.4 to 32.2 s. The limit is lifted when the diagnosis returns."""
    return threadpool_limits(limits=max(1, cpus // max(workers, 1)), user_api="blas")


def _slot_rivals(name: str) -> list[str]:
    """The candidates that may take `name`'s slot in the swap pass: its look-alikes (`joint_with`)
    when it has any, else every candidate without look-alikes. A phase lag (delay, eddy currents, a
    resonance) is only ever mistaken for another phase lag: on six development pairs every swap was
    between look-alikes, and heating, creep and stress-dependent play ended 1.09-8.8x behind in a
    lag's slot; searching them there was a third of a pair's diagnosis."""
    alikes = REGISTRY[name].joint_with
    return [c.name for c in effect_registry.candidates()
            if c.name == name or (c.name in alikes if alikes else not c.joint_with)]


def _swapped(fitter: Fitter, sel: Selection, name: str, by: str, res: SearchResult) -> Selection:
    """`name` replaced by `by` (fitted as `res`) in its slot; the swap's figures are the held-out RMS
    of the model as it stood (with `name`) and with `by` in its place, both with the others in place
    (`name`'s own figure from its round was taken beside fewer effects)."""
    params = params_of(fitter, by, res.specs[2], res.coef_all, res.names)
    prior = sel.trials.get(by)
    trial = Trial(by, res, params, 0) if prior is None else dataclasses.replace(prior, result=res, params=params)
    return dataclasses.replace(
        sel, trials={**sel.trials, by: trial}, fit=res,
        accepted=tuple(by if n == name else n for n in sel.accepted),
        swapped=sel.swapped + ((name, by, math.sqrt(sel.cur_cv), math.sqrt(res.cv_mse)),))


def _name_nothing(sel: Selection, why: str) -> Selection:
    """Nothing named; each effect that was accepted carries `why` as its candidate's note."""
    for name in sel.accepted:
        sel = sel.with_reason(name, f"accepted by the selection, but {why}")
    return dataclasses.replace(sel, accepted=(), ambiguous=())


def _restarted(core: Any, data: Sequence[Any], rule: Any) -> list[Any]:
    """The recordings as they are (rows, folds, what is not scored), each with `core`'s own initial
    state by `rule`. A known state (``plays``) is the base's plays on the recorded drive, not those
    of a core identified again through an input effect: that core's is estimated."""
    if InitialStateSpec.parse(rule).kind == "plays":
        rule = "estimate"
    return [dataclasses.replace(d, start=core.resolve_initial_state(
        d.u, d.s if core.stress_range_MPa is not None else None, rule, d.y, d.t)) for d in data]


def _set_aside_words(failure: SignatureFailure, by_leave_one_out: bool) -> str:
    """What became of a round's winner set aside by a check, for the report's rounds table."""
    if by_leave_one_out:
        return f"{LOO_REFUSED}: {failure.reason}"
    if failure.outside_class:
        return f"outside the model's class, so nothing is named: {failure.reason}"
    return f"set aside, not its effect's signature: {failure.reason}"


def _undecided(named: Trial, refused: Sequence[Trial]) -> tuple[tuple[str, str, str], ...]:
    """The look-alikes of the effect a round named that fitted the held-out blocks better but whose law,
    fitted on the other recordings, did not carry to the one left out. The leave-one-out refuses such a
    law where one recording alone shows the effect (heating in the one long run: fitted on short runs,
    its law is not determined), and a look-alike whose law fails more gently is then named in its place.
    The recordings cannot tell the two apart: a researcher's heated rig was named creep so, and its
    extended model sat 1.3 um above every cold recording. Each with the words `cannot_conclude` gives."""
    out = []
    for r in refused:
        if r.cv_mse < named.cv_mse and _lookalikes(named.effect, r.effect):
            out.append((named.effect, r.effect, (
                f"{r.effect} fitted the held-out blocks better than {named.effect} ({math.sqrt(r.cv_mse):.4g} um "
                f"against {math.sqrt(named.cv_mse):.4g} um), but its law, fitted on the other recordings, did not "
                f"carry to the one left out: these recordings cannot tell the two apart; {decider(named.effect, r.effect)}")))
    return tuple(out)


def _lookalikes(a: str, b: str) -> bool:
    """Does either effect name the other as a look-alike (one it is searched with, or told apart from)?"""
    ca, cb = REGISTRY.get(a), REGISTRY.get(b)
    return any(c is not None and (y in c.joint_with or y in c.deciders) for c, y in ((ca, b), (cb, a)))


def _with_undecided(sel: Selection) -> Selection:
    """The selection with each look-alike pair the leave-one-out left undecided (`_undecided`) among its
    ambiguous pairs, while the named one is still named and the other is not (later passes rebuild the
    ambiguous pairs from the fits with the other effects in place)."""
    extra = tuple((a, b) for a, b, _ in sel.undecided
                  if a in sel.accepted and b not in sel.accepted and not any({a, b} == set(p) for p in sel.ambiguous))
    return dataclasses.replace(sel, ambiguous=sel.ambiguous + extra) if extra else sel
