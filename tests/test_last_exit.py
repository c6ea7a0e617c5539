"""`gma-ffc status` with nothing running says how the last run ended (the last-exit record).

The service runs in-process with the real controller on the sim driver (simulated clock), a NaN
load cell injected after some ticks; then the CLI's own `status` and `status --json` read what
the run left in its runtime directory."""

from __future__ import annotations

import json
import os
import math
from pathlib import Path

import pytest

from gma_ffc.cli import main
from gma_ffc.control.config import load_config
from gma_ffc.control.manager import ControllerManager
from gma_ffc.errors import FaultError
from gma_ffc.service import last_exit
from gma_ffc.service.paths import RuntimePaths
from gma_ffc.service.runner import Service

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "config" / "models" / "sim_sdpi.yaml"


@pytest.fixture
def rig(tmp_path):
    (tmp_path / "cfg.yaml").write_text(f"""\
rate_hz: 1000
clock: simulated
model: {MODEL}
driver: {{kind: sim, load_mass_kg: 15.3}}
reference: {{kind: sine, frequency_hz: 3, amplitude_um: 10, offset_um: 20}}
limits: {{current_min_A: 0, current_max_A: 3, slew_A_per_s: 500}}
telemetry: {{path: {tmp_path / 'tel.csv'}}}
""")
    return tmp_path, RuntimePaths(tmp_path / "rt")


def nan_after(ticks: int):
    """A controller factory whose load cell reads NaN from tick `ticks` on."""
    def make(cfg):
        ctrl = ControllerManager(cfg)
        read, n = ctrl.driver.read, [0]

        def bad_read(inputs):
            read(inputs)
            n[0] += 1
            if n[0] >= ticks:
                inputs.force_N = math.nan
        ctrl.driver.read = bad_read
        return ctrl
    return make


def status_cli(runtime: RuntimePaths, capsys, *extra: str) -> tuple[int, str, str]:
    code = main(["status", "--runtime-dir", str(runtime.directory), *extra])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_status_after_a_fault_names_it_and_the_safe_current(rig, capsys):
    tmp, runtime = rig
    svc = Service(tmp / "cfg.yaml", runtime=runtime, install_signal_handlers=False,
                  load_config=load_config, make_controller=nan_after(200))
    with pytest.raises(FaultError, match="sensor_nan"):
        svc.run()
    record = last_exit.read(runtime)
    assert record["how"] == "fault" and "sensor_nan" in record["faults"] and record["safe_current_written"]
    code, out, err = status_cli(runtime, capsys)
    assert code == 1 and not out
    assert "no controller running" in err and "ended at" in err and "on a fault: sensor_nan: load-cell reading" in err
    assert "safe current (0 A) written" in err and len(err.strip().splitlines()) == 1
    code, out, _ = status_cli(runtime, capsys, "--json")
    doc = json.loads(out)
    assert code == 1 and doc["state"] == "not running" and doc["last_exit"]["how"] == "fault"
    assert "sensor_nan" in doc["last_exit"]["faults"] and doc["last_exit"]["pid"] == record["pid"]


def test_a_clean_stop_records_a_clean_stop(rig, capsys):
    tmp, runtime = rig
    svc = Service(tmp / "cfg.yaml", runtime=runtime, install_signal_handlers=False, duration_s=0.3,
                  load_config=load_config, make_controller=ControllerManager)
    assert svc.run() == 0
    record = last_exit.read(runtime)
    assert record["how"] == "stopped" and record["faults"] == {} and record["safe_current_written"]
    code, _, err = status_cli(runtime, capsys)
    assert code == 1 and ": stopped (" in err and "fault" not in err


def test_a_run_that_never_recorded_its_end_says_so(rig, capsys):
    """A kill -9 leaves the 'running' record: status does not pass it off as a clean end."""
    _, runtime = rig
    runtime.directory.mkdir(mode=0o700)
    last_exit.write(runtime, {**last_exit.started("cfg.yaml"), "pid": 999999})
    code, _, err = status_cli(runtime, capsys)
    assert code == 1 and "left no exit record: it was killed" in err


def test_nothing_recorded_is_the_old_answer(rig, capsys):
    _, runtime = rig
    code, _, err = status_cli(runtime, capsys)
    assert code == 1 and "no controller running" in err and "last run" not in err


def stop_cli(runtime: RuntimePaths, capsys, monkeypatch) -> str:
    """`gma-ffc stop`'s line for a run that already ended in-process (the stop itself stubbed: it
    would wait for this very process to end)."""
    from gma_ffc.service import daemon

    pid = last_exit.read(runtime)["pid"]
    monkeypatch.setattr(daemon, "stop", lambda runtime, timeout_s: daemon.Stopped(pid, "stopped on request", None))
    assert main(["stop", "--runtime-dir", str(runtime.directory)]) == 0
    return capsys.readouterr().out


@pytest.mark.parametrize("duration_s,saved", [(4.0, True), (0.3, False)])
def test_stop_says_where_the_learned_correction_was_saved_or_why_not(rig, capsys, monkeypatch, duration_s, saved):
    """`stop` said nothing of learning: whether the correction went to learning.file was only in the log."""
    tmp, runtime = rig
    learned = tmp / "learned.yaml"
    cfg = tmp / "cfg.yaml"
    cfg.write_text(cfg.read_text() + f"learning: {{kind: repetitive, file: {learned}}}\n")
    svc = Service(cfg, runtime=runtime, install_signal_handlers=False, duration_s=duration_s,
                  load_config=load_config, make_controller=ControllerManager)
    assert svc.run() == 0
    out = stop_cli(runtime, capsys, monkeypatch)
    assert learned.exists() is saved and len(out.strip().splitlines()) == 1
    if saved:
        assert f"learned correction saved to {learned}" in out, out
    else:
        assert f"learned correction NOT saved to {learned}: no correction measured better than feedforward" in out, out


def test_stop_says_nothing_of_learning_for_a_run_without_it(rig, capsys, monkeypatch):
    tmp, runtime = rig
    svc = Service(tmp / "cfg.yaml", runtime=runtime, install_signal_handlers=False, duration_s=0.3,
                  load_config=load_config, make_controller=ControllerManager)
    assert svc.run() == 0
    out = stop_cli(runtime, capsys, monkeypatch)
    assert out.startswith("stopped on request (pid") and "learn" not in out


def test_stop_and_status_name_the_faults_that_recovered(rig, capsys, monkeypatch):
    """9 comms faults that reconnected in 3 s: `stop` said only 'stopped on request'."""
    _, runtime = rig
    runtime.directory.mkdir(mode=0o700)
    final = {"state": "stopped", "fault_messages": {}, "fault_counts": {"comms_error": 9, "comms_timeout": 2},
             "at_safe_current": True, "safe_current_A": 0.0}
    last_exit.write(runtime, last_exit.ended("cfg.yaml", 0.0, final, "stopped", "gma-ffc stop"))
    assert last_exit.read(runtime)["fault_counts"] == {"comms_error": 9, "comms_timeout": 2}
    out = stop_cli(runtime, capsys, monkeypatch)
    assert "faults since start (recovered ones too): comms_error 9, comms_timeout 2" in out, out
    assert "faults active at the end" not in out and len(out.strip().splitlines()) == 1
    code, _, err = status_cli(runtime, capsys)
    assert code == 1 and "faults since start (recovered ones too): comms_error 9, comms_timeout 2" in err, err


def test_stop_with_nothing_running_says_how_the_last_run_ended(rig, capsys):
    """`gma-ffc stop` after a `kill -9` said only "no controller running", which reads as all is well;
    `status` said the run left no exit record and to check the amplifier. `stop` now says it too."""
    _, runtime = rig
    runtime.directory.mkdir(mode=0o700)
    last_exit.write(runtime, {**last_exit.started("cfg.yaml"), "pid": 999999})
    code = main(["stop", "--runtime-dir", str(runtime.directory)])
    err = capsys.readouterr().err
    assert code == 1 and "no controller running" in err and "left no exit record: it was killed" in err, err
    assert "check the amplifier" in err and len(err.strip().splitlines()) == 1


def test_stop_with_nothing_ever_run_is_the_old_answer(rig, capsys):
    _, runtime = rig
    code = main(["stop", "--runtime-dir", str(runtime.directory)])
    err = capsys.readouterr().err
    assert code == 1 and "no controller running" in err and "last run" not in err


def test_status_as_another_user_names_the_system_services_folder_and_its_user(rig, capsys, monkeypatch, tmp_path):
    """A lab user's `gma-ffc status` while the systemd service ran (as user gma-ffc, in /run/gma-ffc)
    said only "no controller running (socket /run/user/1000/gma-ffc/control.sock)". It names the
    service's folder and user; as that user, the default runtime folder is the service's."""
    import pwd

    from gma_ffc.service import paths

    system = tmp_path / "run-gma-ffc"
    system.mkdir(mode=0o700)
    nobody = pwd.getpwnam("nobody")
    os.chown(system, nobody.pw_uid, nobody.pw_gid)
    monkeypatch.setattr(paths, "SYSTEM_RUNTIME_DIR", str(system))
    _, runtime = rig
    for command in ("status", "stop"):
        assert main([command, "--runtime-dir", str(runtime.directory)]) == 1
        err = capsys.readouterr().err
        assert f"the system service keeps its controller's socket in {system}, user nobody" in err, err
        assert "'sudo -u nobody gma-ffc status'" in err and len(err.strip().splitlines()) == 1
    monkeypatch.setattr(paths.os, "geteuid", lambda: nobody.pw_uid)       # as that user, as advised
    assert paths.default_runtime_dir({}) == system
    assert paths.system_service_hint(paths.RuntimePaths(system)) == ""


def test_reload_with_nothing_running_says_how_the_last_run_ended(rig, capsys):
    """A reload after the controller ended on a fault said only "no controller running": the
    fault that ended it was told by status alone."""
    tmp, runtime = rig
    svc = Service(tmp / "cfg.yaml", runtime=runtime, install_signal_handlers=False,
                  load_config=load_config, make_controller=nan_after(200))
    with pytest.raises(FaultError, match="sensor_nan"):
        svc.run()
    assert main(["reload", "--runtime-dir", str(runtime.directory)]) == 1
    err = capsys.readouterr().err
    assert "no controller running" in err and "on a fault: sensor_nan" in err and "safe current (0 A) written" in err
    assert len(err.strip().splitlines()) == 1
