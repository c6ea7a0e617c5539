"""Driver plugins: the hardware side of the controller, found through the entry-point group
``gma_ffc.drivers`` so a lab can add its own DAQ without touching this package."""

from __future__ import annotations

import difflib
from importlib.metadata import EntryPoint, entry_points

from ..errors import ConfigError
from .base import REFUSED, Driver, DriverError, DriverProtocol, Inputs, missing_members

GROUP = "gma_ffc.drivers"

__all__ = ["REFUSED", "Driver", "DriverError", "DriverProtocol", "Inputs", "GROUP", "available_drivers", "driver_class"]


def available_drivers() -> dict[str, EntryPoint]:
    """Installed drivers: name -> entry point (not yet imported)."""
    return {ep.name: ep for ep in entry_points(group=GROUP)}


def driver_class(kind: str, key: str = "driver.kind") -> type[DriverProtocol]:
    """Import the driver registered under `kind`; ConfigError naming `key` when there is none, or
    when it is neither a `Driver` subclass nor a class offering the whole `DriverProtocol`."""
    eps = available_drivers()
    if kind not in eps:
        close = difflib.get_close_matches(str(kind), list(eps), n=1, cutoff=0.5)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise ConfigError(f"config key '{key}': no driver named {kind!r} is installed; "
                          f"installed: {', '.join(sorted(eps)) or 'none'}{hint}")
    try:
        cls = eps[kind].load()
    except Exception as exc:  # a broken plugin must not crash with a traceback
        raise ConfigError(f"config key '{key}': driver {kind!r} failed to load ({exc})") from None
    if not isinstance(cls, type):
        raise ConfigError(f"config key '{key}': {kind!r} does not name a gma_ffc Driver class")
    if not issubclass(cls, Driver):
        missing = missing_members(cls)
        if missing:
            raise ConfigError(f"config key '{key}': {kind!r} does not name a gma_ffc Driver class: it neither "
                              f"subclasses gma_ffc.drivers.Driver nor defines {', '.join(missing)}")
    return cls
