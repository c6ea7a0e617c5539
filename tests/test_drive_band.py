"""The drive's dominant frequency band (`drive.dominant_band`): one sine is one frequency, whatever
its amplitude does; steps and several sines are not."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from gma_ffc.drive import dominant_band

FS = 1000.0


def _t(seconds: float) -> np.ndarray:
    return np.arange(int(seconds * FS)) / FS


@settings(max_examples=60, deadline=None)
@given(f=st.floats(0.5, 80.0), seconds=st.floats(2.0, 20.0), offset=st.floats(-5, 5), amp=st.floats(0.01, 10),
       envelope=st.sampled_from(["flat", "rising", "rising and falling"]))
def test_a_sine_at_any_amplitude_is_one_frequency(f, seconds, offset, amp, envelope):
    """Ten cycles or more: a periodogram's bins are 1 / duration apart, and over fewer cycles a
    rising and falling envelope's sidebands (f +- 1 / duration) fall out of the octave (4.5 cycles:
    0.92). diagnose scores nothing before 16 cycles (`checks.MIN_REVERSALS`)."""
    t = _t(max(seconds, 10.0 / f))
    env = {"flat": np.ones_like(t), "rising": t / t[-1], "rising and falling": np.sin(np.pi * t / t[-1]) ** 2}[envelope]
    f0, share = dominant_band([(t, offset + amp * env * np.sin(2 * np.pi * f * t))])
    assert abs(f0 / f - 1) < 0.25 and share > 0.95


def test_two_sines_an_octave_and_more_apart_are_not_one_frequency():
    t = _t(10.0)
    slow, fast = np.sin(2 * np.pi * 3 * t), np.sin(2 * np.pi * 20 * t)
    assert dominant_band([(t, slow), (t[:3000], fast[:3000])])[1] < 0.8        # two short runs
    assert dominant_band([(t, slow + 0.5 * fast)])[1] < 0.85                  # one run, two tones


def test_steps_and_a_square_wave_spread_their_power():
    t = _t(20.0)
    steps = np.repeat(np.random.default_rng(1).uniform(0, 3, 10), t.size // 10)
    assert dominant_band([(t, steps)])[1] < 0.9
    assert dominant_band([(t, np.sign(np.sin(2 * np.pi * 2 * t)))])[1] < 0.9      # 81 % in its fundamental


def test_a_drive_that_never_moves_has_no_band():
    t = _t(1.0)
    f0, share = dominant_band([(t, np.full(t.size, 1.5))])
    assert np.isnan(f0) and share == 0.0


def test_no_benchmark_drive_is_one_frequency_so_their_figures_cannot_move():
    """The one-frequency rule (`EffectSelector.one_frequency_share`, 0.9) must leave the benchmark
    families alone: a mixed recording, two short runs at two frequencies, and a rising family's."""
    from benchmarks import cases as bench

    known = {c.name: c for c in bench.cases() + bench.rising_cases()}
    for name in ("null#1", "rising:null#1"):
        _, _, rec = bench.case_recordings(known[name], scale=0.5)
        assert dominant_band([(rec.time_s, rec.drive)])[1] < 0.5, name
        if name == "null#1":
            runs = bench.short_runs(rec)
            assert dominant_band([(r.time_s, r.drive) for r in runs])[1] < 0.8
