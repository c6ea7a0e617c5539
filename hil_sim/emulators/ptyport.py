"""Pseudo-terminals that pyserial opens like real serial ports, under a stable path.

The client opens `PtyPort.path`, a symlink to the current pty slave. A dropped connection is a
hang-up (the emulator closes its ends, the client's reads fail, the path disappears, like an
unplugged USB adapter); restoring makes a fresh pty behind the same path, so a client that
reopens the port reconnects. Only the thread that does the I/O may hang up or restore, so a file
descriptor is never closed under a select() in another thread.
"""

from __future__ import annotations

import contextlib
import os
import select
import shutil
import tempfile
import threading
import tty


class PtyPort:
    """One pty pair: the emulator uses `master_fd`, the client opens `path`."""

    def __init__(self, name: str = "ttyGMA", link_dir: str | None = None) -> None:
        self._own_dir = link_dir is None
        self.link_dir = link_dir or tempfile.mkdtemp(prefix="gma-hil-")
        self.path = os.path.join(self.link_dir, name)
        self.master_fd = -1
        self._slave_fd = -1
        self.slave_name = ""
        self.hangups = 0
        self.restore()

    @property
    def up(self) -> bool:
        return self.master_fd >= 0

    def restore(self) -> None:
        """(Re)create the pty and point `path` at it."""
        if self.up:
            return
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo or line editing before the client opens it
        os.set_blocking(master, False)
        self.master_fd, self._slave_fd = master, slave
        self.slave_name = os.ttyname(slave)
        tmp = self.path + ".new"
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        os.symlink(self.slave_name, tmp)
        os.replace(tmp, self.path)

    def hangup(self) -> None:
        """Drop the link: the client's open port fails and `path` vanishes until `restore`."""
        if not self.up:
            return
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.path)
        for fd in (self.master_fd, self._slave_fd):
            with contextlib.suppress(OSError):
                os.close(fd)
        self.master_fd = self._slave_fd = -1
        self.hangups += 1

    def read(self) -> bytes:
        """Whatever is waiting (b'' if nothing)."""
        if not self.up:
            return b""
        try:
            return os.read(self.master_fd, 4096)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:
            return b""

    def write(self, data: bytes) -> None:
        """Write everything (bounded wait if the pty buffer is full); silently lost when down."""
        view = memoryview(data)
        attempts = 0
        while view and self.up and attempts < 200:
            try:
                sent = os.write(self.master_fd, view)
                view = view[sent:]
            except BlockingIOError:
                attempts += 1
                select.select([], [self.master_fd], [], 0.01)
            except OSError:
                return

    def close(self) -> None:
        self.hangup()
        if self._own_dir:
            shutil.rmtree(self.link_dir, ignore_errors=True)


class PtyRelay:
    """Copy bytes both ways between two pty masters (like `socat pty pty`), on its own thread.

    Needed for Modbus RTU: the pymodbus server opens one side as a serial port, the client the
    other. `should_drop()` is polled: while it returns True the client side stays hung up.
    """

    def __init__(self, server_side: PtyPort, client_side: PtyPort, should_drop=lambda: False) -> None:
        self.server_side = server_side
        self.client_side = client_side
        self._should_drop = should_drop
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="pty-relay", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)

    def _run(self) -> None:
        a, b = self.server_side, self.client_side
        while not self._stop.is_set():
            if self._should_drop():
                b.hangup()
            elif not b.up:
                b.restore()
            fds = [p.master_fd for p in (a, b) if p.up]
            try:
                ready, _, _ = select.select(fds, [], [], 0.02)
            except (OSError, ValueError):
                continue
            if a.up and a.master_fd in ready:
                data = a.read()
                if data:
                    b.write(data)
            if b.up and b.master_fd in ready:
                data = b.read()
                if data:
                    a.write(data)
