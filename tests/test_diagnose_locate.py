"""Locating the residual and reading the data's own noise floor and stress levels."""

from __future__ import annotations

import numpy as np

from gma_ffc.diagnose.data import RecData, noise_floor, stress_levels
from gma_ffc.diagnose.locate import locate


def _rec(t: np.ndarray, u: np.ndarray, s: np.ndarray) -> RecData:
    dt = np.concatenate(([t[1] - t[0]], np.diff(t)))
    return RecData("r.csv", t, dt, float(dt[0]), u, np.zeros_like(u), s, s, np.zeros(t.size, np.int8),
                   np.arange(t.size))


def test_noise_floor_reads_white_noise_under_a_slow_signal():
    rng = np.random.default_rng(1)
    t = np.arange(40000) / 2000.0
    for sigma in (0.01, 0.05):
        y = 20 * np.sin(2 * np.pi * 3 * t) + rng.normal(0, sigma, t.size)
        assert abs(noise_floor(y) / sigma - 1) < 0.15


def test_locate_finds_the_window_band_and_heating():
    t = np.arange(20000) / 1000.0
    u = 1 + np.sin(2 * np.pi * 5 * t)
    rec = _rec(t, u, np.full(t.size, -15.0))
    drift = 0.5 * (1 - np.exp(-t / 8.0))                 # grows like accumulated heating
    resid = drift - 0.1                                   # recalibration took out a small offset
    loc = locate(rec, resid + 0.3, resid)
    assert loc.window_s[0] >= 10.0                         # the drift is largest late in the run
    assert loc.band_hz == (0.0, 0.5)                       # and slow
    assert loc.conditions["cumulative_heating"] > 0.8
    assert "integral of I^2" in loc.where
    assert loc.residual_rms_um > loc.residual_rms_recalibrated_um


def test_stress_levels_counts_dwell_levels_not_transitions():
    t = np.arange(30000) / 1000.0
    s = np.where(t < 10, -12.0, np.where(t < 20, -18.0, -23.0)) + np.random.default_rng(0).normal(0, 0.05, t.size)
    s[9990:10010] = np.linspace(-12, -18, 20)              # a short transition is not a level
    assert len(stress_levels([_rec(t, np.zeros_like(t), s)])) == 3
    two = np.where(t < 15, -12.0, -18.0)
    assert len(stress_levels([_rec(t, np.zeros_like(t), two)])) == 2
