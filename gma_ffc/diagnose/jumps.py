"""Jumps of the displacement sensor's zero in a residual (pure maths).

A laser or capacitive sensor re-zeroed mid-run, an interferometer that loses fringes, a mount that
slips or a knock on the table: the measured displacement steps within a sample or two and stays
there, while neither the drive nor the load steps. No actuator physics does that (heating, creep and
relaxation are smooth; the actuator's own steps follow a drive or load step), so such a step is a
sensor event. Left in, it dominates the residual and hides the physics a fit should find; each
one found is given an offset change of its own in every fit (`Fitter`), and the words say so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .noise import mad_sigma, second_difference_sigma

# A jump is a change over a span this many times the spread the noise gives such changes (sqrt(2)
# sigma for white noise, the change Gaussian): exceeded with probability ~1e-23.
JUMP_SIGMAS = 10.0
JUMP_SPAN_S = 1e-3            # a sensor's own filter (1 kHz or faster) may spread a step over this long
JUMP_SPAN_MIN = 2             # samples, at least
SHARPNESS = 5.0               # a step changes the residual 5x more than any change just before or after it
NEIGHBOURS = 8                # (those: the changes 1..8 spans either side; a sine sampled 20x per period
                              # or faster changes by less than that ratio over them, and noise gives 16
                              # such changes a largest of about 2.2 of their sigma, 10 sigmas / 5 above)
LEVEL_S = 0.1                 # the levels either side: straight lines over this long (at least 20 samples)
LEVEL_MIN_SAMPLES = 20
LEVEL_KEPT = 0.5              # the level after must differ from the level before by half the step: not a spike
QUIET_S = 0.01                # the drive and stress may not step themselves within this long either side
MAX_JUMPS = 5                 # more than this in one recording is not a re-zero but a sensor to repair
MAX_CANDIDATES = 5000         # the largest sharp changes judged (a noisy, spiky record can have many)


@dataclass(frozen=True)
class Jump:
    """A step of the sensor's zero: from sample `index` on, the measurement is off by `um` more."""
    index: int
    t_s: float
    um: float


@dataclass(frozen=True)
class Jumps:
    """The jumps found in one recording; `excess` > 0: more than MAX_JUMPS of them (none is modelled)."""
    found: tuple[Jump, ...] = ()
    excess: int = 0


def _changes(x: np.ndarray, span: int) -> np.ndarray:
    """x[k + span] - x[k]: the change a step makes within the span."""
    return x[span:] - x[:-span]


def _spread(change: np.ndarray) -> float:
    """Robust spread of the changes: the MAD's sigma, or half the quantum of a quantised signal
    whose changes are mostly zero."""
    if change.size == 0:
        return 0.0
    return max(mad_sigma(change), 0.5 * _smallest_step(change))


def _noise_spread(r: np.ndarray, span: int) -> float:
    """The spread of a change over the span that the noise alone makes: sqrt(2) sigma (sigma from
    `noise.second_difference_sigma`, which the signal's own motion, however fast at these rates,
    hardly reaches); the changes' own spread where that is 0."""
    if r.size < 3:
        return 0.0
    sigma = second_difference_sigma(r)
    return float(np.sqrt(2.0) * sigma) if sigma > 0 else _spread(_changes(r, span))


def _smallest_step(x: np.ndarray) -> float:
    """The smallest non-zero magnitude in x (0 if none): a quantised signal's quantum, when x holds
    its changes (for an unquantised one it is tiny)."""
    a = np.abs(x)
    a = a[a > 0]
    return float(a.min()) if a.size else 0.0


def _steps_at(change: np.ndarray, k: int, near: int, w: int, floor: float) -> bool:
    """Does the signal whose changes are `change` step itself within +-near of k: a change beyond
    JUMP_SIGMAS of the spread of its changes around k (+-w; a sine's motion is not a step, a step
    out of a hold or a load change is)?"""
    local = change[max(0, k - w): k + w + 1]
    spread = max(_spread(local), floor)
    return bool(np.max(np.abs(change[max(0, k - near): k + near + 1])) > JUMP_SIGMAS * spread)


def _level(r: np.ndarray, t: np.ndarray, a: int, b: int, at: float) -> float:
    """The residual's level at time `at`, from the straight line through r[a:b] (the residual
    drifts with the model's error either side of a step)."""
    return float(np.polyfit(t[a:b] - at, r[a:b], 1)[1])


def _sharp(change: np.ndarray, span: int) -> np.ndarray:
    """Per change index: is it SHARPNESS times each of the NEIGHBOURS changes a span, two spans, ...
    before and after it (a step, not a fast stretch of a smooth signal)? Those neighbours do not
    overlap, so how many the noise offers does not grow with the sampling rate. False where they
    run off the record."""
    a = np.abs(change)
    reach = NEIGHBOURS * span
    out = np.zeros(a.size, dtype=bool)
    if a.size < 2 * reach + 1:
        return out
    k = np.arange(reach, a.size - reach)
    around = np.zeros(k.size)
    for j in range(1, NEIGHBOURS + 1):
        np.maximum(around, np.maximum(a[k - j * span], a[k + j * span]), out=around)
    out[k] = a[k] >= SHARPNESS * around
    return out


def _breaks(seen: np.ndarray, k: int, span: int, step: float) -> bool:
    """Is the measurement itself discontinuous at k by at least LEVEL_KEPT of the residual's step,
    in its direction: its change over the span less the mean of the spans just before and after
    (a smooth motion, however fast, leaves about y'' (span dt)^2 there; a model whose output turns
    a corner leaves the measurement smooth)?"""
    if k - span < 0 or k + span >= seen.size:
        return False
    gap = float(seen[k]) - 0.5 * (float(seen[k - span]) + float(seen[k + span]))
    return gap * step > 0 and abs(gap) >= LEVEL_KEPT * abs(step)


def sensor_jumps(measured: np.ndarray, predicted: np.ndarray, drive: np.ndarray, stress: np.ndarray,
                 t: np.ndarray, dt: float, first: int = 0) -> Jumps:
    """Steps of the residual (measured minus predicted, from sample `first` on) that persist, that
    the measurement itself makes (a model's kink is not the sensor's), and that come while
    neither drive nor stress steps and the samples are evenly spaced. The largest are judged
    first; past MAX_JUMPS the search stops (`excess`: at least that many)."""
    n = measured.size
    span = max(JUMP_SPAN_MIN, int(round(JUMP_SPAN_S / dt)))
    w = max(LEVEL_MIN_SAMPLES, int(round(LEVEL_S / dt)), 4 * span)
    if n - first < 2 * w + span + 1:
        return Jumps()
    y = np.asarray(measured, dtype=float)
    r = y - np.asarray(predicted, dtype=float)
    change = _changes(r, span)                         # change[k] = r[k + span] - r[k]
    seen = _changes(y, span)
    # a quantised sensor ticks by one quantum where the motion is slow, which is no jump
    spread = max(_noise_spread(r[first:], span), 0.5 * _smallest_step(np.diff(y[first:])))
    if spread <= 0:
        return Jumps()
    near = max(span + 1, int(round(QUIET_S / dt)))
    inputs = [(ch, _spread(ch)) for ch in (_changes(np.asarray(x, dtype=float), span) for x in (drive, stress))]
    gaps = np.zeros(n, dtype=bool)
    uneven = np.flatnonzero(np.diff(t) > 1.5 * dt)
    for g in uneven:                                  # a step across a gap is the gap's, not the sensor's
        gaps[max(0, g - near): g + near + 1] = True
    cand = np.flatnonzero((np.abs(change) > JUMP_SIGMAS * spread) & _sharp(change, span))
    cand = cand[(cand >= first + w) & (cand + span + w <= n)]
    found: list[Jump] = []
    for k in cand[np.argsort(-np.abs(change[cand]), kind="stable")][:MAX_CANDIDATES]:
        if not _breaks(seen, k, span, float(change[k])):
            continue                                  # the model's own kink: the measurement is smooth
        if gaps[k: k + span + 1].any() or any(_steps_at(ch, k, near, w, 1e-3 * whole)
                                                     for ch, whole in inputs):
            continue
        if any(abs(k - j.index) < 2 * w for j in found):
            continue                                  # the same step seen from a neighbouring sample
        at = k + 1 + int(np.argmax(np.abs(np.diff(r[k: k + span + 1]))))
        step = _level(r, t, at + span, at + span + w, t[at]) - _level(r, t, at - w, at, t[at])
        if step * change[k] <= 0 or abs(step) < LEVEL_KEPT * abs(change[k]):
            continue                                  # a spike (it comes back) or a wiggle
        found.append(Jump(at, float(t[at]), step))
        if len(found) > MAX_JUMPS:
            break
    if len(found) > MAX_JUMPS:
        return Jumps((), len(found))
    return Jumps(tuple(sorted(found, key=lambda j: j.index)))


def jump_words(jumps: Jumps, unit: str = "um") -> str:
    """What the jumps are, for the located description ('' if none)."""
    if jumps.excess:
        return (f"the residual steps at least {jumps.excess} times while neither the drive nor the load steps: "
                "the displacement sensor loses its zero again and again (fringe counting, a loose mount or "
                "cable); repair it before diagnosing, as these steps are not modelled")
    if not jumps.found:
        return ""
    each = ", ".join(f"{j.um:+.3g} {unit} at t = {j.t_s:.4g} s" for j in jumps.found)
    return (f"the residual steps by {each} within {JUMP_SPAN_S * 1e3:g} ms while neither the drive nor the load "
            "steps: a sensor re-zero, a slip or a knock, not the actuator's response; every fit allows the "
            "sensor's zero to change there")
