"""Current tracking (`current_not_following`): the amplifier's measured current against the command
through its lag. The monitor alone (a lagged command within the tolerance never trips, a departure
as long as the hold always does, a shorter one never); the simulated rig with tracking on (a
full-range slew-limited run, a fast sine, a slow amplifier with its lag configured: no fault); the
Modbus TCP emulator with its amplifier switched off, or its current reading stuck at 0, mid-run
(the fault within the hold and a few ticks, the safe current, the status naming it); the config's
keys, defaults and messages."""

from __future__ import annotations

import math
import re
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings, strategies as st

from gma_ffc.cli import main
from gma_ffc.control import safety
from gma_ffc.control.config import DEFAULT_HOLD_S, DEFAULT_LAG_S, validate_config
from gma_ffc.control.current_tracking import CurrentTracker, hold_ticks
from gma_ffc.control.manager import ControllerManager
from gma_ffc.control.reference import Playback
from gma_ffc.drivers.base import CURRENT
from gma_ffc.errors import ConfigError
from gma_ffc.recordings import read_recording
from gma_ffc.service.status import faults_of
from gma_ffc.sil import cached_sdpi_and_mpi

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "config" / "models" / "sim_sdpi.yaml"
REALISTIC = ROOT / "hil_sim" / "configs" / "realistic.yaml"     # amplifier at 1 kHz, sensor noise: every effect on
NAME = safety.CURRENT_NOT_FOLLOWING


# ---- the monitor alone ---------------------------------------------------------------------------
def lagged(commands, alpha, start):
    """The expected current before each tick: the previous ticks' commands through the lag."""
    out, e = [], start
    for k, c in enumerate(commands):
        if k:
            e += (commands[k - 1] - e) * alpha
        out.append(e)
    return out


COMMANDS = st.lists(st.floats(0.0, 3.0), min_size=1, max_size=300)
PERIODS = st.sampled_from([1e-3, 2e-3, 4e-3, 5e-3])
LAGS = st.sampled_from([0.0, DEFAULT_LAG_S, 1e-3, 5e-3, 0.03])


@settings(max_examples=200, deadline=None)
@given(commands=COMMANDS, period=PERIODS, lag=LAGS, tol=st.floats(0.01, 1.0), hold=st.floats(0.002, 0.2),
       noise=st.lists(st.floats(-1.0, 1.0), min_size=300, max_size=300))
def test_a_lagged_command_within_the_tolerance_never_trips(commands, period, lag, tol, hold, noise):
    tracker = CurrentTracker(tol, lag, hold, period)
    expected = lagged(commands, tracker.alpha, commands[0])
    previous = commands[0]
    for k, c in enumerate(commands):
        measured = expected[k] + (0.999 * tol * noise[k] if k else 0.0)   # anywhere within the tolerance (the
                                                                          # lag starts at the first reading)
        assert tracker.update(measured, previous) == ""
        previous = c


@settings(max_examples=200, deadline=None)
@given(period=PERIODS, hold=st.floats(0.002, 0.2), before=st.integers(1, 50), extra=st.integers(0, 20),
       level=st.floats(0.5, 3.0), missing=st.booleans())
def test_a_departure_as_long_as_the_hold_always_trips_on_its_last_tick(period, hold, before, extra, level, missing):
    tracker = CurrentTracker(0.3, DEFAULT_LAG_S, hold, period)
    n = hold_ticks(hold, period)
    assert n * period >= hold - 1e-12 and (n - 1) * period < hold or n == 2
    for _ in range(before):                                   # following the command
        assert tracker.update(level, level) == ""
    measured = math.nan if missing else 0.0                   # off (nothing flows), or no reading at all
    results = [tracker.update(measured, level) for _ in range(n + extra)]
    assert results[:n - 1] == [""] * (n - 1)
    assert set(results[n - 1:]) == {NAME}
    assert "current_tracking.tolerance_A (0.3 A)" in tracker.message() or missing


@settings(max_examples=200, deadline=None)
@given(period=PERIODS, hold=st.floats(0.002, 0.2), runs=st.lists(st.integers(1, 200), min_size=1, max_size=10),
       level=st.floats(0.5, 3.0))
def test_departures_shorter_than_the_hold_never_trip(period, hold, runs, level):
    tracker = CurrentTracker(0.3, 0.0, hold, period)
    n = hold_ticks(hold, period)
    for run in runs:
        for _ in range(min(run, n - 1)):                      # shorter than the hold ...
            assert tracker.update(0.0, level) == ""
        assert tracker.update(level, level) == ""             # ... and back within the tolerance


def test_the_expected_current_is_the_command_through_the_lag_and_starts_at_the_reading():
    tracker = CurrentTracker(0.3, 1e-3, 0.05, 1e-3)
    assert tracker.alpha == pytest.approx(1.0 - math.exp(-1.0))
    assert tracker.update(0.2, 0.0) == "" and tracker.expected == 0.2     # the lag starts where the amplifier is
    tracker.update(0.2 + (2.0 - 0.2) * tracker.alpha, 2.0)
    assert tracker.expected == pytest.approx(0.2 + 1.8 * (1.0 - math.exp(-1.0)))
    tracker.restart()
    assert math.isnan(tracker.expected) and tracker.run == 0
    assert hold_ticks(0.05, 1e-3) == 50 and hold_ticks(0.05, 0.04) == 2 and hold_ticks(0.001, 1e-3) == 2


def test_the_message_gives_measured_expected_tolerance_and_what_to_check():
    tracker = CurrentTracker(0.3, DEFAULT_LAG_S, 0.01, 1e-3)
    tracker.update(1.5, 1.5)
    while not tracker.update(0.0, 1.5):
        pass
    text = tracker.message()
    for part in ("measured current 0 A", "expected 1.5 A", "current_tracking.tolerance_A (0.3 A)", "10 ticks",
                 "amplifier is enabled", "coil is wired", "current limit", "current_tracking.lag_s"):
        assert part in text, text


# ---- the simulated rig, tracking on: no false alarm --------------------------------------------------
@pytest.fixture(scope="module")
def models(request):
    return cached_sdpi_and_mpi(request.config.cache.mkdir("gma_ffc_sil_models"))


def sim_cfg(reference, plant=REALISTIC, rate=1000, slew=500.0, **extra):
    return validate_config({"rate_hz": rate, "clock": "simulated", "model": str(MODEL),
                            "driver": {"kind": "sim", "load_mass_kg": 15.3,
                                       "plant_config": None if plant is None else str(plant)},
                            "reference": reference,
                            "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": slew},
                            **{"telemetry": {"path": None}, **extra}})


@pytest.mark.parametrize("slew", [500.0, 30.0], ids=["fast slew", "slew ramps longer than the hold"])
def test_a_full_range_slew_limited_run_never_trips(models, slew, tmp_path):
    """A reference stepping between far below and far above the stroke: the command is cut to 0 A
    and 3 A and crosses the whole range at the slew limit, every 0.25 s; a slow slew makes each
    crossing (0.1 s) longer than the hold."""
    cfg = sim_cfg({"kind": "sine", "frequency_hz": 2.0, "amplitude_um": 1.0}, slew=slew,
                  telemetry={"path": str(tmp_path / "steps.csv")})
    ctrl = ControllerManager(cfg, model=models[0])
    t = np.arange(0, 2.0, 1e-3)
    ctrl.setup.law.reference = Playback(t, np.where((t // 0.25) % 2 == 0, -20.0, 200.0))
    s = ctrl.run(duration_s=1.5)
    assert s["state"] == "stopped" and NAME not in s["faults"], s["fault_messages"]
    assert s["current_tracking"]["enabled"] and s["current_measured"]
    cmd = read_recording(cfg.telemetry["path"]).columns["current_cmd_A"]
    assert cmd.min() == 0.0 and cmd.max() == 3.0                            # the whole range, both ways
    assert np.abs(np.diff(cmd)).max() == pytest.approx(slew * cfg.period_s)  # at the slew limit


@pytest.mark.parametrize("plant", [None, REALISTIC], ids=["ideal amplifier", "1 kHz amplifier with noise"])
@pytest.mark.parametrize("rate", [1000, 200])
def test_a_fast_sine_never_trips(models, plant, rate):
    cfg = sim_cfg({"kind": "sine", "frequency_hz": 60.0, "amplitude_um": 20.0, "offset_um": 20.0}, plant=plant,
                  rate=rate)
    s = ControllerManager(cfg, model=models[0]).run(duration_s=1.0)
    assert s["state"] == "stopped" and NAME not in s["faults"], s["fault_messages"]


def test_an_amplifier_slower_than_lag_s_trips_and_its_own_lag_clears_it(models, tmp_path):
    """The comparison is lag-aware: a 5 Hz current loop lags a 10 Hz sine by most of an ampere, the
    fault with the default lag_s; with lag_s set to its time constant, not a tick of departure."""
    slow = tmp_path / "slow_amplifier.yaml"
    slow.write_text("amplifier: {enabled: true, bandwidth_hz: 5.0}\nnoise: {enabled: true}\n")
    ref = {"kind": "sine", "frequency_hz": 10.0, "amplitude_um": 15.0, "offset_um": 20.0}
    s = ControllerManager(sim_cfg(ref, plant=slow), model=models[0]).run(duration_s=1.0)
    assert s["state"] == "fault" and NAME in s["faults"]
    assert "set current_tracking.lag_s to its time constant" in s["exit_reason"]
    tau = 1.0 / (2.0 * math.pi * 5.0)
    ctrl = ControllerManager(sim_cfg(ref, plant=slow, current_tracking={"lag_s": tau}), model=models[0])
    s = ctrl.run(duration_s=1.0)
    assert s["state"] == "stopped" and not s["faults"], s["fault_messages"]


def test_an_amplifier_at_its_own_limit_trips_and_null_tolerance_switches_it_off(models):
    """Limits beyond the simulated amplifier's 4 A: the command at 5 A gets 4 A, 1 A short for as long
    as it is held (the fault is right); `tolerance_A: null` is no tracking at all, and the status says so."""
    ref = {"kind": "sine", "frequency_hz": 0.5, "amplitude_um": 0.0, "offset_um": 90.0}   # far beyond the stroke
    over = {"limits": {"current_min_A": 0.0, "current_max_A": 5.0, "slew_A_per_s": 500.0},
            "stress": {"out_of_range": "clamp"}}
    s = ControllerManager(sim_cfg(ref, plant=None, **over), model=models[0]).run(duration_s=0.5)
    assert s["state"] == "fault" and NAME in s["faults"] and "measured current 4 A" in s["exit_reason"]
    off = sim_cfg(ref, plant=None, current_tracking={"tolerance_A": None}, **over)
    assert off.current_tracking["tolerance_A"] is None
    s = ControllerManager(off, model=models[0]).run(duration_s=0.5)
    assert s["state"] == "stopped" and NAME not in s["faults"]
    assert s["current_tracking"] == {"enabled": False, "why": "current_tracking.tolerance_A is null"}


def test_negative_limits_need_a_bipolar_simulated_amplifier(models, tmp_path):
    """hil_sim's amplifier is unipolar (0 to 4 A): limits that allow -1 A on it command a current it
    cannot give, and the check says so; a plant config with a bipolar amplifier gives it, no fault."""
    ref = {"kind": "sine", "frequency_hz": 1.0, "amplitude_um": 2.0, "offset_um": -10.0}   # below the stroke: -1 A
    over = {"limits": {"current_min_A": -1.0, "current_max_A": 3.0, "slew_A_per_s": 500.0}}
    s = ControllerManager(sim_cfg(ref, plant=None, **over), model=models[0]).run(duration_s=0.5)
    assert s["state"] == "fault" and NAME in s["faults"] and "expected -1 A" in s["exit_reason"], s["exit_reason"]
    bipolar = tmp_path / "bipolar.yaml"
    bipolar.write_text("amplifier: {min_current_A: -4.0, max_current_A: 4.0}\n")
    cfg = sim_cfg(ref, plant=bipolar, telemetry={"path": str(tmp_path / "bipolar.csv")}, **over)
    s = ControllerManager(cfg, model=models[0]).run(duration_s=0.5)
    assert s["state"] == "stopped" and NAME not in s["faults"], s["fault_messages"]
    assert read_recording(cfg.telemetry["path"]).columns["current_A"].min() == pytest.approx(-1.0, abs=0.01)


def test_a_driver_that_reads_no_current_is_not_tracked(models):
    from gma_ffc.drivers.sim import SimDriver

    class NoCurrent(SimDriver):
        def open(self):
            super().open()
            self.channels = tuple(c for c in self.channels if c != CURRENT)

        def read(self, inputs):
            super().read(inputs)
            inputs.current_A = 0.0            # whatever it holds, it is not a reading

    cfg = sim_cfg({"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 12.0, "offset_um": 15.0}, plant=None)
    s = ControllerManager(cfg, model=models[0], driver=NoCurrent(cfg.driver, cfg.period_s)).run(duration_s=0.5)
    assert s["state"] == "stopped" and not s["faults"]
    assert s["current_tracking"] == {"enabled": False, "why": "the driver reads no current"}


def test_the_status_says_the_tracking_the_loop_ran_with(models):
    """The status and the loop read one fact, the manager's `reads_current`, taken from the driver's
    channels at start: the status recomputed it from the driver's channels as they were when asked,
    and said "the driver reads no current" after a run the loop had tracked, once a driver forgot
    its channels on close."""
    from gma_ffc.drivers.sim import SimDriver

    class ForgetsItsChannelsOnClose(SimDriver):
        def close(self):
            super().close()
            self.channels = ()

    cfg = sim_cfg({"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 12.0, "offset_um": 15.0}, plant=None)
    ctrl = ControllerManager(cfg, model=models[0], driver=ForgetsItsChannelsOnClose(cfg.driver, cfg.period_s))
    assert ctrl.reads_current and ctrl.status()["current_tracking"]["enabled"]      # before a run: the driver's word
    s = ctrl.run(duration_s=0.3)
    assert s["state"] == "stopped" and not s["faults"] and ctrl.driver.channels == ()
    assert ctrl.reads_current and s["current_tracking"]["enabled"] and s["current_measured"]


# ---- the Modbus TCP emulator: the amplifier off mid-run ------------------------------------------------
@pytest.fixture(scope="module")
def strong_models(request):
    from test_drivers_modbus import STRONG      # the emulator's rig, as the Modbus SIL tests run it

    return cached_sdpi_and_mpi(request.config.cache.mkdir("gma_ffc_sil_models"), STRONG)


@pytest.mark.realtime     # real time through a socket: the detection is counted in ticks, the run needs a free core
@pytest.mark.parametrize("how", ["output switched off", "current reading stuck at 0"])
def test_an_amplifier_switched_off_mid_run_is_the_fault_within_the_hold(strong_models, how, tmp_path):
    from test_drivers_modbus import Bench, wait_ticks

    bench = Bench("tcp", "amplifier_int16.yaml", noise=True)
    try:
        rate = 200
        # a slow, shallow sine: the command stays well above the tolerance (0.3 A) all the while
        cfg = bench.cfg(tmp_path, "off", rate, reference={"kind": "sine", "frequency_hz": 0.5, "amplitude_um": 3.0,
                                                           "offset_um": 18.0, "lead_s": 1.5 / rate})
        ctrl = ControllerManager(cfg, model=strong_models[0])
        result = {}
        th = threading.Thread(target=lambda: result.setdefault("s", ctrl.run(duration_s=4.0)))
        th.start()
        try:
            wait_ticks(ctrl, th, int(0.6 * rate))
            at_tick = ctrl.stats.count
            if how == "output switched off":
                bench.rig.set_output(False)          # another program (or a trip) switches the amplifier off
            else:
                bench.rig.faults.set("out_of_range:current_A=0")
            th.join(timeout=10.0)
        finally:
            ctrl.request_stop()
            th.join(timeout=10.0)
        s = result["s"]
    finally:
        bench.emu.stop()
    assert s["state"] == "fault" and s["faults"] == [NAME], s["fault_messages"]
    raised = next(h for h in s["fault_history"] if h["fault"] == NAME)
    n_hold = hold_ticks(cfg.current_tracking["hold_s"], cfg.period_s)
    assert at_tick < raised["tick"] <= at_tick + n_hold + 4          # within the hold and a few ticks
    assert re.match(rf"{NAME}: the amplifier's measured current -?0(\.00\d*)? A departed from the expected 1\.\d+ A",
                    s["exit_reason"]), s["exit_reason"]         # the reading (with its noise) vs the expected
    assert "current_tracking.tolerance_A (0.3 A)" in s["exit_reason"]
    assert NAME in s["fault_messages"] and "amplifier is enabled" in s["fault_messages"][NAME]
    assert faults_of(s)[0].startswith(f"{NAME}: the amplifier's measured current")      # as `gma-ffc status` lists it
    assert bench.rig.last_setpoint_A == 0.0 and not bench.rig.output_enabled     # the safe current, output off
    assert s["current_cmd_A"] == 0.0 and s["at_safe_current"]
    rec = read_recording(cfg.telemetry["path"])
    assert rec.columns["current_cmd_A"][-1] == 0.0                    # the fault tick logged with the safe command
    assert rec.columns["current_cmd_A"][: at_tick].min() > 0.5        # it was driving all along before


# ---- the config ---------------------------------------------------------------------------------------
BASE = {"rate_hz": 500, "model": "m.yaml", "driver": {"kind": "sim"},
        "reference": {"kind": "sine", "frequency_hz": 3, "amplitude_um": 10},
        "limits": {"current_min_A": 0.5, "current_max_A": 2.5, "slew_A_per_s": 100, "safe_current_A": 0.5}}


def test_the_defaults_and_their_resolution():
    cfg = validate_config(BASE)
    assert cfg.current_tracking == {"tolerance_A": 0.2, "lag_s": DEFAULT_LAG_S, "hold_s": DEFAULT_HOLD_S}
    assert DEFAULT_LAG_S == pytest.approx(1.59e-4, rel=1e-2)          # hil_sim's 1 kHz amplifier
    slow = validate_config({**BASE, "rate_hz": 20})
    assert slow.current_tracking["hold_s"] == pytest.approx(0.1)       # two ticks at least
    given_ = validate_config({**BASE, "current_tracking": {"tolerance_A": 0.05, "lag_s": 0, "hold_s": 0.2}})
    assert given_.current_tracking == {"tolerance_A": 0.05, "lag_s": 0.0, "hold_s": 0.2}
    assert validate_config({**BASE, "current_tracking": {"tolerance_A": "auto"}}).current_tracking["tolerance_A"] == 0.2


@pytest.mark.parametrize("key,value,message", [
    ("tolerance_A", -0.1, r"'current_tracking.tolerance_A' must be a current in A above 0 \(e.g. 0.3\), 'auto'"),
    ("tolerance_A", 0, r"'current_tracking.tolerance_A' must be a current in A above 0"),
    ("tolerance_A", float("nan"), r"'current_tracking.tolerance_A' must be a current .* got nan"),
    ("tolerance_A", "lots", r"'current_tracking.tolerance_A' must be a current .* or null \(no current tracking\), "
                            r"got 'lots'"),
    ("tolerance_A", True, r"'current_tracking.tolerance_A' must be a current"),
    ("lag_s", -1e-3, r"'current_tracking.lag_s' must be >= 0"),
    ("lag_s", float("nan"), r"'current_tracking.lag_s' must be finite"),
    ("lag_s", "slow", r"'current_tracking.lag_s' must be a number, got 'slow'"),
    ("hold_s", 0, r"'current_tracking.hold_s' must be > 0"),
    ("hold_s", float("inf"), r"'current_tracking.hold_s' must be finite"),
    ("hold_s", "long", r"'current_tracking.hold_s' must be a number"),
    ("hold_s", 0.003, r"'current_tracking.hold_s' \(0.003 s\) must hold at least 2 ticks at rate_hz 500, so that one "
                      r"late reading cannot trip it: make it 0.004 s or more"),
    ("tolerance", 0.3, r"'current_tracking.tolerance' is unknown \(did you mean 'current_tracking.tolerance_A'\?\)"),
])
def test_bad_values_name_the_key_and_what_to_write(key, value, message):
    with pytest.raises(ConfigError, match=message):
        validate_config({**BASE, "current_tracking": {key: value}})


@pytest.mark.parametrize("text,message", [
    ("{tolerance_A: -0.2}", "config key 'current_tracking.tolerance_A' must be a current in A above 0"),
    ("{tolerance_A: .nan}", "config key 'current_tracking.tolerance_A' must be a current in A above 0"),
    ("{hold_s: soon}", "config key 'current_tracking.hold_s' must be a number, got 'soon'"),
    ("{lag_s: -1}", "config key 'current_tracking.lag_s' must be >= 0, got -1.0"),
])
def test_a_bad_value_in_a_config_file_is_one_line_and_exit_2(tmp_path, capsys, text, message):
    data = yaml.safe_load((ROOT / "config" / "sim.yaml").read_text())
    data.update(model=str(MODEL), clock="simulated", telemetry={"path": None}, output_dirs=[],
                current_tracking=yaml.safe_load(text))
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    assert main(["run", "--config", str(path), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err, err


def test_the_fault_has_its_row_writing_the_safe_current_at_once():
    row = safety.FAULT_ACTIONS[NAME]
    assert (row.output, row.then, row.exit_state) == ("immediate", "stop", "fault")
