"""One controller per device: a claim on each amplifier or link a run drives, machine-wide.

Two controllers with different configs, runtime folders and telemetry files could drive one
amplifier at once: each wrote its own setpoints, and one's stop switched the other's output off
(a new user's sweep, 2026-11-30). A driver names the amplifiers its config reaches (`amplifiers`:
"modbus-tcp:HOST:PORT:unitN", "serial:/dev/ttyUSB0"), and the run claims each before the driver opens.

A claim is a Linux abstract-namespace socket bound to the device's name: no file to leave behind
or to clean up, any user may bind one, and the kernel frees it when its process ends, even on
kill -9. A second bind fails; connecting to the name then gives the holder's pid (SO_PEERCRED),
which the refusal names. The names hold within one network namespace, which is the machine for
a service (the unit keeps the host's network: it talks Modbus TCP).
"""

from __future__ import annotations

import hashlib
import socket
import struct
from typing import Sequence

from ..errors import ConfigError

PREFIX = b"\0gma-ffc-device:"


def _address(device: str) -> bytes:
    """The abstract socket name of a device: a hash, so any path or host fits the 108-byte limit."""
    return PREFIX + hashlib.sha256(device.encode()).hexdigest()[:40].encode()


def _holder_pid(address: bytes) -> str:
    """The pid of the process bound to `address`, or '?' when it cannot be told."""
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
    try:
        probe.settimeout(0.5)
        probe.connect(address)
        pid, _uid, _gid = struct.unpack("3i", probe.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, 12))
        return str(pid)
    except OSError:
        return "?"
    finally:
        probe.close()


class DeviceClaim:
    """The claims of one run on its driver's devices; `acquire` before the driver opens, `release`
    after it closed. Both may be called again (a service claims before the run does)."""

    def __init__(self, devices: Sequence[str]) -> None:
        self.devices = tuple(devices)
        self._held: list[socket.socket] = []

    def acquire(self) -> None:
        """Claim every device (nothing if claimed already); ConfigError naming the holder, with none kept."""
        if self._held:
            return
        for device in self.devices:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
            try:
                sock.bind(_address(device))
                sock.listen(4)                 # never accepted: a refused controller's probe reads our pid
            except OSError:
                sock.close()
                self.release()
                pid = _holder_pid(_address(device))
                how = (f"'kill {pid}' (SIGTERM) ramps it to its safe current and ends it" if pid != "?" else
                       "'gma-ffc status --runtime-dir DIR' finds it by its runtime folder, 'gma-ffc stop' ends it")
                raise ConfigError(
                    f"{device} is driven by another controller on this machine (pid {pid}): two controllers on "
                    "one amplifier overwrite each other's setpoints, and one's stop switches the other's output "
                    f"off. Stop that one first: {how}") from None
            self._held.append(sock)

    def release(self) -> None:
        for sock in self._held:
            sock.close()
        self._held = []
