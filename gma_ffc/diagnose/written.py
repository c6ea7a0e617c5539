"""The extended model as written: how it does when run as `gma-ffc simulate` runs it.

The selection judges each effect with terms a model file cannot carry: per recording, its
sensor's zero and each step of it, the creep its unknown history left under way at its start, the
start fitted through the effects. A drift the model lacks (heating) goes partly into them.
`extended_model.yaml` runs without them, from a start estimated on the measured displacement.
`written_rms` is what a user then sees, over the samples the diagnosis scored, beside the base's
own miss there ("before"). Pure maths: no I/O.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from .data import RecData


def written_rms(extended: Any, data: Sequence[RecData], rule: Any) -> float:
    """RMS over the scored samples of `extended` simulated on each recording from the start `rule`
    gives it (estimated on the measured displacement, as `gma-ffc simulate` does); NaN when no
    sample is scored."""
    squares, count = 0.0, 0
    for d in data:
        keep = d.mask
        if not keep.any():
            continue
        stress = d.s if extended.stress_range_MPa is not None else None
        predicted = extended.simulate(d.t, d.u, stress, initial_state=rule, measured_um=d.y)
        miss = (d.y - np.asarray(predicted, dtype=float))[keep]
        squares += float(np.dot(miss, miss))
        count += int(miss.size)
    return math.sqrt(squares / count) if count else math.nan
