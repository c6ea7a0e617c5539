"""A stress-dependent Preisach relay actuator, written independently of the PI operators.

Used as a stand-in rig whose hysteresis mechanism is NOT the model being fitted, so tests of
identification are not judged against the model itself (no inverse crime). Relays with
thresholds alpha >= beta on a grid over the drive range, Gaussian Preisach density in loop
centre and half-width (the width, i.e. the coercive current, does not depend on stress), and a
monotone, stress-dependent magnetostriction curve from magnetisation to displacement.
"""

from __future__ import annotations

from typing import Any

import numpy as np


class PreisachActuator:
    def __init__(self, drive_range: tuple[float, float] = (0.0, 3.0), n_grid: int = 40,
                 width_A: float = 0.18, noise_um: float = 0.0, seed: int = 0, width_spread: float = 0.1) -> None:
        lo, hi = drive_range
        grid = np.linspace(lo, hi, n_grid)
        alpha, beta = np.meshgrid(grid, grid, indexing="ij")
        keep = alpha >= beta
        self.alpha, self.beta = alpha[keep], beta[keep]
        centre, half = 0.5 * (self.alpha + self.beta), 0.5 * (self.alpha - self.beta)
        mid = 0.5 * (lo + hi)
        mu = np.exp(-0.5 * ((centre - mid) / (0.35 * (hi - lo))) ** 2) * np.exp(-0.5 * ((half - width_A) / width_spread) ** 2)
        self.mu = mu / mu.sum()
        self.noise_um = noise_um
        self.rng = np.random.default_rng(seed)

    @staticmethod
    def stroke_um(stress_MPa: float) -> float:
        return 30.0 * (1.0 + 0.045 * (-stress_MPa - 11.3))

    @staticmethod
    def exponent(stress_MPa: float) -> float:
        return 1.15 + 0.035 * (-stress_MPa - 11.3)

    def run(self, drive: np.ndarray, stress_MPa: float) -> np.ndarray:
        state = -np.ones_like(self.mu)  # negatively saturated: the drive came down to the start
        q = np.empty(drive.size)
        for k, x in enumerate(drive):
            state[x >= self.alpha] = 1.0
            state[x <= self.beta] = -1.0
            q[k] = min(max(0.5 * (self.mu @ state + 1.0), 0.0), 1.0)   # rounding never leaves [0, 1]
        y = self.stroke_um(stress_MPa) * q ** self.exponent(stress_MPa) + 0.05 * stress_MPa
        return y + self.rng.normal(0.0, self.noise_um, y.size) if self.noise_um else y


def ferroelectric_recording(width_share: float = 0.2, n_cycles: int = 3, fs: float = 2000.0,
                            peak_V: float = 1400.0, stroke_um: float = 2.0, noise_um: float = 0.002,
                            seed: int = 1) -> "Any":
    """A bipolar +-1400 V wide-loop recording, as a ferroelectric ceramic's: Preisach relays whose
    switching half-widths (the coercive field) sit at `width_share` of the peak drive, so the
    loop is wide and nearly square and its slope just after a reversal nearly zero: what drives the
    zero-threshold play's weight towards nothing. Volts in, micrometres out, 1 Hz."""
    from gma_ffc.recordings import Recording
    width = width_share * peak_V
    act = PreisachActuator(drive_range=(-peak_V, peak_V), n_grid=60, width_A=width, noise_um=0.0,
                           seed=seed, width_spread=0.25 * width)
    t = np.arange(int(n_cycles * fs)) / fs
    v = peak_V * np.sin(2 * np.pi * t)
    y = act.run(v, -11.3) * stroke_um / act.stroke_um(-11.3)
    y = y + np.random.default_rng(seed).normal(0.0, noise_um, y.size)
    return Recording({"time_s": t, "voltage_V": v, "displacement_um": y}, {}, "ferroelectric.csv")
