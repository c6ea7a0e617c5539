"""Locating the residual and reading the data's own noise floor and stress levels."""

from __future__ import annotations

import numpy as np
import pytest

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
    # a long run at one stress beside a load-change recording: each of the latter's levels is a few
    # per cent of all samples, but most of its own recording (issue 9: "dwell at only 1 level")
    long_t = np.arange(240000) / 1000.0
    long_run = _rec(long_t, np.zeros_like(long_t), np.full(long_t.size, -11.3))
    assert stress_levels([long_run, _rec(t, np.zeros_like(t), s)]) == pytest.approx([-23.0, -18.0, -12.0], abs=0.1)


def test_reversals_are_counted_on_smooth_drives_and_on_steps():
    """Smooth loops count their turning points (a counter that only saw jumps once returned 0 here)."""
    from gma_ffc.drive import reversals as _reversals

    t = np.linspace(0.0, 3.0, 6000)
    assert _reversals(1.0 - np.cos(2 * np.pi * t)) == 5          # starts at a minimum: 3 maxima, 2 inner minima
    assert _reversals(np.sin(2 * np.pi * t)) == 6
    tri = np.abs(((t * 4) % 2) - 1.0)                                 # triangle, 6 periods
    assert _reversals(tri) >= 10
    assert _reversals(np.repeat([0.0, 1.0, 0.0, 1.0, 0.0], 10)) == 3
    assert _reversals(np.linspace(0.0, 1.0, 500)) == 0
    # turns smaller than 10 % of the span are not reversals
    assert _reversals(np.linspace(0.0, 1.0, 500) + 0.02 * np.sin(2 * np.pi * 20 * np.linspace(0, 1, 500))) == 0


def _named_explanation(rms_after: float, noise: float, left: list) -> str:
    from gma_ffc.diagnose.explain import explain
    from gma_ffc.diagnose.results import Candidate

    t = np.arange(20000) / 1000.0
    rec = _rec(t, 1 + np.sin(2 * np.pi * 5 * t), np.full(t.size, -15.0))
    base = locate(rec, np.sin(t), np.sin(t))
    cand = Candidate("creep", True, cv_mse=rms_after ** 2, params={"tau_s": 3.0, "gain": 0.02}, accepted=True)
    return explain(["creep"], {"creep": cand}, [base], 1.0, 0.9, rms_after, noise, False, "", "effects_named",
                   "A", 1.5, (0.1, 0.2), left, 3.0)


def test_a_named_effect_that_leaves_much_says_so_and_where():
    """A verdict is not read as the whole story: with 15x the noise left, beyond the core's own
    identification error (0.1-0.2 um), the words say so and where it sits; within that error they
    say it may be the core's own; within 3x the noise, or with nothing located, they say nothing."""
    t = np.arange(20000) / 1000.0
    rec = _rec(t, 1 + np.sin(2 * np.pi * 5 * t), np.full(t.size, -15.0))
    left = np.where((t > 12) & (t < 14), 0.5, 0.01)        # what the extended model leaves, late in the run
    loc = locate(rec, left, left)
    words = _named_explanation(0.3, 0.02, [loc])
    assert "Not all of it is explained" in words and "15.0x the noise floor" in words
    assert "t = 12" in words and "(0.1-0.2 um RMS)" in words
    words = _named_explanation(0.15, 0.02, [loc])
    assert "Not all" not in words and "may be the core's own error" in words and "t = 12" in words
    for quiet in (_named_explanation(0.05, 0.02, [loc]), _named_explanation(0.3, 0.02, [])):
        assert "Not all" not in quiet and "What is left" not in quiet
