"""Checks before any fit: do the recordings overlap the model's range, and is there enough to score."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..drive import HOLD_S, drive_unit, holds, outside_range, reversals, unit_slip
from ..errors import InputError
from ..model import stress_sign_advice
from ..recordings import Recording
from ..sensor_holds import held_notes
from ..unit_slips import unit_slip_factor
from .data import N_BLOCKS, RecData, advised_range, unscored_note
from .locate import LEAST_WINDOW

MIN_REVERSALS = 2 * N_BLOCKS   # drive turning points in all: on average a full drive cycle per time block, or a
                               # held-out block is a piece of one branch that the neighbouring training blocks
                               # interpolate, and blocked cross-validation tests interpolation, not prediction
MIN_HOLDS = 4                  # ...short of them, the slow effects (heating, creep) are still tested where the drive
                               # holds this many times: each hold a step response and a heating level of its own,
                               # so both folds hold parts of several, and a law fitted on one predicts the other's


def check_recordings(recordings: Sequence[Recording], min_samples: int) -> None:
    """Refuse a recording diagnose can say nothing of: one shorter than the least window its residual
    is located over (`locate.LEAST_WINDOW`), or one whose displacement never changes (a sensor not
    connected, a channel logging a constant: identify refuses it too). `min_samples` is what a
    conclusive diagnosis needs in all, which the advice names."""
    for rec in recordings:
        if len(rec) < LEAST_WINDOW:
            raise InputError(
                f"{rec.source}: only {len(rec)} samples; diagnose needs at least {LEAST_WINDOW} in each recording "
                f"to locate a difference, and at least {min_samples} over >= {MIN_REVERSALS // 2} full drive loops in "
                f"all to conclude anything: record at least {min_samples} samples over {MIN_REVERSALS // 2} or more "
                "full drive cycles, at two or more drive frequencies")
        y = rec.column("displacement_um")
        if float(np.ptp(y)) == 0.0:
            raise InputError(
                f"{rec.source}: the displacement is constant ({float(y[0]):.6g} um in all {len(rec)} samples): the "
                "sensor's reading never changes, so there is nothing to compare with the model; check that the "
                "sensor is connected and that displacement_um is its channel")


def check_overlap(model: Any, recordings: Sequence[Recording], margin: float = 0.02,
                  min_overlap: float = 0.05, drive_limits: tuple[float, float] | None = None) -> None:
    """Refuse recordings of which less than `min_overlap` of the samples lie inside the model's drive
    (or stress) range, widened by `margin` of it (`EffectSelector` documents both). The advice asks
    for no drive beyond `drive_limits` (the controller's, when given)."""
    lo, hi = model.drive_range
    srange = model.stress_range_MPa
    drive_overlap = []
    stress_overlap = []
    for rec in recordings:
        u = rec.drive
        inside = ~outside_range(u, (lo, hi), margin)
        drive_overlap.append(float(np.mean(inside)))
        if srange is not None and rec.stress_MPa is not None:
            s = rec.stress_MPa
            tol = margin * max(srange[1] - srange[0], 1.0)
            stress_overlap.append(float(np.mean((s >= srange[0] - tol) & (s <= srange[1] + tol))))
    if max(drive_overlap) < min_overlap:
        a, b, held = advised_range((lo, hi), drive_limits, drive_unit(model.drive_name))
        advice = (f"record inside {a:.3g}..{b:.3g}{held}, or identify a model from recordings covering these "
                  "drives" if a < b else held)
        slips = [unit_slip(r.drive, (lo, hi), r.drive_name) for r in recordings]
        advice = next((f"{r.name}: {w}" for r, w in zip(recordings, slips) if w), advice)
        raise InputError(
            f"cannot conclude anything: the recordings' drive never enters the range the model was identified on "
            f"({lo:.3g}..{hi:.3g}); {advice}")
    if stress_overlap and max(stress_overlap) < min_overlap:
        stress = np.concatenate([r.stress_MPa for r in recordings if r.stress_MPa is not None])
        raise InputError(
            f"cannot conclude anything: every recording's stress lies outside the model's range "
            f"({srange[0]:.3g}..{srange[1]:.3g} MPa); " + (stress_sign_advice(stress, srange) or
            "record at loads inside that range, or identify an SDPI that covers these stresses"))


def beyond_range_notes(model: Any, data: Sequence[RecData], margin: float = 0.02, share: float = 0.01) -> list[str]:
    """With too little data to test saturation: each recording that drives beyond the model's
    identified range (widened by `margin` of it) on more than `share` of its samples, where the base
    only extrapolates (`EffectSelector` documents both). A 13 um miss on a piezo run at 0..150 V
    against a model identified at -75..75 V otherwise came with no word on why."""
    lo, hi = (float(v) for v in model.drive_range)
    unit = drive_unit(model.drive_name)
    notes = []
    for d in data:
        outside = outside_range(d.u, (lo, hi), margin)
        if d.u.size and float(np.mean(outside)) > share:
            notes.append(f"{d.name}: {np.mean(outside):.0%} of the samples drive beyond the range the model was "
                         f"identified on ({lo:.3g}..{hi:.3g} {unit}; this recording {float(np.min(d.u)):.3g}.."
                         f"{float(np.max(d.u)):.3g} {unit}), where the base only extrapolates, and there is too little "
                         "data to test saturation: identify the model from recordings over the whole drive range "
                         "used, or record as much as asked above")
    return notes


def enough_data(data: Sequence[RecData], min_samples: int, clamped_share: float = 0.01,
                folds_filled: bool = True) -> tuple[int, bool, bool, list[str]]:
    """Scored samples in all, whether that is too little to tell effects apart, whether only the
    slow effects can be told apart (too few drive reversals for loops, but holds enough: a step
    test), and what cannot be concluded from the recordings as they are (a recording never scored,
    too little data, stresses outside the model's range). Recordings scored in part are noted once,
    by `data.unscored_starts_note`. A sample is scored where the unknown initial state no longer
    moves the output (`data.known_samples`); `folds_filled` is False when a held-out fold has no
    scored row (it would be fitted to nothing)."""
    cannot = []
    n_samples = sum(d.n_scored for d in data)   # samples scored: where the initial state is known
    n_rev = sum(reversals(d.u[run]) for d in data for run in d.scored_runs())
    n_holds = sum(holds(d.t[run], d.u[run], HOLD_S) for d in data for run in d.scored_runs())
    cannot += [unscored_note(d) for d in data if d.n_scored == 0]
    enough_scored = n_samples >= min_samples and folds_filled
    slow_only = enough_scored and n_rev < MIN_REVERSALS and n_holds >= MIN_HOLDS
    too_little = not enough_scored or (n_rev < MIN_REVERSALS and not slow_only)
    if slow_only:
        cannot.append(
            f"too few drive reversals ({n_rev}) to test the effects that show in loops (rate dependence, resonance, "
            f"delay, stress-dependent play, saturation); heating and creep are tested on the drive's {n_holds} "
            f"holds. Record at least a few cycles (>= {MIN_REVERSALS // 2} full loops) at two or more drive "
            "frequencies to test the others")
    if too_little:
        cannot.append(
            f"too little data to tell effects apart ({n_samples} samples, {n_rev} drive reversals in all): "
            "any effect would be fitted to the same few loops it is judged on; record at least a few cycles "
            f"(>= {MIN_REVERSALS // 2} full loops, >= {min_samples} samples) at two or more drive frequencies")
    for d in data:
        if d.clipped is not None and d.stalled is not None:
            cannot += held_notes(d.name, d.y, d.clipped, d.stalled)
        if d.clamped_fraction > clamped_share:
            cannot.append(f"{d.name}: {d.clamped_fraction:.0%} of the samples are at stresses outside the "
                          "model's range; they were compared at the nearest stress of the range")
    return n_samples, too_little, slow_only, cannot


# the measured displacement's swing against the model's for the same drive: this far apart (either way)
# no physics the vocabulary holds explains it (saturation, heating and creep move it by percents)
SCALE_SLIP_RATIO = 30.0
SCALE_DRIVE_SHARE = 0.2       # judged only where the drive sweeps this share of the identified range


def check_displacement_scale(model: Any, data: Sequence[RecData], predicted: Sequence[np.ndarray]) -> None:
    """Refuse a recording whose measured displacement swings 30x more or less than the model predicts
    for its drive (`displacement_scale_words`). Left to the fits, the static gain took the unit's place
    ('unexplained', an extended model with gain 0.001)."""
    for d, yp in zip(data, predicted):
        words = displacement_scale_words(d.u, model.drive_range, d.y, yp)
        if words:
            raise InputError(f"{d.name}: {words}")


def displacement_scale_words(drive: np.ndarray, drive_range: Any, measured: np.ndarray, predicted: np.ndarray) -> str:
    """'' or why a measured displacement swinging 30x more or less than the model's prediction for the
    same drive (judged where the drive sweeps a fifth of the identified range) cannot be compared: a
    displacement in mm or nm under displacement_um (with the factor to convert by), a sensor that does
    not read the actuator, or a model of another actuator."""
    lo, hi = (float(v) for v in drive_range)
    u_lo, u_hi = np.percentile(drive, [1.0, 99.0])
    if not (np.isfinite(hi - lo) and u_hi - u_lo >= SCALE_DRIVE_SHARE * (hi - lo)):
        return ""
    swing = float(np.subtract(*np.percentile(measured, [99.0, 1.0])))
    model_swing = float(np.subtract(*np.percentile(predicted, [99.0, 1.0])))
    if not (model_swing > 0 and swing > 0):
        return ""
    ratio = swing / model_swing
    if 1 / SCALE_SLIP_RATIO <= ratio <= SCALE_SLIP_RATIO:
        return ""
    slip = unit_slip_factor(ratio)
    power = ratio if slip is None else slip       # nearer 1 than a unit's slip: the ratio itself converts
    factor = max(power, 1 / power)
    factor_text = f"{factor:.0f}" if factor >= 10 else f"{factor:.3g}"
    convert = f"{'multiply' if ratio < 1 else 'divide'} displacement_um by {factor_text}"
    return (f"the measured displacement swings {swing:.3g} um where the model predicts {model_swing:.3g} um for "
            f"this drive ({ratio:.3g}x): a displacement in another unit ({convert}), a sensor that does not read "
            "this actuator, or a model of another actuator (identify one from this actuator's recordings)")
