"""Read a YAML file the way every gma-ffc input is read: one clear error, never a traceback."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import yaml

from .errors import InputError


class DuplicateKeyError(yaml.YAMLError):
    """A mapping names the same key twice: YAML keeps the last silently, we refuse."""


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys, naming the key and both lines."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            line = key_node.start_mark.line + 1
            try:
                first = seen.get(key)
            except TypeError:            # an unhashable key: let the base class say so
                continue
            if first is not None:
                raise DuplicateKeyError(f"key {key!r} appears twice, on lines {first} and {line}")
            seen[key] = line
        return super().construct_mapping(node, deep)


# YAML 1.1 (PyYAML) reads 1e3 and 1.0e3 as strings: its floats need a dot and a signed exponent.
# YAML 1.2 and every other reader take them as numbers, and so do we (a config's `rate_hz: 1e3`).
_UniqueKeyLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."))


def read_yaml(path: str | os.PathLike, what: str, error: type[InputError] = InputError) -> Any:
    """Parsed content of `path`; `error` names the file (and the line) when it cannot be read.

    `what` says what the file should be ("model file", "config file") for "no such ..." messages.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(f"{p}: no such {what}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{p}: cannot read the {what} ({getattr(exc, 'strerror', None) or exc})") from None
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except DuplicateKeyError as exc:
        raise error(f"{p}: {exc}; keep one of them") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        if "'\\t'" in problem:       # PyYAML: "found character '\t' that cannot start any token"
            raise error(f"{p}{where}: a tab character; YAML indents with spaces only: replace the tabs "
                        "with spaces") from None
        raise error(f"{p}{where}: not valid YAML ({problem}); is it a {what}?") from None
