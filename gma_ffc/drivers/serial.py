"""`serial` driver: pyserial and a SCPI-style line protocol built from templates in the config.

For bipolar/unipolar current supplies driven over RS-232/USB: the command that sets the current
is a template such as ``"CURR {current_A:.4f}"``; each measurement is a query such as
``"MEAS:FORC?"`` answered by one line holding a number ("nan" is read as NaN). Queries are
sent together and their replies read in order, so a tick costs one round trip; the input buffer
is flushed first so a late reply from an earlier tick can never be taken for this tick's.

No reply within `timeout_s` raises DriverError(reason="timeout"); a reply that is not a number,
a hung-up port or an I/O error raise DriverError(reason="comms").
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

from ..schema import Field, key_name, validate_section
from ..errors import ConfigError
from .base import CURRENT, DISPLACEMENT, FORCE, STRESS, Driver, DriverError, Inputs

try:      # pyserial flushes a POSIX port with termios, whose error is no OSError: a port that fails
    import termios      # under a flush (EIO on a hung-up pty) is a comms fault, not an exception

    _TERMIOS_ERRORS: tuple[type[BaseException], ...] = (termios.error,)
except ImportError:     # not POSIX
    _TERMIOS_ERRORS = ()

QUERY_CHANNELS = (FORCE, STRESS, CURRENT, DISPLACEMENT)


def _template(value: Any, key: str) -> str:
    try:
        value.format(current_A=0.0)
    except (KeyError, IndexError) as exc:
        raise ConfigError(f"config key '{key}': template {value!r} uses an unknown placeholder {exc} "
                          f"(only {{current_A}} is available)") from None
    except ValueError as exc:
        raise ConfigError(f"config key '{key}': template {value!r} is malformed ({exc})") from None
    return value


def _line_list(value: list, key: str) -> list[str]:
    for i, v in enumerate(value):
        if not isinstance(v, str) or not v:
            raise ConfigError(f"config key '{key}[{i}]' must be a command line (text), got {v!r}")
    return value


SCHEMA = {
    "kind": Field("str"),
    "port": Field("str", help="the serial port, e.g. /dev/ttyUSB0"),
    "baudrate": Field("int", 115200, min=1),
    "parity": Field("choice", "N", choices=("N", "E", "O")),
    "stopbits": Field("int", 1, min=1, max=2),
    "bytesize": Field("int", 8, min=5, max=8),
    "timeout_s": Field("float", 0.1, min=0.0, min_exclusive=True, max=30.0),
    "eol": Field("choice", "\n", choices=("\n", "\r\n", "\r")),
    "init": Field("list", [], check=_line_list),
    "write": Field("str", "CURR {current_A:.4f}", check=_template),
    "enable": Field("str", "OUTP ON", nullable=True),
    "disable": Field("str", "OUTP OFF", nullable=True),
    "verify_safe": Field("str", "CURR?", nullable=True,
                         help="query that reads the setpoint back, so safe() knows it arrived; null = trust"),
    "queries": Field("map", help="channel -> query, e.g. force_N: 'MEAS:FORC?'"),
}


class SerialDriver(Driver):
    """A SCPI-style amplifier (and load cell) on a serial port."""

    kind = "serial"

    def __init__(self, cfg: dict[str, Any], period_s: float) -> None:
        super().__init__(cfg, period_s)
        self.ser: Any = None
        self.eol = cfg["eol"].encode()
        self.queries = tuple((name, q) for name, q in cfg["queries"].items())
        self._query_bytes = b"".join(q.encode() + self.eol for _, q in self.queries)
        self.channels = tuple(n for n, _ in self.queries)
        self.enabled = False
        self.timeouts = 0

    @classmethod
    def amplifiers(cls, cfg: dict[str, Any]) -> list[str]:
        """The amplifier behind the serial port (by its real path: /dev/serial/by-id links included)."""
        return [f"serial:{os.path.realpath(cfg['port'])}"]

    @classmethod
    def validate_config(cls, section: dict[str, Any], prefix: str, base_dir: Path | None) -> dict[str, Any]:
        out = validate_section(section, SCHEMA, prefix)
        queries = out["queries"]
        for name, q in queries.items():
            if name not in QUERY_CHANNELS:
                raise ConfigError(f"config key '{key_name(prefix, 'queries.' + str(name))}' is not a channel "
                                  f"(one of {', '.join(QUERY_CHANNELS)})")
            if not isinstance(q, str) or not q:
                raise ConfigError(f"config key '{key_name(prefix, 'queries.' + name)}' must be a query text, "
                                  f"got {q!r}")
        if FORCE not in queries and STRESS not in queries:
            raise ConfigError(f"config key '{prefix}.queries' needs a load-cell query ('{FORCE}' or '{STRESS}')")
        return out

    def _fail(self, what: str, reason: str) -> DriverError:
        self.errors += 1
        self.last_error = f"serial {self.cfg['port']}: {what}"
        if reason == "timeout":
            self.timeouts += 1
        return DriverError(self.last_error, reason)

    def open(self) -> None:
        import serial

        c = self.cfg
        try:
            self.ser = serial.Serial(c["port"], baudrate=c["baudrate"], parity=c["parity"], stopbits=c["stopbits"],
                                     bytesize=c["bytesize"], timeout=c["timeout_s"], write_timeout=c["timeout_s"])
        except (serial.SerialException, OSError, ValueError) as exc:
            raise self._fail(f"cannot open ({exc})", "comms") from None
        self.enabled = False
        for line in c["init"]:
            self._send(line.encode() + self.eol)

    def close(self) -> None:
        if self.ser is not None:
            try:
                self.ser.close()
            except Exception:
                pass
            self.ser = None
        self.enabled = False

    def _send(self, data: bytes) -> None:
        import serial

        if self.ser is None:
            raise self._fail("not open", "comms")
        try:
            self.ser.write(data)
        except serial.SerialTimeoutException:
            raise self._fail("write timed out", "timeout") from None
        except (serial.SerialException, OSError, *_TERMIOS_ERRORS) as exc:
            raise self._fail(f"write failed ({exc})", "comms") from None

    def read(self, inputs: Inputs) -> None:
        import serial

        ser = self.ser
        if ser is None:
            raise self._fail("not open", "comms")
        try:
            ser.reset_input_buffer()
        except (serial.SerialException, OSError, *_TERMIOS_ERRORS) as exc:
            raise self._fail(f"port failed ({exc})", "comms") from None
        self._send(self._query_bytes)
        for name, query in self.queries:
            setattr(inputs, name, self._reply(query))

    def _reply(self, query: str) -> float:
        """One numeric reply line ('nan' reads as NaN)."""
        import serial

        try:
            line = self.ser.readline()
        except (serial.SerialException, OSError, *_TERMIOS_ERRORS) as exc:
            raise self._fail(f"read failed ({exc})", "comms") from None
        if not line.endswith(self.eol[-1:]):
            raise self._fail(f"no reply to {query!r} within {self.cfg['timeout_s']:g} s", "timeout")
        text = line.strip()
        try:
            return float(text)
        except ValueError:
            raise self._fail(f"reply to {query!r} is not a number: {text[:40]!r}", "comms") from None

    def write(self, current_A: float) -> None:
        if not math.isfinite(current_A):
            raise self._fail(f"refusing to send a non-finite current {current_A!r}", "comms")
        self._send(self.cfg["write"].format(current_A=current_A).encode() + self.eol)
        self.last_written_A = current_A

    def activate(self) -> None:
        """The configured enable command (e.g. OUTP ON), before the first command."""
        if self.cfg["enable"]:
            self._send(self.cfg["enable"].encode() + self.eol)
        self.enabled = True

    def deactivate(self) -> None:
        """The configured disable command at the end of a run, unless `safe()` already sent it."""
        if self.enabled and self.cfg["disable"]:
            self._send(self.cfg["disable"].encode() + self.eol)
        self.enabled = False

    @property
    def switches_off_on_safe(self) -> bool:
        return bool(self.cfg["disable"])

    def _safe_once(self, current_A: float) -> None:
        """Write, switch off, and read the setpoint back: a serial write has no acknowledgement,
        so only the read-back proves the amplifier took the safe current."""
        self._send(self.cfg["write"].format(current_A=current_A).encode() + self.eol)
        self.last_written_A = current_A
        if self.cfg["disable"]:
            self._send(self.cfg["disable"].encode() + self.eol)
        self.enabled = False
        query = self.cfg["verify_safe"]
        if query:
            try:
                self.ser.reset_input_buffer()
            except Exception as exc:
                raise self._fail(f"port failed ({exc})", "comms") from None
            self._send(query.encode() + self.eol)
            value = self._reply(query)
            if not abs(value - current_A) <= 1e-3 + 1e-3 * abs(current_A):
                raise self._fail(f"safe current not confirmed: {query!r} answered {value!r}, "
                                 f"expected {current_A!r}", "comms")

    def health(self) -> dict[str, Any]:
        h = super().health()
        h.update({"port": self.cfg["port"], "open": self.ser is not None, "timeouts": self.timeouts,
                  "output_enabled": self.enabled})
        return h
