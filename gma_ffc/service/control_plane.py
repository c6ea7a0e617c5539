"""The control socket served by a process of its own, so no client can reach the loop's interpreter.

Why a process: the loop is Python, and every thread of its process shares one interpreter lock.
A socket thread under a request flood, 10 MB requests or hundreds of idle connections took that
lock often enough to raise the loop's p99 period jitter from 3.2 to 20.5 us at 1 kHz (issue 33).
Here the socket's whole cost (accepting, checking the peer's uid, reading, parsing, refusing,
answering `status`) is paid in the child; the service's process pays only for what the owner
really asks of it.

The two ends talk over a private SOCK_SEQPACKET pair, one message per datagram:
- service -> child  b"S" + status JSON: the snapshot `status` is answered from (sent every
  half second and after every command, never on a client's demand);
- child -> service  b"C" + token + request JSON: a `stop` or `reload` to carry out;
- service -> child  b"R" + token + reply line.
The listening socket is bound by the service and handed down, so the socket file stays put if the
child has to be started again; the child leaves when the service closes its end (or dies).

Run as `python -m gma_ffc.service.control_plane LISTEN_FD LINK_FD OWNER_UID MAIN_PID` (the
service does this; not a user command).
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

from ..errors import FaultError
from .control_server import ControlServer, Deferred
from .control_socket import MAX_REQUEST, bind_listener, encode_reply, jsonable

log = logging.getLogger(__name__)

FORWARDED = ("stop", "reload")      # the commands the service's own process carries out
MAX_FORWARDED = 4                   # in flight at once; more get "busy" (a reload takes a while)
MAX_SNAPSHOT = 1 << 20              # a status is a few kB; the fault history is bounded
TOKEN = 8                           # bytes of a forwarded request's token
RESPAWN_DELAY_S = 1.0               # before a crashed child is started again
CHILD_NICE = 5                      # the child yields the CPU to the loop on a normal-priority run
CHILD_START_S = 30.0                # a fresh interpreter imports little, but a busy machine is slow
SNAPSHOT, COMMAND, REPLY, HELLO = b"S", b"C", b"R", b"H"

CommandHandler = Callable[[dict[str, Any]], dict[str, Any]]


class ControlPlane:
    """The service's end: binds the socket, runs the child, publishes status, carries out commands."""

    def __init__(self, path: Path, handler: CommandHandler, owner_uid: int | None = None) -> None:
        self.path = Path(path)
        self.handler = handler
        self.owner_uid = os.geteuid() if owner_uid is None else owner_uid
        self._listener: socket.socket | None = None
        self._link: socket.socket | None = None
        self._child: subprocess.Popen | None = None
        self._lock = threading.Lock()
        self._closing = threading.Event()
        self._idle = threading.Event()      # no command between its handler and its reply
        self._idle.set()
        self._last_snapshot = b""
        self._thread = threading.Thread(target=self._carry_out_commands, name="gma-ffc-commands", daemon=True)

    def start(self, wait: bool = True) -> "ControlPlane":
        """Bind the socket and start its process; with `wait`, return once it serves (else call
        `wait_ready`: the service starts it before building the controller, which takes longer)."""
        self._listener = bind_listener(self.path)
        try:
            self._launch()
        except OSError as exc:
            self._give_up(exc)
        if wait:
            self.wait_ready()
        return self

    def wait_ready(self) -> None:
        assert self._link is not None and self._child is not None
        try:
            _wait_hello(self._link, self._child)
        except OSError as exc:
            self._give_up(exc)
        self._thread.start()

    def _give_up(self, exc: OSError) -> None:
        if self._listener is not None:
            self._listener.close()
            self._listener = None
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
        raise FaultError(f"cannot start the control socket's process: {exc.strerror or exc}") from None

    def _spawn(self) -> None:
        """Start the process again (the command thread, after a crash): launch, then wait for it."""
        self._launch()
        assert self._link is not None and self._child is not None
        _wait_hello(self._link, self._child)

    def _launch(self) -> None:
        assert self._listener is not None
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET | socket.SOCK_CLOEXEC)
        env = {k: v for k, v in os.environ.items()
               if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID", "LISTEN_FDS", "LISTEN_PID")}
        fds = (self._listener.fileno(), theirs.fileno())
        try:
            child = subprocess.Popen(
                [sys.executable, "-m", __name__, *map(str, fds), str(self.owner_uid), str(os.getpid())],
                pass_fds=fds, stdin=subprocess.DEVNULL, cwd="/", env=env, close_fds=True)
        finally:
            theirs.close()
        with self._lock:
            self._link, self._child = ours, child
            if self._last_snapshot:
                self._send(SNAPSHOT + self._last_snapshot, 0.0)

    def publish(self, status: dict[str, Any]) -> None:
        """The snapshot the child answers `status` from. Never blocks: a full link drops it."""
        data = json.dumps(status, default=jsonable).encode()
        if len(data) > MAX_SNAPSHOT and "fault_history" in status:
            data = json.dumps({**status, "fault_history": status["fault_history"][-20:]}, default=jsonable).encode()
        with self._lock:
            self._last_snapshot = data
            self._send(SNAPSHOT + data, 0.0)

    def _send(self, message: bytes, patience_s: float) -> None:
        """Send without blocking; retry for up to `patience_s` while the link is full. The link
        stays in blocking mode for the command thread's recv, so sends never change it."""
        link = self._link
        give_up = time.monotonic() + patience_s
        while link is not None:
            try:
                link.send(message, socket.MSG_DONTWAIT)
                return
            except BlockingIOError:
                if time.monotonic() >= give_up:
                    log.warning("control socket: its process is not reading; a message was dropped")
                    return
                time.sleep(0.01)
            except OSError as exc:
                if exc.errno == errno.EMSGSIZE:
                    log.warning("control socket: a %d-byte message does not fit the link; dropped", len(message))
                return            # EPIPE etc.: the child is gone; the command thread starts another

    def _carry_out_commands(self) -> None:
        """The command thread: blocks on the link (releasing the interpreter) until the child asks."""
        while not self._closing.is_set():
            link = self._link
            try:
                message = link.recv(1 + TOKEN + MAX_REQUEST + 1) if link is not None else b""
            except OSError:
                message = b""
            if not message:
                if self._closing.is_set():
                    return
                self._restart_child()
                continue
            if message[:1] == COMMAND:
                self._carry_out(message[1:1 + TOKEN], message[1 + TOKEN:])

    def _carry_out(self, token: bytes, raw: bytes) -> None:
        self._idle.clear()
        try:
            try:
                request = json.loads(raw)
                reply = self.handler(request)
            except Exception as exc:          # the command failed; the service runs on
                log.exception("control socket: command failed")
                reply = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
            with self._lock:
                self._send(REPLY + token + encode_reply(reply), 2.0)
        finally:
            self._idle.set()

    def _restart_child(self) -> None:
        code = self._child.poll() if self._child is not None else None
        log.error("control socket: its process ended (exit code %s); starting it again", code)
        time.sleep(RESPAWN_DELAY_S)
        if self._closing.is_set():
            return
        with self._lock:
            if self._link is not None:
                self._link.close()
                self._link = None
        if self._child is not None:
            with contextlib.suppress(subprocess.TimeoutExpired):
                self._child.wait(timeout=1.0)
        try:
            self._spawn()
        except OSError as exc:
            log.error("control socket: cannot start its process again: %s", exc.strerror or exc)

    @property
    def child_pid(self) -> int | None:
        return self._child.pid if self._child is not None else None

    def close(self) -> None:
        """Stop the child (it leaves when its link closes), then remove the socket file. A command
        being carried out (a `stop` that ended the run) gets its reply out first: closing under it
        would tell its client "the controller is stopping" instead of its answer."""
        if threading.current_thread() is not self._thread:
            self._idle.wait(timeout=2.0)
        self._closing.set()
        with self._lock:
            if self._link is not None:
                with contextlib.suppress(OSError):
                    self._link.shutdown(socket.SHUT_RDWR)
        if self._child is not None:
            try:
                self._child.wait(timeout=2.0)
            except subprocess.TimeoutExpired:
                self._child.kill()
                self._child.wait()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        with self._lock:
            if self._link is not None:
                self._link.close()
                self._link = None
        if self._listener is not None:
            self._listener.close()
            self._listener = None
            with contextlib.suppress(FileNotFoundError):
                self.path.unlink()


def _wait_hello(link: socket.socket, child: subprocess.Popen) -> None:
    """Wait until the child serves (it says HELLO), so the socket answers once `start` returns."""
    link.settimeout(CHILD_START_S)
    try:
        message = link.recv(16)
    except OSError:
        message = b""
    finally:
        link.settimeout(None)
    if message != HELLO:
        link.close()
        if child.poll() is None:
            child.kill()
        child.wait()
        raise OSError(f"its process did not start within {CHILD_START_S:g} s (exit code {child.returncode})")


class _Child:
    """The child's end: the bounded server, answering status from the last snapshot."""

    def __init__(self, listener: socket.socket, link: socket.socket, owner_uid: int, main_pid: int) -> None:
        self.link = link
        self.main_pid = main_pid
        self.snapshot: bytes | None = None
        self.pending: dict[bytes, Deferred] = {}
        self._tokens = 0
        self.server = ControlServer(None, self.handle, owner_uid, listener=listener)
        self.server.watch(link, self.on_link)

    def handle(self, request: dict[str, Any]) -> dict[str, Any] | bytes | Deferred:
        cmd = request["cmd"]
        if cmd == "status":
            return self.status_reply()
        if cmd == "ping":
            return {"ok": True, "pid": self.main_pid}
        if cmd in FORWARDED:
            return self.forward(request)
        return {"ok": False, "error": f"unknown command {cmd!r} (status, stop, reload, ping)"}

    def status_reply(self) -> dict[str, Any] | bytes:
        snapshot = self.snapshot
        if not snapshot or not snapshot.endswith(b"}") or snapshot == b"{}":
            return {"ok": False, "error": "the controller is starting and has no status yet; try again in a second"}
        counters = json.dumps(self.server.counters).encode()
        return b'{"ok": true, "status": ' + snapshot[:-1] + b', "control_socket": ' + counters + b"}}\n"

    def forward(self, request: dict[str, Any]) -> dict[str, Any] | Deferred:
        if len(self.pending) >= MAX_FORWARDED:
            return {"ok": False, "error": f"busy: {MAX_FORWARDED} commands are being carried out; try again"}
        self._tokens += 1
        token = self._tokens.to_bytes(TOKEN, "big")
        try:
            self.link.send(COMMAND + token + json.dumps(request).encode())
        except OSError:
            return {"ok": False, "error": "the controller's process does not answer"}
        deferred = self.server.defer()
        self.pending[token] = deferred
        return deferred

    def on_link(self) -> None:
        try:
            message = self.link.recv(1 + TOKEN + MAX_SNAPSHOT + 64)
        except OSError:
            message = b""
        if not message:                     # the service closed its end, or died: leave
            self.server.stop()
            return
        kind, body = message[:1], message[1:]
        if kind == SNAPSHOT:
            self.snapshot = body
        elif kind == REPLY:
            deferred = self.pending.pop(body[:TOKEN], None)
            if deferred is not None:
                self.server.complete(deferred, body[TOKEN:])

    def run(self) -> None:
        try:
            self.link.send(HELLO)
        except OSError:                     # the service gave up before this process was up (a bad config)
            return
        try:
            self.server.serve()
        finally:
            for deferred in self.pending.values():
                self.server.complete(deferred, {"ok": False, "error": "the controller is stopping"})
            self.server.close()


def child_main(argv: list[str]) -> int:
    # Signals meant for the service (a terminal's Ctrl-C and hang-up reach the whole process
    # group) must not end the socket early: the service closes the link when it is done.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    with contextlib.suppress(OSError):
        os.nice(CHILD_NICE)
    logging.basicConfig(stream=sys.stderr, level=logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    listen_fd, link_fd, owner_uid, main_pid = (int(a) for a in argv)
    listener = socket.socket(fileno=listen_fd)
    link = socket.socket(fileno=link_fd)
    try:
        _Child(listener, link, owner_uid, main_pid).run()
    except Exception as exc:                # one line in the service's log, never a traceback there
        log.error("control socket process failed: %s: %s", type(exc).__name__, exc)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(child_main(sys.argv[1:]))
