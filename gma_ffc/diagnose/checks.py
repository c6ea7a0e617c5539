"""Checks before any fit: do the recordings overlap the model's range, and is there enough to score."""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from ..drive import reversals
from ..errors import InputError
from ..recordings import Recording
from .data import N_BLOCKS, RecData, unscored_note

MIN_REVERSALS = 2 * N_BLOCKS   # drive turning points in all: on average a full drive cycle per time block, or a
                               # held-out block is a piece of one branch that the neighbouring training blocks
                               # interpolate, and blocked cross-validation tests interpolation, not prediction


def check_overlap(model: Any, recordings: Sequence[Recording], margin: float = 0.02,
                  min_overlap: float = 0.05) -> None:
    """Refuse recordings of which less than `min_overlap` of the samples lie inside the model's drive
    (or stress) range, widened by `margin` of it (`EffectSelector` documents both)."""
    lo, hi = model.drive_range
    srange = model.stress_range_MPa
    drive_overlap = []
    stress_overlap = []
    for rec in recordings:
        u = rec.drive
        inside = (u >= lo - margin * (hi - lo)) & (u <= hi + margin * (hi - lo)) if math.isfinite(hi - lo) else np.ones(u.size, bool)
        drive_overlap.append(float(np.mean(inside)))
        if srange is not None and rec.stress_MPa is not None:
            s = rec.stress_MPa
            tol = margin * max(srange[1] - srange[0], 1.0)
            stress_overlap.append(float(np.mean((s >= srange[0] - tol) & (s <= srange[1] + tol))))
    if max(drive_overlap) < min_overlap:
        raise InputError(
            f"cannot conclude anything: the recordings' drive never enters the range the model was identified on "
            f"({lo:.3g}..{hi:.3g}); record inside that range, or identify a model from recordings covering these drives")
    if stress_overlap and max(stress_overlap) < min_overlap:
        raise InputError(
            f"cannot conclude anything: every recording's stress lies outside the model's range "
            f"({srange[0]:.3g}..{srange[1]:.3g} MPa); record at loads inside that range, or identify an SDPI that covers these stresses")


def enough_data(data: Sequence[RecData], min_samples: int, clamped_share: float = 0.01,
                folds_filled: bool = True) -> tuple[int, bool, list[str]]:
    """Scored samples in all, whether that is too little to tell effects apart, and what cannot be
    concluded from the recordings as they are (a recording never scored, too little data, stresses
    outside the model's range). Recordings scored in part are noted once, by `data.unscored_starts_note`.
    A sample is scored where the unknown initial state no longer moves the output (`data.known_samples`);
    `folds_filled` is False when a held-out fold has no scored row (it would be fitted to nothing)."""
    cannot = []
    n_samples = sum(d.n_scored for d in data)   # samples scored: where the initial state is known
    n_rev = sum(reversals(d.u[run]) for d in data for run in d.scored_runs())
    cannot += [unscored_note(d) for d in data if d.n_scored == 0]
    too_little = n_samples < min_samples or n_rev < MIN_REVERSALS or not folds_filled
    if too_little:
        cannot.append(
            f"too little data to tell effects apart ({n_samples} samples, {n_rev} drive reversals in all): "
            "any effect would be fitted to the same few loops it is judged on; record at least a few cycles "
            f"(>= {MIN_REVERSALS // 2} full loops, >= {min_samples} samples) at two or more drive frequencies")
    for d in data:
        if d.clamped_fraction > clamped_share:
            cannot.append(f"{d.name}: {d.clamped_fraction:.0%} of the samples are at stresses outside the "
                          "model's range; they were compared at the nearest stress of the range")
    return n_samples, too_little, cannot
