"""What `gma-ffc run` refuses before it opens the driver: each refusal is one line and exit 2, and
the amplifier (of a controller already running on the rig) is never touched (sweep B)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import yaml

from gma_ffc.control.config import load_config
from gma_ffc.control.manager import ControllerManager
from gma_ffc.registers import load_register_map
from hil_sim.emulators.modbus import ModbusEmulator
from hil_sim.emulators.rig import EmulatedRig
from hil_sim.plant import GMAPlant, PlantConfig

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "config" / "models" / "sim_sdpi.yaml"
MAP = ROOT / "hil_sim" / "configs" / "devices" / "amplifier_int16.yaml"


def gma_ffc(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "GMA_FFC_RUNTIME_DIR": str(cwd / "rt")}
    return subprocess.run([sys.executable, "-m", "gma_ffc.cli", *args], capture_output=True, text=True,
                          timeout=120, cwd=cwd, env=env)


def sim_config(tmp_path: Path, **extra) -> Path:
    data = {"rate_hz": 200, "clock": "simulated", "model": str(MODEL), "driver": {"kind": "sim", "load_mass_kg": 15.3},
            "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 10.0, "offset_um": 20.0},
            "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0},
            "telemetry": {"path": str(tmp_path / "tel" / "tel.csv"), "flush_interval_s": 0.2}}
    data.update(extra)
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def one_line_exit_2(out: subprocess.CompletedProcess, *words: str) -> None:
    assert out.returncode == 2, (out.returncode, out.stderr)
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in out.stderr, out.stderr
    for word in words:
        assert word in lines[0], lines[0]


def _rig() -> EmulatedRig:
    pc = PlantConfig()
    plant = GMAPlant(pc, seed=0)
    plant.reset(pc.mass_for_stress(-15.2))
    return EmulatedRig(plant, dt_s=1e-3, max_current_A=3.5)


def _modbus_config(tmp_path: Path, port: int) -> Path:
    dev = {"transport": "tcp", "host": "127.0.0.1", "port": port, "timeout_s": 0.2, "register_map": str(MAP)}
    data = {"rate_hz": 100, "clock": "real", "model": str(MODEL),
            "driver": {"kind": "modbus", "disable_on_safe": True, "devices": {"amp": dev}},
            "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 10.0, "offset_um": 20.0},
            "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0},
            "telemetry": {"path": str(tmp_path / "tel.csv"), "flush_interval_s": 0.2}}
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_a_second_controller_on_the_rig_is_refused_before_it_touches_the_amplifier(tmp_path):
    """It opened the device, was refused on the telemetry lock, and on its way out wrote the safe
    current and switched the output off under the controller that was running."""
    rig = _rig()
    with ModbusEmulator(rig, load_register_map(MAP), transport="tcp", port=0) as emu:
        cfg_path = _modbus_config(tmp_path, emu.host_port[1])
        first = ControllerManager(load_config(cfg_path))
        stop = threading.Event()
        runner = threading.Thread(target=lambda: first.run(stop), daemon=True)
        runner.start()
        try:
            deadline = time.monotonic() + 240      # a cold numba cache compiles first
            while first.status()["state"] != "running" and time.monotonic() < deadline:
                time.sleep(0.05)
            assert first.status()["state"] == "running"
            seen = len(rig.history())
            second = gma_ffc("run", "--config", str(cfg_path), "--no-socket", "--duration", "1", cwd=tmp_path)
            from_second = rig.history()[seen:]
            still_on = rig.output_enabled
        finally:
            stop.set()
            runner.join(timeout=30)
    assert still_on
    assert [c for c in from_second if c.kind == "output_enable"] == [], from_second
    one_line_exit_2(second, "another controller", f"pid {os.getpid()}")
    assert first.summary()["ok"], first.summary()["fault_messages"]
