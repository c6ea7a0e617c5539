"""What identification recordings show about themselves: whether a drive sweeps a whole loop, when
its start no longer matters, how fast it loops, whether the displacement moves against it (a
butterfly), and what their columns hold that no fit can undo (a sensor at its limit, stresses
logged positive). `identify` reads these to refuse, or to note, with the recording to make.
Pure maths: no I/O.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from . import operators as ops
from .drive import loop_frequency_hz
from .recordings import Recording
from .sensor_holds import held_notes, held_samples
from .unit_slips import unit_slip_factor


def has_full_sweep(x: np.ndarray, tol: float = 0.1) -> bool:
    """True when the drive travels the whole of its range upwards and downwards: a closed major
    loop, wherever in it the recording starts (a cycle cut mid-rise counts; a single ramp does
    not). Without it the loop's two branches cannot both be fitted.

    Travel is counted on the drive passed through a play of half-width tol/2 of the range, so
    noise and small reversals add nothing."""
    lo, hi = (float(v) for v in np.percentile(x, [1.0, 99.0]))  # a start-up or stop ramp is no cycle
    span = hi - lo
    if span <= 0:
        return False
    xs = np.ascontiguousarray(np.clip(x, lo, hi), dtype=float)
    p = np.empty((xs.size, 1))
    ops.play_outputs(xs, np.array([0.5 * tol * span]), np.array([xs[0]]), p)
    step = np.diff(p[:, 0])
    need = (1.0 - 2.0 * tol) * span
    return float(step[step > 0].sum()) >= need and float(-step[step < 0].sum()) >= need


def burn_in_end(x: np.ndarray, tol: float = 0.02) -> int:
    """First sample after the drive has swept from one extreme to the other (play states then
    no longer depend on their initial values); 0 if it never does."""
    lo, hi = float(x.min()), float(x.max())
    span = hi - lo
    if span <= 0:
        return 0
    near_lo = np.flatnonzero(x <= lo + tol * span)
    near_hi = np.flatnonzero(x >= hi - tol * span)
    end = max(int(near_lo[0]), int(near_hi[0]))
    return end if end < len(x) - 10 else 0


def late_sweep_note(shares: Sequence[float]) -> str:
    """identify's note on recordings that reach both ends of their drive late (a single cycle, a
    cut-out window, a rising amplitude): not a fault, but their start state had to be estimated."""
    lo, hi = 100 * min(shares), 100 * max(shares)
    share = f"{lo:.0f} %" if round(lo) == round(hi) else f"{lo:.0f}-{hi:.0f} %"
    return (f"{len(shares)} recording(s) reach both ends of their drive only after {share} of their samples "
            "(a single cycle, a cut-out window or a rising amplitude): their initial hysteresis state was "
            "estimated from the measurement, and every sample fitted")


FAST_LOOP_HZ = 20.0
"""Above this loop rate a failed identification also names the drive's speed as a likely cause: the
GMA's eddy-current and mechanical corner frequencies are tens to hundreds of Hz, and the paper
identifies at 3 Hz."""


def fewer_operators(n_samples: int, n_play: int) -> str:
    """The part of the too-few-samples advice that fits fewer operators, when a model with at least
    two plays and one dead-zone fits in `n_samples` (eight samples per operator): '' otherwise."""
    plays = min(n_samples // 8 - 1, n_play - 1)
    return f", or fit fewer operators (--plays {plays} --deadzones 1)" if plays >= 2 else ""


def loop_rates_hz(recordings: Sequence[Recording]) -> list[float]:
    """Each recording's drive loop rate (`drive.loop_frequency_hz`), those that loop at all."""
    rates = (loop_frequency_hz(r.time_s, r.drive) for r in recordings)
    return [f for f in rates if np.isfinite(f)]


CLOCKWISE_WIDTH = 0.05
"""A clockwise loop wider than this share of the stroke (on average over the drive's travel) is
noted: far above what noise or a settling transient leaves, far below the 10-20 % of the stroke
that real hysteresis loops are wide."""


BUTTERFLY_SHARE = 1.0 / 3.0
"""A recording the model cannot explain is called a butterfly when its displacement moves against
the drive over at least this share of its travel: a symmetric butterfly does over half of it, a
play model never does, and lags and noise after reversals reach a few per cent."""

BRANCH_BINS = 20
"""`travel_against_drive` reads each branch (rising, falling drive) as its mean displacement in this
many bins of the drive's span: enough to draw a butterfly's fall and rise, and each bin averages
many samples, so noise does not make a mean step against the drive."""

BRANCHES_EXPLAIN = 0.5
"""...and it reads them only where those branch means explain at least half the displacement's
variance: a displacement unrelated to the drive (noise, a wrong column) steps against it as often
as with it, and is not a butterfly."""


def travel_against_drive(x: np.ndarray, y: np.ndarray) -> float:
    """The share of the displacement's travel that goes against the drive, read from its mean over
    each branch (rising, falling drive) in BRANCH_BINS bins of the drive's span: 0 for a play model's
    output, about 1/2 for a symmetric butterfly, and 0 where the branches do not explain the
    displacement (BRANCHES_EXPLAIN) or the drive does not move."""
    dx = np.diff(x)
    if x.size < 3 or np.ptp(x) <= 0 or np.var(y) <= 0:
        return 0.0
    rising = np.r_[dx[0] >= 0, dx >= 0]
    bins = np.minimum(((x - x.min()) / np.ptp(x) * BRANCH_BINS).astype(int), BRANCH_BINS - 1)
    cell = bins + BRANCH_BINS * rising
    counts = np.bincount(cell, minlength=2 * BRANCH_BINS)
    means = np.bincount(cell, weights=y, minlength=2 * BRANCH_BINS) / np.maximum(counts, 1)
    if 1.0 - float(np.var(y - means[cell])) / float(np.var(y)) < BRANCHES_EXPLAIN:
        return 0.0
    filled = counts.reshape(2, BRANCH_BINS) > 0           # (falling, rising) x bins along the drive
    steps = np.concatenate([np.diff(m[f]) for m, f in zip(means.reshape(2, BRANCH_BINS), filled)])
    travel = float(np.sum(np.abs(steps)))
    return float(np.sum(-steps[steps < 0])) / travel if travel > 0 else 0.0


def butterfly_words(drive_name: str) -> tuple[str, str]:
    """(why the strain turns round, the drive to identify from instead) for the actuator the drive
    names: a voltage drives a ferroelectric ceramic, which the field repoles; a current drives a
    magnetostrictive rod, whose strain is even in the field, so it follows |I| whatever the poling."""
    if drive_name == "voltage_V":
        return ("as a ferroelectric ceramic's strain when a bipolar drive passes its coercive field",
                "identify from a unipolar drive, from 0 to the peak on the side the ceramic is poled")
    return ("as a magnetostrictive rod's strain when the current changes sign: the strain is even in the field "
            "(magnetostriction does not change sign with the current), so it rises again as the current grows the "
            "other way",
            "identify over a unipolar current, from 0 to the peak, or a biased one that never changes sign")


def column_notes(recordings: Sequence[Recording]) -> list[str]:
    """What the columns show that the fit cannot undo: a sensor's reading held while the drive
    moved (its limit or a stall, fitted as the actuator's), and stresses logged positive."""
    notes = []
    for r in recordings:
        y = r.displacement_um
        if y is not None:
            notes += held_notes(r.name, y, *held_samples(y, r.drive),
                                fate="The model is fitted to them as if the actuator held still there")
    stresses = [r.stress_MPa for r in recordings if r.stress_MPa is not None]
    if stresses and all(float(np.min(s)) > 0.0 for s in stresses):
        notes.append("stress_MPa is positive in every recording, and compression is negative in gma-ffc's "
                     "recordings (docs/recordings.md): if these are the compressive loads an actuator is "
                     "held under, negate the column before identifying")
    else:
        notes += mixed_sign_notes(recordings)
    return notes


def mixed_sign_notes(recordings: Sequence[Recording]) -> list[str]:
    """A note naming the recordings whose stress is positive at every sample when others' is negative
    at every sample: one load cell logs compression negative, gma-ffc's convention, and these were
    logged (or copied) with the other sign. A recording whose stress crosses zero has no sign."""
    signed = [(r.name, float(np.median(r.stress_MPa))) for r in recordings
              if r.stress_MPa is not None and (np.all(r.stress_MPa > 0.0) or np.all(r.stress_MPa < 0.0))]
    positive = [f"{name} ({median:+.3g} MPa)" for name, median in signed if median > 0.0]
    negative = len(signed) - len(positive)
    if not positive or not negative:
        return []
    odd = ", ".join(positive)
    return [f"stress_MPa is positive in {odd} but negative in {negative} other recording(s), and "
            "compression is negative in gma-ffc's recordings (docs/recordings.md): if the positive ones are "
            "compressive loads logged with the other sign, negate their stress_MPa column before identifying"]


SCALE_RATIO = 30.0     # recordings of one actuator whose displacement per drive differs this much: a unit


def scale_mismatch(recordings: Sequence[Recording]) -> str:
    """'' or the refusal's words when a recording's displacement swing per drive swing is 30x off the
    others' median (a displacement in mm or nm under displacement_um, another actuator's run): the fit
    took it in as the same actuator's and wrote a model, or called the lot 'hardly follows the drive'."""
    swings = [float(np.subtract(*np.percentile(r.drive, [99.0, 1.0]))) for r in recordings]
    widest = max(swings, default=0.0)
    gains = []
    for r, du in zip(recordings, swings):     # judged where the drive sweeps a fifth of the widest sweep or more
        y = r.displacement_um
        dy = float(np.subtract(*np.percentile(y, [99.0, 1.0]))) if y is not None else 0.0
        gains.append((r.name, dy / du) if du >= 0.2 * widest > 0 and dy > 0 else (r.name, np.nan))
    known = [g for _, g in gains if np.isfinite(g)]
    if len(known) < 2:
        return ""
    mid = float(np.median(known))
    odd = [(name, g / mid) for name, g in gains if np.isfinite(g) and not (1 / SCALE_RATIO <= g / mid <= SCALE_RATIO)]
    if not odd or len(odd) * 2 >= len(known):
        return ""
    name, ratio = odd[0]
    factor = unit_slip_factor(ratio)
    convert = (f"{'multiply' if ratio < 1 else 'divide'} displacement_um by {max(factor, 1 / factor):.0f}"
               if factor is not None else "check its columns")
    return (f"{name}: its displacement per drive is {ratio:.3g}x the other recordings' (a displacement in another "
            f"unit: {convert}; or a run of another actuator: identify each actuator on its own)")
