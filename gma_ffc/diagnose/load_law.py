"""Whether a named resonance's shift with the load was measured, or only extrapolated.

A resonance's law across loads (`effects.dynamics`: the load's mass from its static stress) is
fitted where the recordings show the resonance. When the model improves on the base as given
only over a narrow part of the recordings' loads, the law's course beyond it rests on the law's
form alone. The twenty-third never-tuned draw's resonance showed it: driven hard at its least
compressive load only (1.6 of 7.5 MPa), the law came out 3x too steep. It met the recording
(0.42 um at that load), but put the resonance 20 % low at the heaviest load, and a probe there went
from 2.5 to 6.0 um. The data there (slow steps) showed no resonance at all: the base was better.
That is then said, with the recording that measures the law: this module finds the loads
improved and words it. It reads the fit and does no I/O.
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from ..effects import rod_load as RL

# The loads are cut into this many equal stress bins over the recordings' static stresses: fine
# enough that a narrow band of loads shows as narrow, coarse enough that each bin of a recording
# held at a load has thousands of samples.
STRESS_BINS = 8
# A bin counts with at least this share of the scored samples: a load passed through on the way
# to another (0.7 % of the draw's samples) shows nothing of a law.
MIN_BIN_SHARE = 0.01
# The law is measured when the loads it improves span at least this share of the recordings' span;
# less, and most of its course is extrapolated from a band narrower than the part beyond it.
LAW_SPAN_SHARE = 0.5


def improved_span(static: Sequence[np.ndarray], scored: Sequence[np.ndarray], before: Sequence[np.ndarray],
                  after: Sequence[np.ndarray], improves: float) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """The stresses over which `after` improves on `before` (squared error cut to at most `improves`
    of it, in a bin of STRESS_BINS that holds MIN_BIN_SHARE of the scored samples), and the
    recordings' stresses; None when the stresses do not vary or no bin improves."""
    s = np.concatenate([x[m] for x, m in zip(static, scored)])
    e0 = np.concatenate([x[m] ** 2 for x, m in zip(before, scored)])
    e1 = np.concatenate([x[m] ** 2 for x, m in zip(after, scored)])
    if s.size == 0 or not np.all(np.isfinite(s)):
        return None
    lo, hi = float(s.min()), float(s.max())
    if hi <= lo:
        return None
    edges = np.linspace(lo, hi, STRESS_BINS + 1)
    which = np.clip(np.searchsorted(edges, s, side="right") - 1, 0, STRESS_BINS - 1)
    n = np.bincount(which, minlength=STRESS_BINS)
    sse0 = np.bincount(which, weights=e0, minlength=STRESS_BINS)
    sse1 = np.bincount(which, weights=e1, minlength=STRESS_BINS)
    better = (n >= MIN_BIN_SHARE * s.size) & (sse1 <= improves * sse0)
    if not better.any():
        return None
    k = np.flatnonzero(better)
    return (float(edges[k[0]]), float(edges[k[-1] + 1])), (lo, hi)


def extrapolation_words(span: tuple[tuple[float, float], tuple[float, float]] | None,
                        params: Mapping[str, float]) -> str:
    """What to say of a resonance law whose improved loads span less than LAW_SPAN_SHARE of the
    recordings' ('' when it spans more, or nothing improved), and the recording that measures it."""
    if span is None:
        return ""
    (a, b), (lo, hi) = span
    if b - a >= LAW_SPAN_SHARE * (hi - lo):
        return ""
    far = lo if abs(lo - 0.5 * (a + b)) > abs(hi - 0.5 * (a + b)) else hi   # the loads' end farthest from it
    f_far = law_frequency(params, far)
    # half to twice the law's frequency there: a law that far off would be no law at all
    sweep = f"a sine swept from {0.5 * f_far:.3g} to {2.0 * f_far:.3g} Hz about the {f_far:.4g} Hz the law puts there, or fast steps"
    return (f"mechanical_dynamics: the resonance improves the fit only at static stresses {_mpa(a)} to {_mpa(b)} of "
            f"the recordings' {_mpa(lo)} to {_mpa(hi)}. Its shift with the load beyond them is extrapolated "
            f"from the law's form, not measured. To measure it, record a drive that excites the resonance "
            f"({sweep}) at {_mpa(far)}.")


def law_frequency(params: Mapping[str, float], stress_MPa: float) -> float:
    """The resonance frequency the fitted law gives at a static stress, as the model runs it
    (`rod_load.resonance_hz`: held where the parameters hold it)."""
    held = tuple(float(params.get(key, end)) for key, end in zip(RL.HELD_KEYS, (-math.inf, math.inf)))
    return RL.resonance_hz(float(params["f_ref_hz"]), float(params.get("beta_per_MPa", 0.0)),
                           float(params.get("stress_ref_MPa", stress_MPa)), stress_MPa, (held[0], held[1]))


def _mpa(stress: float) -> str:
    return f"{stress:.3g} MPa"
