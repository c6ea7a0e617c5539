"""The last step of a diagnosis: the guarded selection as one of four outcomes, in words.

`assemble` reads the frozen `state.Problem` and `state.Final` and returns the `Diagnosis`: the
outcome (`within_noise`, `effects_named`, `unexplained`, `inconclusive`), the candidates as the
report lists them, where the named effects leave residual, the explanation and how it was
validated. It fits nothing, but for the start the written model is run from (`written.py`). Pure maths: no I/O.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

from .. import effects as effect_registry
from .anchor import anchor_words
from .data import none_scored, unscored_starts_note
from .explain import drive_unit, explain, identification_rms, runner_up_words, validation_words
from .locate import locate
from .problem import scored
from .scoring import evidence_weight
from .results import Candidate, Diagnosis
from .state import LOO_REFUSED, Final, Problem, RoundRecord, Selection
from .polarity import displacement_inverted
from .timing import displacement_lead
from .written import written_rms


def candidates(sel: Selection, unit: str = "A") -> dict[str, Candidate]:
    """Every candidate effect (registry order) as the report lists it: its last trial, whether the
    data could test it and why not, and whether it is named. For a voltage drive (`unit` "V") a
    parameter per A^2 is also given per V^2: the key with A2 is the extended model file's, kept
    whatever the drive (files written so far use it), and means per drive unit squared."""
    out = {}
    for cls in effect_registry.candidates():
        name = cls.name
        c = Candidate(name, name in sel.testable, sel.reasons.get(name, ""))
        t = sel.trials.get(name)
        if t is not None:
            c.result, c.cv_mse, c.cv_loss, c.params, c.round = t.result, t.cv_mse, t.cv_loss, dict(t.params), t.round
            c.loglik_gain, c.evidence = t.loglik_gain, evidence_weight(t.loglik_gain)
            if unit == "V":
                c.params.update({k.replace("_per_A2", "_per_V2"): v for k, v in t.params.items() if "_per_A2" in k})
            if t.leave_one_out is not None:
                c.leave_one_out_mse = t.leave_one_out.mse
        c.accepted = name in sel.accepted
        out[name] = c
    for old, new, old_rms, new_rms in sel.swapped:     # accepted, then replaced: the candidate says so
        was = out.get(old)
        if was is not None and not was.accepted:
            swap = (f"accepted in round {was.round}, then replaced by {new}: with the other effects in place, the "
                    f"model with {new} in its place predicts the held-out data better ({new_rms:.4g} um against "
                    f"{old_rms:.4g} um)")
            was.reason = swap + (f"; {was.reason}" if was.reason else "")
    return out


def history_words(sel: Selection) -> str:
    """The selection's story after its first round, told once and in order: each swap, and each effect
    that was accepted (in a round or by a swap) and is no longer, with why (its candidate's note)."""
    words = []
    for old, new, old_rms, new_rms in sel.swapped:
        chosen = sel.trials[old].round if old in sel.trials else 0
        words.append(f"{old} was chosen {f'in round {chosen}, ' if chosen else ''}beside fewer effects; with the "
                     f"other effects in place {new} explains the held-out data better ({new_rms:.4g} um against "
                     f"{old_rms:.4g} um), so it replaced {old}.")
    replaced = {old for old, _, _, _ in sel.swapped}
    came = [r.accepted for r in sel.rounds if r.accepted] + [new for _, new, _, _ in sel.swapped]
    for name in dict.fromkeys(came):
        why = sel.reasons.get(name, "")
        if name in sel.accepted or name in replaced or not why:
            continue
        words.append(f"{name} was then dropped: {why}.")
    return " ".join(words)


def assemble(selector: Any, problem: Problem, final: Final) -> Diagnosis:
    """The outcome, the words and the figures of a guarded selection."""
    sel = final.selection
    too_little, noise = problem.too_little, problem.noise
    cands = candidates(sel, drive_unit(problem.model))
    verdict = [] if too_little else list(sel.accepted)
    verdict, timing = samples_timing(verdict, cands, problem.data, selector.sample_timing_share)
    outcome, conclusive = _outcome(selector, problem, final, verdict)
    cannot = _cannot_conclude(selector, problem, final) + ([timing] if timing else [])
    # a column's sign or timing wrong: effects fitted to it would be confidently wrong (the sign first:
    # a lead on an inverted column means nothing)
    column_fault = (displacement_inverted(problem.data, problem.null.base_pred, noise)
                    or displacement_lead(problem.data, problem.null.base_pred))
    if column_fault is not None:
        cannot.append(column_fault.words())
        if outcome != "unexplained":
            outcome, conclusive = "inconclusive", False
    runner_note = runner_up_words(sel.rounds, sel.accepted, sel.ambiguous)
    runner_note += " " + history_words(sel)
    # where the named effects leave residual: located on the final model's, as the base's was
    left = [scored(d, d.y - yf) for d, yf in zip(problem.data, final.final_pred)] if outcome == "effects_named" else []
    after = [locate(d, r, r) for d, r in zip(problem.data, left)]     # nothing recalibrated away: raw = residual
    null = problem.null
    explanation = explain(verdict, cands, list(null.located), null.rms_before, math.sqrt(null.fit.cv_mse),
                          math.sqrt(final.cv_mse), noise, too_little, runner_note.strip(), outcome,
                          drive_unit(problem.model), selector.noise_factor, identification_rms(problem.model),
                          after, selector.model_error_factor, any(d.s_raw is not None for d in problem.data),
                          not none_scored(problem.data))
    if column_fault is not None:     # the fault to fix first, so it comes first
        explanation = (f"First, a fault in the columns: {column_fault.words()}"
                       + ("." if outcome == "unexplained" else "; what is named below may only compensate it.")
                       + " " + explanation)
    loo = leave_one_out_figures(problem, final)
    tentative = tentative_effects(verdict, outcome, sel, column_fault is not None)
    ordered = sorted(cands.values(), key=lambda c: (not c.accepted, not c.testable,
                                                    c.cv_mse if math.isfinite(c.cv_mse) else math.inf))
    rounds = [r.as_dict() for r in sel.rounds]
    written = math.nan if final.base_kept else written_rms(final.extended, problem.data, selector.initial_state)
    return Diagnosis(outcome, verdict, explanation, list(null.located), ordered, null.rms_before,
                     math.sqrt(null.fit.cv_mse), math.sqrt(final.cv_mse), noise,
                     _validation(selector, problem, final, loo), conclusive,
                     cannot, final.extended, list(problem.data), list(null.base_pred), list(null.null_pred),
                     list(final.final_pred), rounds, rounds[0]["n_eff"] if rounds else float("nan"),
                     str(selector.initial_state), after, problem.identification.to_json(), loo, tentative, written)


def tentative_effects(verdict: list[str], outcome: str, sel: Selection, column_fault: bool) -> list[str]:
    """The named effects the data cannot vouch for (docs/cli.md): each the data fit as well as a
    look-alike (`sel.ambiguous`); every one when a column's fault may be what they compensate, or
    when the outcome is inconclusive for a reason no pair names."""
    if outcome != "inconclusive":
        return []
    paired = [name for name in verdict if any(name in pair for pair in sel.ambiguous)]
    return list(verdict) if column_fault or not paired else paired


TIMED = ("rate_dependence", "mechanical_dynamics")   # effects whose discrete form holds the drive over each sample


def samples_timing(verdict: list[str], cands: dict[str, Candidate], data: Sequence[Any],
                   share: float) -> tuple[list[str], str]:
    """The verdict without a delay under `share` of the sample period found beside a lag or a
    resonance (it stays in the extended model), and what the user is told instead ('' when the rule
    does not apply): such a delay cannot be told from the samples' own timing (`EffectSelector`)."""
    beside = [name for name in TIMED if name in verdict]
    delay = cands.get("time_delay")
    if "time_delay" not in verdict or not beside or delay is None or not data:
        return verdict, ""
    delay_s = float(delay.params.get("delay_s", math.nan))
    period = max(float(d.dt_med) for d in data)
    if not delay_s < share * period:
        return verdict, ""
    note = (f"time_delay: the {delay_s * 1e3:.3g} ms delay found beside {' and '.join(beside)} is kept in the "
            f"extended model but not named as physics: it is shorter than {share * period * 1e3:.3g} ms ({share:g} of "
            f"the {period * 1e3:.3g} ms sample period), within which a drive held over each sample interval and one "
            "moving through it differ in timing; record at "
            f"{1.0 / delay_s:.3g} Hz or faster to tell a transport delay from the samples' timing")
    lag = cands.get("rate_dependence")
    # the delay also stands in for a lag: hil_sim's eddy currents (0.1 ms) beside a resonance, run at 2 and
    # 10 kHz, were fitted as a 0.076 ms delay, and the lag was named nowhere
    if lag is not None and lag.testable and "rate_dependence" not in verdict:
        note += (f". It may also be a first-order lag as short (eddy currents: rate_dependence, not named), which "
                 f"only a drive near {1.0 / (2.0 * math.pi * delay_s):.3g} Hz tells from a delay")
    return [name for name in verdict if name != "time_delay"], note


def _outcome(selector: Any, problem: Problem, final: Final, verdict: list[str]) -> tuple[str, bool]:
    """The outcome (before a column-timing fault is considered), and whether it is conclusive."""
    sel = final.selection
    well_above = math.sqrt(final.cv_mse) > selector.model_error_factor * problem.noise
    if problem.too_little or sel.ambiguous:
        outcome = "inconclusive"     # too little data, or look-alikes the data cannot tell apart
    elif verdict:
        outcome = "effects_named"
    elif not well_above and not sel.outside_class:
        outcome = "within_noise"
    else:
        outcome = "unexplained"
    return outcome, not problem.too_little and not sel.ambiguous


def _cannot_conclude(selector: Any, problem: Problem, final: Final) -> list[str]:
    """What the data could not decide: the selection's notes, a smaller effect short of the margin,
    the recordings' unscored starts and, without the identification recordings, what the effects
    could not do without them."""
    starts = unscored_starts_note(problem.data)
    small = short_of_the_margin(selector, problem, final.selection)
    weak = short_of_the_evidence(selector, problem, final.selection)
    uncarried = not_carried(problem, final.selection)
    cannot = list(final.cannot) + untested_folds(problem, final) + [
        note for note in (uncarried, small, weak, starts) if note]
    if not problem.identification.given:
        lost = [(cls.name, cls.lost_without_identification(problem.fitter)) for cls in effect_registry.candidates()]
        cannot += [f"{name}: {why}" for name, why in lost if why]
    return cannot


def _last_round_unaccepted(sel: Selection) -> RoundRecord | None:
    """The last round when it tried something and accepted nothing (its best is then the one a
    note may speak of), else None."""
    last = sel.rounds[-1] if sel.rounds else None
    return last if last is not None and last.accepted is None and last.table else None


def _fails_own_signature(selector: Any, problem: Problem, sel: Selection, effect: str) -> bool:
    """Does the last round's `effect` fail its own signature check beside the final model's effects?
    Its fit is then not that effect, and no note may say the effect may be there."""
    trial = sel.trials.get(effect)
    return trial is not None and selector.signature_failure(problem, sel.fit.specs, trial) is not None


def not_carried(problem: Problem, sel: Selection) -> str:
    """A note on the last round's best fit when the leave-one-recording-out refused it ('' otherwise):
    it fitted the held-out blocks better than what the round kept, but fitted without one recording it
    predicted that one worse. The user hears which recording, and what would test the law. A slow
    effect whose time constant is over half of every recording is set by none of them (the grid rule
    of creep: a time constant beyond half a recording is a drift it cannot tell from another): the
    note asks for a run that lasts two of them. (A run that alone lasts two is not a test of the law
    when left out, and its fold is not counted: `Problem.sole_setter`.)"""
    last = _last_round_unaccepted(sel)
    refused = [row for row in (last.scored if last else ()) if row[3].startswith(LOO_REFUSED)]
    trial = sel.trials.get(refused[0][0]) if refused else None
    if last is None or trial is None or trial.leave_one_out is None or sel.leave_one_out is None:
        return ""
    effect, rms = refused[0][0], refused[0][1]
    without, carried = sel.leave_one_out, trial.leave_one_out
    judged = [i for i in range(len(problem.data)) if carried.n[i] > 0 and without.n[i] > 0]
    if not judged:
        return ""
    k = max(judged, key=lambda i: carried.sse[i] - without.sse[i])
    name = problem.data[k].name
    words = (f"{effect}: it takes the held-out RMS from {last.current_rms_um:.4g} to {rms:.4g} um, but fitted without "
             f"{name} it predicts {name} worse than the model without it ({_rms(carried.sse[k], carried.n[k]):.4g} um "
             f"against {_rms(without.sse[k], without.n[k]):.4g} um): its law is not shown to carry, so it is not named")
    longest = max(d.duration_s for d in problem.data)
    tau = float(trial.params.get("tau_s", 0.0))
    if effect_registry.REGISTRY[effect].slow and 2.0 * tau > longest:
        return (words + f". Its time constant ({tau:.3g} s) is over half of every recording (the longest "
                f"{longest:.3g} s), so none of them sets it: record a run of {2.0 * tau:.3g} s or more to test its law")
    return words + f"; a recording like {name} at other conditions would test it"


def untested_folds(problem: Problem, final: Final) -> list[str]:
    """A note per named slow effect whose leave-one-recording-out skipped a fold: one recording alone
    is long enough to set its time constant (`Problem.sole_setter`), so its law was tested on the
    other recordings only. The user hears which, and the run that would test it."""
    notes = []
    for name, (k, tau) in _untested(problem, final).items():
        d = problem.data[k]
        notes.append(f"{name}: its law was tested on the recordings other than {d.name} only. That run "
                     f"({d.duration_s:.3g} s) alone lasts two of its time constants ({tau:.3g} s), so fitted "
                     "without it the time constant is extrapolated, not tested. Record a second run as long, "
                     "at another drive level, to test the law on a run it was not fitted on")
    return notes


def _untested(problem: Problem, final: Final) -> dict[str, tuple[int, float]]:
    """Each named slow effect whose time constant one recording alone sets (`Problem.sole_setter`):
    that recording's index, and the time constant."""
    sel = final.selection
    if final.base_kept or sel.leave_one_out is None:
        return {}
    found = {}
    for name in sel.accepted:
        trial = sel.trials.get(name)
        if trial is None or not effect_registry.REGISTRY[name].slow:
            continue
        tau = float(trial.params.get("tau_s", math.inf))
        k = problem.sole_setter(tau)
        if k is not None:
            found[name] = (k, tau)
    return found


def short_of_the_margin(selector: Any, problem: Problem, sel: Selection) -> str:
    """A note on the last round's best, when it is significant by the held-out likelihood and lowers
    the held-out RMS but takes less of the held-out loss than an effect must ('' otherwise): a
    smaller effect may be there, and the user should hear of it rather than find it in a table. Not
    when its fit fails its own signature (a creep that relaxes against the drive's changes): that
    fit is not the effect, so it says nothing of whether the effect is there."""
    last = _last_round_unaccepted(sel)
    if last is None or not sel.accepted:
        return ""
    effect, rms, gain = last.table[0]
    if not (gain > selector.min_loglik_gain and rms < last.current_rms_um):
        return ""
    if _fails_own_signature(selector, problem, sel, effect):
        return ""
    return (f"{effect}: a smaller effect may be there beside {' and '.join(sel.accepted)}: it lowers the held-out "
            f"RMS from {last.current_rms_um:.4g} to {rms:.4g} um ({gain:.0f} nats of penalised held-out likelihood), "
            f"but falls short of what an effect must do to be named (take {1 - selector.min_mse_ratio:.0%} of the "
            f"held-out loss, and more than {selector.min_removed_noise:g} of the noise floor off the RMS), so it is "
            "neither named nor in the extended model; more of the same recording does not change those shares, a "
            "recording where it acts more strongly would")


def short_of_the_evidence(selector: Any, problem: Problem, sel: Selection) -> str:
    """A note on the last round's best when it did to the held-out error all an effect must, passed
    its signature check, and fell short only of the evidence (`min_loglik_gain`); '' otherwise.
    The evidence counts effectively independent samples (`n_eff`, per recording its length over the
    residual's correlation time). A residual slow across the recording leaves few, and a longer run
    of the same kind adds few more, as its correlation stretches with it; another run adds its own.
    On the nineteenth general draw's stress-dependent play (never tuned): 5.98 nats of the 6 over 39
    effective samples, and the outcome said only that no effect explained the rest. Twice as long,
    43 samples and 5.2 nats; the same 84 s as two runs, 5,225 samples, and the play was named
    (`python scripts/short_of_the_evidence.py`)."""
    last = _last_round_unaccepted(sel)
    if last is None:
        return ""
    effect, rms, gain = last.table[0]
    trial = sel.trials.get(effect)
    if trial is None or not 0.0 < gain <= selector.min_loglik_gain:
        return ""
    if not selector.earns_place(rms ** 2, math.inf, last.current_rms_um ** 2, problem.noise):
        return ""            # short of the share of the loss too (`short_of_the_margin`'s case), or worse
    if _fails_own_signature(selector, problem, sel, effect):
        return ""
    return (f"{effect}: may be what is missing: it lowers the held-out RMS from {last.current_rms_um:.4g} to "
            f"{rms:.4g} um, as much as an effect must, but its evidence is {gain:.3g} nats where "
            f"{selector.min_loglik_gain:g} are needed: the residual is slow, so these recordings hold about "
            f"{last.n_eff:.0f} independent samples of it. Record another run like these (a session of its own; a "
            "longer run adds few samples, its residual as slow) and diagnose them together")


def _validation(selector: Any, problem: Problem, final: Final, loo: dict[str, Any]) -> str:
    """How the result was validated, in words: the held-out blocks, the rebase, leave-one-recording-out
    and the anchor."""
    sel, fitter = final.selection, problem.fitter
    validation = validation_words(fitter, problem.null.fit.cv_mse, selector.min_mse_ratio, selector.min_loglik_gain,
                                  not none_scored(problem.data))
    if not final.base_kept:
        validation += sel.rebase_note
    if loo["applies"]:
        validation += (f" With {len(problem.data)} recordings, each was also left out in turn: every effect's law "
                       "(its parameters chosen and its gains fitted on the other recordings) had to lower the "
                       "error on the recording left out, or it was not accepted; leave-one-recording-out RMS "
                       f"{loo['rms_recalibrated_um']} um for the recalibrated base, "
                       f"{loo['rms_after_um'] if loo['rms_after_um'] is not None else 'unchanged'} um for the "
                       "final model (its nonlinear parameters as selected, its gains fitted without the recording)")
        without = loo.get("pooled_without")
        validation += (f", pooled without {', '.join(without)}: the one run long enough to set a named slow "
                       "effect's time constant, which left out is extrapolated, not tested." if without else ".")
    if fitter.anchor_on:
        validation += anchor_words(problem.model, [] if final.base_kept else
                                   fitter.anchor_deviation(sel.fit.specs[2], sel.fit.coef_all),
                                   measured=bool(fitter.identification))
    return validation


def leave_one_out_figures(problem: Problem, final: Final) -> dict[str, Any]:
    """diagnosis.json's leave-one-recording-out figures: per recording, the null's and the final
    model's RMS when that recording was left out of the fit (its own zero fitted on it). A recording
    that alone sets a named slow effect's time constant tests nothing when left out (`_untested`):
    its row says which effects (`untested_for`), and the pooled figures leave it out
    (`pooled_without`), as the selection's judgement of those effects did."""
    null, after = final.selection.null_leave_one_out, final.leave_one_out
    if null is None:
        why = ("too little data" if problem.too_little else
               "one recording: give recordings at other loads, rates or drive shapes to test the laws on "
               "conditions they were not fitted on")
        return {"applies": False, "why": why}
    after = after or null                       # nothing kept beyond the base: as the null
    if final.base_kept:
        after = None
    untested: dict[int, list[str]] = {}
    for name, (k, _) in _untested(problem, final).items():
        untested.setdefault(k, []).append(name)
    rows = []
    for k, d in enumerate(problem.data):
        row = {"recording": d.name, "rms_recalibrated_um": _rms(null.sse[k], null.n[k]),
               "rms_after_um": _rms(after.sse[k], after.n[k]) if after is not None else None}
        rows.append({**row, "untested_for": untested[k]} if k in untested else row)
    pooled = [k for k in range(len(problem.data)) if k not in untested]
    figures: dict[str, Any] = {
        "applies": True, "rms_recalibrated_um": _rms(sum(null.sse[k] for k in pooled), sum(null.n[k] for k in pooled)),
        "rms_after_um": (_rms(sum(after.sse[k] for k in pooled), sum(after.n[k] for k in pooled))
                         if after is not None else None),
        "per_recording": rows}
    if untested:
        figures["pooled_without"] = [problem.data[k].name for k in sorted(untested)]
    return figures


def _rms(sse: float, n: int) -> float | None:
    v = math.sqrt(sse / n) if n > 0 else math.nan
    return float(f"{v:.6g}") if math.isfinite(v) else None
