"""A displacement reading that holds while the drive moves on: the sensor at the end of its range
(the reading sits at exactly its largest or smallest value), or a stalled sensor or logger (it
repeats one value inside the range). Either way the actuator's motion there is not in the file.

An actuator driven by a few percent of its drive span moves by about that share of its stroke:
hundreds of a sensor's least steps. A reading that does not change by one of them over such a
drive change is the sensor's, not physics: `diagnose` does not score those samples, `identify`
says it fits them (pure maths, no I/O).
"""

from __future__ import annotations

import numpy as np

from .drive import moved_since_turn, turning_indices

CLIP_DRIVE_SHARE = 0.01   # the drive moves by at least this share of its span while the reading holds: a sine
                          # clipped over its top tenth of the time spans 2.4 % of its drive range there
CLIP_STEPS = 10           # ... and by enough to move the actuator ten of the sensor's least steps (a quantised
                          # reading repeats at a turning point, over a drive change of about one step)
CLIP_MIN_SAMPLES = 5      # at least this many equal readings in a row: one or two equal samples are a coincidence
AFTER_REVERSAL = 0.1      # a stall inside the range is called one only once the drive has moved this share of its
                          # span since its last reversal: hysteresis holds the output flat after a reversal until
                          # the drive has crossed the smallest play (hil_sim's rod: 1.2 % of the span, at 10 nm)
REPEATS_RARE = 0.05       # a stall inside the range is looked for only where, as the drive moves fast enough to
                          # make a held run in CLIP_MIN_SAMPLES rows, fewer than this share of the rows repeat the
                          # one before: a sensor slower than the logger repeats most of them (and noise-free data
                          # holds between a Preisach rig's relays); a measured run, 0.2-2 % (hil_sim's, a piezo's)


def held_samples(y: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per sample: (clipped, stalled). Both are runs of CLIP_MIN_SAMPLES or more equal readings
    over which the drive moves by CLIP_DRIVE_SHARE of its span and by CLIP_STEPS of the sensor's
    least steps (in drive units, through the stroke's ratio to the drive span). Clipped runs sit
    at the recording's largest or smallest reading; stalled ones anywhere else, looked for only
    where repeated readings are otherwise rare (REPEATS_RARE)."""
    clipped, stalled = np.zeros(y.size, dtype=bool), np.zeros(y.size, dtype=bool)
    span, stroke = (float(np.ptp(u)), float(np.ptp(y))) if y.size else (0.0, 0.0)
    if y.size < CLIP_MIN_SAMPLES or span <= 0.0 or stroke <= 0.0:
        return clipped, stalled
    dy = np.abs(np.diff(y))
    step = float(np.min(dy[dy > 0]))                       # the sensor's least step (its quantum, if it has one)
    moves = max(CLIP_DRIVE_SHARE * span, CLIP_STEPS * step * span / stroke)
    edges = np.r_[0, np.flatnonzero(dy != 0) + 1, y.size]
    held = [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])
            if b - a >= CLIP_MIN_SAMPLES and float(np.ptp(u[a:b])) >= moves]
    at_end = {float(np.max(y)), float(np.min(y))}
    turns = turning_indices(u)
    inside = [(a, b) for a, b in held
              if float(y[a]) not in at_end and moved_since_turn(u, turns, a) >= AFTER_REVERSAL * span]
    fast = np.abs(np.diff(u)) >= moves / CLIP_MIN_SAMPLES      # rows over which a held run would show
    for a, b in held:
        fast[a: b - 1] = False                                   # the runs found are not the sensor's habit
    repeats = float(np.mean(dy[fast] == 0)) if fast.any() else 1.0
    for a, b in held:
        if float(y[a]) in at_end:
            clipped[a:b] = True
    if repeats < REPEATS_RARE:
        for a, b in inside:
            stalled[a:b] = True
    return clipped, stalled


def held_notes(name: str, y: np.ndarray, clipped: np.ndarray, stalled: np.ndarray,
               fate: str = "Those samples are not scored") -> list[str]:
    """What the user is told of a recording whose reading held while the drive moved, and what
    became of those samples (`fate`)."""
    notes = []
    if clipped.any():
        ends = sorted({"largest" if v == np.max(y) else "smallest" for v in np.unique(y[clipped])})
        at = " and ".join(f"{float(np.max(y) if e == 'largest' else np.min(y)):.6g} um, its {e} value" for e in ends)
        notes.append(f"{name}: the displacement holds at {at}, for {np.mean(clipped):.1%} of the samples while the "
                     f"drive moves on: the sensor at the end of its range, not the actuator. {fate}; record with the "
                     "sensor's range covering the whole stroke (or an offset that centres it)")
    if stalled.any():
        runs = int(np.count_nonzero(np.diff(np.r_[0, stalled.astype(np.int8)]) == 1))
        notes.append(f"{name}: the displacement stops changing {runs} time(s) inside its range, for "
                     f"{np.mean(stalled):.1%} of the samples, while the drive moves on: a stalled sensor or logger, "
                     f"not the actuator. {fate}; check the sensor's link and that the logger "
                     "reads it no faster than it updates")
    return notes
