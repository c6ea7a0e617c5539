"""The whole stack through the SCPI serial amplifier emulator (pty, pyserial, real time, short runs)."""

from __future__ import annotations

import threading
import time

from pathlib import Path

import pytest

from gma_ffc.control.config import validate_config
from gma_ffc.control.manager import ControllerManager
from gma_ffc.sil import cached_sdpi_and_mpi, tracking_rms_um
from gma_ffc.errors import ConfigError
from gma_ffc.recordings import read_recording
from hil_sim.emulators.rig import EmulatedRig
from hil_sim.emulators.scpi import SerialAmplifierEmulator
from hil_sim.plant import GMAPlant, PlantConfig

# Through a transport the loop runs at 100-250 Hz, and its discretisation error (~0.5 um) is as
# large as the default rig's paper-like stress effect. These tests check that stress reaches the
# model through the protocol, so they run the strongly stress-sensitive rig, where it decides.
STRONG_PATH = Path(__file__).parents[1] / "hil_sim" / "configs" / "strong_stress.yaml"
STRONG = PlantConfig.from_yaml(STRONG_PATH)
QUERIES = {"force_N": "MEAS:FORC?", "current_A": "MEAS:CURR?", "displacement_um": "MEAS:DISP?"}


@pytest.fixture(scope="module")
def models(request):
    return cached_sdpi_and_mpi(request.config.cache.mkdir("gma_ffc_sil_models"), STRONG)


@pytest.fixture
def amplifier():
    started = []

    def make(stress=-15.2, noise=False):
        pc = PlantConfig.from_yaml(STRONG_PATH)
        pc.noise.enabled = noise
        plant = GMAPlant(pc, seed=0)
        plant.reset(pc.mass_for_stress(stress))
        rig = EmulatedRig(plant, dt_s=1e-3, max_current_A=3.5)
        emu = SerialAmplifierEmulator(rig)
        started.append(emu)
        return rig, emu.start()

    yield make
    for emu in started:
        emu.stop()


def serial_cfg(tmp_path, name, port, rate_hz=200, **extra):
    data = {"rate_hz": rate_hz, "model": "unused.yaml",
            "driver": {"kind": "serial", "port": port, "timeout_s": 0.2, "init": ["*RST", "*CLS"],
                       "queries": QUERIES},
            "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 12.0, "offset_um": 15.0,
                          "lead_s": 1.5 / rate_hz},
            "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0},
            "telemetry": {"path": str(tmp_path / f"{name}.csv"), "flush_interval_s": 0.2}}
    data.update(extra)
    return validate_config(data)


@pytest.mark.realtime   # the serial link times out on the wall clock (0.2 s): a busy machine can fault a tick
@pytest.mark.parametrize("stress", [-15.2, -19.1])
def test_sil_sdpi_beats_mpi_through_serial(models, amplifier, tmp_path, stress):
    rms = {}
    for name, model in zip(("sdpi", "mpi"), models):
        rig, port = amplifier(stress)
        cfg = serial_cfg(tmp_path, name, port)
        summary = ControllerManager(cfg, model=model).run(duration_s=1.5)
        assert summary["ok"], summary["fault_messages"]
        rms[name] = tracking_rms_um(read_recording(cfg.telemetry["path"]), skip_s=0.5)
        assert rig.last_setpoint_A == 0.0 and not rig.output_enabled
    assert rms["sdpi"] <= 0.5 * rms["mpi"], rms


LINK = {"comms_timeout", "comms_error"}


@pytest.mark.realtime   # as above: a tick can fault before the injection, and the test asserts it does not
@pytest.mark.parametrize("spec,expected", [
    ("silent", {"comms_timeout"}), ("delay:0.6", {"comms_timeout"}), ("garbage", LINK),
    ("exception", LINK), ("drop", LINK), ("stuck:force_N", {"sensor_stale"}),
    ("nan:force_N", {"sensor_nan"}), ("out_of_range:force_N", {"sensor_absurd"}),
])
def test_serial_fault_modes_end_at_safe_current(models, amplifier, tmp_path, spec, expected):
    rig, port = amplifier(noise=True)
    cfg = serial_cfg(tmp_path, "fault", port, comms={"on_fault": "stop"}, sensor={"bad_ticks": 3, "stale_ticks": 40})
    ctrl = ControllerManager(cfg, model=models[0])
    out = {}
    th = threading.Thread(target=lambda: out.setdefault("s", ctrl.run(duration_s=4.0)))
    th.start()
    try:
        end = time.monotonic() + 10.0
        while ctrl.stats.count < 80 and th.is_alive() and time.monotonic() < end:   # 0.4 s of ticks
            time.sleep(0.005)
        rig.faults.set(spec)
        t_fault = time.monotonic()
        while th.is_alive() and not ctrl.faults.active and time.monotonic() - t_fault < 3.0:
            time.sleep(0.005)
        rig.faults.clear()          # the link comes back: the safe write must get through
    finally:
        th.join(timeout=10.0)
    assert not th.is_alive()
    s = out["s"]
    assert s["state"] == "fault" and s["ticks"] >= 80, s["fault_messages"]   # fault after the injection
    assert expected & set(s["faults"]), s["fault_messages"]
    assert "safe_write_failed" not in s["faults"]
    setpoints = rig.history("setpoint")
    assert len(setpoints) > 20 and setpoints[-1].value == 0.0
    assert not rig.output_enabled
    rec = read_recording(cfg.telemetry["path"], require=("time_s", "current_A"))
    assert ctrl.recorder.telemetry.dropped == 0 and len(rec) == ctrl.recorder.telemetry.head >= s["ticks"]
    assert rec.time_s[-1] >= 0.35


def test_serial_config_is_validated():
    base = {"rate_hz": 100, "model": "m.yaml", "reference": {"kind": "sine", "frequency_hz": 3, "amplitude_um": 1},
            "limits": {"current_min_A": 0, "current_max_A": 1, "slew_A_per_s": 10}}
    drv = {"kind": "serial", "port": "/dev/null", "queries": QUERIES}
    with pytest.raises(ConfigError, match=r"driver\.write.*unknown placeholder"):
        validate_config({**base, "driver": {**drv, "write": "CURR {amps}"}})
    with pytest.raises(ConfigError, match=r"driver\.queries\.forc_N"):
        validate_config({**base, "driver": {**drv, "queries": {"forc_N": "MEAS:FORC?"}}})
    with pytest.raises(ConfigError, match="load-cell query"):
        validate_config({**base, "driver": {**drv, "queries": {"current_A": "MEAS:CURR?"}}})
    with pytest.raises(ConfigError, match=r"did you mean 'driver\.baudrate'"):
        validate_config({**base, "driver": {**drv, "baud_rate": 9600}})
