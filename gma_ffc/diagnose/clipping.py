"""A displacement sensor at the end of its range: the reading holds at exactly its largest (or
smallest) value while the drive moves on, so the actuator's motion there is not in the file.

An actuator driven by a few percent of its drive span moves by about that share of its stroke:
hundreds of a sensor's least steps. A reading that does not change by one of them over such a
drive change is the sensor's limit, not physics. Those samples are not scored (pure maths, no I/O).
"""

from __future__ import annotations

import numpy as np

CLIP_DRIVE_SHARE = 0.01   # the drive moves by at least this share of its span while the reading holds: a sine
                          # clipped over its top tenth of the time spans 2.4 % of its drive range there
CLIP_STEPS = 10           # ... and by enough to move the actuator ten of the sensor's least steps (a quantised
                          # reading repeats at a turning point, over a drive change of about one step)
CLIP_MIN_SAMPLES = 5      # at least this many equal readings in a row: one or two equal samples are a coincidence


def clipped_samples(y: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Per sample: does the reading sit at its recording's largest or smallest value, in a run of
    equal readings over which the drive moves by CLIP_DRIVE_SHARE of its span and by CLIP_STEPS
    of the sensor's least steps (in drive units, through the stroke's ratio to the drive span)?"""
    out = np.zeros(y.size, dtype=bool)
    span, stroke = (float(np.ptp(u)), float(np.ptp(y))) if y.size else (0.0, 0.0)
    if y.size < CLIP_MIN_SAMPLES or span <= 0.0 or stroke <= 0.0:
        return out
    dy = np.abs(np.diff(y))
    step = float(np.min(dy[dy > 0]))                       # the sensor's least step (its quantum, if it has one)
    moves = max(CLIP_DRIVE_SHARE * span, CLIP_STEPS * step * span / stroke)
    for extreme in (float(np.max(y)), float(np.min(y))):
        at = np.r_[0, (y == extreme).astype(np.int8), 0]
        edges = np.flatnonzero(np.diff(at))
        for a, b in zip(edges[::2], edges[1::2]):
            if b - a >= CLIP_MIN_SAMPLES and float(np.ptp(u[a:b])) >= moves:
                out[a:b] = True
    return out


def clipping_note(name: str, y: np.ndarray, clipped: np.ndarray) -> str:
    """'' or what the user is told of a recording whose sensor reached the end of its range."""
    if not clipped.any():
        return ""
    ends = sorted({"largest" if v == np.max(y) else "smallest" for v in np.unique(y[clipped])})
    at = " and ".join(f"{float(np.max(y) if e == 'largest' else np.min(y)):.6g} um, its {e} value" for e in ends)
    return (f"{name}: the displacement holds at {at}, for {np.mean(clipped):.1%} of the samples while the drive "
            "moves on: the sensor at the end of its range, not the actuator. Those samples are not scored; record "
            "with the sensor's range covering the whole stroke (or an offset that centres it)")
