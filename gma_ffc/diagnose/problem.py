"""The first step of a diagnosis: the recordings prepared, checked, and the null model fitted.

`setup` returns a frozen `state.Problem`: the prepared recordings (arrays, held-out folds, what is
not scored), the fitter over them held by the anchor (the base's own loops), the noise floor
from the data, what cannot be concluded before any fit, and the null model every effect must
beat (the base with a static recalibration). Steps after it only read it. Pure maths: no I/O.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Sequence

import numpy as np

from ..errors import InputError
from ..recordings import Recording
from .anchor import anchor_data, measured_loops
from .checks import beyond_range_notes, check_displacement_scale, check_overlap, check_recordings, enough_data
from .data import RecData, noise_floor, prepare
from .fitting import Fitter, FitSettings
from .specs import Spec
from .identification import IdentificationCheck, check
from .jumps import jump_words, sensor_jumps
from .locate import locate
from .noise import mad_sigma
from .search import SearchResult
from .state import NullFit, Problem


def setup(selector: Any, model: Any, recordings: Sequence[Recording], say: Callable[[str], None],
          identification: Sequence[Recording] = (), checked: IdentificationCheck | None = None) -> Problem:
    """Prepare the recordings, check them, and fit the null model. With the identification
    recordings, the anchor is those measured loops (`anchor.measured_loops`), else the base's own
    output on loops like them (`anchor.anchor_data`)."""
    if not recordings:
        raise InputError("give at least one recording to compare with the model")
    check_recordings(recordings, selector.min_samples)
    limits = getattr(selector, "drive_limits", None)
    check_overlap(model, recordings, selector.range_margin, selector.min_overlap, limits)
    data = prepare(recordings, model, selector.initial_state, drive_limits=limits, range_margin=selector.range_margin)
    anchor = (measured_loops(model, list(identification)) if identification else
              anchor_data(model, min(d.dt_med for d in data)))
    fitter = Fitter(model, data, anchor, FitSettings(selector.min_stress_span_MPa,
                                                     tuple(selector.recalibration_plays), selector.range_margin,
                                                     tuple(limits) if limits is not None else None))
    # each fold needs scored rows to fit on: a fold without any would be fitted to nothing
    folds_filled = min(fitter.n_a, fitter.y_rows.size - fitter.n_a) > 0
    n_samples, too_little, slow_only, cannot = enough_data(data, selector.min_samples, selector.clamped_share,
                                                           folds_filled)
    if too_little:
        cannot += beyond_range_notes(model, data, selector.range_margin, selector.clamped_share)
    noise = float(np.median([noise_floor(d.y) for d in data]))
    fitter.use_anchor(fallback_tolerance_um=noise)
    null, jumps = _null_model(fitter, data, n_samples, noise, selector.huber_k, say, too_little)
    checked = checked or check(model, [r.name for r in identification])
    checked = dataclasses.replace(checked, diagnosed=tuple(r.name for r in recordings if r.name in checked.recorded),
                                  loads=checked.loads and fitter.stress_varies)   # the words follow these recordings
    return Problem(model, model, tuple(data), fitter, noise, n_samples, too_little, tuple(cannot + jumps), null,
                   checked, slow_only)


def scored(d: RecData, r: np.ndarray) -> np.ndarray:
    """The residual with the samples that are not scored set to zero (`data.known_samples`); whole
    for a recording none of which is scored, so that `locate` describes how far off its transient
    is (all zeros, it would report 0 um where the base misses by micrometres)."""
    return d.scored_only(r) if d.n_scored else r


def _null_model(fitter: Fitter, data: list[RecData], n_samples: int, noise: float, huber_k: float,
                say: Callable[[str], None], too_little: bool = False) -> tuple[NullFit, list[str]]:
    """The base as given (rms_before) and recalibrated (the null every effect must beat); the
    sensor's jumps found on the base's residual (each a column of every design from here on).
    With too little scored data nothing is fitted: the base as given is the null (a fit to a fold
    without rows has no coefficients, and one to a few loops would be judged on its own loops)."""
    say("simulating the base model")
    base_pred = tuple(yc for _, yc in fitter.core(Spec()))
    check_displacement_scale(fitter.model, data, base_pred)
    _ = fitter.yc_center          # computed once, before any threads share the fitter
    notes = []
    for d, yc in zip(data, base_pred):     # before any fit: each jump is a column of every design
        d.jumps = sensor_jumps(d.y, yc, d.u, d.recorded_stress, d.t, d.dt_med, d.settled)
        if d.jumps.excess:
            notes.append(f"{d.name}: {jump_words(d.jumps)}")
    # over the scored samples; over all of them when none is (the figure then says how far off the
    # transient is, and cannot_conclude says that nothing was scored)
    judged = [d.mask if n_samples else np.ones(d.t.size, bool) for d in data]
    rms_before = float(np.sqrt(sum(float(np.sum((d.y - yc)[m] ** 2)) for d, yc, m in zip(data, base_pred, judged))
                               / max(sum(int(np.sum(m)) for m in judged), 1)))
    null_specs = (Spec(), Spec(), Spec())
    if too_little:
        fitter.delta = max(2.0 * noise, 1e-12)
        located = tuple(locate(d, scored(d, d.y - yb), scored(d, d.y - yb)) for d, yb in zip(data, base_pred))
        nothing = SearchResult(null_specs, rms_before ** 2, rms_before ** 2, rms_before ** 2, 0, np.zeros(0), [], 0)
        return NullFit(base_pred, rms_before, nothing, base_pred, located), notes
    # Huber scale from the recalibrated base's held-out residual: bursts the core cannot follow at all
    # (e.g. a load change) then weigh in linearly, not quadratically, in fits and in the selection
    r0 = fitter.test_residuals(null_specs)
    # (never below twice the noise floor: Gaussian noise alone must stay in the quadratic part)
    fitter.delta = max(huber_k * mad_sigma(r0), 2.0 * noise, 1e-12)
    null = fitter.score(null_specs, want_coef=True)
    assert null.coef_all is not None
    null_pred = tuple(fitter.predict_full(Spec(), null.coef_all))
    located = tuple(locate(d, scored(d, d.y - yb), scored(d, d.y - yn))
                    for d, yb, yn in zip(data, base_pred, null_pred))
    fit = SearchResult(null_specs, null.held_out_loss, null.held_out_mse, null.all_mse, null.n_held_out,
                       null.coef_all, null.names, 1)
    return NullFit(base_pred, rms_before, fit, null_pred, located), notes
