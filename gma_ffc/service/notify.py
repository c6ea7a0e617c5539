"""systemd's notify protocol spoken directly over $NOTIFY_SOCKET, so no libsystemd is needed.

The protocol is one datagram per message on a Unix socket whose path is in $NOTIFY_SOCKET
(a leading '@' names an abstract socket). Without $NOTIFY_SOCKET every call is a no-op, so the
same code runs under systemd, under `gma-ffc start` (which listens for READY itself) and in a
plain terminal.
"""

from __future__ import annotations

import os
import socket
import time


def _address(raw: str) -> str | bytes:
    """The socket address for $NOTIFY_SOCKET: '@name' is the abstract name '\\0name'."""
    if raw.startswith("@"):
        return "\0" + raw[1:]
    return raw


class Notifier:
    """Sends READY/STATUS/WATCHDOG/STOPPING/RELOADING to systemd (or whoever set NOTIFY_SOCKET)."""

    def __init__(self, environ: dict[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        raw = env.get("NOTIFY_SOCKET", "")
        self.address: str | bytes | None = _address(raw) if raw else None
        self.watchdog_interval_s = self._watchdog_interval(env)
        self._sock: socket.socket | None = None
        if self.address is not None:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    @staticmethod
    def _watchdog_interval(env: dict[str, str] | os._Environ) -> float | None:
        """Half of WATCHDOG_USEC (systemd's advice), or None when no watchdog is asked for us."""
        usec = env.get("WATCHDOG_USEC", "")
        pid = env.get("WATCHDOG_PID", "")
        if not usec:
            return None
        if pid and pid != str(os.getpid()):
            return None
        try:
            value = int(usec)
        except ValueError:
            return None
        return value / 2e6 if value > 0 else None

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def send(self, *fields: str) -> bool:
        """Send one message made of `KEY=value` fields; True if it was delivered."""
        if self._sock is None or self.address is None:
            return False
        message = "\n".join(fields).encode("utf-8", "replace")
        try:
            self._sock.sendto(message, self.address)
        except (FileNotFoundError, ConnectionRefusedError):
            # Nobody listens any more (e.g. `gma-ffc start` got its READY and left): stop trying.
            self.close()
            return False
        except OSError:
            # A full or broken socket: notification is best effort, it must never stop the loop.
            return False
        return True

    def ready(self, status: str | None = None) -> bool:
        return self.send("READY=1", f"MAINPID={os.getpid()}",
                         *([f"STATUS={_one_line(status)}"] if status else []))

    def status(self, text: str) -> bool:
        return self.send(f"STATUS={_one_line(text)}")

    def watchdog(self) -> bool:
        return self.send("WATCHDOG=1")

    def stopping(self, status: str | None = None) -> bool:
        return self.send("STOPPING=1", *([f"STATUS={_one_line(status)}"] if status else []))

    def reloading(self) -> bool:
        """RELOADING=1 with the monotonic timestamp systemd >= 253 asks for."""
        usec = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
        return self.send("RELOADING=1", f"MONOTONIC_USEC={usec}")

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def _one_line(text: str) -> str:
    return " ".join(str(text).split())
