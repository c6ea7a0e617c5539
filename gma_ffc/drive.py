"""What a drive history looks like: its turning points, the loop rate they imply, and its holds.
Pure maths."""

from __future__ import annotations

from typing import Iterator

import numpy as np

from .unit_slips import thousands_exponent


def reversals(u: np.ndarray) -> int:
    """Turning points of the drive by more than 10 % of its span (hysteresis-style counting)."""
    span = float(np.ptp(u))
    if span <= 0:
        return 0
    thr = 0.1 * span
    count, direction = 0, 0
    hi = lo = extreme = float(u[0])
    for v in u[:: max(1, u.size // 20000)]:
        if direction == 0:
            # no direction yet: track both extremes until the drive has moved away from one of them
            hi, lo = max(hi, v), min(lo, v)
            if hi - v > thr:
                direction, extreme = -1, v
            elif v - lo > thr:
                direction, extreme = 1, v
        elif direction > 0:
            if v > extreme:
                extreme = v
            elif extreme - v > thr:
                count += 1
                direction, extreme = -1, v
        else:
            if v < extreme:
                extreme = v
            elif v - extreme > thr:
                count += 1
                direction, extreme = 1, v
    return count


def turning_indices(u: np.ndarray) -> np.ndarray:
    """Every sample where the drive turns, however little (its last before moving the other way)."""
    du = np.sign(np.diff(u))
    moving = np.flatnonzero(du)
    return moving[1:][du[moving[1:]] != du[moving[:-1]]]


def moved_since_turn(u: np.ndarray, turns: np.ndarray, at: int) -> float:
    """How far the drive has moved from its last turn (`turning_indices`) before sample `at`, or
    from its first sample when it has not turned yet."""
    k = int(np.searchsorted(turns, at)) - 1
    return abs(float(u[at]) - float(u[turns[k] if k >= 0 else 0]))


def loop_frequency_hz(time_s: np.ndarray, u: np.ndarray) -> float:
    """Full drive loops per second ((turning points + 1) / 2 / duration: a run from one extreme to
    the other is half a loop; nan without two turning points): the rate a recording sweeps its
    hysteresis loops at, whatever the drive's shape."""
    t = np.asarray(time_s, dtype=float)
    n = reversals(np.asarray(u, dtype=float))
    duration = float(t[-1] - t[0]) if t.size > 1 else 0.0
    if n < 2 or duration <= 0:
        return float("nan")
    return (n + 1) / (2.0 * duration)


def drive_unit(drive_name: str) -> str:
    """The unit a drive column's name ends in (`current_A` -> `A`): units are part of the name
    (docs/recordings.md)."""
    return drive_name.rsplit("_", 1)[-1]


def drive_quantity(drive_name: str) -> str:
    """What a drive column measures, its unit taken off (`voltage_V` -> `voltage`)."""
    return drive_name.rsplit("_", 1)[0]


HOLD_BAND = 0.02
"""A drive that stays within this share of its span holds: well above a current or voltage
sensor's noise over a drive's whole span, well below a step of a step test."""


HOLD_S = 1.0
"""A hold counts once it lasts this long: it then shows creep's fastest central time constant
(`gma_ffc.effects.creep`); and a sine stays within HOLD_BAND of its span at a turning point for
0.09 of its period (0.9 s at 0.1 Hz), so the turns of any faster sine are never holds."""


def _hold_stretches(t: np.ndarray, u: np.ndarray, min_s: float) -> Iterator[tuple[int, int]]:
    """(first, past-last) sample of each stretch of at least `min_s` seconds in which the drive
    stays within HOLD_BAND of its span."""
    band = HOLD_BAND * float(np.ptp(u)) if u.size else 0.0
    if u.size < 2 or band <= 0:
        return
    start, lo, hi = 0, float(u[0]), float(u[0])
    for k in range(1, u.size):
        v = float(u[k])
        if max(hi, v) - min(lo, v) <= band:          # still holding: the stretch grows
            lo, hi = min(lo, v), max(hi, v)
            continue
        if t[k - 1] - t[start] >= min_s:             # the stretch ends: was it long enough?
            yield start, k
        start, lo, hi = k, v, v
    if t[-1] - t[start] >= min_s:                    # the last stretch ends with the recording
        yield start, u.size


def holds(time_s: np.ndarray, u: np.ndarray, min_s: float) -> int:
    """Stretches of at least `min_s` seconds in which the drive stays within HOLD_BAND of its span
    (each after a step or a turn: a step test's levels, a sine's pauses), counted once each."""
    t, u = np.asarray(time_s, dtype=float), np.asarray(u, dtype=float)
    return sum(1 for _ in _hold_stretches(t, u, min_s))


def held(time_s: np.ndarray, u: np.ndarray, min_s: float = HOLD_S) -> np.ndarray:
    """Which samples lie in such a hold (`holds` counts them)."""
    t, u = np.asarray(time_s, dtype=float), np.asarray(u, dtype=float)
    out = np.zeros(u.size, dtype=bool)
    for first, past in _hold_stretches(t, u, min_s):
        out[first:past] = True
    return out


RANGE_MARGIN = 0.02
"""A drive within 2 % of the range a model was identified on is inside it: the range was read off
noisy recordings, to about that."""


def outside_range(u: np.ndarray, drive_range: tuple[float, float], margin: float = RANGE_MARGIN) -> np.ndarray:
    """Which samples of a drive lie beyond `drive_range` widened by `margin` of its span, where a
    model identified on that range only extrapolates (none when the range is not finite)."""
    lo, hi = (float(v) for v in drive_range)
    u = np.asarray(u, dtype=float)
    if not np.isfinite(hi - lo) or hi <= lo:
        return np.zeros(u.shape, dtype=bool)
    wide = margin * (hi - lo)
    return (u < lo - wide) | (u > hi + wide)


UNIT_SLIP_RATIO = 30.0     # a drive this many times the identified range's extent is a unit, not a range


def unit_slip(u: np.ndarray, drive_range: tuple[float, float], column: str) -> str:
    """'' or, when the drive reaches 30x the largest magnitude of `drive_range` (milliamperes or
    millivolts logged under current_A or voltage_V), the conversion that brings it back: advice to
    identify over such a drive (3000 A) is none a rig can follow."""
    lo, hi = (float(v) for v in drive_range)
    top = max(abs(lo), abs(hi))
    peak = float(np.max(np.abs(u))) if np.size(u) else 0.0
    if not (np.isfinite(top) and top > 0 and peak >= UNIT_SLIP_RATIO * top):
        return ""
    ratio = peak / top
    exponent = thousands_exponent(ratio)
    prefix = {3: "m", 6: "u"}.get(exponent)    # milli or micro: the slips a logger makes
    if prefix is None:
        return ""
    unit = drive_unit(column)
    factor = 10 ** exponent
    return (f"the drive reaches {ratio:.0f}x the largest drive identified ({top:.4g} {unit}): a drive in another "
            f"unit ({prefix}{unit} under {column}?): divide {column} by {factor}")


OCTAVE = 2.0 ** 0.5       # half an octave either side: a band one octave wide


def dominant_band(recordings: list[tuple[np.ndarray, np.ndarray]]) -> tuple[float, float]:
    """(frequency in Hz, share) of the drives' (time_s, drive) pairs: the frequency holding the most
    of their power (each drive's mean removed), pooled, and the share of all of it within an octave
    about that frequency. A sine at any amplitude gives ~1; steps, a square wave, sweeps and several
    sines spread it further. So does a unipolar sine whose amplitude rises: its mean rises too, a
    slow second component (about 0.7 for the rising drive of benchmarks.cases). Hann-windowed
    periodograms (scipy), so a sine that ends mid-cycle leaks no further than its neighbouring
    bins; (nan, 0) for drives that never move."""
    from scipy.signal import periodogram

    spectra = []
    for t, u in recordings:
        x = np.asarray(u, dtype=float)
        if x.size < 4 or not np.ptp(x) > 0:
            continue
        dt = float(np.median(np.diff(np.asarray(t, dtype=float))))
        f, p = periodogram(x, fs=1.0 / dt, window="hann", detrend="constant", scaling="spectrum")
        spectra.append((f, p * x.size))          # power, not density: a longer recording weighs more
    total = sum(float(p.sum()) for _, p in spectra)
    if not total > 0:
        return float("nan"), 0.0
    peaks = [float(f[int(np.argmax(p))]) for f, p in spectra]

    def share(f0: float) -> float:
        return sum(float(p[(f >= f0 / OCTAVE) & (f <= f0 * OCTAVE)].sum()) for f, p in spectra) / total

    f0 = max(peaks, key=share)
    return f0, share(f0)
