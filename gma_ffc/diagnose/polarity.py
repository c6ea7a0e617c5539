"""Does the measured displacement move against the model? Then a column's sign is wrong, not the physics.

No effect in the vocabulary reverses an actuator's quasi-static gain: heat, creep, eddy currents,
a delay or a resonance change how far and when it moves, not which way. A displacement that falls
where the model's rises is a sensor mounted the other way, a sign in the DAQ, or a model of another
actuator. A recalibration would take it as a gain of -1 and every later figure would look
excellent, so `diagnose` says what to fix instead. Pure maths: no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .data import RecData

INVERTED_CORRELATION = -0.5
"""A recording is called inverted when its displacement and the base model's prediction correlate
at this or below over the samples judged: most of the stroke then moves against the model, which
no effect of the vocabulary does (they change a gain by tens of percent, never its sign)."""
MIN_SPAN_NOISE = 10.0
"""The model's prediction must span this many noise floors over the samples judged: a prediction
that barely moves (a hold) leaves its correlation with the measurement to noise and slow drifts."""


@dataclass(frozen=True)
class Inverted:
    recording: str
    correlation: float
    gain: float          # least-squares slope of the measurement on the model's prediction

    def words(self) -> str:
        return (f"{self.recording}: the measured displacement moves against the model's (correlation "
                f"{self.correlation:.2f}, gain {self.gain:.3g} on its prediction). No physical effect reverses an "
                "actuator's direction: the displacement column's sign is probably wrong (a sensor mounted the "
                "other way, or a sign in the DAQ), or the model is of another actuator; flip the column's sign, "
                "or identify a model on this rig, and run again")


def displacement_inverted(data: Sequence[RecData], predictions: Sequence[np.ndarray],
                          noise_um: float) -> Inverted | None:
    """The recording whose displacement runs most clearly against the model's prediction, or None.
    Judged over the scored samples, or over every sample when none is scored."""
    worst: Inverted | None = None
    for d, p in zip(data, predictions):
        keep = d.mask if d.n_scored else np.ones(d.t.size, bool)
        y, q = np.asarray(d.y, float)[keep], np.asarray(p, float)[keep]
        if y.size < 3 or np.ptp(y) == 0 or not np.ptp(q) > MIN_SPAN_NOISE * noise_um:
            continue
        r = float(np.corrcoef(y, q)[0, 1])
        if r <= INVERTED_CORRELATION and (worst is None or r < worst.correlation):
            qc = q - q.mean()
            worst = Inverted(d.name, r, float(np.dot(qc, y - y.mean()) / np.dot(qc, qc)))
    return worst
