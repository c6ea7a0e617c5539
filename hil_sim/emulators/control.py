"""A tiny control channel to an emulator running as a subprocess: a unix socket taking one
command line per connection and answering one JSON line.

    fault KIND[:ARG]     activate a fault (see hil_sim.emulators.faults)
    clear [KIND[:CH]]    clear every fault, or some
    load KG              put KG of load mass on the rod (the stress follows)
    status               setpoint, output, faults, plant values, recent command history
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import stat
import tempfile
import threading
from typing import Any

from gma_ffc.errors import FaultError, InputError

from .rig import EmulatedRig


def execute(rig: EmulatedRig, line: str) -> dict[str, Any]:
    """Run one control command against the rig; errors come back as {"ok": false, "error": ...}."""
    verb, _, arg = line.strip().partition(" ")
    verb = verb.lower()
    try:
        if verb == "fault" and arg:
            fault = rig.faults.set(arg)
            return {"ok": True, "set": str(fault)}
        if verb == "clear":
            return {"ok": True, "cleared": [str(f) for f in rig.faults.clear(arg or None)]}
        if verb == "load" and arg:
            try:
                kg = float(arg)
            except ValueError:
                raise InputError(f"control: 'load {arg}': give the mass in kg, e.g. load 20") from None
            rig.set_load_mass(kg)
            return {"ok": True, "load_mass_kg": kg}
        if verb == "status":
            return {"ok": True, **rig.snapshot()}
        raise InputError(f"control: unknown command '{line.strip()}' (use: fault SPEC | clear [SPEC] | load KG | status)")
    except InputError as exc:
        return {"ok": False, "error": str(exc)}


class ControlServer:
    """Serve `execute` on a unix socket in a background thread."""

    def __init__(self, rig: EmulatedRig, path: str | None = None) -> None:
        self.rig = rig
        self._own_dir: str | None = None
        if not path:
            self._own_dir = tempfile.mkdtemp(prefix="gma-hil-ctl-")
            path = os.path.join(self._own_dir, "control.sock")
        self.path = path
        self._sock: socket.socket | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> str:
        if os.path.lexists(self.path):
            if not stat.S_ISSOCK(os.lstat(self.path).st_mode):
                raise InputError(f"--control {self.path}: exists and is not a socket; choose another path")
            os.unlink(self.path)  # a stale socket from an emulator that was killed
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            sock.bind(self.path)
            sock.listen(4)
        except OSError as exc:
            sock.close()
            raise InputError(f"--control {self.path}: cannot listen there ({exc.strerror or exc})") from None
        sock.settimeout(0.1)
        self._sock = sock
        self._thread = threading.Thread(target=self._run, args=(sock,), name="emulator-control", daemon=True)
        self._thread.start()
        return self.path

    def _run(self, sock: socket.socket) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = sock.accept()
            except (socket.timeout, OSError):
                continue
            with conn:
                conn.settimeout(2.0)
                try:
                    data = b""
                    while b"\n" not in data and len(data) < 4096:
                        chunk = conn.recv(4096)
                        if not chunk:
                            break
                        data += chunk
                    reply = execute(self.rig, data.decode("utf-8", "replace").split("\n")[0])
                    conn.sendall(json.dumps(reply).encode() + b"\n")
                except OSError:
                    continue

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        if self._sock is not None:
            self._sock.close()
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.path)
        if self._own_dir:
            shutil.rmtree(self._own_dir, ignore_errors=True)

    def __enter__(self) -> "ControlServer":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def send_control(path: str, command: str, timeout_s: float = 2.0) -> dict[str, Any]:
    """Client side: send one command, return the decoded reply."""
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            sock.settimeout(timeout_s)
            sock.connect(path)
            sock.sendall(command.strip().encode() + b"\n")
            data = b""
            while not data.endswith(b"\n"):
                chunk = sock.recv(65536)
                if not chunk:
                    break
                data += chunk
    except OSError as exc:
        raise FaultError(f"control socket {path}: {exc.strerror or exc}") from None
    try:
        return json.loads(data)
    except ValueError:
        raise FaultError(f"control socket {path}: no valid reply") from None
