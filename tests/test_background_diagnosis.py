"""The background diagnosis alone (issue 30): when it starts, how often, what it runs (a real
`gma-ffc diagnose` at nice 19, SCHED_OTHER), what the status says, and that the child never
outlives the service: killed on close, and killed by the kernel when the service dies."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gma_ffc.modelio import load_model
from gma_ffc.recordings import Recording
from gma_ffc.service.diagnosis import BackgroundDiagnosis, Window, default_state_dir

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "config" / "models" / "sim_sdpi.yaml"


def window_recording(seconds=6.0, rate=500.0):
    """A full-stroke 2 Hz run of the simulated rig the example model was identified on."""
    from hil_sim.plant import GMAPlant, PlantConfig

    cfg = PlantConfig().with_effects(["noise"])
    t = np.arange(int(seconds * rate)) / rate
    drive = 1.5 - 1.45 * np.cos(2 * np.pi * 2 * t)
    run = GMAPlant(cfg, seed=4).run(t, drive, load_mass_kg=cfg.mass_for_stress(-15.2))
    return Recording({"time_s": t, "current_A": run["current_A"], "stress_MPa": run["stress_MPa"],
                      "displacement_um": run["displacement_um"]}, {"sample_rate_hz": rate}, "window.csv")


def make(tmp_path, **cfg):
    monitor = {"window_s": 6.0, "trigger_s": 5.0, "on_drift": "diagnose", "max_per_hour": 2,
               "state_dir": str(tmp_path / "state"), **cfg}
    clock = {"now": 1000.0}
    bg = BackgroundDiagnosis(monitor, lambda s: Window(window_recording(), load_model(MODEL)),
                             now=lambda: clock["now"])
    return bg, clock


def test_starts_after_trigger_s_once_per_episode_and_within_the_hourly_limit(tmp_path, monkeypatch):
    bg, clock = make(tmp_path)
    starts = []
    monkeypatch.setattr(bg, "_start", lambda now: (starts.append(now), bg.started.append(now)))
    bg.poll("ok", 0.0, 50.0)
    bg.poll("drifting", 10.0, 14.9)                 # drifting 4.9 s of loop time: not yet
    assert starts == []
    bg.poll("drifting", 10.0, 15.0)
    assert starts == [1000.0]
    bg.poll("drifting", 10.0, 60.0)                 # the same episode: once
    assert len(starts) == 1
    bg.poll("drifting", 80.0, 90.0)                 # a new episode, 5 min later
    clock["now"] += 300
    bg.poll("drifting", 80.0, 90.0)
    assert len(starts) == 2
    clock["now"] += 300
    bg.poll("drifting", 200.0, 210.0)               # a third within the hour: refused, and said why
    assert len(starts) == 2 and "rate limit" in bg.status()["note"]
    clock["now"] = 1000.0 + 3601
    bg.poll("drifting", 200.0, 210.0)
    assert len(starts) == 3
    warn, _ = make(tmp_path, on_drift="warn")
    monkeypatch.setattr(warn, "_start", lambda now: starts.append(now))
    warn.poll("drifting", 0.0, 100.0)               # warn only: never starts
    assert len(starts) == 3


def _sched(pid):
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[16]), os.sched_getscheduler(pid)     # nice, policy


@pytest.mark.slow
def test_runs_a_real_diagnosis_at_nice_19_and_reports_it(tmp_path, monkeypatch):
    monkeypatch.setenv("GMA_FFC_CPUS", "2")              # the service's own setting must not reach the child
    bg, _ = make(tmp_path)
    bg.poll("drifting", 0.0, 5.0)
    assert bg.current is not None and bg.child is not None
    time.sleep(1.0)                                  # past the child's first lines
    nice, policy = _sched(bg.child.pid)
    assert nice == 19 and policy == os.SCHED_OTHER
    environ = Path(f"/proc/{bg.child.pid}/environ").read_bytes().split(b"\0")
    assert b"GMA_FFC_CPUS=1" in environ                 # one search thread: a core stays the loop's
    end = time.monotonic() + 240
    while bg.child is not None and time.monotonic() < end:
        bg.poll("drifting", 0.0, 6.0)
        time.sleep(0.2)
    last = bg.status()["last"]
    folder = Path(last["folder"])
    doc = json.loads((folder / "diagnosis.json").read_text())
    assert last["outcome"] == doc["outcome"] and last["effects"] == doc["verdict"], last
    assert "thermal_drift" not in last["effects"]        # nothing heats in 6 s on this rig
    assert folder.parent == tmp_path / "state" / "diagnoses"
    assert Path(last["report"]).is_file() and Path(last["recording"]).is_file()
    assert last["extended_model"] == str(folder / "extended_model.yaml")


def test_close_kills_the_child_and_says_so(tmp_path):
    bg, _ = make(tmp_path)
    bg.poll("drifting", 0.0, 5.0)
    pid = bg.child.pid
    bg.close()
    assert not _alive(pid)
    assert bg.status()["last"]["outcome"] == "stopped" and bg.status()["running"] is None


def test_the_child_dies_with_a_killed_service(tmp_path):
    """SIGKILL the parent (no cleanup runs): the kernel kills the child (PR_SET_PDEATHSIG)."""
    code = ("import os, subprocess, sys, time\n"
            "child = subprocess.Popen([sys.executable, '-c', 'from gma_ffc.service.diagnose_child import "
            "bind_to_parent, lower_priority; import os, sys, time; bind_to_parent(int(sys.argv[1])); "
            "lower_priority(); time.sleep(120)', str(os.getpid())])\n"
            "print(child.pid, flush=True)\n"
            "time.sleep(120)\n")
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    child_pid = int(parent.stdout.readline())
    time.sleep(1.0)
    assert _alive(child_pid) and _sched(child_pid)[0] == 19
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    end = time.monotonic() + 10
    while _alive(child_pid) and time.monotonic() < end:
        time.sleep(0.05)
    assert not _alive(child_pid)


def test_an_orphan_exits_at_once():
    """A child whose parent is not the one it was told of exits before doing anything."""
    out = subprocess.run([sys.executable, "-m", "gma_ffc.service.diagnose_child", "1", "--", "--version"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 3 and out.stdout == ""


def test_state_dir_defaults():
    assert default_state_dir({"STATE_DIRECTORY": "/var/lib/gma-ffc:/x"}) == Path("/var/lib/gma-ffc")
    assert default_state_dir({"XDG_STATE_HOME": "/home/u/.state"}) == Path("/home/u/.state/gma-ffc")


def _alive(pid):
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def test_a_state_dir_outside_output_dirs_refuses_the_diagnosis_not_the_run(tmp_path):
    """output_dirs are the only folders the service writes into: a diagnosis that would write
    elsewhere fails with the reason in the status, and writes nothing."""
    monitor = {"window_s": 6.0, "trigger_s": 5.0, "on_drift": "diagnose", "max_per_hour": 2,
               "state_dir": str(tmp_path / "state")}
    bg = BackgroundDiagnosis(monitor, lambda s: Window(window_recording(), load_model(MODEL)),
                             output_dirs=(str(tmp_path / "out"),))
    bg.poll("drifting", 10.0, 16.0)
    assert bg.child is None and bg.last is not None and bg.last["outcome"] == "failed"
    assert "output_dirs" in bg.last["error"] and not (tmp_path / "state").exists()


def test_the_service_passes_its_drive_limits_to_the_diagnosis_it_starts(tmp_path, capsys):
    """diagnose knew only the model's drive range, so its advice could ask for a drive the
    controller's limits do not allow; the service now gives it those limits."""
    import yaml

    from gma_ffc.cli import build_parser, main
    from gma_ffc.control.config import load_config
    from gma_ffc.control.manager import ControllerManager
    from gma_ffc.service.watch import ServiceWatch

    cfg_file = tmp_path / "cfg.yaml"
    cfg_file.write_text(yaml.safe_dump({
        "rate_hz": 1000, "clock": "simulated", "model": str(MODEL), "driver": {"kind": "sim", "load_mass_kg": 15.3},
        "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 10.0, "offset_um": 20.0},
        "limits": {"current_min_A": 0.25, "current_max_A": 2.5, "safe_current_A": 0.25, "slew_A_per_s": 500.0},
        "telemetry": {"path": None}, "monitor": {"state_dir": str(tmp_path / "state")}}))
    cfg = load_config(cfg_file)
    watch = ServiceWatch(cfg, ControllerManager(cfg))
    assert watch.diagnosis is not None
    watch.diagnosis.take_window = lambda s: Window(window_recording(), load_model(MODEL))
    _folder, argv = watch.diagnosis._prepare(1000.0)
    args = build_parser().parse_args(argv[argv.index("--") + 1:])
    assert args.command == "diagnose" and args.drive_limits == [0.25, 2.5]
    assert main(["diagnose", "--model", str(MODEL), "r.csv", "--out", str(tmp_path / "o"),
                 "--drive-limits", "2.5", "0.25"]) == 2
    err = capsys.readouterr().err
    assert "--drive-limits needs LO < HI, got 2.5 0.25" in err and len(err.strip().splitlines()) == 1


def test_with_output_dirs_and_no_state_dir_diagnoses_go_in_the_first_output_dir(tmp_path, monkeypatch):
    """config/sim.yaml names output_dirs: [telemetry] and no monitor.state_dir: the default state
    folder (/var/lib/gma-ffc for root, ~/.local/state/gma-ffc) lay outside it, so every background
    diagnosis of that config failed, after the drift, on "outside the directories the config names
    for output". The default is then the first output_dir; a default already inside them stays."""
    from gma_ffc.service.diagnosis import check_state_dir, state_dir_for

    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path / "var" / "lib" / "gma-ffc"))
    out = tmp_path / "rig" / "telemetry"
    monitor = {"enabled": True, "window_s": 6.0, "trigger_s": 5.0, "on_drift": "diagnose", "max_per_hour": 2,
               "state_dir": None}
    assert state_dir_for(monitor, (str(out),)) == out
    assert state_dir_for(monitor, (str(tmp_path / "var"),)) == tmp_path / "var" / "lib" / "gma-ffc"
    assert state_dir_for(monitor) == tmp_path / "var" / "lib" / "gma-ffc"
    check_state_dir(monitor, (str(out),))
    bg = BackgroundDiagnosis(monitor, lambda s: Window(window_recording(), load_model(MODEL)),
                             output_dirs=(str(out),))
    folder, _argv = bg._prepare(1000.0)
    assert folder.parent == out / "diagnoses" and (folder / "window.csv").is_file()
