"""Drive and load profiles for the unseen cases, deliberately unlike hil_sim's experiments.

hil_sim records sines at fixed frequencies, a 150 s sine then 90 s at zero, fixed current steps
and a load staircase. Here: band-limited random drives, triangles, log chirps, random-level
step sequences with dither, and load changes at odd times. All pure functions of their
arguments and a numpy Generator (deterministic by seed).
"""

from __future__ import annotations

import numpy as np


def time_axis(rate_hz: float, duration_s: float) -> np.ndarray:
    return np.arange(int(round(rate_hz * duration_s))) / rate_hz


def cosine_sweep(t: np.ndarray, freq_hz: float, lo: float, hi: float) -> np.ndarray:
    """Quasi-static identification drive: starts at lo, full swings lo..hi."""
    return lo + 0.5 * (hi - lo) * (1.0 - np.cos(2 * np.pi * freq_hz * t))


def triangle(t: np.ndarray, freq_hz: float, lo: float, hi: float) -> np.ndarray:
    """Triangle lo..hi starting at lo."""
    phase = (t * freq_hz) % 1.0
    return lo + (hi - lo) * (1.0 - np.abs(1.0 - 2.0 * phase))


def log_chirp(t: np.ndarray, f0_hz: float, f1_hz: float, lo: float, hi: float) -> np.ndarray:
    """Full-swing logarithmic chirp from f0 to f1 over the record, starting at lo."""
    dur = t[-1] - t[0] if t.size > 1 else 1.0
    k = np.log(f1_hz / f0_hz) / dur
    phase = 2 * np.pi * f0_hz * (np.exp(k * (t - t[0])) - 1.0) / k
    return lo + 0.5 * (hi - lo) * (1.0 - np.cos(phase))


def band_limited_random(t: np.ndarray, f_lo_hz: float, f_hi_hz: float, lo: float, hi: float,
                        rng: np.random.Generator) -> np.ndarray:
    """Random drive with content in [f_lo, f_hi], scaled so its 1..99 % range spans lo..hi (clipped).

    Faded in over 0.2 s from lo, so the rig starts at rest.
    """
    n = t.size
    rate = 1.0 / (t[1] - t[0])
    spec = np.fft.rfft(rng.normal(size=n))
    f = np.fft.rfftfreq(n, 1.0 / rate)
    spec[(f < f_lo_hz) | (f > f_hi_hz)] = 0.0
    x = np.fft.irfft(spec, n)
    p1, p99 = np.percentile(x, [1, 99])
    y = lo + (hi - lo) * (x - p1) / (p99 - p1)
    fade = np.clip(t / 0.2, 0.0, 1.0)
    return np.clip(lo + fade * (y - lo), lo, hi)


def random_steps(t: np.ndarray, hold_s: tuple[float, float], lo: float, hi: float, rng: np.random.Generator,
                 dither_A: float = 0.0, dither_hz: float = 0.0, min_jump: float = 0.25) -> np.ndarray:
    """Random levels held for random times, optional dither; the first hold is at lo (rig at rest)."""
    y = np.empty_like(t)
    first = min(t.size, max(1, int(hold_s[0] / (t[1] - t[0]))))
    y[:first] = lo
    start, level = first, lo
    while start < t.size:
        hold = rng.uniform(*hold_s)
        stop = min(t.size, start + max(1, int(hold / (t[1] - t[0]))))
        for _ in range(20):
            new = rng.uniform(lo, hi)
            if abs(new - level) >= min_jump:
                break
        level = new
        y[start:stop] = level
        start = stop
    if dither_A > 0:
        y = y + dither_A * np.sin(2 * np.pi * dither_hz * t)
    return np.clip(y, lo, hi)


def decaying_triangle(t: np.ndarray, freq_hz: float, lo: float, hi: float, final_fraction: float) -> np.ndarray:
    """Triangle whose swing shrinks linearly to final_fraction: nested minor loops."""
    frac = 1.0 - (1.0 - final_fraction) * (t - t[0]) / max(t[-1] - t[0], 1e-12)
    return lo + (triangle(t, freq_hz, lo, hi) - lo) * frac


def load_profile(t: np.ndarray, changes: list[tuple[float, float]], initial_kg: float) -> np.ndarray:
    """Load mass against time: `changes` are (time_s, new_mass_kg), applied from that time on."""
    m = np.full(t.size, float(initial_kg))
    for when, mass in sorted(changes):
        m[t >= when] = mass
    return m
