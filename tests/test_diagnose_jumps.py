"""A step of the displacement sensor's zero (a re-zero, a slip, a knock) is found, and nothing else is."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from gma_ffc.diagnose.jumps import MAX_JUMPS, jump_words, sensor_jumps

FS = 2000.0


def signals(seconds: float = 10.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A drive of holds and a slow sine, a load of two levels, and a noisy smooth residual."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * FS)) / FS
    u = np.where(t < 4.0, 0.8, 1.0 - 0.9 * np.cos(2 * np.pi * 2.0 * t)) + rng.normal(0, 1e-3, t.size)
    s = np.where(t < 7.0, -12.0, -20.0) + rng.normal(0, 0.02, t.size)
    r = 0.3 * np.sin(2 * np.pi * 0.2 * t) + 0.2 * (u - 1.0) + rng.normal(0, 0.03, t.size)
    return t, u, s, r


def test_a_re_zero_in_a_hold_and_one_during_the_sine_are_found_with_their_size_and_time():
    t, u, s, r = signals()
    r = r + np.where(t >= 2.5, 0.5, 0.0) - np.where(t >= 5.3, 0.8, 0.0)
    found = sensor_jumps(r, 0 * r, u, s, t, 1 / FS).found
    assert [round(j.t_s, 3) for j in found] == [2.5, 5.3]
    assert abs(found[0].um - 0.5) < 0.05 and abs(found[1].um + 0.8) < 0.05
    assert "at t = 2.5 s" in jump_words(sensor_jumps(r, 0 * r, u, s, t, 1 / FS))


def test_noise_spikes_and_a_smooth_fast_residual_are_not_jumps():
    t, u, s, r = signals()
    assert sensor_jumps(r, 0 * r, u, s, t, 1 / FS).found == ()
    spiky = r.copy()
    spiky[np.random.default_rng(1).choice(t.size, 30, replace=False)] += 2.0     # one-sample spikes
    assert sensor_jumps(spiky, 0 * spiky, u, s, t, 1 / FS).found == ()
    fast = r + 3.0 * np.sin(2 * np.pi * 40.0 * t) * (t > 6)                   # model error on a fast drive
    assert sensor_jumps(fast, 0 * fast, u, s, t, 1 / FS).found == ()


@pytest.mark.parametrize("what", ["drive", "stress", "gap"])
def test_a_step_that_comes_with_a_drive_step_a_load_change_or_a_gap_is_not_the_sensor(what):
    t, u, s, r = signals()
    at = t >= 2.5
    r = r + np.where(at, 0.5, 0.0)
    if what == "drive":
        u = u + np.where(at, 0.05, 0.0)        # 2 % of the drive's range, but 50x its noise
    elif what == "stress":
        s = s + np.where(at, -1.0, 0.0)
    else:
        t = t + np.where(at, 0.3, 0.0)         # 0.3 s of samples lost
    assert sensor_jumps(r, 0 * r, u, s, t, 1 / FS).found == ()


def test_a_quantised_sensor_s_step_is_found_and_its_quantum_is_not():
    t, u, s, r = signals()
    q = 0.05
    stepped = np.round((r + np.where(t >= 3.1, 1.0, 0.0)) / q) * q
    found = sensor_jumps(stepped, 0 * stepped, u, s, t, 1 / FS).found
    assert len(found) == 1 and abs(found[0].t_s - 3.1) < 0.002
    assert sensor_jumps(np.round(r / q) * q, 0 * r, u, s, t, 1 / FS).found == ()


def test_a_sensor_that_keeps_jumping_is_reported_not_modelled():
    t, u, s, r = signals(30.0)
    for k in range(MAX_JUMPS + 3):
        r = r + np.where(t >= 1.0 + 3.5 * k, 0.7 * (-1) ** k, 0.0)
    jumps = sensor_jumps(r, 0 * r, u, s, t, 1 / FS)
    assert jumps.found == () and jumps.excess == MAX_JUMPS + 1     # it stops counting there
    assert "repair it" in jump_words(jumps)


def test_nothing_before_the_first_scored_sample_counts():
    t, u, s, r = signals()
    r = r + np.where(t >= 1.0, 0.5, 0.0)
    assert len(sensor_jumps(r, 0 * r, u, s, t, 1 / FS).found) == 1
    assert sensor_jumps(r, 0 * r, u, s, t, 1 / FS, first=int(2.0 * FS)).found == ()


def test_a_step_in_the_model_s_output_is_the_model_s_not_the_sensor_s():
    """A play operator switching at a reversal can put a corner or a step into the prediction; the
    residual then steps although the measurement does not."""
    t, u, s, r = signals()
    predicted = np.where(t >= 2.5, -0.5, 0.0)
    assert sensor_jumps(r, predicted, u, s, t, 1 / FS).found == ()
    assert len(sensor_jumps(r + np.where(t >= 2.5, 0.5, 0.0), 0 * r, u, s, t, 1 / FS).found) == 1


@pytest.mark.parametrize("name", ["rate_dependence#2", "mechanical_dynamics#3", "saturation#2",
                                  "stress_dependent_play#2", "creep#2"])
def test_no_jump_where_earlier_drafts_saw_one_on_the_benchmark(name):
    """Fast stretches of model error, a step response to a small drive step, a drive turning round
    beyond the identified range and an SDPI reversal kink: each was taken for a jump by a draft of
    the detector; none is one (the 49 benchmark recordings hold no sensor jump)."""
    from gma_ffc.diagnose.data import prepare
    from benchmarks.cases import cases, make_case

    case = next(c for c in cases() if c.name == name)
    model, rec = make_case(case)
    d = prepare([rec], model)[0]
    yc = model.simulate(d.t, d.u, d.s, initial_state=d.start)
    assert sensor_jumps(d.y, yc, d.u, d.s_raw, d.t, d.dt_med, d.settled).found == ()


@pytest.mark.parametrize("fs, filter_hz", [(200.0, None), (10000.0, 1000.0), (50000.0, 2000.0)])
def test_a_step_is_found_at_low_rates_and_through_a_sensor_s_filter_at_high_rates(fs, filter_hz):
    """At 10-50 kHz a sensor's own 1-2 kHz filter spreads a step over tens of samples: the span a
    step may take is a time (1 ms), not a number of samples."""
    rng = np.random.default_rng(2)
    t = np.arange(int(8 * fs)) / fs
    u = 1.0 - 0.9 * np.cos(2 * np.pi * 2.0 * t) + rng.normal(0, 1e-3, t.size)
    step = np.where(t >= 2.5, 0.5, 0.0)
    if filter_hz is not None:                       # first-order sensor filter
        a = np.exp(-2 * np.pi * filter_hz / fs)
        step = np.asarray(lfilter([1 - a], [1, -a], step))
    r = 0.3 * np.sin(2 * np.pi * 0.2 * t) + 0.2 * (u - 1.0) + rng.normal(0, 0.03, t.size) + step
    found = sensor_jumps(r, 0 * r, u, np.zeros_like(t), t, 1 / fs).found
    assert len(found) == 1 and abs(found[0].t_s - 2.5) < 1e-3 and abs(found[0].um - 0.5) < 0.05


def test_a_step_in_a_hold_is_found_however_much_fast_model_error_the_rest_of_the_run_holds():
    """Thousands of larger changes elsewhere (a model missing a rate effect, on a fast sine) do not
    crowd out the one step: only sharp changes are candidates."""
    t, u, s, r = signals()
    r = r + 10.0 * np.sin(2 * np.pi * 40.0 * t) * (t > 6) + np.where(t >= 2.5, 1.0, 0.0)
    assert np.sum(np.abs(r[2:] - r[:-2]) > 1.0) > 5000
    found = sensor_jumps(r, 0 * r, u, s, t, 1 / FS).found
    assert [round(j.t_s, 3) for j in found] == [2.5]


def test_a_quantised_sensor_ticking_through_a_slow_motion_is_not_jumping():
    """Where the motion is slow, a sensor of 0.2 um resolution holds still and then ticks by one
    quantum: against a smooth prediction each tick is sharp and persists, but it is the sensor's
    resolution, not a step of its zero."""
    fs = 5000.0
    t = np.arange(int(10 * fs)) / fs
    u = 75.0 * np.sin(2 * np.pi * 1.0 * t)
    smooth = 20.0 * np.sin(2 * np.pi * 1.0 * t - 0.2)
    measured = np.round((smooth + np.random.default_rng(3).normal(0, 0.002, t.size)) / 0.2) * 0.2
    assert sensor_jumps(measured, smooth, u, np.zeros_like(t), t, 1 / fs).found == ()
    stepped = measured + np.where(t >= 4.3, 2.0, 0.0)
    assert [round(j.t_s, 2) for j in sensor_jumps(stepped, smooth, u, np.zeros_like(t), t, 1 / fs).found] == [4.3]


@pytest.mark.parametrize("name", ["JUMP_SIGMAS", "SHARPNESS", "LEVEL_KEPT"])
@pytest.mark.parametrize("factor", [0.7, 1.3])
def test_each_detection_threshold_moved_30_percent_changes_no_answer(monkeypatch, name, factor):
    """A threshold that flips the answers when moved by 30 % is a tuned number. (On the 49 benchmark
    recordings the same sweep finds no jump where none was added and every 1 um step in a drive
    hold: scripts/scan_sensor_jumps.py with the constants moved.)"""
    import gma_ffc.diagnose.jumps as jumps

    monkeypatch.setattr(jumps, name, getattr(jumps, name) * factor)
    t, u, s, r = signals()
    spiky = r.copy()
    spiky[np.random.default_rng(1).choice(t.size, 30, replace=False)] += 2.0
    fast = r + 3.0 * np.sin(2 * np.pi * 40.0 * t) * (t > 6)
    for quiet in (r, spiky, fast):
        assert jumps.sensor_jumps(quiet, 0 * r, u, s, t, 1 / FS).found == ()
    stepped = fast + np.where(t >= 2.5, 0.8, 0.0) - np.where(t >= 5.3, 0.8, 0.0)
    assert [round(j.t_s, 3) for j in jumps.sensor_jumps(stepped, 0 * r, u, s, t, 1 / FS).found] == [2.5, 5.3]
    assert jumps.sensor_jumps(r, np.where(t >= 2.5, -0.8, 0.0), u, s, t, 1 / FS).found == ()
