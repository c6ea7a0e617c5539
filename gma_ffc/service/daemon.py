"""`gma-ffc start` / `stop`: the foreground service (`gma-ffc run`) as a background process.

`start` spawns `gma-ffc run` in its own session with its output in the log file and listens on
a private notify socket of its own, exactly as systemd would: it returns when the child sends
READY=1, or reports the child's own error line when it exits first. `stop` asks over the control
socket, waits, escalates to SIGTERM, and reports. It never sends SIGKILL on its own: that would
skip the controller's safe-current exit path.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from .. import safe_files
from ..errors import FaultError, GmaError, InputError, NoAnswerError, NotRunningError
from .control_socket import ask, check_socket_path, refuse_if_running, request
from .paths import RuntimePaths, ensure_private_dir

POLL_S = 0.05


@dataclass
class Started:
    pid: int
    status: str


def process_alive(pid: int) -> bool:
    """True while `pid` runs (a zombie, exited but not yet reaped, counts as gone)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True
    return stat.rsplit(")", 1)[-1].split()[0] != "Z"


def looks_like_gma_ffc(pid: int) -> bool:
    """A pid from a stale pid file may have been reused: only signal a gma-ffc process."""
    try:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")
    except OSError:
        return False
    return b"gma_ffc" in cmdline or b"gma-ffc" in cmdline


def read_pid(path: Path) -> int | None:
    try:
        pid = int(path.read_text().strip())
    except (OSError, ValueError):
        return None
    return pid if pid > 0 else None


def start(config: Path, runtime: RuntimePaths, *, duration_s: float | None = None,
          timeout_s: float = 60.0, python: str = sys.executable) -> Started:
    """Spawn the service and wait until it is ready; raise with its reason if it is not."""
    from ..control.config import check_config_file

    config = Path(config)
    check_config_file(config)
    ensure_private_dir(runtime.directory)
    refuse_if_running(runtime, read_pid(runtime.pid_file))
    notify_path = runtime.directory.absolute() / f"start-{os.getpid()}.notify"
    check_socket_path(notify_path)
    with contextlib.suppress(FileNotFoundError):
        notify_path.unlink()
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
    old_umask = os.umask(0o177)
    try:
        listener.bind(str(notify_path))
    finally:
        os.umask(old_umask)
    cmd = [python, "-m", "gma_ffc.cli", "run", "--config", str(config.resolve()),
           "--runtime-dir", str(runtime.directory.absolute())]
    if duration_s is not None:
        cmd += ["--duration", repr(float(duration_s))]
    env = dict(os.environ, NOTIFY_SOCKET=str(notify_path))
    if env.get("PYTHONPATH"):        # the child runs in /: a relative entry keeps meaning the caller's folder
        env["PYTHONPATH"] = os.pathsep.join(os.path.abspath(p) if p else p for p in env["PYTHONPATH"].split(os.pathsep))
    for key in ("WATCHDOG_USEC", "WATCHDOG_PID", "LISTEN_FDS", "LISTEN_PID"):
        env.pop(key, None)
    log_offset = runtime.log_file.stat().st_size if runtime.log_file.exists() else 0
    try:
        fd = safe_files.open_for_writing(runtime.log_file, (runtime.directory,), safe_files.LOG,
                                         append=True, mode=0o600)
        with os.fdopen(fd, "ab") as log:
            # cwd /: `python -m` puts the working folder first on sys.path, so a `gma_ffc` folder
            # there (another checkout) would be the code the service runs
            child = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=log, cwd="/",
                                     env=env, start_new_session=True, close_fds=True)
        return _wait_ready(child, listener, runtime, log_offset, timeout_s)
    finally:
        listener.close()
        with contextlib.suppress(FileNotFoundError):
            notify_path.unlink()


class StartInterrupted(KeyboardInterrupt):
    """Ctrl-C while a controller was starting: it was sent SIGTERM (and waited for)."""


# How long an interrupted start waits for the controller it was starting to leave after SIGTERM: a
# controller still importing dies at once, one past its start ramps to the safe current (a few s).
ABANDON_WAIT_S = 5.0


def _wait_ready(child: subprocess.Popen, listener: socket.socket, runtime: RuntimePaths,
                log_offset: int, timeout_s: float) -> Started:
    """Wait for READY; Ctrl-C (KeyboardInterrupt) stops the controller being started, then goes on up:
    it ran on, driving the rig, after the one who started it had cancelled."""
    try:
        return _wait_ready_loop(child, listener, runtime, log_offset, timeout_s)
    except KeyboardInterrupt:
        with contextlib.suppress(ProcessLookupError):
            child.send_signal(signal.SIGTERM)
        with contextlib.suppress(subprocess.TimeoutExpired):
            child.wait(ABANDON_WAIT_S)
        raise StartInterrupted from None


def _wait_ready_loop(child: subprocess.Popen, listener: socket.socket, runtime: RuntimePaths,
                     log_offset: int, timeout_s: float) -> Started:
    deadline = time.monotonic() + timeout_s
    listener.settimeout(POLL_S)
    while time.monotonic() < deadline:
        try:
            message = listener.recv(65536).decode("utf-8", "replace")
        except socket.timeout:
            message = ""
        fields = dict(line.split("=", 1) for line in message.splitlines() if "=" in line)
        if fields.get("READY") == "1":
            return Started(int(fields.get("MAINPID", child.pid)), fields.get("STATUS", ""))
        code = child.poll()
        if code is not None:
            reason = _last_error(runtime.log_file, log_offset) or f"it exited with code {code}"
            error: type[GmaError] = InputError if code == 2 else FaultError
            raise error(f"the controller did not start: {reason} (log: {runtime.log_file})")
    with contextlib.suppress(ProcessLookupError):
        child.send_signal(signal.SIGTERM)
    raise FaultError(f"the controller did not report ready within {timeout_s:g} s; it was sent "
                     f"SIGTERM (log: {runtime.log_file})")


def _last_error(log_file: Path, offset: int) -> str | None:
    """The child's one-line error (the CLI prints 'gma-ffc run: error: ...')."""
    try:
        with open(log_file, "rb") as fh:
            fh.seek(offset)
            lines = fh.read().decode("utf-8", "replace").splitlines()
    except OSError:
        return None
    for line in reversed(lines):
        if ": error: " in line:
            return line.split(": error: ", 1)[1].strip()
    for line in reversed(lines):
        if line.strip():
            return line.strip()
    return None


@dataclass
class Stopped:
    pid: int | None
    how: str
    final_status: dict | None


def stop(runtime: RuntimePaths, *, timeout_s: float = 10.0, term_timeout_s: float = 5.0) -> Stopped:
    """Ask the controller to stop; SIGTERM if it does not; report what happened."""
    pid = read_pid(runtime.pid_file)
    final: dict | None = None
    try:
        reply = request(runtime.socket, {"cmd": "status"}, timeout_s=2.0)
    except FaultError:
        if pid is None or not process_alive(pid) or not looks_like_gma_ffc(pid):
            raise NotRunningError(f"no controller running (socket {runtime.socket})") from None
        asked = False     # a live controller behind a dead socket: straight to SIGTERM
    else:
        if not reply.get("ok"):   # e.g. not the owner: never signal someone else's controller
            raise FaultError(str(reply.get("error", "the controller refused the request")))
        final = reply.get("status")
        try:
            reply = ask(runtime.socket, {"cmd": "stop", "reason": "gma-ffc stop"}, timeout_s=2.0)
        except NoAnswerError:      # stopped (SIGSTOP), stuck in a call or starved: wait, then SIGTERM
            if pid is None or not process_alive(pid) or not looks_like_gma_ffc(pid):
                raise
            reply = {}
        pid = int(reply.get("pid") or pid or 0) or None
        asked = True
    if pid is None:  # it answered but we cannot watch the process: wait for the socket to go
        if _wait(lambda: not runtime.socket.exists(), timeout_s):
            return Stopped(None, "stopped on request", final)
        raise FaultError(f"the controller did not stop within {timeout_s:g} s (socket {runtime.socket})")
    if asked and _wait(lambda: not process_alive(pid), timeout_s):
        return Stopped(pid, "stopped on request", final)
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGTERM)
        os.kill(pid, signal.SIGCONT)     # a stopped process (SIGSTOP) takes its SIGTERM only once it runs again
    if _wait(lambda: not process_alive(pid), term_timeout_s):
        how = "stopped with SIGTERM" + (" after it ignored the request" if asked else
                                        " (its socket did not answer)")
        return Stopped(pid, how, final)
    raise FaultError(f"the controller (pid {pid}) did not stop, even on SIGTERM; check the "
                     f"amplifier, then 'kill -KILL {pid}' (log: {runtime.log_file})")


def _wait(done, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if done():
            return True
        time.sleep(POLL_S)
    return done()
