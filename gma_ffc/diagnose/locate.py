"""Where and under which conditions the residual appears (pure maths on arrays).

For one recording and its residual: the time windows where it is largest, the frequency band
holding most of its power, a narrow spectral line if one holds a fair share of it (and whether
the drive can have put it there), and how strongly its size follows the drive rate, the drive
amplitude, the stress, the time since a step and the cumulative heating (drive squared
integrated through a long time constant).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..effects import kernels as K
from ..recordings import time_text
from .data import RecData, noise_floor
from .jumps import Jumps, jump_words
from .lines import Line, line_words, spectral_line

BANDS_HZ = (0.0, 0.5, 5.0, 50.0, 500.0, np.inf)


@dataclass
class Located:
    recording: str
    where: str
    residual_rms_um: float
    residual_rms_recalibrated_um: float
    window_s: tuple[float, float]
    band_hz: tuple[float, float]
    band_share: float
    conditions: dict[str, float] = field(default_factory=dict)
    line: Line | None = None
    jumps: Jumps = field(default_factory=Jumps)

    def to_json(self) -> dict:
        return {"recording": self.recording, "where": self.where,
                "residual_rms_um": round(self.residual_rms_um, 6),
                "residual_rms_recalibrated_um": round(self.residual_rms_recalibrated_um, 6),
                "window_s": [round(v, 6) for v in self.window_s],
                "band_hz": [self.band_hz[0], None if not np.isfinite(self.band_hz[1]) else self.band_hz[1]],
                "band_share": round(self.band_share, 4),
                "line": None if self.line is None else {"hz": round(self.line.hz, 4),
                                                         "share": round(self.line.share, 4),
                                                         "from_drive": self.line.from_drive or None},
                "sensor_jumps": [{"t_s": round(j.t_s, 6), "um": round(j.um, 6)} for j in self.jumps.found],
                "conditions": {k: round(v, 4) for k, v in self.conditions.items()}}


LEAST_WINDOW = 5       # samples the residual's size is smoothed over at least: fewer are one noisy sample's
                       # size, not a trend that conditions (drive rate, heating) could correlate with


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    den = float(np.sqrt((a @ a) * (b @ b)))
    return float(a @ b / den) if den > 0 else 0.0


def band_powers(r: np.ndarray, dt: float) -> np.ndarray:
    """Share of the residual's (mean-removed) power in each of BANDS_HZ."""
    x = r - r.mean()
    spec = np.abs(np.fft.rfft(x)) ** 2
    freqs = np.fft.rfftfreq(x.size, dt)
    total = float(spec[1:].sum()) or 1.0
    shares = []
    for lo, hi in zip(BANDS_HZ[:-1], BANDS_HZ[1:]):
        sel = (freqs >= lo) & (freqs < hi)
        sel[0] = False
        shares.append(float(spec[sel].sum()) / total)
    return np.array(shares)


STRONG_R = 0.3      # a correlation this size explains a tenth of the residual size's variance: worth saying


def condition_words(cond: dict[str, float], drive_symbol: str = "I", n: int = 2) -> list[str]:
    """The n strongest conditions (|r| >= STRONG_R) as phrases that carry their direction, each with
    |r|: "is largest just after steps (r = 0.54)", never "grows with the time since steps (r = -0.54)",
    which a reader takes the wrong way round."""
    heat = " (cumulative heating)" if drive_symbol != "V" else ""   # a voltage drive heats no coil (docs/diagnose.md)
    up = {"drive_rate": "grows with the drive rate", "drive_amplitude": "grows with the drive amplitude",
          "cumulative_heating": f"follows the integral of {drive_symbol}^2{heat}",
          "stress": "grows as the compression eases", "after_steps": "is largest just after steps"}
    down = {"drive_rate": "is largest where the drive is slow",
            "drive_amplitude": "is largest near the drive's median",
            "cumulative_heating": f"runs against the integral of {drive_symbol}^2{heat}",
            "stress": "grows with the compression", "after_steps": "grows with the time since steps"}
    strong = sorted(((abs(v), key, v) for key, v in cond.items() if abs(v) >= STRONG_R), reverse=True)
    return [f"{(up if v > 0 else down)[key]} (r = {a:.2f})" for a, key, v in strong[:n]]


RATIO_FLOOR_SHARE = 1e-3   # a window's ratio is against at least this share of the largest window's RMS: a
                           # residual 1000x larger in one window than the typical one is all a reader needs
                           # to know, and beyond that the figure would measure rounding, not the recording


def _windows(keep: np.ndarray, n_windows: int) -> list[np.ndarray]:
    """The judged samples in `n_windows` runs of equal count, in time order (windows with no samples left out)."""
    idx = np.flatnonzero(keep)
    return [w for w in np.array_split(idx, min(n_windows, max(idx.size, 1))) if w.size]


def locate(d: RecData, raw_residual: np.ndarray, residual: np.ndarray, n_windows: int = 10) -> Located:
    """Locate the residual (after static recalibration) of one recording, over its scored samples
    (over all of them when none is scored: the words then describe the transient, which
    cannot_conclude says was not scored)."""
    n = residual.size
    t = d.t
    keep = d.mask if d.n_scored else np.ones(n, bool)
    windows = _windows(keep, n_windows)
    rms_w = np.array([float(np.sqrt(np.mean(residual[w] ** 2))) for w in windows])
    k = int(np.argmax(rms_w))
    win = (float(t[windows[k][0]]), float(t[windows[k][-1]]))
    # against a positive floor: the typical window's RMS, at least the sensor's noise (no window can be
    # told quieter than that) and RATIO_FLOOR_SHARE of the largest
    floor = max(float(np.median(rms_w)), noise_floor(d.y), RATIO_FLOOR_SHARE * float(rms_w[k]), 1e-300)
    ratio = float(rms_w[k] / floor)
    shares = band_powers(residual, d.dt_med)
    b = int(np.argmax(shares))
    band = (BANDS_HZ[b], BANDS_HZ[b + 1])

    # conditions, on a smoothed residual size (window ~ 1 % of the record, at least 5 samples), over
    # the judged samples only (an unscored stretch is zeros, which would correlate with anything slow)
    width = max(LEAST_WINDOW, n // 100)
    kern = np.ones(width) / width
    size = np.sqrt(np.convolve(residual ** 2, kern, mode="same"))
    du = np.abs(np.gradient(d.u, t)) if n > 1 else np.zeros(n)
    span = max(float(np.ptp(d.u)), 1e-12)
    steps = np.flatnonzero(np.abs(np.diff(d.u)) > 0.1 * span) + 1
    since = np.full(n, np.inf)
    if steps.size:
        last = np.maximum.accumulate(np.where(np.isin(np.arange(n), steps), np.arange(n), -1))
        ok = last >= 0
        since[ok] = t[ok] - t[last[ok]]
    heat = K.lag_filter(d.u * d.u, d.dt, max(d.duration_s / 4, 1e-6), 0.0)
    cond = {
        "drive_rate": _corr(size[keep], np.convolve(du, kern, mode="same")[keep]),
        "drive_amplitude": _corr(size[keep], np.abs(d.u - np.median(d.u))[keep]),
        "cumulative_heating": _corr(np.convolve(residual, kern, mode="same")[keep], heat[keep]),
    }
    if float(np.ptp(d.s)) > 0.5:
        cond["stress"] = _corr(size[keep], d.s[keep])
    if steps.size:
        fin = np.isfinite(since) & keep
        if fin.sum() > 10:
            cond["after_steps"] = _corr(size[fin], -np.log(since[fin] + d.dt_med))
    where = _window_words(win, ratio, float(shares[b]), band, d.dt_med)
    if not d.n_scored:
        where += "; none of it is scored (the start-up transient may be all this is)"
    line = spectral_line(residual, d.u, d.dt_med)
    if line is not None:
        where += "; " + line_words(line)
    jumped = jump_words(d.jumps)
    if jumped:
        where += "; " + jumped
    follows = condition_words(cond, d.extra.get("drive_symbol", "I"), 2)
    if follows:
        where += "; residual " + ", ".join(follows)
    return Located(d.name, where, float(np.sqrt(np.mean(raw_residual[keep] ** 2))),
                   float(np.sqrt(np.mean(residual[keep] ** 2))), win, band, float(shares[b]), cond, line, d.jumps)


def _window_words(win: tuple[float, float], ratio: float, share: float, band: tuple[float, float],
                  dt: float) -> str:
    """Where the largest residual sits, its size against the median window and its band."""
    band_txt = f"{band[0]:g}-{band[1]:g} Hz" if np.isfinite(band[1]) else f"above {band[0]:g} Hz"
    step = max((win[1] - win[0]) / 100, dt)      # a hundredth of the window: its ends to about 1 %
    return (f"t = {time_text(win[0], step)}-{time_text(win[1], step)} s ({ratio:.1f}x the median window); "
            f"{share:.0%} of its power at {band_txt}")
