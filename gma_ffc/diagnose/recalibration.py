"""The static recalibration's terms, each kept only where it carries beyond the data it was fitted on.

The null model every effect must beat is the base with a static recalibration (gain, offset,
curvature, stress gain, loop width; `fitting.py`). Fitted on one recording's held-out blocks, a
term can take up part of a slow effect, or the class's misfit at that recording's few loads, and
miss at other loads. After the selection, three judges ask whether it carries:

    carried(problem, sel)    curvature and stress gain, by leaving out each stress level, then a
                             stress gain on the identification loops (`diagnose --ident`)
    on_loops(problem, sel)   the whole map, where every accepted law and core were fitted on the loops
    doubt(problem, ...)      with nothing named, why the recalibration alone would not hold

Each returns a new frozen `Selection` (`state.py`), or words for the user. No I/O.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

import numpy as np

from ..effects import REGISTRY
from .fitting import Fitter
from .specs import LeaveOneOut, Score, Spec
from .scoring import Specs
from .search import SearchResult
from .state import Problem, Selection

TERMS = ("quadratic", "stress_gain")     # the recalibration's terms judged across loads


def carried(problem: Problem, sel: Selection) -> Selection:
    """The recalibration's curvature and stress gain, each kept only where it carries to the load
    it was not fitted on. Where the recordings hold two or more stress levels (a load change, or
    recordings at other loads), the final model is fitted without each level and judged on it
    (`Fitter.left_out_blocks`, each level's own zero fitted on it, as the leave-one-recording-out
    does); a term whose absence predicts the levels left out no worse is left out of the model,
    and the model fitted again without it. Held-out time blocks of one load share that load, so
    they cannot show whether a term carries to another: beside slow effects (heating, creep,
    fitted with forms that follow them only in part) curvature and a stress gain take up part of
    them on the one recording, and miss at other loads (the eleventh draw's heating with creep:
    probes 0.535 um as fitted, 0.349 um without the curvature, base 0.653 um). A stress gain
    fitted on two levels is never judged so (one level left, it is not identified): it is the
    difference between the levels alone, which on a load change in one recording is also the
    slow states' change between before and after, and is left out. A stress gain the levels keep
    is then judged on the measured identification loops too (`diagnose --ident`), whose loads
    may reach beyond the recording's (`_stress_gain_on_loops`)."""
    if problem.too_little or not sel.fit.names:
        return sel
    fitter = problem.fitter
    present = [t for t in TERMS if t in sel.fit.names]
    if not present:
        return sel
    blocks = fitter.level_blocks()
    off = _not_carried_to_levels(fitter, sel.fit.specs[2], blocks, present) if len(blocks) >= 2 else []
    note = left_out_words(off, len(blocks), any(d.s_raw is not None for d in problem.data),
                          len(blocks) == len(fitter.stress_levels() or [0.0])) if off else ""
    sc: Score | None = None
    if "stress_gain" in present and "stress_gain" not in off:
        judged = _stress_gain_on_loops(fitter, sel.fit.specs, off)
        if judged is not None:
            with_gain, without, sc = judged
            off.append("stress_gain")
            note += stress_gain_loops_words(with_gain, without)
    if not off:
        return sel
    fitter.drop_static(off)
    if sc is None:                    # else the loops' judge has fitted the model without `off` already
        sc = fitter.score(sel.fit.specs, want_coef=True)
    assert sc.coef_all is not None
    fit = SearchResult(sel.fit.specs, sc.held_out_loss, sc.held_out_mse, sc.all_mse, sc.n_held_out, sc.coef_all,
                       sc.names, sel.fit.evaluated)
    return dataclasses.replace(sel, fit=fit, rebase_note=sel.rebase_note + note,
                               leave_one_out=problem.leave_one_out(sel.fit.specs[2]) if sel.leave_one_out is not None
                               else None)

def on_loops(problem: Problem, sel: Selection) -> Selection:
    """Where every accepted effect's law and core were fitted on the identification loops
    (`fitted_on_loops`: stress-dependent play with `--ident`), nothing but the recalibration is
    fitted on these recordings. It is kept only where it also predicts those loops better, each
    loop's zero free and its gain judged; else the model is the loops' own (the static map the
    identity, each recording's zero fitted). A map fitted on the recording's few loads beside a
    core the loops made at all of theirs took up the class's misfit at those loads: on the four
    development and seventeenth-draw cases, the loops refused it each time, and without it the
    probes at other loads, rates and shapes went from 1.29x to 1.39x the base's, 1.18x to 1.35x,
    1.16x to 1.73x and 1.26x to 1.38x (`scripts/recalibration_carries.py`)."""
    fitter = problem.fitter
    if problem.too_little or not sel.accepted or not all(REGISTRY[n].fitted_on_loops(fitter) for n in sel.accepted):
        return sel
    specs = sel.fit.specs
    with_map = fitter.loops_misfit(specs[2], sel.fit.coef_all, shared_scale=False)
    without = fitter.loops_misfit(specs[2], fitter.identity_map_coef(specs[2]), shared_scale=False)
    if not without <= with_map:       # NaN (no loops at two loads) keeps the map
        return sel
    sc = fitter.score_identity_map(specs)      # scored only once the loops have refused the map
    assert sc.coef_all is not None
    fit = SearchResult(specs, sc.held_out_loss, sc.held_out_mse, sc.all_mse, sc.n_held_out, sc.coef_all,
                       sc.names, sel.fit.evaluated)
    loo = None if sel.leave_one_out is None else LeaveOneOut.of(fitter.identity_map_left_out(specs[2]))
    return dataclasses.replace(sel, fit=fit, rebase_note=sel.rebase_note + loops_own_words(with_map, without),
                               leave_one_out=loo)

def _not_carried_to_levels(fitter: Fitter, spec: Spec, blocks: Sequence[Any], present: Sequence[str]) -> list[str]:
    """Of the recalibration terms `present`, those whose absence predicts each stress level left
    out (the model fitted on the others) no worse."""
    def left_out_loss(off: tuple[str, ...]) -> float:
        return LeaveOneOut.of(fitter.left_out_blocks(spec, blocks, off)).loss_per_sample

    full = left_out_loss(())
    return [t for t in present if left_out_loss((t,)) <= full]

def _stress_gain_on_loops(fitter: Fitter, specs: Specs, off: Sequence[str]) -> tuple[float, float, Score] | None:
    """(misfit with, misfit without, the fit without) on the measured identification loops, where
    the final model with its stress gain misses them (`Fitter.loops_misfit`, one sensor
    scale for all loops) no better than refitted without it; None where the gain holds there, or
    there are no such loops. The recording's own stress levels cannot judge a gain beyond their span: the
    fourteenth never-tuned draw's stress-dependent play kept one fitted on -18.6 to -13.4 MPa,
    and its probe at -24 MPa came out 1.20 um against the base's 0.58 um. The identification
    loops, four loads wide, held that gain at 0.55 um and the model without it at 0.24 um."""
    if len(fitter.identification) < 2:
        return None

    def misfit(terms: Sequence[str]) -> tuple[float, Score]:
        fitter.drop_static(terms)
        sc = fitter.score(specs, want_coef=True)
        assert sc.coef_all is not None
        return fitter.loops_misfit(specs[2], sc.coef_all), sc

    (with_gain, _), (without, fitted_without) = misfit(off), misfit([*off, "stress_gain"])
    fitter.drop_static(off)
    if not without <= with_gain:      # NaN (no loops at two loads) keeps the gain as the levels judged it
        return None
    return with_gain, without, fitted_without


def doubt(problem: Problem, specs: Specs, rms_after: float, min_removed_noise: float) -> str:
    """With nothing named, why the static recalibration alone would not hold in another session,
    or ''. It is kept only where (1) it beats the base on every recording's held-out blocks,
    (2) by as much as an effect must take off (min_removed_noise), and (3) fitted without each
    recording, it predicts that one better than the base: held-out blocks of one recording share
    its drive and loads, and a recalibration fitted to them did not carry to other rates."""
    worse = _recalibration_hurts(problem.fitter, problem.null.base_pred, specs)
    if worse:
        return f"on held-out blocks it is worse than the base model on {', '.join(worse)}"
    removed = problem.null.rms_before - rms_after
    if removed < min_removed_noise * problem.noise:
        return (f"it takes {removed:.2g} um off the base's held-out RMS, less than "
                f"{min_removed_noise:g}x the noise floor ({problem.noise:.2g} um)")
    if len(problem.data) < 2:
        return ("fitted to one recording, it cannot be shown to hold in another session; give two or more "
                "(another load, rate or drive shape) and it is kept where it predicts each one left out")
    worse = _recalibration_fails_left_out(problem, specs[2])
    if worse:
        return f"fitted without {', '.join(worse)}, it predicts it worse than the base model"
    return ""


def left_out_words(off: Sequence[str], n_blocks: int, has_stress: bool, by_level: bool) -> str:
    """The validation's sentence on recalibration terms `off` left out, for `n_blocks` blocks each fitted
    without: stress levels only where the recordings have a stress column and each block is one level
    (`by_level`); without a stress column each block is a recording, which differ in their drive."""
    what = " and ".join(t.replace("_", " ") for t in off)
    were, them, they = ("were", "them", "they") if len(off) > 1 else ("was", "it", "it")
    if not has_stress:
        parts, left, elsewhere = f"{n_blocks} recordings", "the recording left out", "other recordings"
    elif by_level:
        parts, left, elsewhere = f"{n_blocks} stress levels", "the level left out", "other loads"
    else:        # a block per recording and load
        parts, left, elsewhere = (f"{n_blocks} parts (each recording at each of its loads)", "the part left out",
                                  "other loads or recordings")
    return (f" The recalibration's {what} {were} left out: fitted without each of the {parts}, the model "
            f"predicted {left} no worse without {them}, so {they} would not carry to {elsewhere}.")


def loops_own_words(with_map_um: float, without_um: float) -> str:
    """The validation's sentence on a recalibration the identification loops refused."""
    return (" The recalibration fitted on these recordings was left out: the effect's law and core were fitted "
            f"on the identification loops, which the model missed by {with_map_um:.3g} um with it and "
            f"{without_um:.3g} um without (each loop's zero free), so it would not carry to other loads.")


def stress_gain_loops_words(with_gain_um: float, without_um: float) -> str:
    """The validation's sentence on a stress gain the identification loops refused."""
    return (" The recalibration's stress gain was left out: on the identification loops, one sensor scale for "
            f"all their loads, the model missed by {with_gain_um:.3g} um with it and {without_um:.3g} um without, "
            "so it would not carry to loads beyond the recording's.")


def _base_residuals(fitter: Fitter, base_pred: Sequence[Any]) -> list[Any]:
    """Per recording, the base model's residual on its scored rows, fold A's then fold B's (the order
    of the fitter's rows)."""
    return [np.concatenate([(d.y - yb)[ra], (d.y - yb)[rb]]) for d, yb, (ra, rb) in
            zip(fitter.data, base_pred, fitter.rows_ab)]


def _recalibration_hurts(fitter: Fitter, base_pred: Sequence[Any], specs: Specs) -> list[str]:
    """Recordings on whose held-out blocks the selected (recalibrated) model does worse than the base."""
    held_out = fitter.test_residuals(specs)
    rows = fitter.row_blocks()                      # per recording: (fold A rows, fold B rows) in held_out
    worse = []
    for d, idx, base_r in zip(fitter.data, rows, _base_residuals(fitter, base_pred)):
        if float(held_out[idx] @ held_out[idx]) > float(base_r @ base_r):
            worse.append(d.name)
    return worse


def _recalibration_fails_left_out(problem: Problem, spec: Spec) -> list[str]:
    """Recordings the spec, fitted on the others (`Fitter.left_out`), predicts worse than the base
    model does; each with its own sensor zero, as the left-out fit has."""
    fitter = problem.fitter
    worse = []
    for d, part, base_r in zip(fitter.data, fitter.left_out(spec), _base_residuals(fitter, problem.null.base_pred)):
        base_r = base_r - base_r.mean() if base_r.size else base_r
        if part.sse > float(base_r @ base_r):
            worse.append(d.name)
    return worse
