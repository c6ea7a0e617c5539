"""The service in-process with a small fake controller that obeys the Controller contract:
notify messages, watchdog only while the loop progresses, SIGHUP/socket reloads (a bad config is
refused and the old one keeps running), stop requests, stats JSON, the control socket's
permissions and peer-credential check."""

from __future__ import annotations

import json
import os
import signal
import socket
import shutil
import stat
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import pytest

from gma_ffc.errors import ConfigError, FaultError
from gma_ffc.service import control_server, control_socket
from gma_ffc.service.notify import Notifier
from gma_ffc.service.paths import RuntimePaths, ensure_private_dir
from gma_ffc.service.runner import Service


class FakeController:
    """Contract: run(stop_event, duration_s) -> summary; status(); request_stop(); reload()."""

    def __init__(self, cfg: dict) -> None:
        self.cfg = cfg
        self.ticks = 0
        self.state = "idle"
        self.stop_reason: str | None = None
        self.stall = threading.Event()       # while set, the loop makes no progress
        self.fault: str | None = None         # when set, the loop ends on this fault
        self.stress_MPa = -15.2
        self.safe_on_exit = False
        self._lock = threading.Lock()

    def run(self, stop_event: threading.Event, duration_s: float | None = None) -> dict:
        self.state = "running"
        t_end = None if duration_s is None else time.monotonic() + duration_s
        try:
            while not stop_event.is_set() and (t_end is None or time.monotonic() < t_end):
                if self.fault:
                    self.state = "fault"
                    break
                if not self.stall.is_set():
                    with self._lock:
                        self.ticks += 1
                stop_event.wait(0.002)
        finally:
            self.safe_on_exit = True
            if self.state != "fault":
                self.state = "stopped"
        return {"ticks": self.ticks, "stop_reason": self.stop_reason}

    def status(self) -> dict[str, Any]:
        with self._lock:
            return {"state": self.state, "ticks": self.ticks, "rate_hz": 500.0,
                    "jitter_us": {"p50": 3.0, "p99": 20.0, "max": 40.0}, "overruns": 0,
                    "stress_MPa": self.stress_MPa, "current_A": 0.1, "reference_um": 1.0,
                    "faults": [self.fault] if self.fault else [], "gain": self.cfg["gain"]}

    def request_stop(self, reason: str) -> None:
        self.stop_reason = reason

    def reload(self, new_cfg: dict) -> None:
        self.cfg = new_cfg


def load_fake_config(path: Path) -> dict:
    text = Path(path).read_text()
    if "gain:" not in text:
        raise ConfigError(f"{path}: key 'gain' is missing")
    return {"gain": float(text.split("gain:")[1].split()[0])}


class NotifyListener:
    """A fake systemd: a datagram socket collecting notify messages."""

    def __init__(self, abstract: bool, tmp: Path) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        if abstract:
            name = f"gma-ffc-test-{uuid.uuid4().hex}"
            self.sock.bind("\0" + name)
            self.env_value = "@" + name
        else:
            path = tmp / "notify.sock"
            self.sock.bind(str(path))
            self.env_value = str(path)
        self.sock.settimeout(0.05)
        self.messages: list[tuple[float, str]] = []

    def drain(self) -> list[str]:
        while True:
            try:
                self.messages.append((time.monotonic(), self.sock.recv(65536).decode()))
            except (socket.timeout, BlockingIOError):
                return [m for _, m in self.messages]

    def close(self) -> None:
        self.sock.close()


def wait_for(predicate, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return predicate()


@pytest.fixture
def cfg_file(tmp_path: Path) -> Path:
    path = tmp_path / "cfg.yaml"
    path.write_text("gain: 1.0\n")
    return path


def make_service(cfg_file: Path, **kw) -> Service:
    made: list[FakeController] = []

    def factory(cfg: dict) -> FakeController:
        made.append(FakeController(cfg))
        return made[-1]

    svc = Service(cfg_file, load_config=load_fake_config, make_controller=factory, **kw)
    svc.made = made  # type: ignore[attr-defined]
    return svc


def run_in_thread(svc: Service) -> tuple[threading.Thread, dict]:
    out: dict = {}

    def target() -> None:
        try:
            out["code"] = svc.run()
        except BaseException as exc:  # noqa: BLE001 - the test inspects it
            out["error"] = exc

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    return thread, out


@pytest.mark.realtime   # watchdog pings every 20 ms, windows of 0.15-0.4 s on the wall clock
@pytest.mark.parametrize("abstract", [True, False], ids=["abstract", "path"])
def test_notify_ready_status_watchdog_only_while_progressing_then_stopping(tmp_path, cfg_file, abstract):
    listener = NotifyListener(abstract, tmp_path)
    env = {"NOTIFY_SOCKET": listener.env_value, "WATCHDOG_USEC": "40000"}  # ping every 20 ms
    svc = make_service(cfg_file, notifier=Notifier(env), install_signal_handlers=False)
    thread, out = run_in_thread(svc)
    try:
        assert wait_for(lambda: any("READY=1" in m for m in listener.drain()))
        assert wait_for(lambda: sum("WATCHDOG=1" in m for m in listener.drain()) >= 3)
        ready = next(m for m in listener.messages if "READY=1" in m[1])[1]
        assert f"MAINPID={os.getpid()}" in ready and "STATUS=running" in ready
        ctrl = svc.made[0]
        ctrl.stall.set()                                   # the loop stops making progress
        time.sleep(0.15)                                   # let the supervisor see the stall
        listener.drain()
        n_before = len(listener.messages)
        time.sleep(0.4)                                    # 20 ping periods
        stalled = [m for _, m in listener.messages[n_before:]] + listener.drain()[n_before:]
        assert not any("WATCHDOG=1" in m for m in stalled), stalled
        ctrl.stall.clear()                                 # progress again: pings resume
        assert wait_for(lambda: any("WATCHDOG=1" in m for m in listener.drain()[n_before:]))
        n_before = len(listener.messages)
        ctrl.stress_MPa = -19.1                            # a changed status is reported
        assert wait_for(lambda: any(m.startswith("STATUS=") and "-19.1 MPa" in m
                                    for m in listener.drain()[n_before:]), 3.0)
        svc.request_stop("test")
        thread.join(10)
        assert out == {"code": 0}
        messages = listener.drain()
        stopping = [m for m in messages if "STOPPING=1" in m]
        assert stopping and "test" in stopping[0]
        assert "WATCHDOG=1" not in messages[-1]
        assert ctrl.safe_on_exit
    finally:
        svc.request_stop("teardown")
        thread.join(10)
        listener.close()


@pytest.mark.realtime   # a 0.5 s grace judged in windows of 0.25-0.5 s on the wall clock
def test_watchdog_fed_while_reconnecting_only_within_grace(tmp_path, cfg_file, monkeypatch):
    """A reconnect (no ticks, amplifier safe) is not a hang, but one that lasts too long is."""
    from gma_ffc.service import runner

    listener = NotifyListener(True, tmp_path)
    env = {"NOTIFY_SOCKET": listener.env_value, "WATCHDOG_USEC": "40000"}
    svc = make_service(cfg_file, notifier=Notifier(env), install_signal_handlers=False)
    monkeypatch.setattr(runner, "RECONNECT_GRACE_S", 0.5)
    thread, out = run_in_thread(svc)
    try:
        assert wait_for(lambda: any("READY=1" in m for m in listener.drain()))
        ctrl = svc.made[0]
        ctrl.stall.set()
        ctrl.state = "reconnecting"
        time.sleep(0.1)
        n0 = len(listener.drain())
        time.sleep(0.25)                                   # inside the grace: still fed
        assert any("WATCHDOG=1" in m for m in listener.drain()[n0:])
        time.sleep(0.5)                                    # grace over
        n1 = len(listener.drain())
        time.sleep(0.3)
        assert not any("WATCHDOG=1" in m for m in listener.drain()[n1:])
    finally:
        svc.request_stop("teardown")
        thread.join(10)
        listener.close()
    assert out == {"code": 0}


def test_socket_path_too_long_is_a_clear_config_error(tmp_path):
    deep = tmp_path / ("d" * 120)
    with pytest.raises(ConfigError, match="shorter --runtime-dir"):
        control_socket.request(deep / "control.sock", {"cmd": "status"})


def test_without_notify_socket_notifier_is_silent():
    notifier = Notifier({})
    assert not notifier.enabled
    assert notifier.ready() is False and notifier.watchdog() is False
    assert Notifier({"NOTIFY_SOCKET": "@x", "WATCHDOG_USEC": "1000000"}).watchdog_interval_s == 0.5
    assert Notifier({"WATCHDOG_USEC": "1000000", "WATCHDOG_PID": "1"}).watchdog_interval_s is None


def test_notifier_gives_up_when_listener_is_gone(tmp_path):
    listener = NotifyListener(False, tmp_path)
    notifier = Notifier({"NOTIFY_SOCKET": listener.env_value})
    assert notifier.status("one")
    listener.close()
    os.unlink(listener.env_value)
    assert notifier.status("two") is False
    assert not notifier.enabled


def test_sighup_reload_good_then_bad_keeps_old(tmp_path, cfg_file):
    """Signal handlers live in the main thread: the service runs there, the checks in a helper."""
    runtime = RuntimePaths(tmp_path / "rt")
    svc = make_service(cfg_file, runtime=runtime)
    errors: list[BaseException] = []

    def body() -> None:
        try:
            assert wait_for(lambda: runtime.socket.exists() and svc.status()["service"]["ready"])
            cfg_file.write_text("gain: 2.5\n")
            os.kill(os.getpid(), signal.SIGHUP)
            assert wait_for(lambda: (svc.status()["service"]["last_reload"] or {}).get("ok") is True)
            assert svc.status()["gain"] == 2.5
            cfg_file.write_text("nonsense: true\n")
            os.kill(os.getpid(), signal.SIGHUP)
            assert wait_for(lambda: (svc.status()["service"]["last_reload"] or {}).get("ok") is False)

            def over_socket() -> dict:   # a snapshot published after the reload (at most 0.5 s old)
                return control_socket.request(runtime.socket, {"cmd": "status"})["status"]

            assert wait_for(lambda: over_socket()["service"]["last_reload"]["ok"] is False)
            status = over_socket()
            assert status["gain"] == 2.5 and status["state"] == "running"
            assert "refused" in status["service"]["last_reload"]["message"]
            assert "gain" in status["service"]["last_reload"]["message"]
            ticks = status["ticks"]
            assert wait_for(lambda: svc.status()["ticks"] > ticks)   # the old one keeps running
            reply = control_socket.request(runtime.socket, {"cmd": "reload"})   # socket reload too
            assert reply["ok"] is False and "gain" in reply["error"]
            cfg_file.write_text("gain: 3.0\n")
            assert control_socket.request(runtime.socket, {"cmd": "reload"})["ok"] is True
            assert svc.status()["gain"] == 3.0
            os.kill(os.getpid(), signal.SIGTERM)                       # a clean stop on SIGTERM
            assert wait_for(lambda: svc.status()["service"]["stop_reason"] is not None)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the main thread
            errors.append(exc)
        finally:
            svc.request_stop("teardown")

    previous = signal.getsignal(signal.SIGTERM)
    helper = threading.Thread(target=body, daemon=True)
    helper.start()
    code = svc.run()
    helper.join(10)
    assert signal.getsignal(signal.SIGTERM) is previous            # handlers restored
    if errors:
        raise errors[0]
    assert code == 0
    assert svc.status()["service"]["stop_reason"] == "SIGTERM"
    assert svc.made[0].safe_on_exit


def test_stop_over_socket_writes_stats_and_cleans_up(tmp_path, cfg_file):
    runtime = RuntimePaths(tmp_path / "rt")
    stats = tmp_path / "out" / "stats.json"
    svc = make_service(cfg_file, runtime=runtime, stats_json=stats, install_signal_handlers=False)
    thread, out = run_in_thread(svc)
    try:
        assert wait_for(lambda: runtime.socket.exists() and svc.status()["service"]["ready"])
        assert int(runtime.pid_file.read_text()) == os.getpid()
        reply = control_socket.request(runtime.socket, {"cmd": "bogus"})
        assert reply["ok"] is False and "unknown command" in reply["error"]
        assert control_socket.request(runtime.socket, {"cmd": "stop", "reason": "by test"})["ok"]
        thread.join(10)
    finally:
        svc.request_stop("teardown")
        thread.join(10)
    assert out == {"code": 0}
    assert not runtime.socket.exists() and not runtime.pid_file.exists()
    data = json.loads(stats.read_text())
    assert data["status"]["service"]["stop_reason"] == "by test"
    assert data["status"]["ticks"] > 0 and data["summary"]["ticks"] == data["status"]["ticks"]


def test_duration_ends_run_and_fault_gives_exit_1(tmp_path, cfg_file):
    svc = make_service(cfg_file, duration_s=0.1, install_signal_handlers=False)
    assert svc.run() == 0
    assert svc.status()["state"] == "stopped"

    svc = make_service(cfg_file, install_signal_handlers=False)
    thread, out = run_in_thread(svc)
    assert wait_for(lambda: svc.made and svc.status()["service"]["ready"])
    svc.made[0].fault = "comms timeout"
    thread.join(10)
    assert isinstance(out.get("error"), FaultError)
    assert "comms timeout" in str(out["error"])


def test_second_service_on_same_socket_is_refused(tmp_path, cfg_file):
    runtime = RuntimePaths(tmp_path / "rt")
    first = make_service(cfg_file, runtime=runtime, install_signal_handlers=False)
    thread, out = run_in_thread(first)
    try:
        assert wait_for(lambda: runtime.socket.exists() and first.status()["service"]["ready"])
        second = make_service(cfg_file, runtime=runtime, install_signal_handlers=False)
        with pytest.raises(FaultError, match="already running"):
            second.run()
        assert control_socket.is_answering(runtime.socket)   # the first one is untouched
    finally:
        first.request_stop("teardown")
        thread.join(10)


def test_a_controller_still_starting_is_named_by_its_pid_not_pid_question_mark(tmp_path, cfg_file):
    """Between its socket and its pid file (the model is being built) a controller answers, but a
    second `start` or `run` read the missing pid file and named it "pid ?"."""
    from gma_ffc.service import daemon
    from gma_ffc.service.control_plane import ControlPlane

    runtime = RuntimePaths(tmp_path / "rt")
    ensure_private_dir(runtime.directory)
    plane = ControlPlane(runtime.socket, lambda request: {"ok": True}).start()
    try:
        assert not runtime.pid_file.exists()                      # as while the first one starts
        second = make_service(cfg_file, runtime=runtime, install_signal_handlers=False)
        with pytest.raises(FaultError) as refused:
            second.run()
        with pytest.raises(FaultError) as started:
            daemon.start(cfg_file, runtime, timeout_s=5.0)
        for exc in (refused.value, started.value):
            assert f"already running (pid {os.getpid()}," in str(exc) and "pid ?" not in str(exc)
            assert f"'gma-ffc stop --runtime-dir {runtime.directory}'" in str(exc)
        assert not second.made and control_socket.is_answering(runtime.socket)
    finally:
        plane.close()


def test_a_controller_whose_pid_cannot_be_told_is_said_to_be_starting(tmp_path):
    """An answer without a pid and no pid file: the refusal says what is going on and what to do."""
    runtime = RuntimePaths(tmp_path / "rt")
    ensure_private_dir(runtime.directory)
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(str(runtime.socket))
    server.listen(1)

    def answer() -> None:
        conn, _ = server.accept()
        conn.recv(4096)
        conn.sendall(b'{"ok": true}\n')
        conn.close()

    threading.Thread(target=answer, daemon=True).start()
    try:
        with pytest.raises(FaultError) as refused:
            control_socket.refuse_if_running(runtime)
    finally:
        server.close()
    text = str(refused.value)
    assert "pid ?" not in text and f"another controller is starting in {runtime.directory}" in text
    assert f"'gma-ffc status --runtime-dir {runtime.directory}'" in text and "another --runtime-dir" in text


def test_two_controllers_starting_at_once_one_runs_the_other_names_it(tmp_path, cfg_file, monkeypatch):
    """Both looked at the socket before either bound it: both ran, the second's socket replacing
    the first's. The look and the bind are now one step (the runtime folder's claim lock)."""
    from gma_ffc.service import runner

    look = runner.refuse_if_running

    def slow_look(*args):           # the window between the look and the bind, made wide
        look(*args)
        time.sleep(0.5)

    monkeypatch.setattr(runner, "refuse_if_running", slow_look)
    runtime = RuntimePaths(tmp_path / "rt")
    services = [make_service(cfg_file, runtime=runtime, install_signal_handlers=False) for _ in range(2)]
    runs = [run_in_thread(svc) for svc in services]
    try:
        assert wait_for(lambda: any(out for _, out in runs) or all(svc.made for svc in services), 20)
        assert wait_for(lambda: any(out for _, out in runs), 5), "both controllers ran"
        errors = [out.get("error") for _, out in runs if out.get("error")]
        assert len(errors) == 1 and "already running (pid" in str(errors[0])
        assert sum(1 for svc in services if svc.made) == 1
    finally:
        for (thread, _), svc in zip(runs, services):
            svc.request_stop("teardown")
            thread.join(10)


def test_runtime_dir_and_socket_are_owner_only(tmp_path, cfg_file):
    runtime = RuntimePaths(tmp_path / "rt")
    runtime.directory.mkdir(mode=0o755)
    svc = make_service(cfg_file, runtime=runtime, install_signal_handlers=False)
    thread, out = run_in_thread(svc)
    try:
        assert wait_for(lambda: runtime.socket.exists())
        assert stat.S_IMODE(runtime.directory.stat().st_mode) == 0o700
        info = runtime.socket.stat()
        assert stat.S_ISSOCK(info.st_mode) and stat.S_IMODE(info.st_mode) == 0o600
        assert info.st_uid == os.geteuid()
    finally:
        svc.request_stop("teardown")
        thread.join(10)


def test_runtime_dir_of_another_user_is_refused(tmp_path):
    if os.geteuid() != 0:
        pytest.skip("needs root to create a directory owned by another uid")
    other = tmp_path / "other"
    other.mkdir(mode=0o700)
    os.chown(other, 65534, 65534)
    with pytest.raises(ConfigError, match="belongs to uid 65534"):
        ensure_private_dir(other)


def test_peer_credentials_are_checked(tmp_path):
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    with a, b:
        pid, uid, gid = control_socket.peer_credentials(a)
    assert (pid, uid, gid) == (os.getpid(), os.geteuid(), os.getegid())
    assert control_socket.peer_allowed(uid, uid)
    assert not control_socket.peer_allowed(uid + 1, uid)
    assert not control_socket.peer_allowed(0, 1000)          # not even root


def test_server_refuses_a_peer_with_another_uid(tmp_path):
    """A server that believes it belongs to another uid must refuse us, and never call the handler."""
    calls: list = []
    path = tmp_path / "s.sock"
    server = control_server.ControlServer(path, lambda r: calls.append(r) or {"ok": True},
                                          owner_uid=os.geteuid() + 12345).start()
    try:
        reply = control_socket.request(path, {"cmd": "status"})
    finally:
        server.close()
    assert reply["ok"] is False and "permission denied" in reply["error"]
    assert calls == []
    assert not path.exists()


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to connect as another uid")
def test_real_other_uid_is_refused(tmp_path):
    """A process running as 'nobody' cannot use the socket even when the file mode lets it in."""
    calls: list = []
    d = Path(tempfile.mkdtemp(prefix="gma-ffc-peer-"))    # under /tmp, which nobody can traverse
    os.chmod(d, 0o777)
    path = d / "s.sock"
    server = control_server.ControlServer(path, lambda r: calls.append(r) or {"ok": True}).start()
    os.chmod(path, 0o666)                          # simulate a loosened socket file
    read_fd, write_fd = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: drop to nobody, ask, report the reply through the pipe
        try:
            os.close(read_fd)
            os.setgid(65534)
            os.setuid(65534)
            try:
                reply = control_socket.request(path, {"cmd": "status"}, timeout_s=3.0)
                text = json.dumps(reply)
            except Exception as exc:  # noqa: BLE001
                text = json.dumps({"exception": str(exc)})
            os.write(write_fd, text.encode())
        finally:
            os._exit(0)
    os.close(write_fd)
    try:
        with os.fdopen(read_fd) as fh:
            reply = json.loads(fh.read() or "{}")
        os.waitpid(pid, 0)
    finally:
        server.close()
        shutil.rmtree(d, ignore_errors=True)
    assert reply.get("ok") is False and "permission denied" in reply.get("error", ""), reply
    assert calls == []


STUBBORN = r"""
import os, signal, sys, time, threading
from pathlib import Path
from gma_ffc.service.control_server import ControlServer
rt = Path(sys.argv[1]); answer = sys.argv[2] == "answer"
got_term = threading.Event()
signal.signal(signal.SIGTERM, lambda *a: got_term.set())
server = ControlServer(rt / "control.sock", lambda r: {"ok": True, "pid": os.getpid(), "status": {}}).start() \
    if answer else None
(rt / "gma-ffc.pid").write_text(f"{os.getpid()}\n")
print("up", flush=True)
deadline = time.monotonic() + 30
while not got_term.is_set() and time.monotonic() < deadline:   # ignores 'stop' requests
    time.sleep(0.02)
if server:
    server.close()
"""


@pytest.mark.parametrize("answer", ["answer", "silent"])
def test_stop_escalates_to_sigterm(tmp_path, answer):
    """A controller that ignores the stop request (or whose socket is dead) gets SIGTERM."""
    import subprocess
    import sys

    from gma_ffc.service.daemon import process_alive, stop

    runtime = RuntimePaths(tmp_path / "rt")
    ensure_private_dir(runtime.directory)
    proc = subprocess.Popen([sys.executable, "-c", STUBBORN, str(runtime.directory), answer],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "up"
        result = stop(runtime, timeout_s=0.3, term_timeout_s=10.0)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert result.pid == proc.pid and not process_alive(proc.pid)
    expected = "after it ignored the request" if answer == "answer" else "its socket did not answer"
    assert result.how.startswith("stopped with SIGTERM") and expected in result.how


def test_stop_refused_by_another_owner_never_signals(tmp_path):
    """Not the owner: stop reports the refusal and sends no signal to the pid in the pid file."""
    import subprocess
    import sys

    from gma_ffc.service.daemon import process_alive, stop

    runtime = RuntimePaths(tmp_path / "rt")
    ensure_private_dir(runtime.directory)
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)  # gma_ffc"])
    runtime.pid_file.write_text(f"{sleeper.pid}\n")
    server = control_server.ControlServer(runtime.socket, lambda r: {"ok": True},
                                          owner_uid=os.geteuid() + 4242).start()
    try:
        with pytest.raises(FaultError, match="permission denied"):
            stop(runtime, timeout_s=0.2, term_timeout_s=0.2)
        assert process_alive(sleeper.pid)
        assert control_socket.is_answering(runtime.socket)     # a refusal is still a live controller
    finally:
        server.close()
        sleeper.kill()
        sleeper.wait()


def test_stale_pid_file_of_an_unrelated_process_is_not_signalled(tmp_path):
    import subprocess
    import sys

    from gma_ffc.service.daemon import process_alive, stop

    runtime = RuntimePaths(tmp_path / "rt")
    ensure_private_dir(runtime.directory)
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    runtime.pid_file.write_text(f"{other.pid}\n")                # as if the pid had been reused
    try:
        with pytest.raises(FaultError, match="no controller running"):
            stop(runtime, timeout_s=0.2, term_timeout_s=0.2)
        assert process_alive(other.pid)
    finally:
        other.kill()
        other.wait()


def test_default_runtime_dir_order(tmp_path, monkeypatch):
    from gma_ffc.service import paths

    monkeypatch.setattr(paths, "SYSTEM_RUNTIME_DIR", str(tmp_path / "absent"))
    assert paths.default_runtime_dir({"GMA_FFC_RUNTIME_DIR": "/a", "RUNTIME_DIRECTORY": "/b"}) == Path("/a")
    assert paths.default_runtime_dir({"RUNTIME_DIRECTORY": "/b:/c", "XDG_RUNTIME_DIR": "/x"}) == Path("/b")
    assert paths.default_runtime_dir({"XDG_RUNTIME_DIR": "/x"}) == Path("/x/gma-ffc")
    system = tmp_path / "system"                          # the systemd service's, and ours
    system.mkdir()
    monkeypatch.setattr(paths, "SYSTEM_RUNTIME_DIR", str(system))
    assert paths.default_runtime_dir({"XDG_RUNTIME_DIR": "/x"}) == system
    if os.geteuid() == 0:                                 # someone else's: not chosen
        os.chown(system, 65534, 65534)
        assert paths.default_runtime_dir({"XDG_RUNTIME_DIR": "/x"}) == Path("/x/gma-ffc")


def test_status_table_and_line_show_faults_and_reload():
    from gma_ffc.service.status import format_table, status_line

    snap = {"state": "fault", "ticks": 1234, "target_rate_hz": 1000.0, "achieved_rate_hz": 998.7,
            "jitter_p50_us": 2.5, "jitter_p99_us": 41.0, "jitter_max_us": 120.0, "overruns": 3,
            "stress_MPa": -19.1, "current_cmd_A": 0.0, "current_A": 0.01, "reference_um": 12.5,
            "faults": ["comms_timeout"], "fault_messages": {"comms_timeout": "no answer in 20 ms"},
            "service": {"pid": 42, "last_reload": {"ok": False, "message": "reload refused: bad",
                                                   "at_unix": 0.0}}}
    table = format_table(snap)
    rows = {line.split("  ")[0].strip(): line for line in table.splitlines()}
    assert "998.7 Hz (target 1000 Hz)" in rows["rate"]
    assert "p50 2.5 us" in rows["period jitter"] and "p99 41.0 us" in rows["period jitter"]
    assert "max 120.0 us" in rows["period jitter"] and rows["overruns"].endswith("3")
    assert "-19.10 MPa" in rows["stress"] and "12.500 um" in rows["reference"]
    assert "comms_timeout: no answer in 20 ms" in rows["faults"]
    assert "REFUSED" in rows["last reload"] and rows["pid"].endswith("42")
    line = status_line(snap)
    assert line.startswith("fault:") and "comms_timeout" in line and "\n" not in line
    assert "control socket" not in rows
    attacked = format_table({**snap, "control_socket": {"served": 9, "refused_uid": 4, "evicted": 2}})
    assert "4 connections from other users refused, 2 idle connections closed" in attacked
    empty = format_table({"state": "starting"})             # nothing measured yet: dashes
    assert "rate           -" in empty and "faults         none" in empty


def test_faults_that_recovered_are_shown_beside_no_active_fault():
    """Comms faults that reconnected left no active fault: the table said 'faults none' through
    9 of them in 3 s, and only --json had fault_counts (a new user's sweep, 2026-11-30)."""
    from gma_ffc.service.status import fields

    snap = {"state": "running", "faults": [], "fault_messages": {}, "fault_counts": {"comms_error": 9},
            "fault_history": [{"fault": "comms_error", "message": "read input 0+3: connection lost",
                               "at_unix_s": 990.0, "tick": 12}]}
    rows = dict(fields(snap, now=1000.0))
    assert rows["faults"] == "none"
    assert rows["faults since start"] == "comms_error 9"
    assert rows["last recovered"] == "comms_error 10.0 s ago: read input 0+3: connection lost"
    still = dict(fields({**snap, "faults": ["comms_error"], "fault_messages": {"comms_error": "down"}}, now=1000.0))
    assert still["faults since start"] == "comms_error 9" and "last recovered" not in still   # active, not recovered
    assert "faults since start" not in dict(fields({"state": "running", "fault_counts": {}}))


def test_a_running_state_the_snapshot_age_or_the_watchdog_contradicts_is_not_shown_as_running():
    from gma_ffc.service.status import state_words

    fresh = {"state": "running", "service": {"status_at_unix": 1000.0}, "faults": []}
    assert state_words(fresh, now=1000.4) == "running"
    assert state_words(fresh, now=1005.7).startswith("NOT RESPONDING: its last snapshot is 5.7 s old")
    stuck = {**fresh, "fault_messages": {"watchdog": "the loop made no progress for 1.2 s"}}
    assert "STUCK" in state_words(stuck, now=1000.4)
    assert state_words({**fresh, "state": "fault"}, now=1005.7) == "fault"     # an ended run is what it says


def test_a_current_the_amplifier_did_not_report_is_not_called_measured():
    """With the readback missing or absurd the command stands in for it; status said "measured
    1.0071 A" all the same (a new user's sweep, 2026-11-30)."""
    from gma_ffc.service.status import fields

    row = dict(fields({"state": "running", "current_cmd_A": 1.0071, "current_A": 1.0071, "current_measured": False}))
    assert row["current"] == "command 1.0071 A, measured - (no reading: telemetry's current_A is the command)"
    row = dict(fields({"state": "running", "current_cmd_A": 1.0071, "current_A": 1.0012, "current_measured": True}))
    assert row["current"] == "command 1.0071 A, measured 1.0012 A"


def test_a_loop_that_cannot_keep_its_rate_says_so():
    """5 kHz over Modbus ran at 2.5 kHz with every tick an overrun and 'faults none' (a new user's
    sweep, 2026-11-30): nothing told the user the rate asked for was not kept."""
    from gma_ffc.service.status import fields

    behind = dict(fields({"state": "running", "achieved_rate_hz": 2517.7, "target_rate_hz": 5000,
                          "overruns": 7749, "ticks": 7749}))
    assert behind["rate"].startswith("2517.7 Hz (target 5000 Hz); CANNOT KEEP IT: 100 % of ticks overran")
    keeping = dict(fields({"state": "running", "achieved_rate_hz": 999.9, "target_rate_hz": 1000,
                           "overruns": 3, "ticks": 60000}))
    assert keeping["rate"] == "999.9 Hz (target 1000 Hz)"


@pytest.mark.parametrize("model", [123, "", ["m.yaml"]])
def test_a_reload_with_a_model_that_is_no_path_is_refused_not_ignored(cfg_file, model):
    """{"cmd": "reload", "model": 123} answered ok and re-read the config instead (a new user's
    sweep, 2026-11-30): a field that cannot mean what was asked is refused, the model kept."""
    svc = make_service(cfg_file)
    reply = svc.handle_request({"cmd": "reload", "model": model})
    assert reply["ok"] is False and "'model' must be a model file's path" in reply["error"]


def test_a_runtime_folder_that_cannot_be_made_gives_advice_that_is_not_what_was_just_done(tmp_path):
    """'--runtime-dir /ro/x' failed with 'pass --runtime-dir', which had just been done."""
    from gma_ffc.service.paths import ensure_private_dir

    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(ConfigError, match=r"give --runtime-dir \(or GMA_FFC_RUNTIME_DIR\) a folder this user may create"):
        ensure_private_dir(blocker / "x")


def test_a_background_diagnosis_that_concluded_nothing_says_why_and_quotes_no_unscored_rms():
    """The status read 'inconclusive: no effect named (held-out RMS 0.462 -> 0.462 um)' where
    nothing had been scored, and the reason stood only in the JSON (a new user's sweep, 2026-11-30)."""
    from gma_ffc.service.status import summary_words

    last = {"outcome": "inconclusive", "effects": [], "rms_before_um": 0.462, "rms_after_um": 0.462, "scored": False,
            "cannot_conclude": ["none of it is scored: 0 samples", "record longer"]}
    words = summary_words(last)
    assert words == "inconclusive: no effect named; first of 2 reasons: none of it is scored: 0 samples"
    named = {"outcome": "effects_named", "effects": ["thermal_drift"], "rms_before_um": 0.5, "rms_after_um": 0.1,
             "scored": True, "cannot_conclude": ["something minor"]}
    assert summary_words(named) == "effects_named: thermal_drift (held-out RMS 0.5 -> 0.1 um)"


def test_ctrl_c_while_start_waits_stops_the_controller_it_was_starting(tmp_path, monkeypatch, capsys):
    """Ctrl-C during `gma-ffc start`'s wait for READY said "interrupted" and left the controller
    starting: it then ran on, driving the rig, after the one who started it had cancelled. The wait
    now sends it SIGTERM and waits for it; the command says so, exit 130."""
    import subprocess
    import sys

    from gma_ffc.cli import main
    from gma_ffc.service import daemon

    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])

    class CtrlC:
        def settimeout(self, _s):
            pass

        def recv(self, _n):
            raise KeyboardInterrupt

    try:
        with pytest.raises(daemon.StartInterrupted):
            daemon._wait_ready(child, CtrlC(), RuntimePaths(tmp_path / "rt"), 0, 30.0)
        assert child.poll() == -signal.SIGTERM
    finally:
        child.kill()
        child.wait()

    cfg = tmp_path / "c.yaml"
    cfg.write_text("model: m.yaml\n")
    for raised, said in ((daemon.StartInterrupted, "; the controller it was starting was stopped (SIGTERM)"),
                         (KeyboardInterrupt, "")):       # before any controller was started: nothing to stop
        def interrupted_start(*_a, raised=raised, **_k):
            raise raised
        monkeypatch.setattr(daemon, "start", interrupted_start)
        assert main(["start", "--config", str(cfg), "--runtime-dir", str(tmp_path / "rt")]) == 130
        err = capsys.readouterr().err
        assert err == f"gma-ffc start: interrupted{said}\n", err


def test_ctrl_c_while_the_commands_load_is_one_line_not_a_traceback(monkeypatch, capsys):
    """Ctrl-C in the half second every command spends importing numba printed a 50-line traceback."""
    import gma_ffc.cli as cli

    def slow_import():
        raise KeyboardInterrupt
    monkeypatch.setattr(cli, "build_parser", slow_import)
    assert cli.main(["status"]) == 130
    assert capsys.readouterr().err == "gma-ffc: interrupted\n"
