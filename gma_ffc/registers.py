"""Modbus register maps: named channels and the codec between physical values and 16-bit words.

Shared by the Modbus device emulator (hil_sim.emulators) and the controller's Modbus driver, so
both sides agree on addresses, types, word/byte order and scaling by construction. Real devices
differ in all of these, hence one YAML map per device. Pure: no I/O except `load_register_map`.

A map in YAML::

    defaults:            # optional; applied to every channel that does not set the key
      unit_id: 1
      word_order: big
    channels:
      current_setpoint_A: {function: holding, address: 0, type: int16, scale: 0.001, access: rw}
      output_enable:      {function: coil, address: 0, access: rw}
      force_N:            {function: input, address: 10, type: float32, word_order: little}

physical = raw * scale + offset. Word order: which 16-bit word of a 32-bit value comes first
("big" = most significant first, the Modbus convention). Byte order: the byte order inside each
16-bit word ("big" = high byte first). Coils and discrete inputs are single bits (type bool).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from os import PathLike
from typing import Any, Callable, Iterable, Mapping, Sequence

from gma_ffc.errors import ConfigError

# Names the project uses; maps may hold others (status words, heartbeat counters...).
CURRENT_SETPOINT = "current_setpoint_A"
OUTPUT_ENABLE = "output_enable"
CURRENT = "current_A"
FORCE = "force_N"
DISPLACEMENT = "displacement_um"
STATUS = "status"
HEARTBEAT = "heartbeat"

REGISTER_FUNCTIONS = ("holding", "input")
BIT_FUNCTIONS = ("coil", "discrete")
FUNCTIONS = REGISTER_FUNCTIONS + BIT_FUNCTIONS
WRITABLE_FUNCTIONS = ("holding", "coil")

# type -> (struct code, number of 16-bit registers, raw min, raw max); float32 limits are its finite range.
_FLOAT32_MAX = 3.4028234663852886e38
TYPES: dict[str, tuple[str, int, float, float]] = {
    "int16": ("h", 1, -(2**15), 2**15 - 1),
    "uint16": ("H", 1, 0, 2**16 - 1),
    "int32": ("i", 2, -(2**31), 2**31 - 1),
    "uint32": ("I", 2, 0, 2**32 - 1),
    "float32": ("f", 2, -_FLOAT32_MAX, _FLOAT32_MAX),
}
ORDERS = ("big", "little")
ACCESS = ("r", "rw")
CHANNEL_KEYS = (
    "function", "address", "type", "word_order", "byte_order", "scale", "offset", "unit_id", "access",
)
DEFAULTABLE_KEYS = ("type", "word_order", "byte_order", "scale", "offset", "unit_id", "access")
MAX_ADDRESS = 0xFFFF
UNIT_ID_RANGE = (1, 247)  # valid on RTU and TCP alike; 0 is broadcast (no reply)
# Largest single reads the Modbus spec allows (FC3/FC4 registers, FC1/FC2 bits).
MAX_READ_REGISTERS = 125
MAX_READ_BITS = 2000


@dataclass(frozen=True)
class Channel:
    """One named quantity on a device: where it lives and how its words map to a physical value."""

    name: str
    function: str
    address: int
    type: str = "uint16"
    word_order: str = "big"
    byte_order: str = "big"
    scale: float = 1.0
    offset: float = 0.0
    unit_id: int = 1
    access: str = "r"

    @property
    def is_bit(self) -> bool:
        """Coils and discrete inputs carry one bit, not registers."""
        return self.function in BIT_FUNCTIONS

    @property
    def count(self) -> int:
        """How many registers (or bits) the channel occupies."""
        return 1 if self.is_bit else TYPES[self.type][1]

    @property
    def writable(self) -> bool:
        return self.access == "rw"

    @property
    def end(self) -> int:
        """One past the last address used."""
        return self.address + self.count

    def _fail(self, key: str, why: str) -> ConfigError:
        return ConfigError(f"register map channel '{self.name}', key '{key}': {why}")

    def encode(self, value: float | bool) -> list[int]:
        """Physical value -> registers (or [bit]) to write; ConfigError if the type cannot hold it."""
        if self.is_bit:
            if isinstance(value, bool) or value in (0, 1):
                return [1 if value else 0]
            raise self._fail("value", f"{value!r} is not a bit (use true/false or 0/1)")
        try:
            physical = float(value)
        except (TypeError, ValueError):
            raise self._fail("value", f"{value!r} is not a number") from None
        code, _, lo, hi = TYPES[self.type]
        if self.type == "float32":
            raw: float | int = (physical - self.offset) / self.scale
            if math.isfinite(raw) and not lo <= raw <= hi:
                raise self._fail("value", f"{physical!r} scales to {raw!r}, beyond float32's range")
        else:
            if not math.isfinite(physical):
                raise self._fail("value", f"{physical!r} cannot be encoded as {self.type}")
            raw = round((physical - self.offset) / self.scale)
            if not lo <= raw <= hi:
                raise self._fail(
                    "value",
                    f"{physical!r} is out of range for {self.type} with scale {self.scale} and offset "
                    f"{self.offset} (physical range {self.physical_range[0]!r} to {self.physical_range[1]!r})",
                )
        data = struct.pack(">" + code, raw)
        words = [data[i:i + 2] for i in range(0, len(data), 2)]
        if self.byte_order == "little":
            words = [w[::-1] for w in words]
        if self.word_order == "little":
            words.reverse()
        return [int.from_bytes(w, "big") for w in words]

    def decode(self, words: Sequence[int] | Sequence[bool]) -> float | bool:
        """Registers (or [bit]) read from the device -> physical value (float; bool for bits)."""
        if len(words) != self.count:
            raise self._fail("value", f"expected {self.count} {'bit' if self.is_bit else 'register'}(s), got {len(words)}")
        if self.is_bit:
            return bool(words[0])
        for word in words:
            if not (isinstance(word, int) and 0 <= word <= 0xFFFF):
                raise self._fail("value", f"register value {word!r} is not a 16-bit word")
        chunks = [int(w).to_bytes(2, "big") for w in words]
        if self.word_order == "little":
            chunks.reverse()
        if self.byte_order == "little":
            chunks = [c[::-1] for c in chunks]
        (raw,) = struct.unpack(">" + TYPES[self.type][0], b"".join(chunks))
        value = float(raw) * self.scale
        # no offset: leave the value alone, so a device's -0.0 reads back as -0.0 (adding 0.0 makes it +0.0)
        return value + self.offset if self.offset else value

    @property
    def physical_range(self) -> tuple[float, float]:
        """Smallest and largest physical values the channel can encode."""
        if self.is_bit:
            return (0.0, 1.0)
        _, _, lo, hi = TYPES[self.type]
        ends = sorted((lo * self.scale + self.offset, hi * self.scale + self.offset))
        return (ends[0], ends[1])


@dataclass(frozen=True)
class ReadBlock:
    """One Modbus read request covering several adjacent channels on one device and table."""

    unit_id: int
    function: str
    address: int
    count: int
    channels: tuple[Channel, ...]

    def decode(self, words: Sequence[int] | Sequence[bool]) -> dict[str, float | bool]:
        """Split one read response into the channels' physical values."""
        if len(words) < self.count:
            raise ConfigError(
                f"read of {self.function} {self.address}+{self.count} on unit {self.unit_id} "
                f"returned {len(words)} values"
            )
        return {
            ch.name: ch.decode(list(words[ch.address - self.address:ch.end - self.address]))
            for ch in self.channels
        }


@dataclass(frozen=True)
class RegisterMap:
    """A validated set of named channels; build with `from_dict` / `from_yaml_text` / `load_register_map`."""

    channels: Mapping[str, Channel] = field(default_factory=dict)

    def __getitem__(self, name: str) -> Channel:
        try:
            return self.channels[name]
        except KeyError:
            raise ConfigError(
                f"register map has no channel '{name}' (it has: {', '.join(sorted(self.channels)) or 'none'})"
            ) from None

    def __contains__(self, name: object) -> bool:
        return name in self.channels

    def __iter__(self):
        return iter(self.channels.values())

    def __len__(self) -> int:
        return len(self.channels)

    @property
    def unit_ids(self) -> tuple[int, ...]:
        return tuple(sorted({ch.unit_id for ch in self.channels.values()}))

    def require(self, *names: str, writable: Iterable[str] = ()) -> None:
        """ConfigError naming the first channel a driver needs that the map lacks (or has read-only)."""
        for name in names:
            self[name]
        for name in writable:
            ch = self[name]
            if not ch.writable or ch.function not in WRITABLE_FUNCTIONS:
                raise ConfigError(
                    f"register map channel '{name}', key 'access': must be rw on a holding register or coil"
                )

    def encode(self, name: str, value: float | bool) -> list[int]:
        return self[name].encode(value)

    def decode(self, name: str, words: Sequence[int] | Sequence[bool]) -> float | bool:
        return self[name].decode(words)

    def read_plan(self, names: Iterable[str] | None = None, max_gap: int = 0) -> list[ReadBlock]:
        """Group channels into as few read requests as possible (same unit and table, gaps <= max_gap)."""
        chosen = [self[n] for n in names] if names is not None else list(self.channels.values())
        chosen.sort(key=lambda c: (c.unit_id, FUNCTIONS.index(c.function), c.address))
        blocks: list[ReadBlock] = []
        group: list[Channel] = []
        for ch in chosen:
            limit = MAX_READ_BITS if ch.is_bit else MAX_READ_REGISTERS
            if group:
                head = group[0]
                end = max(c.end for c in group)
                if (
                    ch.unit_id == head.unit_id
                    and ch.function == head.function
                    and ch.address - end <= max_gap
                    and max(end, ch.end) - head.address <= limit
                ):
                    group.append(ch)
                    continue
                blocks.append(_block(group))
            group = [ch]
        if group:
            blocks.append(_block(group))
        return blocks

    @classmethod
    def from_dict(cls, data: Any) -> "RegisterMap":
        """Validate a parsed map (see the module docstring); ConfigError names channel and key."""
        if not isinstance(data, Mapping):
            raise ConfigError("register map: expected a mapping with a 'channels' key")
        unknown = set(data) - {"channels", "defaults"}
        if unknown:
            raise ConfigError(f"register map: unknown top-level key '{sorted(unknown)[0]}' (allowed: channels, defaults)")
        defaults = data.get("defaults") or {}
        if not isinstance(defaults, Mapping):
            raise ConfigError("register map, key 'defaults': expected a mapping")
        for key in defaults:
            if key not in DEFAULTABLE_KEYS:
                raise ConfigError(
                    f"register map, key 'defaults.{key}': not a defaultable key (allowed: {', '.join(DEFAULTABLE_KEYS)})"
                )
        raw_channels = data.get("channels")
        if not isinstance(raw_channels, Mapping) or not raw_channels:
            raise ConfigError("register map, key 'channels': expected a non-empty mapping of channel name -> fields")
        channels = {
            str(name): _channel(str(name), spec, defaults) for name, spec in raw_channels.items()
        }
        _check_overlaps(channels.values())
        return cls(channels)

    @classmethod
    def from_yaml_text(cls, text: str, source: str = "register map") -> "RegisterMap":
        import yaml

        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise ConfigError(f"{source}: not valid YAML ({str(exc).splitlines()[0]})") from None
        return cls.from_dict(data)

    def to_dict(self) -> dict[str, Any]:
        """Plain data that `from_dict` accepts back (for configs, logs and the emulator's --help)."""
        return {
            "channels": {
                ch.name: {k: getattr(ch, k) for k in CHANNEL_KEYS} for ch in self.channels.values()
            }
        }


def load_register_map(path: str | PathLike) -> RegisterMap:
    """Read and validate a register-map YAML file."""
    try:
        with open(path, encoding="utf-8") as handle:
            text = handle.read()
    except OSError as exc:
        raise ConfigError(f"register map {path}: cannot read ({exc.strerror})") from None
    return RegisterMap.from_yaml_text(text, source=f"register map {path}")


def _block(group: list[Channel]) -> ReadBlock:
    head = group[0]
    end = max(c.end for c in group)
    return ReadBlock(head.unit_id, head.function, head.address, end - head.address, tuple(group))


def _channel(name: str, spec: Any, defaults: Mapping[str, Any]) -> Channel:
    """One channel of a register map, checked field by field; each error names the channel and key."""
    where = f"register map channel '{name}'"
    if not name.isidentifier():
        raise ConfigError(f"{where}: the name must be an identifier (letters, digits, underscores)")
    if not isinstance(spec, Mapping):
        raise ConfigError(f"{where}: expected a mapping of fields ({', '.join(CHANNEL_KEYS)})")
    for key in spec:
        if key not in CHANNEL_KEYS:
            raise ConfigError(f"{where}, key '{key}': unknown (allowed: {', '.join(CHANNEL_KEYS)})")
    merged = {**defaults, **spec}

    def fail(key: str, why: str) -> ConfigError:
        return ConfigError(f"{where}, key '{key}': {why}")

    for key in ("function", "address"):
        if key not in merged:
            raise fail(key, "missing")
    function = merged["function"]
    if function not in FUNCTIONS:
        raise fail("function", f"{function!r} is not one of {', '.join(FUNCTIONS)}")
    ctype = _channel_type(function, spec, merged, fail)
    address = _channel_address(merged["address"], 1 if function in BIT_FUNCTIONS else TYPES[ctype][1], fail)
    orders = {}
    for key in ("word_order", "byte_order"):
        value = merged.get(key, "big")
        if value not in ORDERS:
            raise fail(key, f"{value!r} is not big or little")
        orders[key] = value
    numbers = _channel_numbers(merged, fail)
    unit_id = merged.get("unit_id", 1)
    lo, hi = UNIT_ID_RANGE
    if isinstance(unit_id, bool) or not isinstance(unit_id, int) or not lo <= unit_id <= hi:
        raise fail("unit_id", f"{unit_id!r} is not an integer {lo}..{hi}")
    access = merged.get("access", "r")
    if access not in ACCESS:
        raise fail("access", f"{access!r} is not r or rw")
    if access == "rw" and function not in WRITABLE_FUNCTIONS:
        raise fail("access", f"{function} tables are read-only in Modbus; use holding or coil for rw")
    return Channel(
        name=name, function=function, address=address, type=ctype, unit_id=unit_id, access=access,
        scale=numbers["scale"], offset=numbers["offset"], **orders,
    )


def _channel_type(function: str, spec: Mapping[str, Any], merged: Mapping[str, Any],
                  fail: Callable[[str, str], ConfigError]) -> str:
    """The channel's value type: bool for a bit table (which takes no scale or offset), else one of TYPES."""
    if function in BIT_FUNCTIONS:
        ctype = merged.get("type", "bool")
        if ctype != "bool":
            raise fail("type", f"{function} channels are single bits: type must be bool (or omitted), not {ctype!r}")
        for key, neutral in (("scale", 1), ("offset", 0)):
            if key in spec and spec[key] != neutral:
                raise fail(key, f"does not apply to a {function} bit")
        return "bool"
    ctype = merged.get("type", "uint16")
    if ctype not in TYPES:
        raise fail("type", f"{ctype!r} is not one of {', '.join(TYPES)}")
    return str(ctype)


def _channel_address(address: Any, count: int, fail: Callable[[str, str], ConfigError]) -> int:
    """The first register's address, with the channel's `count` registers inside the table."""
    if isinstance(address, bool) or not isinstance(address, int) or not 0 <= address <= MAX_ADDRESS:
        raise fail("address", f"{address!r} is not an integer 0..{MAX_ADDRESS}")
    if address + count - 1 > MAX_ADDRESS:
        raise fail("address", f"{address} + {count} registers runs past {MAX_ADDRESS}")
    return address


def _channel_numbers(merged: Mapping[str, Any], fail: Callable[[str, str], ConfigError]) -> dict[str, float]:
    """Scale (not zero) and offset: finite numbers."""
    numbers = {}
    for key, default in (("scale", 1.0), ("offset", 0.0)):
        value = merged.get(key, default)
        if isinstance(value, str):  # YAML 1.1 reads 1e-6 (no dot) as a string: accept what float() reads
            try:
                value = float(value)
            except ValueError:
                pass
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise fail(key, f"{value!r} is not a finite number")
        numbers[key] = float(value)
    if numbers["scale"] == 0.0:
        raise fail("scale", "must not be zero")
    return numbers


def _check_overlaps(channels: Iterable[Channel]) -> None:
    by_table: dict[tuple[int, str], list[Channel]] = {}
    for ch in channels:
        by_table.setdefault((ch.unit_id, ch.function), []).append(ch)
    for (unit_id, function), group in by_table.items():
        group.sort(key=lambda c: c.address)
        for prev, cur in zip(group, group[1:]):
            if cur.address < prev.end:
                raise ConfigError(
                    f"register map channel '{cur.name}', key 'address': {function} {cur.address} on unit "
                    f"{unit_id} overlaps channel '{prev.name}' ({prev.address}..{prev.end - 1})"
                )
