"""The driver lifecycle, in ros2_control's order, on every shipped driver (issue 10):
open (configure) -> activate (output on) -> read/write per tick -> safe -> deactivate (output off)
-> close (cleanup). The output is switched on by `activate`, before the first command, never as
a side effect of a write; the device itself sees that order (Modbus and serial emulators)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from gma_ffc.control.config import validate_config
from gma_ffc.control.manager import ControllerManager
from gma_ffc.drivers import driver_class
from gma_ffc.registers import load_register_map
from hil_sim.emulators.modbus import ModbusEmulator
from hil_sim.emulators.rig import EmulatedRig
from hil_sim.emulators.scpi import SerialAmplifierEmulator
from hil_sim.plant import GMAPlant, PlantConfig

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "config" / "models" / "sim_sdpi.yaml"
MAP = ROOT / "hil_sim" / "configs" / "devices" / "amplifier_int16.yaml"
LIFECYCLE = ("open", "activate", "read", "write", "safe", "deactivate", "close", "reconnect")


def _rig() -> EmulatedRig:
    pc = PlantConfig()
    plant = GMAPlant(pc, seed=0)
    plant.reset(pc.mass_for_stress(-15.2))
    return EmulatedRig(plant, dt_s=1e-3, max_current_A=3.5)


def _cfg(tmp_path: Path, driver: dict[str, Any], rate_hz: float, clock: str = "real") -> Any:
    return validate_config({
        "rate_hz": rate_hz, "clock": clock, "model": str(MODEL), "driver": driver,
        "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 10.0, "offset_um": 20.0},
        "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0},
        "telemetry": {"path": str(tmp_path / "tel.csv"), "flush_interval_s": 0.2}})


def _spied(cfg: Any) -> tuple[Any, list[str]]:
    """The configured driver with each lifecycle call the controller makes logged, in order
    (consecutive repeats once; calls a driver makes to itself, like safe() writing, not logged)."""
    driver = driver_class(cfg.driver["kind"])(cfg.driver, cfg.period_s)
    calls: list[str] = []
    depth = [0]

    def logged(name: str, method: Any) -> Any:
        def call(*args: Any, **kwargs: Any) -> Any:
            if depth[0] == 0 and (not calls or calls[-1] != name):
                calls.append(name)
            depth[0] += 1
            try:
                return method(*args, **kwargs)
            finally:
                depth[0] -= 1
        return call

    for name in LIFECYCLE:
        setattr(driver, name, logged(name, getattr(driver, name)))
    return driver, calls


def _assert_order(calls: list[str]) -> None:
    assert calls[:3] == ["open", "activate", "read"], calls
    assert calls[-3:] == ["safe", "deactivate", "close"], calls
    assert calls.count("activate") == calls.count("deactivate") == 1, calls
    assert set(calls[2:-3]) == {"read", "write"}, calls      # only ticks between activate and safe


def _assert_device_order(rig: EmulatedRig) -> None:
    """The device saw output on before the first setpoint, and the run end at 0 A, output off."""
    events = [(c.kind, c.value) for c in rig.history() if c.kind in ("setpoint", "output_enable")]
    assert events[0] == ("output_enable", 1.0), events[:3]
    assert events[-2:] == [("setpoint", 0.0), ("output_enable", 0.0)], events[-3:]
    assert [e for e in events if e[0] == "output_enable"] == [("output_enable", 1.0), ("output_enable", 0.0)]
    assert not rig.output_enabled


def test_sim_driver_lifecycle(tmp_path):
    cfg = _cfg(tmp_path, {"kind": "sim", "load_mass_kg": 15.3}, 200, clock="simulated")
    driver, calls = _spied(cfg)
    status = ControllerManager(cfg, driver=driver).run(duration_s=0.5)
    assert status["ok"], status["fault_messages"]
    _assert_order(calls)


@pytest.mark.realtime   # a 0.2 s link timeout on the wall clock: a busy machine can fault a tick
def test_modbus_driver_lifecycle(tmp_path):
    rig = _rig()
    rmap = load_register_map(MAP)
    with ModbusEmulator(rig, rmap, transport="tcp", port=0) as emu:
        host, port = emu.host_port
        dev = {"transport": "tcp", "host": host, "port": port, "timeout_s": 0.2, "register_map": rmap.to_dict()}
        cfg = _cfg(tmp_path, {"kind": "modbus", "devices": {"amp": dev}}, 100)
        driver, calls = _spied(cfg)
        status = ControllerManager(cfg, driver=driver).run(duration_s=0.5)
    assert status["ok"], status["fault_messages"]
    _assert_order(calls)
    _assert_device_order(rig)


@pytest.mark.realtime   # a 0.2 s link timeout on the wall clock: a busy machine can fault a tick
def test_serial_driver_lifecycle(tmp_path):
    rig = _rig()
    with SerialAmplifierEmulator(rig) as emu:
        drv = {"kind": "serial", "port": emu.path, "timeout_s": 0.2, "init": ["*CLS"],
               "queries": {"force_N": "MEAS:FORC?", "current_A": "MEAS:CURR?", "displacement_um": "MEAS:DISP?"}}
        cfg = _cfg(tmp_path, drv, 100)
        driver, calls = _spied(cfg)
        status = ControllerManager(cfg, driver=driver).run(duration_s=0.5)
    assert status["ok"], status["fault_messages"]
    _assert_order(calls)
    _assert_device_order(rig)
