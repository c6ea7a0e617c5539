"""The service end to end with real subprocesses and the real Controller on the sim driver:
start/status/stop, SIGHUP with a good and a bad model, notify messages with a fake
NOTIFY_SOCKET, bad usage and bad config, and the systemd unit verified by systemd-analyze."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import stat
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from gma_ffc.model import SDPIModel
from gma_ffc.modelio import save_model

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "gma_ffc.cli"]
RATE_HZ = 200


def write_model(path: Path, gain: float) -> None:
    """A small valid SDPI model: the service's tests need a model file, not a good fit."""
    model = SDPIModel(play_thresholds=[0.0, 0.1, 0.2, 0.3], play_weights=[8.0 * gain, 3.0, 2.0, 1.0],
                      deadzone_thresholds=[-0.5, 0.0, 0.5],
                      deadzone_coeffs=[[0.5, 1.0, 0.3], [-0.01, -0.01, 0.0], [0.0, 0.0, 0.0]],
                      stress_range_MPa=(-25.0, -10.0), drive_range=(0.0, 2.0))
    save_model(model, path)


def write_config(path: Path, model: str) -> None:
    # watchdog_s: after a source change numba recompiles (the controller warms up before tick 1, but
    # a loaded 2-core machine can still stretch early ticks past the default 0.5 s watchdog).
    path.write_text(f"""\
rate_hz: {RATE_HZ}
watchdog_s: 20.0
model: {model}
driver: {{kind: sim, load_mass_kg: 20}}
reference: {{kind: sine, frequency_hz: 3, amplitude_um: 5, offset_um: 6}}
limits: {{current_min_A: 0, current_max_A: 2, slew_A_per_s: 200}}
telemetry: {{path: telemetry.csv}}
""")


@pytest.fixture
def rig(tmp_path: Path):
    write_model(tmp_path / "model.yaml", 1.0)
    write_model(tmp_path / "model2.yaml", 1.5)
    (tmp_path / "bad_model.yaml").write_text("format: gma-ffc-model\nversion: 1\nkind: sdpi\nplay: [1, 2\n")
    write_config(tmp_path / "sim.yaml", "model.yaml")
    runtime = tmp_path / "run"
    yield tmp_path, runtime
    # Never leave a daemon behind, even one whose pid file is not written yet (a start that timed
    # out on a busy machine): every process started with this runtime directory.
    for pid in _processes_naming(str(runtime)):
        try:
            os.kill(pid, signal.SIGTERM)
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:
                os.kill(pid, 0)
                time.sleep(0.05)
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def _processes_naming(text: str) -> list[int]:
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and int(entry.name) != os.getpid():
            try:
                if text.encode() in (entry / "cmdline").read_bytes():
                    pids.append(int(entry.name))
            except OSError:
                pass
    return pids


def cli(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items()
           if k not in ("GMA_FFC_RUNTIME_DIR", "NOTIFY_SOCKET", "WATCHDOG_USEC")}
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout, env=env,
                          cwd=ROOT)


def status_json(runtime: Path) -> dict:
    res = cli("status", "--json", "--runtime-dir", str(runtime))
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout)


def wait_until(predicate, timeout_s: float = 15.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.1)
    return predicate()


def one_line_error(res: subprocess.CompletedProcess, code: int) -> str:
    assert res.returncode == code, (res.returncode, res.stdout, res.stderr)
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    return lines[0]


def test_start_status_stop(rig):
    tmp, runtime = rig
    res = cli("start", "--config", str(tmp / "sim.yaml"), "--runtime-dir", str(runtime))
    assert res.returncode == 0, res.stderr
    assert "started: pid" in res.stdout
    pid = int(res.stdout.split("pid ")[1].split(",")[0])
    assert int((runtime / "gma-ffc.pid").read_text()) == pid

    assert stat.S_IMODE(runtime.stat().st_mode) == 0o700
    sock = runtime / "control.sock"
    assert stat.S_ISSOCK(sock.stat().st_mode) and stat.S_IMODE(sock.stat().st_mode) == 0o600

    first = status_json(runtime)
    assert first["state"] == "running" and first["service"]["pid"] == pid
    assert wait_until(lambda: status_json(runtime)["ticks"] > first["ticks"] + RATE_HZ // 4)
    snap = status_json(runtime)
    assert 0.5 * RATE_HZ < snap["achieved_rate_hz"] < 1.5 * RATE_HZ
    assert snap["jitter_p99_us"] >= snap["jitter_p50_us"] >= 0
    assert -25 < snap["stress_MPa"] < -10 and snap["faults"] == []

    table = cli("status", "--runtime-dir", str(runtime))
    assert table.returncode == 0
    for label in ("state", "rate", "period jitter", "overruns", "stress", "current", "reference",
                  "faults"):
        assert any(line.startswith(label) for line in table.stdout.splitlines()), label
    assert "running" in table.stdout and f"target {RATE_HZ} Hz" in table.stdout

    again = cli("start", "--config", str(tmp / "sim.yaml"), "--runtime-dir", str(runtime))
    assert "already running" in one_line_error(again, 1)

    res = cli("stop", "--runtime-dir", str(runtime))
    assert res.returncode == 0, res.stderr
    assert f"stopped on request (pid {pid})" in res.stdout
    assert wait_until(lambda: not Path(f"/proc/{pid}").exists()
                      or "Z" in Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0])
    assert not sock.exists() and not (runtime / "gma-ffc.pid").exists()
    assert "stopped: gma-ffc stop" in (runtime / "gma-ffc.log").read_text()
    telemetry = (tmp / "telemetry.csv").read_text().splitlines()
    assert sum(1 for line in telemetry if line and line[0].isdigit()) > snap["ticks"]

    assert "no controller running (socket" in one_line_error(
        cli("status", "--runtime-dir", str(runtime)), 1)
    assert "no controller running" in one_line_error(cli("stop", "--runtime-dir", str(runtime)), 1)


def test_sighup_good_model_then_bad_model(rig):
    tmp, runtime = rig
    cfg = tmp / "sim.yaml"
    res = cli("start", "--config", str(cfg), "--runtime-dir", str(runtime))
    assert res.returncode == 0, res.stderr
    pid = int((runtime / "gma-ffc.pid").read_text())

    write_config(cfg, "model2.yaml")
    os.kill(pid, signal.SIGHUP)
    assert wait_until(lambda: (status_json(runtime)["service"]["last_reload"] or {}).get("ok") is True)

    write_config(cfg, "bad_model.yaml")
    os.kill(pid, signal.SIGHUP)
    assert wait_until(lambda: (status_json(runtime)["service"]["last_reload"] or {}).get("ok") is False)
    snap = status_json(runtime)
    assert snap["state"] == "running" and snap["faults"] == []
    assert "refused, old config kept" in snap["service"]["last_reload"]["message"]
    assert "bad_model.yaml" in snap["service"]["last_reload"]["message"]
    table = cli("status", "--runtime-dir", str(runtime)).stdout
    assert "REFUSED" in table and "bad_model.yaml" in table
    ticks = snap["ticks"]
    assert wait_until(lambda: status_json(runtime)["ticks"] > ticks + RATE_HZ // 4)  # old one runs on

    assert cli("stop", "--runtime-dir", str(runtime)).returncode == 0


def test_run_speaks_notify_protocol_and_writes_stats(rig):
    tmp, runtime = rig
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    name = f"gma-ffc-e2e-{uuid.uuid4().hex}"
    listener.bind("\0" + name)
    listener.settimeout(0.1)
    stats = tmp / "stats" / "final.json"
    env = dict(os.environ, NOTIFY_SOCKET="@" + name, WATCHDOG_USEC="200000")
    env.pop("GMA_FFC_RUNTIME_DIR", None)
    proc = subprocess.Popen([*CLI, "run", "--config", str(tmp / "sim.yaml"), "--runtime-dir",
                             str(runtime), "--stats-json", str(stats)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    messages: list[str] = []

    def collect(until, timeout_s: float = 30.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if until():
                return True
            try:
                messages.append(listener.recv(65536).decode())
            except socket.timeout:
                if proc.poll() is not None:
                    break
        return until()

    try:
        assert collect(lambda: sum("WATCHDOG=1" in m for m in messages) >= 3), (messages, proc.poll())
        ready = [i for i, m in enumerate(messages) if "READY=1" in m]
        assert ready and f"MAINPID={proc.pid}" in messages[ready[0]]
        assert "STATUS=running" in messages[ready[0]]
        assert all("WATCHDOG=1" not in m for m in messages[:ready[0]])   # no pings before READY
        # STATUS= follows when the status text changes (rate, jitter, overruns): allow for a loaded machine
        assert collect(lambda: sum(m.startswith("STATUS=") for m in messages) >= 1, 20.0)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=20)
        collect(lambda: any("STOPPING=1" in m for m in messages), 2.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        listener.close()
    assert proc.returncode == 0, err
    stopping = [i for i, m in enumerate(messages) if "STOPPING=1" in m]
    assert stopping and "SIGTERM" in messages[stopping[0]]
    assert all("WATCHDOG=1" not in m for m in messages[stopping[0]:])
    final = json.loads(stats.read_text())
    assert final["status"]["state"] == "stopped"
    assert final["status"]["service"]["stop_reason"] == "SIGTERM"
    assert final["status"]["driver"]["last_written_A"] == 0.0   # safe current last
    assert not list(stats.parent.glob(".*.tmp"))


def test_bad_usage_and_bad_config_are_one_line_exit_2(rig):
    tmp, runtime = rig
    assert "--config" in one_line_error(cli("run"), 2)
    assert "--duration" in one_line_error(cli("run", "--config", str(tmp / "sim.yaml"),
                                              "--duration", "soon"), 2)
    assert "not found" in one_line_error(cli("run", "--config", str(tmp / "nope.yaml")), 2)
    assert "--timeout" in one_line_error(cli("stop", "--timeout", "0"), 2)
    assert "unrecognized" in one_line_error(cli("status", "--jsn"), 2)

    bad = tmp / "bad.yaml"
    bad.write_text((tmp / "sim.yaml").read_text().replace("rate_hz:", "rate_hzz:"))
    line = one_line_error(cli("run", "--config", str(bad), "--runtime-dir", str(runtime)), 2)
    assert "rate_hzz" in line
    line = one_line_error(cli("start", "--config", str(bad), "--runtime-dir", str(runtime)), 2)
    assert "did not start" in line and "rate_hzz" in line and "gma-ffc.log" in line

    bad.write_text((tmp / "sim.yaml").read_text().replace("model.yaml", "bad_model.yaml"))
    line = one_line_error(cli("start", "--config", str(bad), "--runtime-dir", str(runtime)), 2)
    assert "bad_model.yaml" in line
    assert not (runtime / "control.sock").exists()


def test_unit_file_verifies_and_install_script_renders_it(tmp_path):
    script = ROOT / "scripts" / "install_service.sh"
    assert subprocess.run([str(script), "--help"], capture_output=True).returncode == 0
    res = subprocess.run([str(script), "--frobnicate"], capture_output=True, text=True)
    assert res.returncode == 2 and "unknown option" in res.stderr

    prefix = Path(sys.executable).parent.parent          # the venv: prefix/bin/gma-ffc exists
    assert (prefix / "bin" / "gma-ffc").exists()
    res = subprocess.run([str(script), "--dry-run", "--prefix", str(prefix), "--user", "labuser",
                          "--config", "/etc/gma-ffc/rig2.yaml"], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert "would run: install -m 0644" in res.stderr              # dry run: nothing changed
    unit_text = res.stdout
    assert f"ExecStart={prefix}/bin/gma-ffc run --config /etc/gma-ffc/rig2.yaml\n" in unit_text
    # A Python under a home directory (pyenv, conda) must stay visible, or the unit fails to exec.
    home = str(Path(sys.executable).resolve()).startswith(("/home/", "/root/"))
    assert ("ProtectHome=read-only" if home else "ProtectHome=yes") in unit_text
    for setting in ("Type=notify", "Restart=on-failure", "WatchdogSec=", "NoNewPrivileges=yes",
                    "ProtectSystem=strict", "PrivateTmp=yes", "ReadWritePaths=",
                    "DeviceAllow=char-ttyUSB rw", "ExecReload=/bin/kill -HUP $MAINPID", "User=labuser"):
        assert setting in unit_text, setting

    if shutil.which("systemd-analyze") is None:
        pytest.skip("systemd-analyze is not installed on this machine: unit not verified")
    unit = tmp_path / "gma-ffc.service"
    unit.write_text(unit_text)
    res = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True, text=True)
    assert res.returncode == 0 and res.stdout + res.stderr == "", res.stdout + res.stderr
    # and the check does catch a broken unit (so its silence above means something)
    unit.write_text(unit_text.replace("WatchdogSec=", "WatchdogSecs="))
    res = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True, text=True)
    assert "WatchdogSecs" in res.stdout + res.stderr


def test_start_reports_a_fault_before_ready_in_one_line_exit_1(rig):
    """A Modbus device nobody answers for: start fails with the controller's own reason."""
    import yaml

    tmp, runtime = rig
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()                                   # a free port with nobody listening
    cfg = yaml.safe_load((ROOT / "config" / "modbus_tcp.yaml").read_text())
    cfg["driver"]["devices"]["amp"]["port"] = port
    cfg.update(model=str(tmp / "model.yaml"), telemetry={"path": str(tmp / "mb.csv")},
               comms={"on_fault": "reconnect", "backoff_initial_s": 0.05, "backoff_max_s": 0.1,
                      "max_attempts": 2})
    (tmp / "mb.yaml").write_text(yaml.safe_dump(cfg))
    line = one_line_error(cli("start", "--config", str(tmp / "mb.yaml"), "--runtime-dir", str(runtime)), 1)
    assert "did not start" in line and f"127.0.0.1:{port}" in line and "gave up" in line
    assert not (runtime / "control.sock").exists() and not (runtime / "gma-ffc.pid").exists()


@pytest.mark.realtime
def test_a_frozen_controller_is_shown_not_responding_and_stop_ends_it_at_the_safe_current(rig):
    """A controller stopped by SIGSTOP: its socket's process still answers from the last snapshot,
    which said "running" (a new user's sweep, 2026-11-30), and `stop` gave up after 2 s with exit 1,
    never sending the SIGTERM its help promises. Now the status says it is not responding, and stop
    waits its --timeout, sends SIGTERM (and SIGCONT, so a stopped process takes it), and the
    controller ends at its safe current."""
    tmp, runtime = rig
    res = cli("start", "--config", str(tmp / "sim.yaml"), "--runtime-dir", str(runtime))
    assert res.returncode == 0, res.stderr
    pid = int(res.stdout.split("pid ")[1].split(",")[0])
    assert wait_until(lambda: status_json(runtime)["ticks"] > RATE_HZ // 2)
    os.kill(pid, signal.SIGSTOP)
    try:
        time.sleep(3.0)                                   # past the 2 s a snapshot may age
        table = cli("status", "--runtime-dir", str(runtime))
        assert table.returncode == 0 and "NOT RESPONDING" in table.stdout, table.stdout
        doc = status_json(runtime)
        assert doc["service"]["responding"] is False and doc["service"]["snapshot_age_s"] > 2.0
        res = cli("stop", "--timeout", "1", "--runtime-dir", str(runtime))
    finally:
        os.kill(pid, signal.SIGCONT)
    assert res.returncode == 0, res.stderr
    assert f"stopped with SIGTERM" in res.stdout and f"pid {pid}" in res.stdout
    assert wait_until(lambda: not Path(f"/proc/{pid}").exists()
                      or "Z" in Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0])
    rows = [line.split(",") for line in (tmp / "telemetry.csv").read_text().splitlines()
            if line and line[0].isdigit()]
    assert float(rows[-1][2]) == 0.0                      # current_cmd_A: the safe current


def test_a_model_of_a_voltage_drive_is_refused_by_the_current_controller(rig):
    """The controller writes a current setpoint through every driver: a model identified on a
    voltage drive gives volts, which the amplifier would take as amperes. It ran, exit 0 and no
    fault, on the sim and the Modbus driver (a new user's sweep, 2026-11-30)."""
    tmp, runtime = rig
    model = SDPIModel(play_thresholds=[0.0, 0.1, 0.2, 0.3], play_weights=[8.0, 3.0, 2.0, 1.0],
                      deadzone_thresholds=[-0.5, 0.0, 0.5],
                      deadzone_coeffs=[[0.5, 1.0, 0.3], [-0.01, -0.01, 0.0], [0.0, 0.0, 0.0]],
                      stress_range_MPa=(-25.0, -10.0), drive_range=(0.0, 2.0), drive_name="voltage_V")
    save_model(model, tmp / "volts.yaml")
    write_config(tmp / "volts_cfg.yaml", "volts.yaml")
    res = cli("run", "--config", str(tmp / "volts_cfg.yaml"), "--duration", "0.2", "--no-socket",
              "--runtime-dir", str(runtime))
    line = one_line_error(res, 2)
    assert "the model's drive is voltage_V" in line and "current_A" in line, line
    assert not (tmp / "telemetry.csv").exists()           # refused before anything was driven


def test_the_install_note_on_a_missing_config_gives_a_config_that_loads(tmp_path):
    """install_service.sh's note said to copy a config/*.yaml to /etc/gma-ffc and set its telemetry and
    output_dirs. Followed, the config named 'models/sim_sdpi.yaml' beside it, which was not there: the
    service would not start. The note now says where the model goes; followed, the config loads and
    its controller builds."""
    import re

    from gma_ffc.control.config import load_config
    from gma_ffc.control.manager import ControllerManager

    etc, var = tmp_path / "etc", tmp_path / "var"
    etc.mkdir(), var.mkdir()
    config = etc / "config.yaml"
    res = subprocess.run([str(ROOT / "scripts" / "install_service.sh"), "--dry-run", "--config", str(config)],
                         capture_output=True, text=True)
    note = next(line for line in res.stderr.splitlines() if "does not exist yet" in line)
    model_to = re.search(r"to (\S+/model\.yaml) and set 'model: model\.yaml'", note)
    assert model_to and Path(model_to.group(1)) == etc / "model.yaml", note
    # what the note says, on the shipped simulated rig's config (a real clock is not needed to build)
    shutil.copy(ROOT / "config" / "sim.yaml", config)
    shutil.copy(ROOT / "config" / "models" / "sim_sdpi.yaml", model_to.group(1))
    text = re.sub(r"(?m)^model: .*$", "model: model.yaml", config.read_text())
    text = re.sub(r"(?m)^output_dirs: .*$", f"output_dirs: [{var}]", text)
    config.write_text(re.sub(r"(?m)^  path: telemetry/sim_run.csv", f"  path: {var}/sim_run.csv", text))
    ctrl = ControllerManager(load_config(config))
    assert ctrl.setup.cfg.model == str(etc / "model.yaml")
