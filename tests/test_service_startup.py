"""What `gma-ffc run` refuses before it opens the driver: each refusal is one line and exit 2, and
the amplifier (of a controller already running on the rig) is never touched (sweep B)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
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


@pytest.fixture
def read_only_folder(tmp_path):
    """A folder no new file can be made in: chmod 555 for a user; root ignores modes, so for root
    a read-only bind mount (skipped where mounting is not allowed)."""
    folder = tmp_path / "ro"
    folder.mkdir()
    if os.geteuid() != 0:
        folder.chmod(0o555)
        yield folder
        folder.chmod(0o755)
        return
    bind = subprocess.run(["mount", "--bind", str(folder), str(folder)], capture_output=True)
    if bind.returncode != 0:
        pytest.skip("cannot bind-mount here to make a read-only folder as root")
    try:
        if subprocess.run(["mount", "-o", "remount,bind,ro", str(folder)], capture_output=True).returncode != 0:
            pytest.skip("cannot remount read-only here")
        yield folder
    finally:
        subprocess.run(["umount", str(folder)], capture_output=True)


def test_a_read_only_stats_json_folder_is_refused_before_the_run(tmp_path, read_only_folder):
    """It ran, then failed naming a temporary file ('.stats.json.9e843d8f.tmp: Read-only file system')."""
    cfg = sim_config(tmp_path)
    out = gma_ffc("run", "--config", str(cfg), "--no-socket", "--duration", "0.2",
                  "--stats-json", str(read_only_folder / "stats.json"), cwd=tmp_path)
    one_line_exit_2(out, str(read_only_folder / "stats.json"), "read-only", "choose another --stats-json")
    assert not (tmp_path / "tel").exists()                 # refused before the run
    follow = gma_ffc("run", "--config", str(cfg), "--no-socket", "--duration", "0.2",
                     "--stats-json", str(tmp_path / "stats.json"), cwd=tmp_path)
    assert follow.returncode == 0, follow.stderr
    assert json.loads((tmp_path / "stats.json").read_text())["status"]


def test_a_read_only_telemetry_folder_is_refused_before_the_driver_opens(tmp_path, read_only_folder):
    """It became a run-time fault (exit 1) after the device was opened."""
    cfg = sim_config(tmp_path, telemetry={"path": str(read_only_folder / "tel.csv")})
    out = gma_ffc("run", "--config", str(cfg), "--no-socket", "--duration", "0.2", cwd=tmp_path)
    one_line_exit_2(out, str(read_only_folder / "tel.csv"), "read-only", "choose another telemetry.path")


def test_a_read_only_monitor_state_dir_is_refused_at_start_while_diagnoses_are_on(tmp_path, read_only_folder):
    """It was found only when the first background diagnosis started, maybe hours into the run."""
    state = read_only_folder / "state"
    cfg = sim_config(tmp_path, monitor={"on_drift": "diagnose", "state_dir": str(state)})
    out = gma_ffc("run", "--config", str(cfg), "--no-socket", "--duration", "0.2", cwd=tmp_path)
    one_line_exit_2(out, "config key 'monitor.state_dir'", str(read_only_folder), "monitor.on_drift: warn")
    assert not (tmp_path / "tel").exists()                 # refused before the run
    warn = sim_config(tmp_path, monitor={"on_drift": "warn", "state_dir": str(state)})    # the advice works
    follow = gma_ffc("run", "--config", str(warn), "--no-socket", "--duration", "0.2", cwd=tmp_path)
    assert follow.returncode == 0, follow.stderr


def test_a_monitor_state_dir_under_a_file_is_refused_at_start_and_another_folder_runs(tmp_path):
    (tmp_path / "a_file").write_text("not a folder\n")
    cfg = sim_config(tmp_path, monitor={"state_dir": str(tmp_path / "a_file" / "state")})
    out = gma_ffc("run", "--config", str(cfg), "--no-socket", "--duration", "0.2", cwd=tmp_path)
    one_line_exit_2(out, "config key 'monitor.state_dir'", f"{tmp_path / 'a_file'} is a file, not a folder",
                    "set monitor.state_dir to a folder this user may write")
    cfg = sim_config(tmp_path, monitor={"state_dir": str(tmp_path / "state")})
    follow = gma_ffc("run", "--config", str(cfg), "--no-socket", "--duration", "0.2", cwd=tmp_path)
    assert follow.returncode == 0, follow.stderr
    assert not (tmp_path / "state").exists()               # the check made nothing


def test_stats_json_on_the_telemetry_file_is_refused_before_the_run(tmp_path):
    cfg = sim_config(tmp_path)
    out = gma_ffc("run", "--config", str(cfg), "--no-socket", "--duration", "0.2",
                  "--stats-json", str(tmp_path / "tel" / "tel.csv"), cwd=tmp_path)
    one_line_exit_2(out, "--stats-json", "telemetry.path", "choose another --stats-json")
    assert not (tmp_path / "tel").exists()


def test_learned_on_the_telemetry_file_names_the_option_given(tmp_path):
    """It failed after the run, with advice naming the config key learning.file the user never set."""
    cfg = sim_config(tmp_path, learning={"kind": "repetitive"})
    out = gma_ffc("run", "--config", str(cfg), "--no-socket", "--duration", "0.2",
                  "--learned", str(tmp_path / "tel" / "tel.csv"), cwd=tmp_path)
    one_line_exit_2(out, "--learned", "choose another --learned")
    assert "learning.file" not in out.stderr
    assert not (tmp_path / "tel").exists()


@pytest.mark.parametrize("name", ["same path", "symlink", "hard link"])
def test_a_playback_of_the_runs_own_telemetry_is_refused_before_it_is_truncated(tmp_path, name):
    """Replaying a run's telemetry with the same config truncated the recording it was to play."""
    cfg = sim_config(tmp_path)
    assert gma_ffc("run", "--config", str(cfg), "--no-socket", "--duration", "0.2", cwd=tmp_path).returncode == 0
    tel = tmp_path / "tel" / "tel.csv"
    before = tel.read_bytes()
    played = {"same path": tel, "symlink": tmp_path / "link.csv", "hard link": tmp_path / "hard.csv"}[name]
    if name == "symlink":
        played.symlink_to(tel)
    elif name == "hard link":
        os.link(tel, played)
    cfg = sim_config(tmp_path, reference={"kind": "playback", "file": str(played)})
    out = gma_ffc("run", "--config", str(cfg), "--no-socket", "--duration", "0.2", cwd=tmp_path)
    one_line_exit_2(out, str(tel), "reference.file", "choose another telemetry.path")
    assert tel.read_bytes() == before
    if name == "same path":       # the advice works: another telemetry.path plays the recording
        cfg = sim_config(tmp_path, reference={"kind": "playback", "file": str(played)},
                         telemetry={"path": str(tmp_path / "replay.csv")})
        follow = gma_ffc("run", "--config", str(cfg), "--no-socket", "--duration", "0.2", cwd=tmp_path)
        assert follow.returncode == 0, follow.stderr
        assert tel.read_bytes() == before


@pytest.mark.parametrize("given", ["tel/", "tel"])
def test_a_telemetry_path_that_is_a_folder_says_so_first(tmp_path, given):
    """It said the folder was outside output_dirs, and adding it there only led to 'is not a
    regular file'. The suggested file name works."""
    (tmp_path / "tel").mkdir()
    cfg = sim_config(tmp_path, telemetry={"path": given}, output_dirs=[str(tmp_path / "tel")])
    out = gma_ffc("run", "--config", str(cfg), "--no-socket", "--duration", "0.2", cwd=tmp_path)
    one_line_exit_2(out, "config key 'telemetry.path'", "is a folder, not a file")
    suggested = out.stderr.strip().rsplit("e.g. ", 1)[1]
    cfg = sim_config(tmp_path, telemetry={"path": suggested}, output_dirs=[str(tmp_path / "tel")])
    follow = gma_ffc("run", "--config", str(cfg), "--no-socket", "--duration", "0.2", cwd=tmp_path)
    assert follow.returncode == 0, follow.stderr
    assert (tmp_path / suggested).is_file()


@pytest.mark.parametrize("command", ["run", "start"])
def test_a_config_that_is_a_folder_says_so_and_names_a_config_in_it(tmp_path, command):
    """It said 'config file cfg not found' of a folder that is there."""
    folder = tmp_path / "cfg"
    folder.mkdir()
    sim_config(folder)
    (folder / "a_model.yaml").write_text(MODEL.read_text())       # not a config: never suggested
    out = gma_ffc(command, "--config", str(folder), *(["--no-socket"] if command == "run" else []), cwd=tmp_path)
    one_line_exit_2(out, f"config file {folder} is a folder, not a file", "--config")
    suggested = out.stderr.split("--config ", 1)[1].split(" ", 1)[0]
    assert suggested == str(folder / "cfg.yaml")
    follow = gma_ffc("run", "--config", suggested, "--no-socket", "--duration", "0.2", cwd=tmp_path)
    assert follow.returncode == 0, follow.stderr


def test_a_sim_plant_config_that_is_not_valid_yaml_is_refused_at_config_load(tmp_path):
    """A missing one was refused up front; a damaged one became a fault when the driver opened (exit 1)."""
    (tmp_path / "plant.yaml").write_text("rig: {a: [1,\n")
    cfg = sim_config(tmp_path, driver={"kind": "sim", "load_mass_kg": 15.3, "plant_config": str(tmp_path / "plant.yaml")})
    out = gma_ffc("run", "--config", str(cfg), "--no-socket", "--duration", "0.2", cwd=tmp_path)
    one_line_exit_2(out, "config key 'driver.plant_config'", str(tmp_path / "plant.yaml"), "not valid YAML")
    assert not (tmp_path / "tel").exists()


def test_start_runs_the_installed_code_not_a_gma_ffc_folder_in_the_working_directory(tmp_path):
    """`python -m` puts the working folder first on sys.path: started from a folder holding another
    checkout's `gma_ffc`, the service ran that code. The runtime folder is given relative, as users do."""
    decoy = tmp_path / "gma_ffc"
    decoy.mkdir()
    (decoy / "__init__.py").write_text(f"open({str(tmp_path / 'decoy_ran')!r}, 'w').close()\nraise SystemExit(3)\n")
    cfg = sim_config(tmp_path, clock="real")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    run = lambda *a: subprocess.run([sys.executable, "-c", "import sys; sys.path.remove(''); from gma_ffc.cli import main; "
                                     "sys.exit(main(sys.argv[1:]))", *a], capture_output=True, text=True,
                                    timeout=120, cwd=tmp_path, env=env)
    started = run("start", "--config", str(cfg), "--runtime-dir", "rt")
    try:
        assert started.returncode == 0, started.stderr
        status = run("status", "--json", "--runtime-dir", "rt")
        assert json.loads(status.stdout)["state"] == "running"
    finally:
        stopped = run("stop", "--runtime-dir", "rt")
    assert stopped.returncode == 0, stopped.stderr
    assert not (tmp_path / "decoy_ran").exists()
    # stop reports how the run itself ended (its last-exit record), not the status before the stop
    assert stopped.stdout.startswith("stopped on request (pid ") and "; safe current (0 A) written" in stopped.stdout
