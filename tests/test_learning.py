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
                                         ({"kind": "repetitive", "lead_samples": 0.5}, "learning.lead_samples"),
                                         ({"kind": "repetitive", "cutoff_harmonics": 0}, "learning.cutoff_harmonics"),
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


def closed_loop(ln, periods, disturbance, *, reference=lambda t: 0.0, sign=1.0, floor=-math.inf, slew=math.inf,
                noise_um=0.0, seed=0, skip_every=0):
    """The learner in a loop as the controller drives it, on a plant that is linear apart from
    its limits: the inverse is the identity (u = r + c), the limiter cuts u at `floor` and
    `slew`, and y = r + sign * (u - r) - d(t) + noise. sign -1 is a plant whose response to the
    correction has the wrong sign. `skip_every` k > 0 drops every k-th tick (missed deadlines).
    Returns the per-period RMS of r - y and the error of the last period by phase."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / ln.rate_hz
    lim = safety.Limiter(floor, math.inf, slew, dt, max(reference(0.0), floor))
    rms, last = [], np.zeros(ln.n)
    for k in range(periods):
        errs = []
        for i in range(ln.n):
            tick = k * ln.n + i
            if skip_every and tick % skip_every == 0:
                continue
            t = tick * dt
            r = reference(t)
            asked = r + ln.correction(t)
            u = lim.apply(asked)
            if u != asked:
                ln.limited(t, lim.clipped, u - asked)
            y = r + sign * (u - r) - disturbance(t) + noise_um * rng.standard_normal() + jitter(t)
            ln.observe(t, r, y, -15.0, True)
            errs.append(r - y)
            last[i] = r - y
        rms.append(float(np.sqrt(np.mean(np.square(errs)))))
    return np.array(rms), last


def two_tones(t):
    return np.sin(2 * np.pi * 4 * t) + 0.3 * np.sin(2 * np.pi * 8 * t)


BASE = 1 + ON.baseline_periods      # periods of feedforward alone: the start-up one, then the baseline


def test_a_repeating_disturbance_is_learned_away_in_closed_loop():
    """P = 1: after the feedforward baseline the error must shrink by about (1 - L) per period
    until the robustness filter's leak, and the correction must become the disturbance."""
    ln = RepetitiveLearner(ON, 1000.0, 0.25)
    rms, _ = closed_loop(ln, BASE + 12, two_tones)
    assert rms[0] > 0.7 and np.ptp(rms[:BASE]) < 0.01                  # feedforward: nothing applied
    learning = rms[BASE - 1:BASE + 6]
    assert all(b < 0.7 * a for a, b in zip(learning[:-1], learning[1:]))    # monotone, about halving
    assert rms[-1] < 0.02 * rms[0]
    st = ln.status()
    assert st["stage"] == "learning" and not st["frozen"] and ln.learned_periods >= 12
    assert st["baseline_rms_um"] == pytest.approx(rms[1], rel=0.01) and st["backoffs"] == 0
    assert "feedforward baseline" in st["events"][0]["text"]


def test_a_tenth_of_every_period_clipped_learns_the_rest_and_does_not_wind_up_there():
    """The reference dips below the current floor for 10 % of each period: the rig cannot follow
    it there. The learner keeps learning the other 90 % to the same precision as without a limit,
    and where the command was clipped the correction stays inside its bound: it never pushes
    further into the floor (a learner without the projection runs to -max_correction there)."""
    period, rate = 0.25, 1000.0
    n = int(period * rate)

    def reference(t):          # a dip to 1 um below the floor (0) mid-period, below it on 10 % of the period
        return 5.0 * (1.0 - 1.2 * math.exp(-((((t / period) % 1.0) - 0.5) / 0.117) ** 2))

    phases = np.arange(n) / rate
    clipped = np.array([reference(t) < 0.0 for t in phases])
    assert 0.08 <= clipped.mean() <= 0.12
    ln = RepetitiveLearner(ON, rate, period)
    rms, err = closed_loop(ln, BASE + 30, two_tones, reference=reference, floor=0.0)
    free = ~clipped
    inner = np.convolve(clipped, np.ones(11), "same") == 11          # 5 samples inside the clipped stretch

    assert np.sqrt(np.mean(err[free] ** 2)) < 0.03 * np.sqrt(np.mean(two_tones(phases[free]) ** 2))
    c = ln.correction_um
    assert np.all(np.abs(c) <= ON.max_correction_um)
    edge = min(c[np.flatnonzero(np.diff(clipped.astype(int)))].min(), 0.0)
    assert c[inner].min() >= edge - 0.05, (c[inner].min(), edge)     # no wind-up into the floor
    st = ln.status()
    assert st["limited"]["by"] == {"current_min": pytest.approx(clipped.mean(), abs=0.02)}
    assert st["reference_beyond_limits"][0]["limit"] == "current_min"
    assert st["reference_beyond_limits"][0]["from"] == pytest.approx(np.flatnonzero(clipped)[0] / n, abs=0.02)
    assert any("cannot follow" in e["text"] for e in st["events"]) and ln.learned_periods >= 25
    # the same learner told nothing of the limit winds the correction up to its bound there
    naive = RepetitiveLearner(ON, rate, period)
    naive.limited = lambda *args: None
    closed_loop(naive, BASE + 30, two_tones, reference=reference, floor=0.0)
    assert naive.correction_um[inner].min() < -0.9 * ON.max_correction_um


def test_a_wrong_sign_plant_backs_off_within_five_periods_and_ends_at_feedforward():
    """The correction acts with the wrong sign: every learning step makes the error grow by
    (1 + L). The learner must back off within 5 periods of starting, say so, and end no worse
    than feedforward (here: at feedforward, learning stopped)."""
    ln = RepetitiveLearner(ON, 1000.0, 0.25)
    rms, _ = closed_loop(ln, BASE + 30, two_tones, sign=-1.0, noise_um=0.02)
    ff = rms[1:BASE].mean()
    events = ln.status()["events"]
    backoff = next(e for e in events if "backed off" in e["text"])
    assert backoff["t_s"] <= (BASE + 5) * 0.25 + 1e-9, events            # within 5 periods of learning
    assert "worse than feedforward" in backoff["text"]
    assert rms[BASE:].max() < 5 * ff                                     # never ran away
    assert rms[-5:].mean() <= ff * 1.02                                  # ends no worse than feedforward
    st = ln.status()
    assert st["stage"] == "holding" and st["backoffs"] == ON.max_backoffs
    assert not ln.saveable and not np.any(ln.to_dict()["correction_um"])


def test_a_slow_divergence_is_caught_before_it_costs_much():
    """A plant that passes the correction with 100 degrees of lag at the disturbance's tones
    (beyond what the learning can take): it diverges slowly. The learner backs off and ends
    no worse than feedforward."""
    ln = RepetitiveLearner(ON, 1000.0, 0.25)
    lag = int(0.28 * 250)                     # 100 degrees of the 4 Hz tone
    history = np.zeros(100_000)

    rng = np.random.default_rng(1)
    dt = 1e-3
    rms = []
    for k in range(BASE + 40):
        errs = []
        for i in range(250):
            tick = k * 250 + i
            t = tick * dt
            history[tick] = ln.correction(t)
            y = history[tick - lag] - two_tones(t) + 0.02 * rng.standard_normal()
            ln.observe(t, 0.0, y, -15.0, True)
            errs.append(-y)
        rms.append(float(np.sqrt(np.mean(np.square(errs)))))
    ff = np.mean(rms[1:BASE])
    assert ln.backoffs >= 1
    assert np.mean(rms[-5:]) <= 1.05 * ff


def test_missed_ticks_do_not_stop_learning():
    """Every 7th tick missing (an overloaded loop skipping deadlines): the periods are still
    learned from, on the phases that were seen."""
    ln = RepetitiveLearner(ON, 1000.0, 0.25)
    rms, _ = closed_loop(ln, BASE + 12, two_tones, skip_every=7)
    assert rms[-1] < 0.05 * rms[0] and ln.learned_periods >= 12


def test_the_limiter_says_which_limit_cut_the_command():
    lim = safety.Limiter(0.0, 3.0, 100.0, 1e-3, 0.0)         # 0.1 A per tick
    assert lim.apply(1.0) == pytest.approx(0.1) and lim.clipped == safety.RAMP   # the start-up ramp
    for _ in range(9):
        lim.apply(1.0)
    assert lim.apply(1.0) == 1.0 and lim.clipped == safety.NOT_LIMITED                 # caught up: no ramp
    assert lim.apply(1.5) == pytest.approx(1.1) and lim.clipped == safety.SLEW
    lim.apply(1.1)
    lim.force(0.0)                                             # a safe-current write: ramps again
    assert lim.apply(0.5) == pytest.approx(0.1) and lim.clipped == safety.RAMP
    assert lim.apply(-1.0) == 0.0 and lim.clipped == safety.CURRENT_MIN
    lim.force(2.95)
    lim.apply(2.95)
    assert lim.apply(9.0) == 3.0 and lim.clipped == safety.CURRENT_MAX
    assert lim.apply(2.0) == pytest.approx(2.9) and lim.clipped == safety.SLEW
    # a ramp ends at the latest after the time the slew limit takes to cross the whole range
    slow = safety.Limiter(0.0, 1.0, 1.0, 0.1, 0.0)            # 0.1 A per tick: 10 ticks across
    kinds = [(slow.apply(5.0 if i % 2 else -5.0) and slow.clipped) for i in range(40)]
    assert safety.RAMP not in kinds[12:]


def test_frozen_ticks_teach_nothing_and_say_why():
    ln = RepetitiveLearner(ON, 1000.0, 0.25)
    t = feed(ln, BASE + 2, lambda t: -1.0 + jitter(t))         # learn a constant offset (open loop)
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


def test_a_reading_held_still_with_its_command_is_no_stuck_sensor_one_held_while_the_command_moves_is():
    """A command held at a limit holds a noise-free displacement too: learning froze as a 'stuck
    sensor' on the simulated rig whenever a reference reached current_max (a new user's sweep,
    2026-11-30), the very case learning must handle."""
    cfg = LearningConfig.from_mapping({"kind": "repetitive", "stale_ticks": 20})
    dt = 1e-3
    held = RepetitiveLearner(cfg, 1000.0, 0.25)
    for i in range(750):                                   # three periods at one held command
        held.observe(i * dt, 0.0, 0.123, -15.0, True, "", 1.2)
    assert "stuck" not in str(held.status()["frozen_reason"])
    moving = RepetitiveLearner(cfg, 1000.0, 0.25)
    for i in range(750):                                   # the command moves, the reading does not
        moving.observe(i * dt, 0.0, 0.123, -15.0, True, "", 1.0 + 1e-3 * (i % 50))
    assert "stuck" in moving.status()["frozen_reason"]


def test_learning_leaves_its_baseline_when_the_reference_asks_past_current_max_on_the_noise_free_rig(tmp_path):
    from gma_ffc.control.config import validate_config
    from gma_ffc.control.manager import ControllerManager
    from gma_ffc.modelio import load_model

    root = Path(__file__).resolve().parents[1]
    cfg = validate_config({
        "rate_hz": 1000, "clock": "simulated", "model": str(root / "config" / "models" / "sim_sdpi.yaml"),
        "driver": {"kind": "sim", "load_mass_kg": 15.3},
        "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 12.0, "offset_um": 15.0},
        "limits": {"current_min_A": 0.0, "current_max_A": 1.2, "slew_A_per_s": 500.0},
        "learning": {"kind": "repetitive"}, "telemetry": {"path": str(tmp_path / "t.csv")}})
    summary = ControllerManager(cfg, model=load_model(cfg.model)).run(duration_s=6.0)
    learning = summary["learning"]
    assert learning["learned_periods"] > 0 and "stuck" not in str(learning.get("frozen_reason")), learning


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
    dt = 1e-3

    def tick(t):
        c = ln.correction(t + 0.001)
        ln.observe(t, 1.0, 0.5 + c + 0.01 * math.sin(40 * t), -15.0, True)

    for i in range(int((BASE + 3) * 50)):                        # past the baseline, learning
        tick(i * dt)
    t = (BASE + 3) * 0.05
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        peak = 0
        for i in range(400):                                     # 8 period boundaries included
            tick(t + i * dt)
            peak = max(peak, tracemalloc.get_traced_memory()[0] - base)
    finally:
        tracemalloc.stop()
    assert peak < 1024, peak
    assert ln.learned_periods >= 8 and ln.stage == "learning"


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

def write_config(tmp_path, learning, **extra):
    cfg = base_cfg(driver={"kind": "sim", "load_mass_kg": 15.3,
                           "plant_config": str(tmp_path / "plant.yaml")},
                   telemetry={"path": str(tmp_path / "tel.csv")}, learning=learning, **extra)
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
    first = gma("run", "--config", cfg, "--duration", 5, "--no-socket", "--learned", learned, "--stats-json", stats)
    assert first.returncode == 0, first.stderr
    saved = yaml.safe_load(learned.read_text())
    assert saved["format"] == "gma-ffc-learned-correction" and saved["learned_periods"] >= 8
    assert saved["rms_um"] < 0.5 * saved["baseline_rms_um"]     # what is saved was measured better
    rec1 = read_recording(tmp_path / "tel.csv")
    e1 = rec1.columns["reference_um"] - rec1.displacement_um
    assert "correction_um" in rec1.columns
    second = gma("run", "--config", cfg, "--duration", 2, "--no-socket", "--learned", learned)
    assert second.returncode == 0, second.stderr
    rec2 = read_recording(tmp_path / "tel.csv")
    e2 = rec2.columns["reference_um"] - rec2.displacement_um
    n = 333                                                    # one 3 Hz period at 1 kHz
    base = slice(2 * n, 3 * n)                                 # a feedforward baseline period
    loaded = slice(BASE * n, (BASE + 1) * n)                   # the first period with the loaded correction
    assert not np.any(rec2.columns["correction_um"][base])
    # it is as good as the first run's last, and far better than the feedforward before it
    assert np.sqrt(np.mean(e2[loaded] ** 2)) < 1.5 * np.sqrt(np.mean(e1[-n:] ** 2))
    assert np.sqrt(np.mean(e2[loaded] ** 2)) < 0.5 * np.sqrt(np.mean(e2[base] ** 2))


def test_a_correction_never_measured_better_is_not_saved(tmp_path):
    """A learning that can only make things worse (its phase lead half a period wrong turns the
    fundamental's sign): it backs off, says so, and the file is not written."""
    cfg = write_config(tmp_path, {"kind": "repetitive", "lead_samples": 166})
    learned = tmp_path / "learned.yaml"
    stats = tmp_path / "s.json"
    out = gma("run", "--config", cfg, "--duration", 8, "--no-socket", "--learned", learned, "--stats-json", stats)
    assert out.returncode == 0, out.stderr
    assert not learned.exists()
    import json

    status = json.loads(stats.read_text())["status"]["learning"]
    texts = [e["text"] for e in status["events"]]
    assert any("backed off" in t for t in texts) and any("not saved" in t for t in texts), texts
    assert status["backoffs"] >= 1


def test_a_reference_to_the_current_floor_is_said_once_at_start_and_learned_around(tmp_path):
    """The issue 32 case: the sine's bottom asks for less than 0 A. The log says once, before
    learning starts, where in the phase and which limit; learning goes on around it, and the
    status and its table show the share of the period that was limited."""
    import json

    from gma_ffc.service.status import format_table

    floor_ref = {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 12.0, "offset_um": 12.0}
    cfg = write_config(tmp_path, {"kind": "repetitive"}, reference=floor_ref)
    stats = tmp_path / "s.json"
    out = gma("run", "--config", cfg, "--duration", 5, "--no-socket", "--stats-json", stats)
    assert out.returncode == 0, out.stderr
    said = [line for line in out.stderr.splitlines() if "cannot follow" in line]
    assert len(said) == 1 and "current_min" in said[0] and "phase 0.9" in said[0], out.stderr
    baseline = [line for line in out.stderr.splitlines() if "feedforward baseline" in line]
    assert baseline and out.stderr.index(baseline[0]) <= out.stderr.index(said[0])   # before learning starts
    status = json.loads(stats.read_text())["status"]
    learning = status["learning"]
    assert learning["learned_periods"] >= 8 and learning["backoffs"] == 0
    assert 0.01 < learning["limited"]["share"] < 0.2 and set(learning["limited"]["by"]) == {"current_min"}
    assert learning["rms_trend_um"][-1] < 0.5 * learning["baseline_rms_um"]
    assert re.search(r"learning limits +\d+\.\d % of the last period limited: current_min at phase", format_table(status))


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


@pytest.mark.parametrize("reference,period_s", [
    ({"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 10.0, "offset_um": 15.0}, 0.5),
    ({"kind": "multisine", "components": [{"frequency_hz": 3.0, "amplitude_um": 6.0},
                                          {"frequency_hz": 3.7, "amplitude_um": 4.0}], "offset_um": 15.0}, 1 / 3),
])
def test_a_learning_period_the_reference_does_not_repeat_in_is_refused_and_the_advised_one_is_accepted(
        tmp_path, reference, period_s):
    """A 0.5 s period on a 3 Hz sine, and 1/3 s on 3 Hz + 3.7 Hz: learning ran 15-20 % worse than
    the feedforward alone, with no back-off (a new user's sweep, 2026-11-30)."""
    import re

    def config(period):
        return base_cfg(reference=reference, learning={"kind": "repetitive", "period_s": period},
                        telemetry={"path": str(tmp_path / "t.csv")})

    with pytest.raises(ConfigError, match=r"does not repeat in it\. Set learning.period_s to ([0-9.]+) s") as e:
        validate_config(config(period_s))
    advised = float(re.search(r"Set learning.period_s to ([0-9.]+) s", str(e.value)).group(1))
    assert validate_config(config(advised)).learning.period_s == pytest.approx(advised)


def test_learning_on_a_rig_without_a_displacement_channel_is_refused(tmp_path):
    """It started with exit 0 and stayed frozen all run on 'displacement reading missing or NaN'
    (a new user's sweep, 2026-11-30): learning corrects a measured error, and there was none."""
    from gma_ffc.control.manager import ControllerManager
    from gma_ffc.drivers.sim import SimDriver
    from gma_ffc.modelio import load_model

    cfg = validate_config(base_cfg(learning={"kind": "repetitive"}))
    blind = SimDriver(cfg.driver, cfg.period_s)
    blind.channels = tuple(c for c in blind.channels if c != "displacement_um")
    with pytest.raises(ConfigError, match=r"learning' is on, but driver 'sim' provides no 'displacement_um' channel"):
        ControllerManager(cfg, model=load_model(cfg.model), driver=blind)


def test_a_freeze_that_lasts_across_periods_keeps_the_time_it_began():
    """'FROZEN since t=3.34 s' became 'since t=9.00 s' for one unbroken freeze (a new user's sweep,
    2026-11-30): the start was taken again at every period's end."""
    ln = RepetitiveLearner(ON, 1000.0, 0.25)
    feed(ln, 2, lambda t: jitter(t))                                      # learning along
    t = feed(ln, 3, lambda t: math.nan, t0=0.5)                           # then no reading, for three periods
    status = ln.status()
    assert "missing or NaN" in status["frozen_reason"] and status["frozen_since_s"] == pytest.approx(0.5)
    feed(ln, 1, lambda t: jitter(t), t0=t)                                # a clean period, then frozen again
    feed(ln, 1, lambda t: math.nan, t0=t + 0.25)
    assert ln.status()["frozen_since_s"] == pytest.approx(t + 0.25)
