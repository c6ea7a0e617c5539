"""The controller watching its own model, end to end (issue 30).

* The rig drifting: the simulated GMA behind the Modbus TCP emulator runs with nothing missing for
  60 s, then its coil heats (Joule heating switched on in the plant). In order: the monitor is ok,
  then drifting; the background diagnosis (a real `gma-ffc diagnose` child) names the heating;
  `gma-ffc status --json` shows it with the report's path; `gma-ffc reload --model` with the
  extended model brings the residual ratio back to ok.
* The same heating under the shipped config/sim.yaml's narrow tracking sine (0.36-1.8 A of the
  model's 0-3 A), on the in-process simulated rig: the diagnosis is handed the play state at its
  window's first sample, so it scores the window and names the heating (with the state unknown
  it scored none of it: the drive never sweeps far enough to forget the start).
* Nothing changing: ok for 10 minutes of loop time, never drifting.
* Metrics: scraped over HTTP while the loop runs, parsed as Prometheus text.

Time is simulated where the real-time path is not what is tested: the loop, the emulated rig and
the plant share one simulated clock (the protocol, the driver and the service are real), and the
loop is held while the diagnosis runs, as if it took no time on the rig.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

import pytest
import yaml

from gma_ffc.control.config import validate_config
from gma_ffc.control.manager import ControllerManager
from gma_ffc.control.scheduler import SimulatedClock
from gma_ffc.modelio import save_model
from gma_ffc.recordings import read_recording
from gma_ffc.registers import load_register_map
from gma_ffc.service.paths import RuntimePaths
from gma_ffc.service.runner import Service
from gma_ffc.service.watch import ServiceWatch
from gma_ffc.sil import cached_sdpi_and_mpi
from hil_sim import kernels as K
from hil_sim.emulators.modbus import ModbusEmulator
from hil_sim.emulators.rig import EmulatedRig
from hil_sim.plant import GMAPlant, PlantConfig

RATE = 250.0
STRESS = -15.2
# Full stroke: the drive sweeps ~0.05-2.9 A of the model's 0-3 A, so every play of the model is
# swept each period and a window of telemetry says what state the hysteresis is in (diagnose
# does not score a recording until it has; see docs/monitor.md).
REFERENCE = {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 25.5, "offset_um": 26.0, "lead_s": 1.0 / RATE}
LIMITS = {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0}
# The shipped config/sim.yaml's tracking reference and model: 3-27 um, the drive 0.36-1.8 A.
SHIPPED_MODEL = Path(__file__).resolve().parents[1] / "config" / "models" / "sim_sdpi.yaml"
NARROW = {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 12.0, "offset_um": 15.0, "phase_deg": -90.0,
          "lead_s": 1.0 / RATE}


class ScriptedClock(SimulatedClock):
    """The simulated clock, with actions at given loop times and a hold the test can set."""

    def __init__(self, events=()):
        super().__init__()
        self.events = sorted(events, key=lambda e: e[0])
        self.hold = threading.Event()

    def sleep_until(self, deadline):
        while self.events and self.events[0][0] <= deadline:
            self.events.pop(0)[1]()
        while self.hold.is_set():
            time.sleep(0.01)
        super().sleep_until(deadline)


@pytest.fixture(scope="module")
def model(request):
    return cached_sdpi_and_mpi(request.config.cache.mkdir("gma_ffc_sil_models"), None)[0]


@pytest.fixture(scope="module")
def model_file(model, tmp_path_factory):
    """The model as the config names it: a service refuses a config whose model file is missing,
    before anything starts (the controller here is built around the model object itself)."""
    path = tmp_path_factory.mktemp("model") / "sdpi.yaml"
    save_model(model, path)
    return str(path)


def noisy_plant():
    pc = PlantConfig().with_effects(["noise"])
    plant = GMAPlant(pc, seed=5)
    plant.reset(pc.mass_for_stress(STRESS))
    return plant


def short_dir():
    """Unix socket paths are short: a runtime directory under /tmp."""
    return Path(tempfile.mkdtemp(prefix="gmaw-", dir="/tmp"))


def cli(*args, timeout=60):
    out = subprocess.run([sys.executable, "-m", "gma_ffc.cli", *args], capture_output=True, text=True, timeout=timeout)
    assert out.returncode == 0, out.stderr
    return out.stdout


def wait(cond, limit_s, what):
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        value = cond()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def start_service(cfg, ctrl, runtime):
    svc = Service("unused.yaml", runtime=runtime, load_config=lambda p: cfg, make_controller=lambda c: ctrl,
                  install_signal_handlers=False)
    result = {}
    thread = threading.Thread(target=lambda: result.setdefault("code", svc.run()), daemon=True)
    thread.start()
    return svc, thread


@pytest.mark.slow
@pytest.mark.realtime   # the Modbus requests have a 0.5 s wall-clock timeout: a busy machine can fault a tick
def test_heating_rig_drifts_diagnosis_names_it_and_the_extended_model_fits_again(tmp_path, model, model_file):
    plant = noisy_plant()
    heating_at = 60.0
    clock = ScriptedClock([(heating_at, lambda: plant._p.__setitem__(K.P_ON_THERMAL, 1.0))])
    rig = EmulatedRig(plant, dt_s=1e-3, max_current_A=3.5, clock=clock.now)
    rmap = load_register_map("hil_sim/configs/devices/amplifier_int16.yaml")
    emu = ModbusEmulator(rig, rmap, transport="tcp", port=0)
    host, port = emu.start()
    runtime = RuntimePaths(short_dir())
    try:
        cfg = validate_config({
            "rate_hz": RATE, "model": model_file, "reference": REFERENCE, "limits": LIMITS, "watchdog_s": 1.0,
            "driver": {"kind": "modbus", "devices": {"amp": {"transport": "tcp", "host": host, "port": port,
                                                             "timeout_s": 0.5, "register_map": rmap.to_dict()}}},
            "telemetry": {"path": str(tmp_path / "telemetry.csv")},
            "monitor": {"window_s": 30.0, "trigger_s": 10.0, "max_per_hour": 2, "state_dir": str(tmp_path / "state")}})
        ctrl = ControllerManager(cfg, model=model, clock=clock)
        svc, thread = start_service(cfg, ctrl, runtime)
        seen = []

        def fit():
            s = ctrl.status().get("monitor") or {}
            if s.get("state") and (not seen or seen[-1][0] != s["state"]):
                seen.append((s["state"], s.get("since_s")))
            return s

        wait(lambda: fit().get("state") == "ok", 120, "the monitor to be ok")
        drifting = wait(lambda: fit().get("state") == "drifting" and fit(), 300, "the monitor to drift")
        started = wait(lambda: (svc.status().get("diagnosis") or {}).get("running"), 120, "the diagnosis to start")
        clock.hold.set()                                    # the rig waits while the diagnosis runs
        assert clock.t - drifting["since_s"] >= cfg.monitor["trigger_s"] - 1e-9
        last = wait(lambda: (svc.status().get("diagnosis") or {}).get("last"), 600, "the diagnosis to finish")
        status = json.loads(cli("status", "--json", "--runtime-dir", str(runtime.directory)))
        print(cli("status", "--runtime-dir", str(runtime.directory)))       # the screen docs/monitor.md shows
        clock_at_reload = clock.t
        cli("reload", "--model", last["extended_model"], "--runtime-dir", str(runtime.directory))
        clock.hold.clear()
        ok = wait(lambda: clock.t > clock_at_reload + 31 and fit().get("state") == "ok" and fit(), 300,
                  "the extended model to fit")
        # (not `gma-ffc stop`: the service is this test's process, which SIGTERM would end)
        svc.request_stop("test over")
        thread.join(timeout=60)
    finally:
        clock.hold.clear()
        emu.stop()
    # in order: ok with nothing missing, drifting once the coil heats, ok again with the extended model
    states = [s for s, _ in seen if s != "unknown"]          # unknown: before the first window, after the reload
    assert seen[0][0] == "unknown" and states == ["ok", "drifting", "ok"], seen
    assert drifting["since_s"] > heating_at and drifting["ratio"] > 3.0
    assert started["recording"].startswith(str(tmp_path / "state" / "diagnoses"))
    assert last["outcome"] == "effects_named" and "thermal_drift" in last["effects"], last
    shown = status["diagnosis"]["last"]
    assert shown["report"] == last["report"] and Path(shown["report"]).is_file()
    assert status["monitor"]["state"] == "drifting"
    assert ok["ratio"] < 2.0 and "replayed from the start of the recording" in ok["prediction"], ok
    assert not thread.is_alive()


@pytest.mark.slow
def test_a_narrow_tracking_run_that_heats_gets_a_diagnosis_that_scores_its_window_and_names_the_heating(tmp_path):
    """The lab's defect: under the shipped narrow sine, the background diagnosis could score none of
    its 30 s window (the drive never sweeps the model's range, so the unknown hysteresis state at
    the window's start never stops mattering) and never concluded. The service's parts (the
    controller's model-fit monitor, `ServiceWatch` and its background diagnosis, a real `gma-ffc
    diagnose` child) on the simulated rig, the coil heating from 60 s; the service's poll comes
    once a second of loop time, the loop waiting for the monitor to catch up, as if it took no time."""
    plant_yaml = tmp_path / "plant.yaml"
    plant_yaml.write_text(yaml.safe_dump({"noise": {"enabled": True}}))
    cfg = validate_config({
        "rate_hz": RATE, "clock": "simulated", "model": str(SHIPPED_MODEL), "reference": NARROW, "limits": LIMITS,
        "driver": {"kind": "sim", "plant_config": str(plant_yaml), "seed": 5,
                   "load_mass_kg": PlantConfig().mass_for_stress(STRESS)},
        "telemetry": {"path": None},
        "monitor": {"window_s": 30.0, "trigger_s": 10.0, "max_per_hour": 2, "state_dir": str(tmp_path / "state")}})
    holder = {}

    def service_poll(at_s):
        def poll():
            def caught_up():
                m = holder["ctrl"].status()["monitor"]
                return m if (m.get("t_s") or -1.0) >= at_s - 2.0 / RATE else None
            wait(caught_up, 60, f"the monitor to reach {at_s} s")
            holder["watch"].poll(holder["ctrl"].status())
        return poll

    def heat():
        holder["ctrl"].driver.plant._p[K.P_ON_THERMAL] = 1.0

    clock = ScriptedClock([(60.0, heat)] + [(float(k), service_poll(float(k))) for k in range(1, 121)])
    ctrl = holder["ctrl"] = ControllerManager(cfg, clock=clock)
    watch = holder["watch"] = ServiceWatch(cfg, ctrl)
    try:
        assert ctrl.run(duration_s=120.5)["ok"]
        bg = watch.diagnosis
        wait(lambda: bg.poll("ok", None, None) or bg.child is None, 300, "the diagnosis to finish")
    finally:
        watch.close()
    last = bg.status()["last"]
    assert last is not None and bg.status()["in_last_hour"] == 1, bg.status()
    folder = Path(last["folder"])
    window = read_recording(folder / "window.csv")
    assert 0.2 < window.drive.min() and window.drive.max() < 2.0        # the narrow run: 0.36-1.8 A of 0-3 A
    (state,) = json.loads((folder / "diagnosis.json").read_text())["initial_state"]
    assert state["how"].startswith("known") and state["scored_share"] == 1.0, state
    assert (folder / "initial_state.json").is_file()
    assert last["scored"] and last["outcome"] == "effects_named" and "thermal_drift" in last["effects"], last


# real time: each of the 120 samples waits for the monitor, which runs at 2 Hz of wall time, so the
# test is ~60 s of waiting and ~5 s of CPU; on the real-time worker it leaves the others' cores busy
@pytest.mark.realtime
def test_nothing_changing_stays_ok_for_ten_minutes(tmp_path, model, model_file):
    """The same rig with nothing switched on: sampled every 5 s of loop time, never drifting."""
    samples = []
    plant_yaml = tmp_path / "plant.yaml"
    plant_yaml.write_text(yaml.safe_dump({"noise": {"enabled": True}}))
    cfg = validate_config({
        "rate_hz": RATE, "clock": "simulated", "model": model_file, "reference": REFERENCE, "limits": LIMITS,
        "driver": {"kind": "sim", "plant_config": str(plant_yaml), "seed": 5,
                   "load_mass_kg": PlantConfig().mass_for_stress(STRESS)},
        "telemetry": {"path": None}, "monitor": {"window_s": 30.0}})
    holder = {}

    def sample(at_s):
        # The loop waits here; the monitor is fed by the telemetry writer's thread, which on a busy
        # machine lags the simulated clock: sample once it has seen the rows up to this tick.
        def caught_up():
            m = holder["c"].status()["monitor"]
            return m if (m.get("t_s") or -1.0) >= at_s - 2.0 / RATE else None
        return lambda: samples.append(wait(caught_up, 60, f"the monitor to reach {at_s} s"))

    clock = ScriptedClock([(5.0 * k, sample(5.0 * k)) for k in range(1, 121)])
    ctrl = holder["c"] = ControllerManager(cfg, model=model, clock=clock)
    summary = ctrl.run(duration_s=600.5)
    assert summary["ok"]
    states = [s["state"] for s in samples]
    assert states[:5] == ["unknown"] * 5 and set(states[6:]) == {"ok"}, states
    assert max(s["ratio"] for s in samples[6:]) < 2.0


def test_metrics_are_scraped_while_the_loop_runs(tmp_path, model, model_file):
    from prometheus_client.parser import text_string_to_metric_families

    plant_yaml = tmp_path / "plant.yaml"
    plant_yaml.write_text(yaml.safe_dump({"noise": {"enabled": True}}))
    cfg = validate_config({
        "rate_hz": RATE, "model": model_file, "reference": REFERENCE, "limits": LIMITS,
        "driver": {"kind": "sim", "plant_config": str(plant_yaml), "load_mass_kg": PlantConfig().mass_for_stress(STRESS)},
        "telemetry": {"path": None}, "monitor": {"window_s": 1.0, "on_drift": "warn"}, "metrics": {"port": 0}})
    ctrl = ControllerManager(cfg, model=model)
    runtime = RuntimePaths(short_dir())
    svc, thread = start_service(cfg, ctrl, runtime)
    try:
        url = wait(lambda: (svc.status().get("metrics") or {}).get("url"), 60, "the metrics server")
        wait(lambda: (ctrl.status().get("monitor") or {}).get("state") == "ok", 60, "a whole window")
        time.sleep(1.5)                                 # the service's next snapshot
        scrapes = []
        for _ in range(3):
            with urllib.request.urlopen(url, timeout=5) as reply:
                scrapes.append({(s.name, tuple(sorted(s.labels.items()))): s.value
                                for f in text_string_to_metric_families(reply.read().decode()) for s in f.samples})
            time.sleep(1.1)
    finally:
        svc.request_stop("test over")
        thread.join(timeout=30)
    first, last = scrapes[0], scrapes[-1]
    assert last[("gma_ffc_ticks_total", ())] > first[("gma_ffc_ticks_total", ())] > 0       # the loop ran meanwhile
    assert last[("gma_ffc_model_fit_state", (("state", "ok"),))] == 1
    assert 0 < last[("gma_ffc_model_residual_ratio", ())] < 2
    assert 0 < last[("gma_ffc_period_jitter_seconds", (("quantile", "0.99"),))] < 0.05
    assert ("gma_ffc_tracking_rms_meters", ()) in last and ("gma_ffc_overruns_total", ()) in last
