"""Narrow spectral lines in a residual, and whether the drive can have put them there (pure maths).

A hysteresis model's error on a periodic drive is periodic: its lines sit at harmonics of the
drive (and at mixing products of two drive tones). A line that no drive content accounts for,
such as 50 Hz hum on the sensor's cable, is not the actuator's response, and no effect in the
vocabulary should be fitted to it; the words say which it is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import median_filter

# A line is a bin of the Hann-windowed periodogram this many times the spectrum's local median. A
# periodogram bin of broadband noise is (median / ln 2) x Exp(1), so it passes with probability
# exp(-30 ln 2) ~ 1e-9: about 1e-4 for a whole 100 000-bin spectrum.
LINE_PROMINENCE = 30.0
LINE_MIN_SHARE = 0.05        # said only when it holds at least 5 % of the residual's power
LINE_BACKGROUND_HZ = 2.0     # the local median spans +-2 Hz (at least 25 bins): a resonance is wider
LINE_LOBE_BINS = 2           # a Hann line's main lobe: the peak bin +-2
LINE_MIN_HZ = 1.0            # below 1 Hz a "line" is drift, and a few bins cannot tell it apart
HARMONICS = 20               # a residual line at up to the 20th harmonic of a drive line is the drive's
MIXING = 5                   # or at m f1 +- n f2 of two drive lines, m, n <= 5
SEGMENT_S = 4.0              # a drive that changes over the run is judged again on pieces this long


@dataclass(frozen=True)
class Line:
    """A narrow spectral line in a residual."""
    hz: float
    share: float                 # of the residual's (mean-removed) power
    from_drive: str              # how the drive puts it there, or "" where nothing in the drive can


def _periodogram(x: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    x = x - x.mean()
    p = np.abs(np.fft.rfft(x * np.hanning(x.size))) ** 2
    return np.fft.rfftfreq(x.size, dt), p


def _prominent(p: np.ndarray, width: int) -> np.ndarray:
    """Each bin over its local median (a floor at 1e-12 of the peak keeps a noiseless drive finite)."""
    bg = median_filter(p, size=2 * width + 1, mode="nearest")
    return p / np.maximum(bg, 1e-12 * max(float(p.max()), 1e-300))


def _lobe_hz(freqs: np.ndarray) -> float:
    """How far a line's placing may be off in a spectrum: its main lobe and a bin."""
    return (LINE_LOBE_BINS + 1) * float(freqs[1])


def _lines(p: np.ndarray, freqs: np.ndarray, width: int, most: int = 8) -> list[float]:
    """The frequencies of a spectrum's strongest lines (one per main lobe), strongest first."""
    prom = _prominent(p, width)
    strong = np.flatnonzero((prom >= LINE_PROMINENCE) & (freqs > 0) & (p >= 1e-6 * float(p[1:].max(initial=0.0))))
    out: list[float] = []
    tol = _lobe_hz(freqs)
    for j in strong[np.argsort(p[strong])[::-1]]:
        if all(abs(freqs[j] - g) > tol for g in out):
            out.append(float(freqs[j]))
        if len(out) == most:
            break
    return out


def _peak_hz(p: np.ndarray, freqs: np.ndarray, j: int) -> float:
    """A peak's frequency between bins: the vertex of the parabola through its log powers (a Hann
    line's is within a few per cent of a bin), so that harmonic 17 of 3 Hz is not taken for 50 Hz."""
    if j <= 0 or j >= p.size - 1 or min(p[j - 1], p[j], p[j + 1]) <= 0:
        return float(freqs[j])
    a, b, c = np.log(p[j - 1: j + 2])
    den = a - 2 * b + c
    shift = 0.5 * (a - c) / den if den < 0 else 0.0
    return float(freqs[j] + float(np.clip(shift, -0.5, 0.5)) * (freqs[1] - freqs[0]))


def _width(df: float, least: int) -> int:
    return max(least, int(round(LINE_BACKGROUND_HZ / df)))


def _content_floor(freqs: np.ndarray, p: np.ndarray) -> float:
    """What counts as drive content: LINE_PROMINENCE x the drive spectrum's median above
    LINE_MIN_HZ (a short burst counts, though it is no narrow line)."""
    above = freqs >= LINE_MIN_HZ
    return LINE_PROMINENCE * max(float(np.median(p[above])) if np.any(above) else 0.0,
                                 1e-12 * max(float(p.max()), 1e-300))


def _drive_relation(f: float, freqs: np.ndarray, p: np.ndarray, mixing: bool = True) -> tuple[str, tuple[float, ...]]:
    """How the drive (its periodogram `freqs`, `p`) puts a residual line at f, and the drive
    frequencies that do; ("", ()) when nothing in it can: f is a harmonic of drive content or
    (`mixing`) a mixing product of two of the drive's lines (what a hysteresis or other nonlinear
    error of the drive makes). Mixing products of a few lines at a short piece's coarse bins
    cover most frequencies, so a piece is tested for harmonics only."""
    df = float(freqs[1])
    tol = _lobe_hz(freqs)
    floor = _content_floor(freqs, p)
    for k in range(1, HARMONICS + 1):
        near = np.flatnonzero(np.abs(freqs - f / k) <= tol)
        if f / k < df or near.size == 0 or float(p[near].max()) < floor:
            continue
        g = _peak_hz(p, freqs, int(near[np.argmax(p[near])]))
        if abs(k * g - f) <= (0.5 + 0.1 * k) * df:     # both peaks placed to ~0.05 bin, g k-fold: 2x that
            words = f"the drive's {g:.4g} Hz content" if k == 1 else f"harmonic {k} of the drive's {g:.4g} Hz content"
            return words, (g,)
    lines = _lines(p, freqs, _width(df, 25)) if mixing else []
    for i, f1 in enumerate(lines):
        for f2 in lines[i + 1:]:
            for m in range(1, MIXING + 1):
                for n in range(1, MIXING + 1):
                    if min(abs(f - (m * f1 + n * f2)), abs(f - abs(m * f1 - n * f2))) <= tol:
                        return f"a mixing product of the drive's {f1:.4g} and {f2:.4g} Hz lines", (f1, f2)
    return "", ()


def _has_content(freqs: np.ndarray, p: np.ndarray, at: tuple[float, ...]) -> bool:
    """Whether a piece of the drive (its periodogram) holds content at each of the frequencies `at`."""
    floor, tol = _content_floor(freqs, p), _lobe_hz(freqs)
    return all(np.any((np.abs(freqs - g) <= tol) & (p >= floor)) for g in at)


def spectral_line(residual: np.ndarray, drive: np.ndarray, dt: float) -> Line | None:
    """The strongest narrow line of the residual above LINE_MIN_HZ, when it holds at least
    LINE_MIN_SHARE of the residual's power; with how the drive makes it, if it does.

    A drive that changes over the run (a few seconds of one sine, then another) has lines the
    whole record shows, but a line the residual holds where the drive has none related to it is
    not the drive's: in each SEGMENT_S piece where the residual's line stands out, either the drive
    content the whole record says makes it is there, or the piece's own drive makes the piece's
    peak (a piece's coarser bins may merge another harmonic with the line)."""
    if residual.size < 64 or not dt > 0:
        return None
    freqs, p = _periodogram(residual, dt)
    df = float(freqs[1])
    width = _width(df, 25)
    ok = freqs >= max(LINE_MIN_HZ, (width + LINE_LOBE_BINS) * df)
    cand = np.flatnonzero(ok & (_prominent(p, width) >= LINE_PROMINENCE))
    total = float(p[1:].sum())
    if cand.size == 0 or total <= 0:
        return None
    k = int(cand[np.argmax(p[cand])])
    share = float(p[max(k - LINE_LOBE_BINS, 1): k + LINE_LOBE_BINS + 1].sum()) / total
    if share < LINE_MIN_SHARE:
        return None
    f = _peak_hz(p, freqs, k)
    relation, makers = _drive_relation(f, *_periodogram(drive, dt))
    n_seg = int(residual.size * dt // SEGMENT_S)
    if relation and n_seg >= 2:
        edges = np.linspace(0, residual.size, n_seg + 1).astype(int)
        for a, b in zip(edges[:-1], edges[1:]):
            fs, ps = _periodogram(residual[a:b], dt)
            near = np.abs(fs - f) <= _lobe_hz(fs)
            held = float(ps[near].sum()) / max(float(ps[1:].sum()), 1e-300)
            if (not np.any(near) or held < LINE_MIN_SHARE
                    or float(np.max(_prominent(ps, _width(float(fs[1]), 8))[near])) < LINE_PROMINENCE):
                continue                 # the line is not in this piece, or too weak there to judge
            here = _peak_hz(ps, fs, int(np.flatnonzero(near)[np.argmax(ps[near])]))
            piece = _periodogram(drive[a:b], dt)      # the same bins as the residual's piece
            if not _has_content(*piece, makers) and not _drive_relation(here, *piece, mixing=False)[0]:
                relation = ""            # it is where nothing in the drive makes it
                break
    return Line(f, share, relation)


def line_words(line: Line) -> str:
    """The line in words: the drive's making, or a pickup (mains when at 50/60 Hz or a harmonic)."""
    if line.from_drive:
        return f"a narrow line at {line.hz:.4g} Hz holds {line.share:.0%} of its power ({line.from_drive})"
    mains = any(abs(line.hz - k * m) <= max(0.01 * k * m, 0.2) for m in (50.0, 60.0) for k in (1, 2, 3))
    source = ("mains pickup (50/60 Hz and harmonics) in the sensor or its cabling" if mains
              else "pickup or a vibration the sensor sees")
    return (f"a narrow line at {line.hz:.4g} Hz holds {line.share:.0%} of its power where nothing in the drive "
            f"puts one: {source}, not the actuator's response to its drive")
