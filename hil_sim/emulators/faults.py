"""Fault modes the emulated devices can be put in, so the controller's fault handling can be tested.

A fault is written `KIND[:ARG]` on the command line, the control socket and in tests:

    silent                      stop answering (requests are read and ignored, writes not applied)
    delay:SECONDS               answer late, after SECONDS
    garbage                     answer with random bytes instead of a valid reply
    exception[:CODE]            Modbus exception reply (CODE 1-11, default 4 = device failure);
                                serial: commands fail, queries get no reply, SYST:ERR? reports -300
    drop                        drop the connection (TCP: close it; pty: hang up the port) and keep
                                it dropped until the fault is cleared
    stuck:CHANNEL               the sensor keeps reporting the value it had when the fault was set
    nan:CHANNEL                 the sensor reports NaN (float32 NaN; int registers: the type's
                                invalid marker, its most negative raw value; serial: "nan")
    out_of_range:CHANNEL[=VALUE]  the sensor reports an absurd VALUE (default 1e6)

CHANNEL is one of current_A, force_N, displacement_um.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

from gma_ffc.errors import InputError

SENSOR_CHANNELS = ("current_A", "force_N", "displacement_um")
LINK_FAULTS = ("silent", "delay", "garbage", "exception", "drop")
SENSOR_FAULTS = ("stuck", "nan", "out_of_range")
KINDS = LINK_FAULTS + SENSOR_FAULTS
DEFAULT_OUT_OF_RANGE = 1e6
DEFAULT_EXCEPTION_CODE = 4


class FaultSpecError(InputError):
    """A fault description that cannot be understood."""


@dataclass(frozen=True)
class Fault:
    """One active fault; `channel` for sensor faults, `value` for delay/exception/out_of_range."""

    kind: str
    channel: str | None = None
    value: float | None = None

    @property
    def key(self) -> tuple[str, str | None]:
        return (self.kind, self.channel)

    @property
    def number(self) -> float:
        """`value` for the kinds that carry one (delay, exception, out_of_range; `parse_fault` always
        sets it); FaultSpecError for a fault built by hand without it, rather than a TypeError
        inside a protocol thread."""
        if self.value is None:
            raise FaultSpecError(f"fault '{self}' needs a value")
        return self.value

    def __str__(self) -> str:
        text = self.kind
        if self.channel:
            text += f":{self.channel}"
            if self.kind == "out_of_range" and self.value is not None:
                text += f"={self.value:g}"
        elif self.value is not None:
            text += f":{self.value:g}"
        return text


def parse_fault(spec: str) -> Fault:
    """`KIND[:ARG]` -> Fault; FaultSpecError (exit 2) naming what to fix."""
    text = spec.strip()
    kind, _, arg = text.partition(":")
    kind = kind.strip().lower().replace("-", "_")
    arg = arg.strip()
    hint = f"fault '{spec}'"
    if kind not in KINDS:
        raise FaultSpecError(f"{hint}: unknown kind '{kind}' (use one of {', '.join(KINDS)})")
    if kind in ("silent", "garbage", "drop"):
        if arg:
            raise FaultSpecError(f"{hint}: '{kind}' takes no argument")
        return Fault(kind)
    if kind == "delay":
        seconds = _number(arg, hint, "delay needs SECONDS, e.g. delay:0.5")
        if not 0 < seconds <= 3600:
            raise FaultSpecError(f"{hint}: the delay must be between 0 and 3600 s")
        return Fault(kind, value=seconds)
    if kind == "exception":
        code = _number(arg, hint, "exception takes a Modbus exception code 1-11") if arg else DEFAULT_EXCEPTION_CODE
        if code != int(code) or not 1 <= code <= 11:
            raise FaultSpecError(f"{hint}: the Modbus exception code must be an integer 1-11")
        return Fault(kind, value=float(int(code)))
    channel, _, value_text = arg.partition("=")
    channel = channel.strip()
    if channel not in SENSOR_CHANNELS:
        raise FaultSpecError(f"{hint}: '{kind}' needs a sensor channel: {', '.join(SENSOR_CHANNELS)}")
    if kind == "out_of_range":
        value = _number(value_text, hint, "write out_of_range:CHANNEL=VALUE") if value_text else DEFAULT_OUT_OF_RANGE
        return Fault(kind, channel, value)
    if value_text:
        raise FaultSpecError(f"{hint}: '{kind}' takes only a channel")
    return Fault(kind, channel)


def _number(text: str, hint: str, usage: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise FaultSpecError(f"{hint}: {usage}") from None
    if not math.isfinite(value):
        raise FaultSpecError(f"{hint}: {usage}")
    return value


class FaultSet:
    """The device's active faults; thread-safe, as the protocol threads and the tests share it."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._active: dict[tuple[str, str | None], Fault] = {}
        self._listeners: list = []

    def set(self, fault: Fault | str) -> Fault:
        """Activate a fault (replacing one of the same kind and channel)."""
        if isinstance(fault, str):
            fault = parse_fault(fault)
        with self._lock:
            self._active[fault.key] = fault
            listeners = list(self._listeners)
        for listener in listeners:
            listener(fault, True)
        return fault

    def clear(self, spec: str | None = None) -> list[Fault]:
        """Clear every fault, or those of one KIND, or one KIND:CHANNEL; returns what was cleared."""
        kind, channel = None, None
        if spec:
            kind, _, channel_text = spec.strip().partition(":")
            kind = kind.strip().lower().replace("-", "_")
            channel = channel_text.split("=")[0].strip() or None
            if kind not in KINDS:
                raise FaultSpecError(f"clear '{spec}': unknown kind '{kind}' (use one of {', '.join(KINDS)})")
        with self._lock:
            gone = [
                f for f in self._active.values()
                if (kind is None or f.kind == kind) and (channel is None or f.channel == channel)
            ]
            for f in gone:
                del self._active[f.key]
            listeners = list(self._listeners)
        for f in gone:
            for listener in listeners:
                listener(f, False)
        return gone

    def get(self, kind: str, channel: str | None = None) -> Fault | None:
        with self._lock:
            return self._active.get((kind, channel))

    def has(self, kind: str) -> bool:
        with self._lock:
            return any(f.kind == kind for f in self._active.values())

    def active(self) -> list[Fault]:
        with self._lock:
            return sorted(self._active.values(), key=str)

    def add_listener(self, callback) -> None:
        """callback(fault, active: bool) after a fault is set or cleared (e.g. to hang up a port)."""
        with self._lock:
            self._listeners.append(callback)
