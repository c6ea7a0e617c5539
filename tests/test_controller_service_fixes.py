"""Issue 10 faults found on an unseen rig: the telemetry's wall clock, one writer per telemetry
file, status --json with nothing running, and duplicate config keys."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gma_ffc.control.config import load_config, validate_config
from gma_ffc.control.manager import ControllerManager
from gma_ffc.control.telemetry import Telemetry
from gma_ffc.drivers.sim import SimDriver
from gma_ffc.errors import ConfigError
from gma_ffc.recordings import read_recording

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "config" / "models" / "sim_sdpi.yaml"


def cfg_for(tmp_path, **extra):
    data = {"rate_hz": 100, "clock": "real", "model": str(MODEL), "driver": {"kind": "sim", "load_mass_kg": 15.3},
            "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 10.0, "offset_um": 20.0},
            "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0},
            "telemetry": {"path": str(tmp_path / "tel.csv"), "flush_interval_s": 0.2}, "watchdog_s": 2.0}
    data.update(extra)
    return validate_config(data)


class WallStampingSim(SimDriver):
    """The sim rig, noting the wall-clock time of every read: the instrument the lab aligns with."""

    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self.walls: list[float] = []

    def read(self, inputs):
        self.walls.append(time.time())
        super().read(inputs)


@pytest.mark.realtime
@pytest.mark.slow
def test_telemetry_wall_clock_is_within_2_ms_at_start_and_after_60_s(tmp_path):
    cfg = cfg_for(tmp_path)
    drv = WallStampingSim(cfg.driver, cfg.period_s)
    status = ControllerManager(cfg, driver=drv).run(duration_s=61.0)
    assert status["ok"], status["fault_messages"]
    rec = read_recording(cfg.telemetry["path"])
    start = float(rec.metadata["start_unix_s"])
    rows = start + rec.time_s
    n = min(len(rows), len(drv.walls))
    first = abs(rows[0] - drv.walls[0])
    at_60 = [abs(rows[k] - drv.walls[k]) for k in range(n) if rec.time_s[k] >= 60.0][:10]
    assert first < 2e-3, first
    assert at_60 and max(at_60) < 2e-3, at_60
    assert abs(status["started_unix_s"] - start) < 1e-6


def test_a_second_controller_on_the_same_telemetry_file_is_refused_naming_the_first(tmp_path):
    this_rig = {"source": "gma-ffc controller", "config": "<memory>"}    # the file stays this rig's telemetry
    first = Telemetry(tmp_path / "tel.csv", ["time_s", "x"], this_rig, capacity=64)
    first.start()
    try:
        with pytest.raises(ConfigError, match=f"another controller \\(pid {os.getpid()}\\)"):
            Telemetry(tmp_path / "tel.csv", ["time_s", "x"], this_rig, capacity=64).start()
        cfg = cfg_for(tmp_path, clock="simulated")
        status = ControllerManager(cfg).run(duration_s=0.1)
        assert not status["ok"] and any("another controller" in m for m in status["fault_messages"].values())
    finally:
        first.close()
    assert ControllerManager(cfg_for(tmp_path, clock="simulated")).run(duration_s=0.1)["ok"]   # free again
    assert read_recording(tmp_path / "tel.csv").time_s.size > 0
    assert b"\0" not in (tmp_path / "tel.csv").read_bytes()


def test_a_controller_in_another_process_is_refused_naming_its_pid(tmp_path):
    """As on the rig: the second writer is another process (`gma-ffc start` with another runtime
    directory). A child holds the telemetry file as a running controller does; the controller
    started here is refused, names the child's pid, and writes nothing into the file."""
    tel = tmp_path / "tel.csv"
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys; from gma_ffc.control.telemetry import Telemetry\n"
         "t = Telemetry(sys.argv[1], ['time_s', 'x'], {}, capacity=64); t.start()\n"
         "print('holding', flush=True); sys.stdin.readline(); t.close()", str(tel)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "holding"
        before = tel.read_bytes() if tel.exists() else b""
        status = ControllerManager(cfg_for(tmp_path, clock="simulated")).run(duration_s=0.1)
        assert not status["ok"]
        assert any(f"another controller (pid {holder.pid})" in m for m in status["fault_messages"].values()), \
            status["fault_messages"]
        assert (tel.read_bytes() if tel.exists() else b"") == before
        advice = next(m for m in status["fault_messages"].values() if "another controller" in m)
        assert f"'kill {holder.pid}'" in advice
        holder.terminate()                    # the advice, followed: the first goes, this one runs
        holder.wait(timeout=60)
        assert ControllerManager(cfg_for(tmp_path, clock="simulated")).run(duration_s=0.1)["ok"]
    finally:
        if holder.poll() is None:
            holder.communicate("\n", timeout=60)
    assert holder.returncode is not None


def test_duplicate_config_keys_are_refused_naming_the_key_and_both_lines(tmp_path):
    (tmp_path / "cfg.yaml").write_text(f"rate_hz: 100\nmodel: {MODEL}\nrate_hz: 200\n")
    with pytest.raises(ConfigError, match="'rate_hz' appears twice, on lines 1 and 3"):
        load_config(tmp_path / "cfg.yaml")


def test_status_json_with_nothing_running_is_still_json(tmp_path):
    out = subprocess.run([sys.executable, "-m", "gma_ffc.cli", "status", "--json", "--runtime-dir",
                          str(tmp_path / "rt")], capture_output=True, text=True, timeout=60)
    doc = json.loads(out.stdout)
    assert doc["state"] == "not running" and out.returncode == 1


def test_a_simulated_clock_without_an_end_is_refused_and_the_advice_works(tmp_path):
    """The demo's configs run on a simulated clock; started as a service without --duration one ran
    65,000 ticks a second while its status said 1000 Hz. Both pieces of advice are followed."""
    import yaml

    data = {"rate_hz": 1000, "clock": "simulated", "model": str(MODEL), "driver": {"kind": "sim"},
            "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 10.0, "offset_um": 20.0},
            "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0},
            "telemetry": {"path": str(tmp_path / "tel.csv")}}
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(yaml.safe_dump(data))

    def run(*extra):
        return subprocess.run([sys.executable, "-m", "gma_ffc.cli", "run", "--config", str(cfg), "--no-socket",
                               *extra], capture_output=True, text=True, timeout=120)

    refused = run()
    assert refused.returncode == 2 and "Traceback" not in refused.stderr
    assert "config key 'clock' is 'simulated'" in refused.stderr and "give --duration S" in refused.stderr
    assert not (tmp_path / "tel.csv").exists()
    assert run("--duration", "0.2").returncode == 0
    cfg.write_text(yaml.safe_dump({**data, "clock": "real"}))
    real = subprocess.Popen([sys.executable, "-m", "gma_ffc.cli", "run", "--config", str(cfg), "--no-socket"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and real.poll() is None and \
                len((tmp_path / "tel.csv").read_text().splitlines() if (tmp_path / "tel.csv").exists() else []) < 50:
            time.sleep(0.1)
        assert real.poll() is None            # set to a real clock, it runs until stopped
    finally:
        real.terminate()
        real.wait(timeout=60)


@pytest.mark.parametrize("policy", ["warn", "clamp", "fault"])
def test_a_command_beyond_the_identified_drive_range_is_never_silent(tmp_path, policy):
    """A reference beyond the model's stroke with current limits wider than the identified range
    (the unseen rig commanded 7.8 A on a model identified to 3 A, silently)."""
    cfg = cfg_for(tmp_path, clock="simulated",
                  reference={"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 40.0, "offset_um": 40.0},
                  limits={"current_min_A": 0.0, "current_max_A": 8.0, "slew_A_per_s": 500.0,
                          "beyond_model": policy})
    ctrl = ControllerManager(cfg)
    status = ctrl.run(duration_s=1.0)
    lo, hi = ctrl.setup.model.drive_range
    assert "drive_out_of_model_range" in status["faults"]
    assert status["outside_model"]["drive_ticks"] > 0 and status["outside_model"]["policy"] == policy
    rec = read_recording(cfg.telemetry["path"])
    assert (rec.columns["outside_model"].astype(int) & 1).any()
    cmd = rec.columns["current_cmd_A"]
    if policy == "clamp":
        assert cmd.max() <= hi + 0.01 * (hi - lo) + 1e-9
    elif policy == "warn":
        assert cmd.max() > hi + 0.01 * (hi - lo)
        assert status["ok"]
    else:
        assert not status["ok"] and status["state"] == "fault" and cmd[-1] == 0.0
