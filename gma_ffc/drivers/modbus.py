"""`modbus` driver: pymodbus 3.16 sync clients, TCP and RTU, register maps from the config.

Channels may live on different devices: each entry of `devices` has its own connection (TCP host
and port, or an RTU serial port) and its own register map (gma_ffc.registers, inline or a file),
and unit ids may differ per channel inside a map. The controller's signals are found by channel
name across all devices:

    current_setpoint_A   required, writable (holding register)
    output_enable        optional coil: switched on by `activate()`, off by `safe()` and `deactivate()`
    force_N | stress_MPa the load cell (one of them is required)
    current_A, displacement_um   optional measurements

Reads are grouped into as few requests per device as the map allows (`read_plan`). A timeout or
no response raises DriverError(reason="timeout"); a Modbus exception reply, a dropped
connection or an undecodable reply raise DriverError(reason="comms"), except Modbus exceptions 1
(illegal function) and 2 (illegal data address): the device has no such register, which no
reconnect mends, so they raise DriverError(reason="refused") naming the channel and its config key. Integer channels report
the type's most negative raw value as "invalid" (NaN), as many devices do.
"""

from __future__ import annotations

import logging
import math
import os
import socket
from pathlib import Path
from typing import Any

from ..schema import Field, key_name, validate_section
from ..errors import ConfigError
from ..registers import (CURRENT, CURRENT_SETPOINT, DISPLACEMENT, FORCE, OUTPUT_ENABLE, TYPES, Channel, ReadBlock,
                         RegisterMap, load_register_map)
from .base import REFUSED, STRESS, Driver, DriverError, Inputs

READ_CHANNELS = (FORCE, STRESS, CURRENT, DISPLACEMENT)

# Modbus exceptions that are facts of the device, not of the link: a reconnect cannot mend them.
NO_SUCH = {1: ("function", "the device has no such function (Modbus exception 1, illegal function)"),
           2: ("address", "the device has no such register (Modbus exception 2, illegal data address)")}

DEVICE = {
    "transport": Field("choice", choices=("tcp", "rtu")),
    "host": Field("str", "127.0.0.1"),
    "port": Field("any", None, nullable=True, help="TCP port number, or the RTU serial port path"),
    "baudrate": Field("int", 115200, min=1),
    "parity": Field("choice", "N", choices=("N", "E", "O")),
    "stopbits": Field("int", 1, min=1, max=2),
    "bytesize": Field("int", 8, min=5, max=8),
    "timeout_s": Field("float", 0.1, min=0.0, min_exclusive=True, max=30.0),
    "register_map": Field("any", help="a register map (mapping) or the path of a register-map YAML"),
}

TOP = {
    "kind": Field("str"),
    "devices": Field("map", help="name -> {transport, host/port, register_map}"),
    "disable_on_safe": Field("bool", True),
}


class _Device:
    """One connection and the channels read from it."""

    def __init__(self, name: str, cfg: dict[str, Any]) -> None:
        self.name = name
        self.cfg = cfg
        self.map: RegisterMap = cfg["register_map"]
        self.map_key: str = cfg.get("register_map_key", "register_map.channels")   # where the map's channels are set
        self.client: Any = None
        self.plan: list[ReadBlock] = []
        self.slots: list[tuple[ReadBlock, tuple[tuple[str, Channel, int, float], ...]]] = []

    def make_client(self) -> Any:
        from pymodbus.client import ModbusSerialClient, ModbusTcpClient

        # pymodbus logs each failed connect itself ("Connection ... failed", "Repeating...."): the
        # driver's own DriverError, and the status, already say it once, in gma-ffc's words
        logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
        c = self.cfg
        if c["transport"] == "tcp":
            return ModbusTcpClient(c["host"], port=c["port"], timeout=c["timeout_s"], retries=0,
                                   reconnect_delay=0, name=f"gma-ffc-{self.name}")
        return ModbusSerialClient(c["port"], baudrate=c["baudrate"], parity=c["parity"], stopbits=c["stopbits"],
                                  bytesize=c["bytesize"], timeout=c["timeout_s"], retries=0,
                                  reconnect_delay=0, name=f"gma-ffc-{self.name}")

    @property
    def where(self) -> str:
        c = self.cfg
        return f"{c['host']}:{c['port']}" if c["transport"] == "tcp" else str(c["port"])

    def why_no_connection(self) -> str:
        """What is known of a failed connect: a serial port that is not there (pymodbus says only
        False, and "cannot connect" alone sent a lab to check baud rates and wiring)."""
        port = str(self.cfg["port"])
        if self.cfg["transport"] != "tcp" and not os.path.exists(port):
            return (f" ({port} does not exist: is the adapter plugged in? 'ls /dev/serial/by-id/' lists the serial "
                    f"ports by adapter; set driver.devices.{self.name}.port to one)")
        return ""


def _invalid_marker(ch: Channel) -> float:
    """The physical value of an integer channel's "invalid" raw value: the most negative for
    signed types, all ones for unsigned (the common device convention); NaN for float32."""
    if ch.type == "float32" or ch.is_bit:
        return math.nan
    _, _, lo, hi = TYPES[ch.type]
    return (hi if lo == 0 else lo) * ch.scale + ch.offset


class ModbusDriver(Driver):
    """Amplifier, load cell and displacement sensor over Modbus TCP and/or RTU."""

    kind = "modbus"

    def __init__(self, cfg: dict[str, Any], period_s: float) -> None:
        super().__init__(cfg, period_s)
        self.devices = [_Device(n, d) for n, d in cfg["devices"].items()]
        self._enable: tuple[_Device, Channel] | None = None
        found: dict[str, tuple[_Device, Channel]] = {}
        for dev in self.devices:
            for ch in dev.map:
                found[ch.name] = (dev, ch)
        self._setpoint: tuple[_Device, Channel] = found[CURRENT_SETPOINT]
        self._setpoint_only = (self._setpoint[1],)       # built once: the tick's write allocates no tuple
        self._enable = found.get(OUTPUT_ENABLE)
        self.channels = tuple(n for n in READ_CHANNELS if n in found)
        for dev in self.devices:
            names = [n for n in READ_CHANNELS if n in dev.map]
            dev.plan = dev.map.read_plan(names) if names else []
            dev.slots = [(blk, tuple((ch.name, ch, ch.address - blk.address, _invalid_marker(ch))
                                     for ch in blk.channels)) for blk in dev.plan]
        self.enabled = False
        self.timeouts = 0

    # ---- configuration ---------------------------------------------------------------------
    @classmethod
    def amplifiers(cls, cfg: dict[str, Any]) -> list[str]:
        """The amplifier: the device holding the current setpoint, by its link and unit id (two
        amplifiers behind one gateway are two devices; an RTU bus is its serial port)."""
        for dev in cfg["devices"].values():
            if CURRENT_SETPOINT in dev["register_map"]:
                unit = dev["register_map"][CURRENT_SETPOINT].unit_id
                links = (tcp_link_names(dev["host"], dev["port"]) if dev["transport"] == "tcp"
                         else [f"serial:{os.path.realpath(str(dev['port']))}"])
                return [f"{where}:unit{unit}" for where in links]
        return []

    @classmethod
    def validate_config(cls, section: dict[str, Any], prefix: str, base_dir: Path | None) -> dict[str, Any]:
        out = validate_section(section, TOP, prefix)
        devices = out["devices"]
        if not devices:
            raise ConfigError(f"config key '{prefix}.devices' must name at least one device")
        owner: dict[str, str] = {}
        checked = {}
        for name, raw in devices.items():
            key = key_name(prefix, f"devices.{name}")
            dev = validate_section(raw, DEVICE, key)
            dev["register_map_key"] = _map_key(dev["register_map"], f"{key}.register_map", base_dir)
            dev["register_map"] = _load_map(dev["register_map"], f"{key}.register_map", base_dir)
            dev["port"] = _port(dev, key)
            for ch in dev["register_map"]:
                if ch.name in owner and ch.name in (READ_CHANNELS + (CURRENT_SETPOINT, OUTPUT_ENABLE)):
                    raise ConfigError(f"config key '{key}.register_map': channel '{ch.name}' is also on device "
                                      f"'{owner[ch.name]}'; each signal must come from one device")
                owner[ch.name] = name
            checked[name] = dev
        if CURRENT_SETPOINT not in owner:
            raise ConfigError(f"config key '{prefix}.devices': no device has the channel '{CURRENT_SETPOINT}' "
                              f"(the amplifier's current setpoint)")
        sp_map = checked[owner[CURRENT_SETPOINT]]["register_map"]
        try:
            sp_map.require(CURRENT_SETPOINT, writable=[CURRENT_SETPOINT])
            if OUTPUT_ENABLE in owner:
                checked[owner[OUTPUT_ENABLE]]["register_map"].require(OUTPUT_ENABLE, writable=[OUTPUT_ENABLE])
        except ConfigError as exc:
            raise ConfigError(f"config key '{prefix}.devices.{owner[CURRENT_SETPOINT]}.register_map': {exc}") from None
        if FORCE not in owner and STRESS not in owner:
            raise ConfigError(f"config key '{prefix}.devices': no device has a load-cell channel "
                              f"('{FORCE}' or '{STRESS}')")
        out["devices"] = checked
        return out

    @classmethod
    def setpoint_range_A(cls, cfg: dict[str, Any]) -> tuple[float, float, str] | None:
        for name, dev in cfg["devices"].items():
            if CURRENT_SETPOINT in dev["register_map"]:
                ch = dev["register_map"][CURRENT_SETPOINT]
                lo, hi = ch.physical_range
                return lo, hi, (f"the register map's '{CURRENT_SETPOINT}' on device '{name}' ({ch.type}, scale "
                                f"{ch.scale:g}, offset {ch.offset:g})")
        return None

    # ---- lifecycle ------------------------------------------------------------------------------
    def open(self) -> None:
        for dev in self.devices:
            dev.client = dev.make_client()
            try:
                ok = dev.client.connect()
            except Exception as exc:
                ok = False
                self.last_error = f"{type(exc).__name__}: {exc}"
            if not ok:
                raise DriverError(f"modbus device '{dev.name}' at {dev.where}: cannot connect{dev.why_no_connection()}",
                                  "comms")
        self.enabled = False

    def close(self) -> None:
        for dev in self.devices:
            if dev.client is not None:
                try:
                    dev.client.close()
                except Exception:
                    pass
                dev.client = None
        self.enabled = False

    # ---- per tick ----------------------------------------------------------------------------------
    def _fail(self, dev: _Device, what: str, exc: BaseException | None, reason: str) -> DriverError:
        self.errors += 1
        detail = f": {exc}" if exc is not None else ""
        self.last_error = f"modbus device '{dev.name}' at {dev.where}: {what}{detail}"
        if reason == "timeout":
            self.timeouts += 1
        return DriverError(self.last_error, reason)

    def _call(self, dev: _Device, what: str, chans: tuple[Channel, ...], fn: Any, *args: Any, **kwargs: Any) -> Any:
        from pymodbus.exceptions import ConnectionException, ModbusIOException

        if dev.client is None:
            raise self._fail(dev, f"{what}: not connected", None, "comms")
        try:
            resp = fn(*args, **kwargs)
        except ConnectionException as exc:
            raise self._fail(dev, f"{what}: connection lost", exc, "comms") from None
        except ModbusIOException as exc:
            raise self._fail(dev, f"{what}: no response", exc, "timeout") from None
        except Exception as exc:  # framing errors on garbage, decode errors...
            raise self._fail(dev, f"{what}: bad reply ({type(exc).__name__})", exc, "comms") from None
        if resp is None or resp.isError():
            code = getattr(resp, "exception_code", None)
            if code in NO_SUCH:
                raise self._refused(dev, chans, code)
            raise self._fail(dev, f"{what}: device answered with Modbus exception {code}", None, "comms")
        return resp

    def _refused(self, dev: _Device, chans: tuple[Channel, ...], code: int) -> DriverError:
        """Modbus exception 1 or 2: the channel (of a block: the ones the device refuses alone) by
        its config key, and what to check. Off the hot path: a fault ends the tick anyway."""
        which, words = NO_SUCH[code]
        named = self._missing(dev, chans, code) if len(chans) > 1 else chans
        keys = ", ".join(f"{dev.map_key}.{ch.name}.{which} "
                         f"{ch.address if which == 'address' else ch.function}" for ch in named or chans)
        self.errors += 1
        self.last_error = (f"{keys}{'' if named else ' (one of them)'}: {words}: check the {which} in the rig's "
                           f"manual (modbus device '{dev.name}' at {dev.where})")
        return DriverError(self.last_error, REFUSED)

    def _missing(self, dev: _Device, chans: tuple[Channel, ...], code: int) -> tuple[Channel, ...]:
        """Of a block the device refused, the channels it refuses when asked for alone."""
        readers = {"holding": "read_holding_registers", "input": "read_input_registers",
                   "coil": "read_coils", "discrete": "read_discrete_inputs"}
        missing = []
        for ch in chans:
            try:
                resp = getattr(dev.client, readers[ch.function])(ch.address, count=ch.count, device_id=ch.unit_id)
            except Exception:
                continue                         # the link, not the register: leave it unnamed
            if resp is not None and resp.isError() and getattr(resp, "exception_code", None) == code:
                missing.append(ch)
        return tuple(missing)

    def read(self, inputs: Inputs) -> None:
        for dev in self.devices:
            client = dev.client
            for blk, chans in dev.slots:
                if blk.function == "holding":
                    fn = client.read_holding_registers if client else None
                else:
                    fn = client.read_input_registers if client else None
                resp = self._call(dev, f"read {blk.function} {blk.address}+{blk.count}", blk.channels, fn, blk.address,
                                  count=blk.count, device_id=blk.unit_id)
                regs = resp.registers
                if len(regs) < blk.count:
                    raise self._fail(dev, f"read {blk.function} {blk.address}: short reply "
                                          f"({len(regs)} of {blk.count} registers)", None, "comms")
                for name, ch, off, marker in chans:
                    value = ch.decode(regs[off:off + ch.count])
                    if value == marker:
                        value = math.nan
                    setattr(inputs, name, value)

    def write(self, current_A: float) -> None:
        dev, ch = self._setpoint
        try:
            words = ch.encode(current_A)
        except ConfigError as exc:
            raise DriverError(f"current {current_A!r} A cannot be encoded on the setpoint register: {exc}",
                              "comms") from None
        client = dev.client
        if len(words) == 1:
            self._call(dev, f"write setpoint {ch.address}", self._setpoint_only, client.write_register if client else None,
                       ch.address, words[0], device_id=ch.unit_id)
        else:
            self._call(dev, f"write setpoint {ch.address}", self._setpoint_only, client.write_registers if client else None,
                       ch.address, words, device_id=ch.unit_id)
        self.last_written_A = current_A

    def activate(self) -> None:
        """Output enable on (when the map has one), before the first command."""
        self._set_enable(True)

    def deactivate(self) -> None:
        """Output enable off (when the map has one) at the end of a run, unless `safe()` already
        switched it off (`disable_on_safe`)."""
        if self.enabled:
            self._set_enable(False)

    def _set_enable(self, on: bool) -> None:
        if self._enable is None:
            return
        dev, ch = self._enable
        client = dev.client
        if ch.is_bit:
            self._call(dev, f"write output_enable {ch.address}", (ch,), client.write_coil if client else None,
                       ch.address, on, device_id=ch.unit_id)
        else:
            words = ch.encode(1 if on else 0)
            fn = (client.write_register if len(words) == 1 else client.write_registers) if client else None
            self._call(dev, f"write output_enable {ch.address}", (ch,), fn, ch.address,
                       words[0] if len(words) == 1 else words, device_id=ch.unit_id)
        self.enabled = on

    @property
    def switches_off_on_safe(self) -> bool:
        return self._enable is not None and bool(self.cfg["disable_on_safe"])

    def _safe_once(self, current_A: float) -> None:
        """Setpoint to the safe current, then output off (when configured and present)."""
        self.write(current_A)
        if self._enable is not None and self.cfg["disable_on_safe"]:
            self._set_enable(False)

    def health(self) -> dict[str, Any]:
        h = super().health()
        h.update({"devices": {d.name: {"transport": d.cfg["transport"], "where": d.where,
                                       "connected": bool(d.client is not None and d.client.connected)}
                              for d in self.devices},
                  "timeouts": self.timeouts, "output_enabled": self.enabled})
        return h


def _map_path(value: str, base_dir: Path | None) -> Path:
    p = Path(value).expanduser()
    return base_dir / p if not p.is_absolute() and base_dir is not None else p


def _map_key(value: Any, key: str, base_dir: Path | None) -> str:
    """Where a device's channels are written, for a message naming one: a config key, or a file's."""
    return f"register map {_map_path(value, base_dir)}: channels" if isinstance(value, str) else f"{key}.channels"


def _load_map(value: Any, key: str, base_dir: Path | None) -> RegisterMap:
    try:
        if isinstance(value, str):
            return load_register_map(_map_path(value, base_dir))
        if isinstance(value, dict):
            return RegisterMap.from_dict(value)
    except ConfigError as exc:
        raise ConfigError(f"config key '{key}': {exc}") from None
    raise ConfigError(f"config key '{key}' must be a register map (mapping) or a file path, got {value!r}")


def _port(dev: dict[str, Any], key: str) -> Any:
    port = dev["port"]
    if dev["transport"] == "tcp":
        if port is None:
            return 502
        if isinstance(port, bool) or not isinstance(port, int) or not 1 <= port <= 65535:
            raise ConfigError(f"config key '{key}.port' must be a TCP port 1..65535, got {port!r}")
        _host_exists(dev["host"], key)
        return port
    if not isinstance(port, str) or not port:
        raise ConfigError(f"config key '{key}.port' must be the serial port path for RTU (e.g. /dev/ttyUSB0), "
                          f"got {port!r}")
    return port


def tcp_link_names(host: str, port: int) -> list[str]:
    """The names a Modbus TCP link is claimed by: one per address the host resolves to, so that
    "localhost" and "127.0.0.1" (or a name and its IP) are one amplifier, which the host as text
    missed (two controllers drove one amplifier, 2026-11-30). Any shared address collides: a name
    resolving to 127.0.0.1 and ::1 meets a claim on either. A name that does not resolve is
    named by its text, as before (the run then fails to connect, as a device that is down does)."""
    try:
        found = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError):
        return [f"modbus-tcp:{host.lower()}:{port}"]
    addresses = sorted({str(info[4][0]) for info in found})
    return [f"modbus-tcp:{address}:{port}" for address in addresses] or [f"modbus-tcp:{host.lower()}:{port}"]


def _host_exists(host: str, key: str) -> None:
    """A host name that does not exist is a typo in the config, refused at once: the reconnect policy
    retried one (127.0.0.l) ten times over 14 s. A name the resolver cannot answer for now (no DNS
    yet at boot) is left to the reconnects, as a device that is down is."""
    try:
        socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        if exc.errno in (socket.EAI_NONAME, getattr(socket, "EAI_NODATA", socket.EAI_NONAME)):
            raise ConfigError(f"config key '{key}.host': {host!r} is no host this machine can find ({exc.strerror}); "
                              "give the device's IP address or a name that resolves") from None
