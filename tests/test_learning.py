"""Learning feedforward (issue 12): the learner alone, its safety, and the loop on the simulated rig."""

from __future__ import annotations

import math
import re
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from gma_ffc.control import safety
from gma_ffc.control.config import validate_config
from gma_ffc.control.learning import (LearningConfig, RepetitiveLearner, _lowpass_circular,
                                      filter_coefficient, reference_period_s)
from gma_ffc.errors import ConfigError
from gma_ffc.sil import run_tracking

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "config" / "models" / "sim_sdpi.yaml"
ON = LearningConfig.from_mapping({"kind": "repetitive"})


def base_cfg(**extra):
    data = {"rate_hz": 1000, "clock": "simulated", "model": str(MODEL), "driver": {"kind": "sim"},
            "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 10.0, "offset_um": 20.0},
            "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0},
            "telemetry": {"path": None}}
    data.update(extra)
    return data


# ---- configuration ------------------------------------------------------------------------------

def test_learning_is_off_by_default_and_kind_alone_turns_it_on():
    assert not validate_config(base_cfg()).learning.enabled
    cfg = validate_config(base_cfg(learning={"kind": "repetitive"}))
    assert cfg.learning.enabled and cfg.learning.gain == 0.5 and cfg.learning.period_s is None


@pytest.mark.parametrize("section,key", [({"kind": "repetitive", "gain": 1.5}, "learning.gain"),
                                         ({"kind": "repetitive", "gainn": 0.5}, "learning.gainn"),
                                         ({"kind": "ilc"}, "learning.kind"),
                                         ({"kind": "repetitive", "lead_samples": -1}, "learning.lead_samples"),
                                         ({"kind": "repetitive", "forgetting": 0.1}, "learning.forgetting")])
def test_bad_learning_keys_are_refused_by_name(section, key):
    with pytest.raises(ConfigError, match=f"'{key}'"):
        validate_config(base_cfg(learning=section))


def test_a_non_periodic_reference_needs_an_explicit_period(tmp_path):
    ref = tmp_path / "ref.csv"
    ref.write_text("time_s,reference_um\n0,1\n1,2\n")
    data = base_cfg(reference={"kind": "playback", "file": str(ref)}, learning={"kind": "repetitive"})
    with pytest.raises(ConfigError, match="learning.period_s"):
        validate_config(data)
    assert validate_config({**data, "learning": {"kind": "repetitive", "period_s": 0.5}}).learning.period_s == 0.5


def test_periods_of_the_references():
    assert reference_period_s({"kind": "sine", "frequency_hz": 4.0}) == 0.25
    assert reference_period_s({"kind": "multisine", "components": [{"frequency_hz": 2.0}, {"frequency_hz": 6.0}]}) == 0.5
    assert reference_period_s({"kind": "multisine", "components": [{"frequency_hz": 2.0}, {"frequency_hz": 2.5}]}) is None


# ---- the filter ---------------------------------------------------------------------------------

@pytest.mark.parametrize("zero_phase", [True, False])
def test_robustness_filter_has_its_cutoff_and_zero_phase_has_no_lag(zero_phase):
    rate, n, harmonic = 1000.0, 1000, 40          # a 1 s period; 40 Hz at the cutoff
    x = np.sin(2 * np.pi * harmonic * np.arange(n) / n)
    y = x.copy()
    _lowpass_circular(y, filter_coefficient(40.0, rate, zero_phase), zero_phase)
    gain = np.sqrt(np.mean(y ** 2) / np.mean(x ** 2))
    assert gain == pytest.approx(1 / math.sqrt(2), rel=0.05)
    shift = np.angle(np.fft.fft(y)[harmonic] / np.fft.fft(x)[harmonic])
    if zero_phase:
        assert abs(shift) < 1e-3                  # radians
    else:
        assert -np.pi / 2 < shift < -0.1          # a causal first-order filter lags


# ---- the learner alone --------------------------------------------------------------------------

def jitter(t):
    """A sensor's last digit: real readings are never identical for long (no stuck-sensor freeze)."""
    return 1e-6 * ((t * 1e3) % 7)


def feed(learner, periods, y_of_t, stress=-15.0, ok=True, t0=0.0):
    dt = 1.0 / learner.rate_hz
    n = int(round(periods * learner.period_s * learner.rate_hz))
    for i in range(n):
        t = t0 + i * dt
        learner.observe(t, 0.0, y_of_t(t), stress, ok, "" if ok else "fault")
    return t0 + n * dt


def test_a_repeating_disturbance_is_learned_away_in_closed_loop():
    """Plant y = c - d with a periodic d (P = 1): the error r - y = d - c must shrink by about
    (1 - L) per period until the robustness filter's leak, and c must become d."""
    ln = RepetitiveLearner(ON, 1000.0, 0.25)
    dt = 1e-3
    rms = []
    for k in range(16):
        errs = []
        for i in range(250):
            t = (k * 250 + i) * dt
            d = math.sin(2 * math.pi * 4 * t) + 0.3 * math.sin(2 * math.pi * 8 * t)
            y = ln.correction(t) - d
            ln.observe(t, 0.0, y, -15.0, True)
            errs.append(-y)
        rms.append(float(np.sqrt(np.mean(np.square(errs)))))
    assert rms[0] > 0.7
    assert all(b < 0.7 * a for a, b in zip(rms[1:6], rms[2:7]))    # monotone, about halving
    assert rms[-1] < 0.02 * rms[0]
    assert not ln.status()["frozen"] and ln.learned_periods >= 14


def test_frozen_ticks_teach_nothing_and_say_why():
    ln = RepetitiveLearner(ON, 1000.0, 0.25)
    t = feed(ln, 3, lambda t: -1.0 + jitter(t))                # learn a constant offset
    ln.observe(t, 0.0, 5.0, -15.0, False, "fault")             # closes the last clean period
    before = ln.correction_um.copy()
    assert np.all(before > 0.9)
    t = feed(ln, 3, lambda t: 5.0, ok=False, t0=t + 1e-3)      # a fault: nothing learned
    assert np.array_equal(ln.correction_um, before)
    assert ln.status()["frozen"] and ln.status()["frozen_reason"] == "fault"
    feed(ln, 3, lambda t: float("nan"), t0=t)
    assert np.array_equal(ln.correction_um, before)
    assert "NaN" in ln.status()["frozen_reason"]


def test_a_stuck_displacement_reading_freezes_learning():
    ln = RepetitiveLearner(LearningConfig.from_mapping({"kind": "repetitive", "stale_ticks": 20}), 1000.0, 0.25)
    feed(ln, 3, lambda t: 0.123)                                # identical readings: stuck
    assert not np.any(ln.correction_um)
    assert "stuck" in ln.status()["frozen_reason"]


def test_stress_rule_scales_a_small_gain_change_and_resets_a_large_one():
    gains = {-11.0: 1.0, -12.0: 1.05, -20.0: 1.6}
    ln = RepetitiveLearner(ON, 1000.0, 0.1, gain_of_stress=lambda s: gains[round(s)])
    t = feed(ln, 5, lambda t: -1.0 + jitter(t), stress=-11.0)
    ln.observe(t, 0.0, jitter(t), -12.0, True)                 # closes the last period at -11 MPa
    c11 = ln.correction_um.copy()
    assert np.all(c11 > 0)
    t = feed(ln, 1, jitter, stress=-12.0, t0=t + 1e-3)         # ~zero error: only the scaling acts
    ln.observe(t, 0.0, jitter(t), -20.0, True)
    assert ln.correction_um == pytest.approx(1.05 * c11, rel=1e-4)
    t = feed(ln, 1, jitter, stress=-20.0, t0=t + 1e-3)         # +52 % gain: the shape is another plant's
    ln.observe(t, 0.0, jitter(t), -20.0, True)
    assert not np.any(ln.correction_um)
    assert "reset" in ln.status()["last_event"]


def test_save_and_load_round_trip_and_refusals():
    ln = RepetitiveLearner(ON, 1000.0, 0.25, fingerprint="abc")
    feed(ln, 4, lambda t: -math.cos(2 * math.pi * 4 * t))
    d = yaml.safe_load(yaml.safe_dump(ln.to_dict()))
    other = RepetitiveLearner(ON, 1000.0, 0.25, fingerprint="abc")
    other.load_dict(d, "learned.yaml")
    assert np.array_equal(other.correction_um, ln.correction_um)
    with pytest.raises(ConfigError, match="another model"):
        RepetitiveLearner(ON, 1000.0, 0.25, fingerprint="xyz").load_dict(d, "learned.yaml")
    with pytest.raises(ConfigError, match="0.25 s period"):
        RepetitiveLearner(ON, 1000.0, 0.5, fingerprint="abc").load_dict(d, "learned.yaml")


def test_the_tick_allocates_nothing():
    ln = RepetitiveLearner(ON, 1000.0, 0.05)
    feed(ln, 3, lambda t: math.sin(t))                           # compile the period kernel, warm up
    dt = 1e-3
    t = 3 * 0.05
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        peak = 0
        for i in range(400):                                     # 8 period boundaries included
            tt = t + i * dt
            c = ln.correction(tt + 0.001)
            ln.observe(tt, 1.0, 0.5 + c, -15.0, True)
            peak = max(peak, tracemalloc.get_traced_memory()[0] - base)
    finally:
        tracemalloc.stop()
    assert peak < 1024, peak
    assert ln.learned_periods >= 8


@settings(max_examples=60, deadline=None)
@given(readings=st.lists(st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=64),
                                   st.just(float("nan")), st.just(3.0), st.floats(-1e9, 1e9)),
                         min_size=50, max_size=600),
       bound=st.floats(0.01, 20.0), slew=st.floats(1.0, 1000.0))
def test_whatever_the_readings_the_correction_and_command_stay_in_bounds(readings, bound, slew):
    """NaN, infinities, stuck values and spikes: c stays inside its bound, and the command that
    goes through the controller's limiter stays inside the current and slew limits."""
    cfg = LearningConfig.from_mapping({"kind": "repetitive", "max_correction_um": bound, "stale_ticks": 5})
    ln = RepetitiveLearner(cfg, 1000.0, 0.01)
    lim = safety.Limiter(0.0, 3.0, slew, 1e-3, 0.0)
    for i, y in enumerate(readings):
        t = i * 1e-3
        c = ln.correction(t)
        assert abs(c) <= bound
        cmd = lim.apply(0.2 * (10.0 + c))                       # a linear stand-in for the inverse
        assert 0.0 <= cmd <= 3.0
        ln.observe(t, 10.0, y, -15.0, True)
    assert np.all(np.abs(ln.correction_um) <= bound)


# ---- the loop on the simulated rig (noise, delay, eddy currents, a load step) -------------------

@pytest.mark.parametrize("freq", [3.0, 20.0])
def test_learning_beats_feedforward_by_far_after_ten_periods_through_a_load_step(freq):
    periods = 24
    sched = ((0.0, 0.0), (16 / freq, 30.6))                    # -11.3 -> -19.1 MPa after period 16
    ff = run_tracking(MODEL, freq, periods, load_schedule=sched)
    ln = run_tracking(MODEL, freq, periods, learning={"kind": "repetitive"}, load_schedule=sched)
    ratio = ln.period_rms_um[10:16].mean() / ff.period_rms_um[10:16].mean()
    assert ratio <= 0.4, (ln.period_rms_um, ff.period_rms_um)
    after = ln.period_rms_um[-4:].mean() / ff.period_rms_um[-4:].mean()
    assert after <= 0.4                                       # and again after the load step
    assert ln.status["learning"]["learned_periods"] >= periods - 4
    assert ff.status["learning"] == {"enabled": False}


@pytest.mark.slow
def test_two_thousand_periods_without_growth():
    """Monotone convergence of the filtered error: after it settles, the error never creeps up
    and the correction does not drift (a learner that is only marginally stable would)."""
    run = run_tracking(MODEL, 20.0, 2000, rate_hz=500.0, learning={"kind": "repetitive"})
    rms = run.period_rms_um
    settled = np.median(rms[20:120])
    windows = rms[20:].reshape(-1, 20).mean(axis=1)           # 99 windows of 20 periods
    assert windows.max() <= 1.25 * settled, (settled, windows.max())
    assert rms[-100:].mean() <= 1.1 * rms[20:120].mean()
    assert run.status["learning"]["correction_rms_um"] < ON.max_correction_um


# ---- the command line -----------------------------------------------------------------------------

def write_config(tmp_path, learning):
    cfg = base_cfg(driver={"kind": "sim", "load_mass_kg": 15.3,
                           "plant_config": str(tmp_path / "plant.yaml")},
                   telemetry={"path": str(tmp_path / "tel.csv")}, learning=learning)
    (tmp_path / "plant.yaml").write_text(yaml.safe_dump({"delay": {"enabled": True, "delay_ms": 1.0},
                                                          "noise": {"enabled": True}}))
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def gma(*args):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "gma_ffc.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=120)


def test_run_learned_saves_and_a_second_run_starts_where_the_first_left_off(tmp_path):
    from gma_ffc.recordings import read_recording

    cfg = write_config(tmp_path, {"kind": "repetitive"})
    learned = tmp_path / "learned.yaml"
    stats = tmp_path / "s1.json"
    first = gma("run", "--config", cfg, "--duration", 4, "--no-socket", "--learned", learned, "--stats-json", stats)
    assert first.returncode == 0, first.stderr
    saved = yaml.safe_load(learned.read_text())
    assert saved["format"] == "gma-ffc-learned-correction" and saved["learned_periods"] >= 8
    rec1 = read_recording(tmp_path / "tel.csv")
    e1 = rec1.columns["reference_um"] - rec1.displacement_um
    assert "correction_um" in rec1.columns
    second = gma("run", "--config", cfg, "--duration", 1, "--no-socket", "--learned", learned)
    assert second.returncode == 0, second.stderr
    rec2 = read_recording(tmp_path / "tel.csv")
    e2 = rec2.columns["reference_um"] - rec2.displacement_um
    n = 333                                                    # one 3 Hz period at 1 kHz
    # the second run's second period (after the start-up ramp) is as good as the first run's last
    assert np.sqrt(np.mean(e2[n:2 * n] ** 2)) < 1.5 * np.sqrt(np.mean(e1[-n:] ** 2))
    assert np.sqrt(np.mean(e2[n:2 * n] ** 2)) < 0.5 * np.sqrt(np.mean(e1[n:2 * n] ** 2))


def test_run_learned_without_learning_in_the_config_is_refused(tmp_path):
    cfg = write_config(tmp_path, {})
    out = gma("run", "--config", cfg, "--duration", 1, "--no-socket", "--learned", tmp_path / "l.yaml")
    assert out.returncode == 2 and "learning is off" in out.stderr and "Traceback" not in out.stderr


def test_status_table_shows_learning_and_why_it_froze():
    from gma_ffc.service.status import format_table

    run = run_tracking(MODEL, 20.0, 12, learning={"kind": "repetitive"})
    table = format_table(run.status)
    assert "learning" in table and "periods learned" in table and "stopping" in table   # frozen at stop
    assert re.search(r"^learning +off$", format_table(run_tracking(MODEL, 20.0, 2).status), re.M)
