"""A bipolar current amplifier with a SCPI-style line protocol on a pty that pyserial opens.

Commands (newline-terminated, case-insensitive, SCPI short or long keywords, `SOURce:` optional):

    *IDN?                 identity
    *RST                  output off, setpoint 0 A, error queue cleared
    *CLS                  clear the error queue
    *OPC?                 1 once every earlier command is done (to synchronise after settings)
    OUTPut ON|OFF|1|0     enable / disable the output (disabled = 0 A)
    OUTPut?               1 or 0
    CURRent <A>           current setpoint, refused beyond the rating (-222 Data out of range)
    CURRent?              the setpoint
    MEASure:CURRent?      measured current, A
    MEASure:FORCe?        load cell, N
    MEASure:DISPlacement? displacement sensor, um
    SYSTem:ERRor?         next queued error, `0,"No error"` when empty

Queries reply with one line; settings reply nothing (errors go to the queue, as on real supplies).
A NaN sensor replies `nan`.
"""

from __future__ import annotations

import math
import random
import select
import threading
import time
from collections import deque

from gma_ffc.errors import FaultError

from .ptyport import PtyPort
from .rig import EmulatedRig, SetpointOutOfRange

MAX_LINE = 256
ERROR_QUEUE = 16
NO_ERROR = '0,"No error"'
ERRORS = {
    -100: "Command error",
    -102: "Syntax error",
    -104: "Data type error",
    -113: "Undefined header",
    -222: "Data out of range",
    -300: "Device-specific error",
    -350: "Queue overflow",
}


def _keyword(token: str, long_form: str) -> bool:
    """SCPI rule: a keyword is its short form (capitals) or its full long form."""
    short = "".join(c for c in long_form if c.isupper() or c.isdigit())
    return token.upper() in (short, long_form.upper())


class ScpiAmplifier:
    """The protocol, separate from the port so it can be reasoned about line by line."""

    def __init__(self, rig: EmulatedRig) -> None:
        self.rig = rig
        self.errors: deque[int] = deque()
        self.lines_received = 0

    def push_error(self, code: int) -> None:
        if len(self.errors) >= ERROR_QUEUE:
            self.errors[-1] = -350
        else:
            self.errors.append(code)

    def handle(self, line: str) -> str | None:
        """One command line -> reply line (without newline) or None."""
        self.lines_received += 1
        self.rig.requests += 1
        text = line.strip()
        if not text:
            return None
        header, _, arg = text.partition(" ")
        arg = arg.strip()
        nodes = header.split(":")
        if nodes and nodes[0] == "":
            nodes = nodes[1:]  # leading colon = root
        query = header.endswith("?")
        if query:
            nodes[-1] = nodes[-1][:-1]
        if self.rig.faults.get("exception") is not None and not (
            query and len(nodes) == 2 and _keyword(nodes[0], "SYSTem") and _keyword(nodes[1], "ERRor")
        ):
            self.push_error(-300)
            return None
        try:
            return self._dispatch(nodes, query, arg)
        except SetpointOutOfRange:
            self.push_error(-222)
        return None

    def _dispatch(self, nodes: list[str], query: bool, arg: str) -> str | None:
        upper = [n.upper() for n in nodes]
        if len(nodes) == 1 and upper[0].startswith("*"):
            if upper[0] == "*IDN" and query:
                return self.rig.identity
            if upper[0] == "*OPC" and query:  # everything before it is done: lets clients synchronise
                return "1"
            if upper[0] == "*RST" and not query:
                self.rig.set_output(False)
                self.rig.set_current(0.0)
                self.errors.clear()
                return None
            if upper[0] == "*CLS" and not query:
                self.errors.clear()
                return None
            self.push_error(-113)
            return None
        if len(nodes) == 1 and _keyword(nodes[0], "OUTPut"):
            if query:
                return "1" if self.rig.output_enabled else "0"
            state = arg.upper()
            if state in ("ON", "1"):
                self.rig.set_output(True)
            elif state in ("OFF", "0"):
                self.rig.set_output(False)
            else:
                self.push_error(-104)
            return None
        if nodes and _keyword(nodes[0], "SOURce"):
            nodes, upper = nodes[1:], upper[1:]
        if len(nodes) == 1 and _keyword(nodes[0], "CURRent"):
            if query:
                return f"{self.rig.setpoint_A:.6g}"
            try:
                value = float(arg)
            except ValueError:
                self.push_error(-104)
                return None
            self.rig.set_current(value)  # SetpointOutOfRange -> -222 in handle()
            return None
        if len(nodes) == 2 and _keyword(nodes[0], "MEASure") and query:
            for long_form, channel in (("CURRent", "current_A"), ("FORCe", "force_N"),
                                       ("DISPlacement", "displacement_um")):
                if _keyword(nodes[1], long_form):
                    value = self.rig.read(channel)
                    return "nan" if math.isnan(value) else f"{value:.7g}"
        if len(nodes) == 2 and _keyword(nodes[0], "SYSTem") and _keyword(nodes[1], "ERRor") and query:
            if not self.errors:
                return NO_ERROR
            code = self.errors.popleft()
            return f'{code},"{ERRORS[code]}"'
        self.push_error(-113)
        return None


class SerialAmplifierEmulator:
    """The SCPI amplifier on a pty: `with SerialAmplifierEmulator(rig) as emu: serial.Serial(emu.path)`."""

    def __init__(self, rig: EmulatedRig, *, seed: int = 0) -> None:
        self.rig = rig
        self.protocol = ScpiAmplifier(rig)
        self._rng = random.Random(seed)
        self._port: PtyPort | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._ready = threading.Event()
        self.path: str | None = None
        self.lines_seen = 0  # every line read, answered or not (faults included)

    @property
    def address(self) -> str | None:
        return self.path

    def start(self, timeout_s: float = 5.0) -> str:
        """Start answering; returns the path to open with pyserial."""
        if self._thread is not None and self.path is not None:
            return self.path
        try:
            port = PtyPort("ttyGMA-amp")
        except OSError as exc:
            raise FaultError(f"serial amplifier emulator: cannot create a pseudo-terminal: {exc.strerror or exc}") from None
        self._port, self.path = port, port.path
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, args=(port,), name="scpi-amplifier", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            self.stop()
            raise FaultError("serial amplifier emulator failed to start")
        return port.path

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        if self._port is not None:
            self._port.close()
        self._thread = None

    def __enter__(self) -> "SerialAmplifierEmulator":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def _run(self, port: PtyPort) -> None:
        buffer = b""
        self._ready.set()
        while not self._stop.is_set():
            if self.rig.faults.has("drop"):
                port.hangup()
                buffer = b""
                self._stop.wait(0.02)
                continue
            if not port.up:
                port.restore()
            try:
                ready, _, _ = select.select([port.master_fd], [], [], 0.02)
            except (OSError, ValueError):
                continue
            if not ready:
                continue
            buffer += port.read()
            while b"\n" in buffer:
                raw, buffer = buffer.split(b"\n", 1)
                try:
                    self._answer(port, raw)
                except Exception:  # the device must keep running; the client sees a queued error
                    self.protocol.push_error(-300)
            if len(buffer) > MAX_LINE:  # a line that never ends is noise, not a command
                buffer = b""
                self.protocol.push_error(-102)

    def _answer(self, port: PtyPort, raw: bytes) -> None:
        self.lines_seen += 1
        faults = self.rig.faults
        if faults.has("silent") or faults.has("drop"):
            return
        delay = faults.get("delay")
        if delay is not None:
            deadline = time.monotonic() + delay.number
            while not self._stop.is_set() and time.monotonic() < deadline:
                self._stop.wait(min(0.02, max(0.0, deadline - time.monotonic())))
        if faults.has("garbage"):
            noise = bytes(self._rng.randrange(128, 256) for _ in range(self._rng.randint(3, 12)))
            port.write(noise + b"\n")
            return
        try:
            line = raw.decode("ascii").rstrip("\r")
        except UnicodeDecodeError:
            self.protocol.push_error(-102)
            return
        reply = self.protocol.handle(line)
        if reply is not None:
            port.write(reply.encode("ascii") + b"\n")
