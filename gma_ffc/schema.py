"""A small declarative validator for YAML config sections.

Every error is a `ConfigError` naming the dotted key and what is wrong; unknown keys are
refused with a did-you-mean. Drivers reuse it for their own sections, so a lab's plugin gives
the same quality of message.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

from .errors import ConfigError

_MISSING = object()


@dataclass(frozen=True)
class Field:
    """One key: its kind, default (omit for required) and optional extra check."""

    kind: str                      # "float" | "int" | "bool" | "str" | "choice" | "list" | "map" | "any"
    default: Any = _MISSING
    choices: Sequence[str] = ()
    min: float | None = None
    max: float | None = None
    min_exclusive: bool = False
    nullable: bool = False
    check: Callable[[Any, str], Any] | None = None   # (value, key) -> value; raise ConfigError
    help: str = ""

    @property
    def required(self) -> bool:
        return self.default is _MISSING


def key_name(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix else key


def refuse_unknown(section: Mapping[str, Any], known: Sequence[str], prefix: str) -> None:
    """ConfigError for the first key not in `known`, suggesting the closest known key."""
    for key in section:
        if key not in known:
            close = difflib.get_close_matches(str(key), list(known), n=1, cutoff=0.5)
            hint = f" (did you mean '{key_name(prefix, close[0])}'?)" if close else \
                f" (known keys: {', '.join(sorted(known))})"
            raise ConfigError(f"config key '{key_name(prefix, str(key))}' is unknown{hint}")


def as_section(value: Any, prefix: str) -> dict[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ConfigError(f"config key '{prefix}' must be a mapping of keys to values, got {type(value).__name__}")
    return dict(value)


def check_value(value: Any, spec: Field, key: str) -> Any:
    """Coerce and range-check one value; the message names the key."""
    if value is None:
        if spec.nullable:
            return None
        raise ConfigError(f"config key '{key}' must have a value (it is empty)")
    kind = spec.kind
    if kind == "float":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"config key '{key}' must be a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(f"config key '{key}' must be finite, got {value!r}")
    elif kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"config key '{key}' must be a whole number, got {value!r}")
    elif kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"config key '{key}' must be true or false, got {value!r}")
    elif kind == "str":
        if not isinstance(value, str) or not value:
            raise ConfigError(f"config key '{key}' must be a non-empty text, got {value!r}")
    elif kind == "choice":
        if value not in spec.choices:
            close = difflib.get_close_matches(str(value), list(spec.choices), n=1, cutoff=0.5)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise ConfigError(f"config key '{key}' must be one of {', '.join(spec.choices)}, got {value!r}{hint}")
    elif kind == "list":
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"config key '{key}' must be a list, got {value!r}")
        value = list(value)
    elif kind == "map":
        value = as_section(value, key)
    if kind in ("float", "int"):
        if spec.min is not None and (value < spec.min or (spec.min_exclusive and value == spec.min)):
            op = ">" if spec.min_exclusive else ">="
            raise ConfigError(f"config key '{key}' must be {op} {spec.min:g}, got {value!r}")
        if spec.max is not None and value > spec.max:
            raise ConfigError(f"config key '{key}' must be <= {spec.max:g}, got {value!r}")
    if spec.check is not None:
        value = spec.check(value, key)
    return value


def validate_section(section: Any, schema: Mapping[str, Field], prefix: str) -> dict[str, Any]:
    """Validated copy of `section` with defaults filled in."""
    data = as_section(section, prefix)
    refuse_unknown(data, list(schema), prefix)
    out: dict[str, Any] = {}
    for key, spec in schema.items():
        name = key_name(prefix, key)
        if key in data:
            out[key] = check_value(data[key], spec, name)
        elif spec.required:
            raise ConfigError(f"config key '{name}' is required{(': ' + spec.help) if spec.help else ''}")
        else:
            out[key] = spec.default
    return out


def pair(value: Any, key: str) -> tuple[float, float]:
    """A [lo, hi] pair of numbers with lo < hi."""
    if not isinstance(value, (list, tuple)) or len(value) != 2 or any(
            isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) for v in value):
        raise ConfigError(f"config key '{key}' must be a pair of numbers [low, high], got {value!r}")
    lo, hi = float(value[0]), float(value[1])
    if not lo < hi:
        raise ConfigError(f"config key '{key}' must have low < high, got {value!r}")
    return lo, hi
