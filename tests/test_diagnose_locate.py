"""Locating the residual (its windows, band, narrow lines, correlations) and reading the data's own noise floor and stress levels."""

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


# ---- narrow lines in the residual: the drive's harmonics, or a pickup the drive cannot make

FS = 2000.0


def _tone(t: np.ndarray, hz: float, amp: float, phase: float = 0.3) -> np.ndarray:
    return amp * np.sin(2 * np.pi * hz * t + phase)


def test_a_mains_line_the_drive_cannot_make_is_called_pickup():
    from gma_ffc.diagnose.lines import line_words, spectral_line

    rng = np.random.default_rng(3)
    t = np.arange(60000) / FS
    u = 1 + np.sin(2 * np.pi * 3 * t)
    hysteresis_error = _tone(t, 6, 0.05) + _tone(t, 9, 0.03)          # the drive's own harmonics
    r = rng.normal(0, 0.03, t.size) + hysteresis_error + _tone(t, 50, 0.15)
    line = spectral_line(r, u, 1 / FS)
    # (17 x 3 Hz is 51 Hz, not 50: the harmonic test places both peaks between bins)
    assert line is not None and line.hz == pytest.approx(50, abs=0.01) and line.from_drive == ""
    assert line.share > 0.5
    assert "mains pickup" in line_words(line)
    # the same through locate: the words are part of where the residual sits, the line in the JSON
    rec = _rec(t, u, np.full(t.size, -15.0))
    loc = locate(rec, r, r)
    assert "50 Hz" in loc.where and "mains pickup" in loc.where
    assert loc.to_json()["line"]["hz"] == pytest.approx(50, abs=0.01)


def test_a_line_at_a_harmonic_of_the_drive_is_the_drives():
    from gma_ffc.diagnose.lines import line_words, spectral_line

    rng = np.random.default_rng(4)
    t = np.arange(60000) / FS
    noise = rng.normal(0, 0.03, t.size)
    at_6 = spectral_line(noise + _tone(t, 6, 0.1), 1 + np.sin(2 * np.pi * 3 * t), 1 / FS)
    assert at_6 is not None and "harmonic 2" in at_6.from_drive
    # 50 Hz on a 10 Hz drive is its fifth harmonic: no pickup is claimed, mains or not
    at_50 = spectral_line(noise + _tone(t, 50, 0.1), 1 + np.sin(2 * np.pi * 10 * t), 1 / FS)
    assert at_50 is not None and "harmonic 5" in at_50.from_drive
    assert "pickup" not in line_words(at_50)
    # a mixing product of two drive tones: 2 x 7 + 3 Hz
    two = 1 + 0.5 * np.sin(2 * np.pi * 3 * t) + 0.5 * np.sin(2 * np.pi * 7 * t)
    mixed = spectral_line(noise + _tone(t, 17, 0.1), two, 1 / FS)
    assert mixed is not None and mixed.from_drive != ""


def test_a_line_is_judged_where_the_drive_changes():
    """A drive at 10 Hz for half the run could make a 50 Hz line, but a line that stays when the
    drive moves to 3 Hz is not its making; one only where the 10 Hz runs is."""
    from gma_ffc.diagnose.lines import spectral_line

    rng = np.random.default_rng(5)
    t = np.arange(64000) / FS
    first = t < t[-1] / 2
    u = 1 + np.where(first, np.sin(2 * np.pi * 10 * t), np.sin(2 * np.pi * 3 * t))
    noise = rng.normal(0, 0.03, t.size)
    throughout = spectral_line(noise + _tone(t, 50, 0.1), u, 1 / FS)
    assert throughout is not None and throughout.from_drive == ""
    only_with_10hz = spectral_line(noise + np.where(first, _tone(t, 50, 0.1), 0.0), u, 1 / FS)
    assert only_with_10hz is not None and "harmonic 5" in only_with_10hz.from_drive


def test_noise_and_a_resonance_are_no_line():
    from scipy.signal import lfilter

    from gma_ffc.diagnose.lines import spectral_line

    rng = np.random.default_rng(6)
    t = np.arange(60000) / FS
    u = 1 + np.sin(2 * np.pi * 3 * t)
    assert spectral_line(rng.normal(0, 0.03, t.size), u, 1 / FS) is None
    # a 300 Hz resonance (damping 0.04, some 24 Hz wide) rung by noise is a band, not a line
    w, zeta = 2 * np.pi * 300 / FS, 0.04
    rr = np.exp(-zeta * w)
    a = [1.0, -2 * rr * np.cos(w * np.sqrt(1 - zeta ** 2)), rr * rr]
    ringing = lfilter([1.0], a, rng.normal(0, 0.01, t.size))
    assert spectral_line(ringing + rng.normal(0, 0.03, t.size), u, 1 / FS) is None
    # and a line too small to matter is not said (under 5 % of the residual's power)
    assert spectral_line(rng.normal(0, 0.1, t.size) + _tone(t, 50, 0.02), u, 1 / FS) is None


def test_a_correlation_is_worded_by_its_sign():
    """A residual largest where the drive turns round (slow) is not said to grow with the rate."""
    rng = np.random.default_rng(7)
    t = np.arange(20000) / 1000.0
    u = 1 + np.sin(2 * np.pi * 1 * t)
    slow = np.abs(np.cos(2 * np.pi * 1 * t)) < 0.3            # near the turning points
    resid = rng.normal(0, 0.01, t.size) + np.where(slow, rng.normal(0, 0.2, t.size), 0.0)
    loc = locate(_rec(t, u, np.full(t.size, -15.0)), resid, resid)
    assert loc.conditions["drive_rate"] < -0.3
    assert "grows with the drive rate" not in loc.where and "largest where the drive is slow" in loc.where
    fast = np.where(~slow, rng.normal(0, 0.2, t.size), 0.0)
    loc = locate(_rec(t, u, np.full(t.size, -15.0)), fast, fast)
    assert loc.conditions["drive_rate"] > 0.3 and "grows with the drive rate" in loc.where


@pytest.mark.parametrize("r", [-0.54, 0.54])
def test_each_phrase_carries_its_direction_and_the_r_printed_is_its_size(r):
    """"grows with the time since steps (r = -0.54)" reads the wrong way round; each phrase says
    the direction and prints |r|, in the location and in an unexplained residual's words alike."""
    from gma_ffc.diagnose.explain import residual_words
    from gma_ffc.diagnose.locate import Located, condition_words
    cond = {"after_steps": r, "drive_rate": 0.1, "stress": -0.4, "cumulative_heating": 0.35}
    words = condition_words(cond, "V", 3)
    assert [w.split(" (r = ")[1] for w in words] == ["0.54)", "0.40)", "0.35)"]     # strongest first, no sign
    assert words[0].startswith("is largest just after steps" if r > 0 else "grows with the time since steps")
    assert words[1].startswith("grows with the compression") and "V^2" in words[2]
    loc = Located("a.csv", "t = 0-1 s", 1.0, 1.0, (0.0, 1.0), (0.0, 1.0), 0.5, cond, None, None)
    text = residual_words(loc, "V")
    assert "r = -" not in text and words[0] in text and "drive rate" not in text
