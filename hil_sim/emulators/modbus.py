"""Modbus TCP server and Modbus RTU device (over a pty) exposing the emulated rig through a
register map from YAML, with pymodbus 3.16 doing the framing exactly as on a real bus.

Why a custom datastore: pymodbus 3.16's SimDevice keeps static register images; our values are
computed per request (the plant advances in real time, sensors may be faulty, writes are
validated and recorded), so the server gets a context object answering `async_getValues` /
`async_setValues` directly. Link faults (silent, late, garbage, dropped) live in the request
handler, which sees each request before pymodbus answers it.
"""

from __future__ import annotations

import asyncio
import dataclasses
import errno
import math
import random
import socket
import threading
import time
from typing import Sequence, cast

from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusServerContext
from pymodbus.exceptions import NoSuchIdException
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler

from gma_ffc.errors import ConfigError, FaultError, InputError
from gma_ffc.registers import (
    CURRENT_SETPOINT, HEARTBEAT, OUTPUT_ENABLE, STATUS, TYPES, Channel, RegisterMap,
)

from .faults import SENSOR_CHANNELS
from .ptyport import PtyPort, PtyRelay
from .rig import EmulatedRig, SetpointOutOfRange

READ_FUNCTIONS = {1: "coil", 2: "discrete", 3: "holding", 4: "input", 23: "holding", 5: "coil",
                  15: "coil", 6: "holding", 16: "holding"}
WRITE_FUNCTIONS = {5: "coil", 15: "coil", 6: "holding", 16: "holding", 23: "holding"}
DEVICE_VALUES = set(SENSOR_CHANNELS) | {CURRENT_SETPOINT, OUTPUT_ENABLE, STATUS, HEARTBEAT}


def encode_sensor(channel: Channel, value: float) -> list[int]:
    """Encode what a sensor reports, even when absurd. Integer registers cannot hold NaN, so a NaN
    becomes the type's invalid marker (most negative raw value; all ones if unsigned, the common
    device convention, which the modbus driver decodes as NaN); values beyond the type saturate
    at its limits, one step short of the marker, as real transmitters do."""
    if channel.is_bit:
        return [1 if value else 0]
    try:
        return channel.encode(value)
    except ConfigError:
        pass
    _, _, lo, hi = TYPES[channel.type]
    raw_channel = dataclasses.replace(channel, scale=1.0, offset=0.0)
    if channel.type == "float32":
        return raw_channel.encode(min(max((value - channel.offset) / channel.scale, lo), hi))
    marker = hi if lo == 0 else lo
    if math.isnan(value):
        return raw_channel.encode(marker)
    lo, hi = (lo, hi - 1) if lo == 0 else (lo + 1, hi)
    raw = (value - channel.offset) / channel.scale
    return raw_channel.encode(min(max(round(raw) if math.isfinite(raw) else raw, lo), hi))


class RigContext(ModbusServerContext):
    """pymodbus datastore answering from the rig through the register map."""

    def __init__(self, rig: EmulatedRig, register_map: RegisterMap) -> None:  # no super(): see module doc
        self.rig = rig
        self.map = register_map
        self.old_simulator = True  # pymodbus then calls our async_getValues/async_setValues as-is
        self.simdevices = []
        self._stored: dict[str, list[int]] = {}
        self._heartbeat = 0
        self._tables: dict[tuple[int, str], dict[int, Channel]] = {}
        register_map.require(CURRENT_SETPOINT, writable=[CURRENT_SETPOINT])
        if OUTPUT_ENABLE in register_map:
            register_map.require(writable=[OUTPUT_ENABLE])
        for ch in register_map:
            if ch.function in ("input", "discrete") and ch.name not in DEVICE_VALUES:
                raise ConfigError(
                    f"register map channel '{ch.name}': the emulator has no value for a read-only channel "
                    f"of that name (it provides {', '.join(sorted(DEVICE_VALUES))})"
                )
            table = self._tables.setdefault((ch.unit_id, ch.function), {})
            for address in range(ch.address, ch.end):
                table[address] = ch
            if ch.writable and ch.name not in DEVICE_VALUES:
                self._stored[ch.name] = [0] * ch.count
        if OUTPUT_ENABLE not in register_map:
            rig.set_output(True)  # a device without an enable switch is always on

    def device_ids(self) -> list[int]:
        return list(self.map.unit_ids)

    def _channel_words(self, ch: Channel) -> list[int]:
        name = ch.name
        if name in SENSOR_CHANNELS:
            return encode_sensor(ch, self.rig.read(name))
        if name == CURRENT_SETPOINT:
            return encode_sensor(ch, self.rig.setpoint_A)
        if name == OUTPUT_ENABLE:
            return ch.encode(1 if self.rig.output_enabled else 0)
        if name == STATUS:
            return ch.encode(self.rig.status_word())
        if name == HEARTBEAT and not ch.writable:
            self._heartbeat += 1
            lo, hi = ch.physical_range
            return ch.encode(self._heartbeat % int(hi + 1) if hi >= 1 else 0)
        return list(self._stored.get(name, [0] * ch.count))

    def _check(self, device_id: int) -> ExcCodes | None:
        if device_id not in self.map.unit_ids:
            raise NoSuchIdException(f"unit {device_id}")
        fault = self.rig.faults.get("exception")
        if fault is not None:
            return ExcCodes(int(fault.number))
        return None

    async def async_getValues(self, device_id: int, func_code: int, address: int, count: int = 1):
        if (code := self._check(device_id)) is not None:
            return code
        self.rig.requests += 1
        table = self._tables.get((device_id, READ_FUNCTIONS.get(func_code, "")), {})
        cache: dict[str, list[int]] = {}
        out: list = []
        for a in range(address, address + count):
            ch = table.get(a)
            if ch is None:
                return ExcCodes.ILLEGAL_ADDRESS
            if ch.name not in cache:
                cache[ch.name] = self._channel_words(ch)
            word = cache[ch.name][a - ch.address]
            out.append(bool(word) if ch.is_bit else word)
        return out

    async def async_setValues(self, device_id: int, func_code: int, address: int, values: Sequence):
        if (code := self._check(device_id)) is not None:
            return code
        table = self._tables.get((device_id, WRITE_FUNCTIONS.get(func_code, "")), {})
        end = address + len(values)
        touched: list[Channel] = []
        for a in range(address, end):
            ch = table.get(a)
            if ch is None or not ch.writable:
                return ExcCodes.ILLEGAL_ADDRESS
            if ch.address < address or ch.end > end:  # half of a 32-bit value: refuse, never guess
                return ExcCodes.ILLEGAL_ADDRESS
            if not touched or touched[-1] is not ch:
                touched.append(ch)
        decoded = {}
        for ch in touched:
            words = [int(v) for v in values[ch.address - address:ch.end - address]]
            decoded[ch.name] = (ch, words, ch.decode(words))
        if CURRENT_SETPOINT in decoded:
            value = decoded[CURRENT_SETPOINT][2]
            if not (math.isfinite(value) and abs(value) <= self.rig.max_current_A):
                return ExcCodes.ILLEGAL_VALUE
        for name, (ch, words, value) in decoded.items():
            try:
                if name == CURRENT_SETPOINT:
                    self.rig.set_current(value)
                elif name == OUTPUT_ENABLE:
                    self.rig.set_output(bool(value))
                else:
                    self._stored[name] = words
            except SetpointOutOfRange:
                return ExcCodes.ILLEGAL_VALUE
        return None


class FaultyRequestHandler(ServerRequestHandler):
    """Applies link faults before pymodbus answers a request."""

    async def handle_request(self):
        pdu, addr = self.last_pdu, self.last_addr
        if not pdu:
            return
        emulator: ModbusEmulator = self.server.emulator
        faults = emulator.rig.faults
        if faults.has("drop"):
            if emulator.transport == "tcp":
                self.close()
            return
        if faults.has("silent"):
            return
        emulator.wait_latency()
        delay = faults.get("delay")
        if delay is not None:
            await asyncio.sleep(delay.value)
            self.last_pdu, self.last_addr = pdu, addr
        if faults.has("garbage"):
            self.send(emulator.garbage(), addr)
            return
        await super().handle_request()


class _TcpServer(ModbusTcpServer):
    emulator: ModbusEmulator

    def callback_new_connection(self):
        return FaultyRequestHandler(self, self.trace_packet, self.trace_pdu, self.trace_connect)


class _RtuServer(ModbusSerialServer):
    emulator: ModbusEmulator

    def callback_new_connection(self):
        return FaultyRequestHandler(self, self.trace_packet, self.trace_pdu, self.trace_connect)


def check_latency(latency_s: tuple[float, float] | None) -> tuple[float, float] | None:
    """(lo, hi) seconds with 0 <= lo <= hi <= 1, or None; a FaultError naming the fix otherwise."""
    if latency_s is None:
        return None
    try:
        lo, hi = (float(v) for v in latency_s)
    except (TypeError, ValueError):
        raise FaultError(f"modbus emulator: latency {latency_s!r} must be two numbers (lo, hi) in seconds") from None
    if not (0.0 <= lo <= hi <= 1.0):
        raise FaultError(f"modbus emulator: latency {lo:g}-{hi:g} s must satisfy 0 <= lo <= hi <= 1 s")
    return lo, hi


def _check_bindable(host: str, port: int) -> None:
    """FaultError naming the reason (address in use, no such interface...) before pymodbus tries."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
        with socket.socket(infos[0][0], socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            probe.bind(infos[0][4])
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:        # the user's to fix, with a way that always works
            raise InputError(f"cannot listen on {host}:{port}: it is in use (another emulator, or a real device's "
                             "server): stop that, or give --port 0 for a free port (printed as 'connect: "
                             "HOST:PORT') and set the config's driver.devices.NAME.port to it") from None
        raise FaultError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None


class ModbusEmulator:
    """A Modbus device in a background thread: `with ModbusEmulator(rig, map) as emu: emu.address`.

    transport "tcp": listens on host:port (port 0 = a free port), `address` is (host, port).
    transport "rtu": a pty the client opens with pyserial/pymodbus, `address` is its path.
    """

    def __init__(self, rig: EmulatedRig, register_map: RegisterMap, *, transport: str = "tcp",
                 host: str = "127.0.0.1", port: int = 0, baudrate: int = 115200, seed: int = 0,
                 latency_s: tuple[float, float] | None = None) -> None:
        if transport not in ("tcp", "rtu"):
            raise ConfigError(f"modbus emulator: transport '{transport}' is not tcp or rtu")
        self.latency_s = check_latency(latency_s)
        self._latency_rng = random.Random(seed + 1)   # its own stream: the garbage bytes stay as they were
        self.latencies_s: list[float] = []            # every latency applied, in order (for benchmarks)
        self.rig = rig
        self.map = register_map
        self.transport = transport
        self.host = host
        self.port = port
        self.baudrate = baudrate
        self.context = RigContext(rig, register_map)
        self._rng = random.Random(seed)
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_event: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._server_pty: PtyPort | None = None
        self._client_pty: PtyPort | None = None
        self._relay: PtyRelay | None = None
        self._server: _TcpServer | _RtuServer | None = None
        self.address: tuple[str, int] | str | None = None
        rig.faults.add_listener(self._on_fault)

    def _on_fault(self, fault, active: bool) -> None:
        """A drop cuts open TCP connections at once, not only at their next request."""
        loop = self._loop
        if fault.kind == "drop" and active and self.transport == "tcp" and loop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(self._close_connections)
            except RuntimeError:  # loop shutting down
                pass

    def _close_connections(self) -> None:
        if self._server is not None:
            for connection in list(self._server.active_connections.values()):
                connection.close()

    @property
    def connections(self) -> int:
        """Open client connections (TCP)."""
        return len(self._server.active_connections) if self._server is not None else 0

    def wait_latency(self) -> None:
        """Hold the request for a random latency (uniform in `latency_s`) before it takes effect:
        a write acts, and a read samples the plant, that much later, as over a busy network.
        It blocks the server's loop on purpose: a small device answers one request at a time,
        and asyncio's timers are 1 ms coarse, too coarse for a 1-2 ms latency."""
        if self.latency_s is None:
            return
        lo, hi = self.latency_s
        wait = self._latency_rng.uniform(lo, hi)
        self.latencies_s.append(wait)
        time.sleep(wait)

    def garbage(self) -> bytes:
        """Bytes that are not a valid reply (seeded, so runs repeat)."""
        return bytes(self._rng.randrange(256) for _ in range(self._rng.randint(3, 12)))

    @property
    def path(self) -> str | None:
        return self._client_pty.path if self._client_pty else None

    @property
    def host_port(self) -> tuple[str, int]:
        """(host, port) of a started TCP emulator, for a client to connect to."""
        if not isinstance(self.address, tuple):
            raise FaultError(f"modbus {self.transport} emulator has no TCP address (address {self.address!r})")
        return self.address

    @property
    def serial_path(self) -> str:
        """The pty path of a started RTU emulator, for a client to open."""
        if self.path is None:
            raise FaultError(f"modbus {self.transport} emulator has no serial port (address {self.address!r})")
        return self.path

    def start(self, timeout_s: float = 10.0):
        """Start serving; returns (host, port) for TCP or the pty path for RTU."""
        if self._thread is not None:
            return self.address
        if self.transport == "rtu":
            try:
                self._server_pty = PtyPort("ttyGMA-rtu-server")
                self._client_pty = PtyPort("ttyGMA-rtu", link_dir=self._server_pty.link_dir)
            except OSError as exc:
                self.stop()
                raise FaultError(f"modbus rtu emulator: cannot create a pseudo-terminal: {exc.strerror or exc}") from None
            self._relay = PtyRelay(self._server_pty, self._client_pty, lambda: self.rig.faults.has("drop"))
            self._relay.start()
        self._thread = threading.Thread(target=self._thread_main, name=f"modbus-{self.transport}", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s) or self._error is not None:
            self.stop()
            if isinstance(self._error, (FaultError, InputError)):
                raise self._error
            raise FaultError(f"modbus {self.transport} emulator failed to start: {self._error or 'timeout'}")
        return self.address

    def _thread_main(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as exc:  # reported to start(); the thread must not die silently
            self._error = exc
            self._ready.set()

    async def _serve(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop_event = asyncio.Event()
        server: _TcpServer | _RtuServer
        if self.transport == "tcp":
            _check_bindable(self.host, self.port)  # pymodbus only logs why it could not listen
            server = _TcpServer(self.context, address=(self.host, self.port))
        else:
            if self._server_pty is None or self._client_pty is None:
                raise FaultError("modbus rtu emulator: the pseudo-terminals were not created (start() makes them)")
            server = _RtuServer(self.context, port=self._server_pty.slave_name, baudrate=self.baudrate,
                                ignore_missing_devices=True, reconnect_delay=0.5)
        server.emulator = self
        self._server = server
        await server.serve_forever(background=True)
        if isinstance(server, _TcpServer):
            # pymodbus types `transport` as BaseTransport; a listening server's is the asyncio.Server
            # its create_server returned.
            host, port = cast(asyncio.Server, server.transport).sockets[0].getsockname()[:2]
            self.address = (str(host), int(port))
            self.port = int(port)
        elif self._client_pty is not None:
            self.address = self._client_pty.path
        self._ready.set()
        try:
            await self._stop_event.wait()
        finally:
            await server.shutdown()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop serving and release the port / ptys (idempotent)."""
        if self._loop is not None and self._stop_event is not None and not self._loop.is_closed():
            try:
                self._loop.call_soon_threadsafe(self._stop_event.set)
            except RuntimeError:
                pass
        if self._thread is not None:
            self._thread.join(timeout_s)
        if self._relay is not None:
            self._relay.stop()
        for pty in (self._client_pty, self._server_pty):
            if pty is not None:
                pty.close()
        self._thread = None
        self._relay = None

    def __enter__(self) -> "ModbusEmulator":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
