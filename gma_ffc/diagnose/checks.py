"""Checks before any fit: do the recordings overlap the model's range, and are there enough loops."""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from ..errors import InputError
from ..recordings import Recording


def check_overlap(model: Any, recordings: Sequence[Recording]) -> None:
    lo, hi = model.drive_range
    srange = model.stress_range_MPa
    drive_overlap = []
    stress_overlap = []
    for rec in recordings:
        u = rec.drive
        inside = (u >= lo - 0.02 * (hi - lo)) & (u <= hi + 0.02 * (hi - lo)) if math.isfinite(hi - lo) else np.ones(u.size, bool)
        drive_overlap.append(float(np.mean(inside)))
        if srange is not None and rec.stress_MPa is not None:
            s = rec.stress_MPa
            tol = 0.02 * max(srange[1] - srange[0], 1.0)
            stress_overlap.append(float(np.mean((s >= srange[0] - tol) & (s <= srange[1] + tol))))
    if max(drive_overlap) < 0.05:
        raise InputError(
            f"cannot conclude anything: the recordings' drive never enters the range the model was identified on "
            f"({lo:.3g}..{hi:.3g}); record inside that range, or identify a model from recordings covering these drives")
    if stress_overlap and max(stress_overlap) < 0.05:
        raise InputError(
            f"cannot conclude anything: every recording's stress lies outside the model's range "
            f"({srange[0]:.3g}..{srange[1]:.3g} MPa); record at loads inside that range, or identify an SDPI that covers these stresses")
