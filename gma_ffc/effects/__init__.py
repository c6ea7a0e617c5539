"""The physical effects the extended model can add to an SDPI/MPI core, one class per file.

Each class implements `base.Effect`: its block(s) in the extended model (batch filter, forward
and inverse stepper states, file form) and how the diagnosis fits it (testability, parameter
grid, least-squares regressors, coefficients -> block, signature check, words). To add an
effect, write one module here and add its class to `REGISTRY` below; the extended model, its
files and `gma-ffc diagnose` pick it up from there (`register` does the same at run time).

The registry's order is the diagnosis' candidate order (reports list candidates in it); the
signal path is ordered by each class's `position`.
"""

from __future__ import annotations

from .base import Effect
from .creep import Creep
from .delay import Delay
from .dynamics import Dynamics
from .eddy import EddyLag
from .saturation import Saturation
from .static import StaticMap
from .stress_play import StressPlay
from .thermal import Thermal

REGISTRY: dict[str, type[Effect]] = {}


def register(cls: type[Effect]) -> type[Effect]:
    """Add an effect class (by its `name`); its block keys must be new, and each block's keys declared
    (`block_keys`: a model file's key it does not read is refused, not ignored). Returns the class (a decorator)."""
    taken = {k for c in REGISTRY.values() for k in c.keys}
    if cls.name in REGISTRY or taken & set(cls.keys):
        raise ValueError(f"effect {cls.name!r} or one of its blocks {cls.keys} is registered already")
    undeclared = [k for k in cls.keys if k not in getattr(cls, "block_keys", {})]
    if undeclared:
        raise ValueError(f"effect {cls.name!r}: declare the keys of its block(s) {undeclared} in block_keys")
    REGISTRY[cls.name] = cls
    return cls


def unregister(name: str) -> None:
    """Remove an effect class registered at run time (tests)."""
    REGISTRY.pop(name, None)


for _cls in (EddyLag, Dynamics, Thermal, Creep, Delay, StressPlay, Saturation, StaticMap):
    register(_cls)


def path_order() -> list[type[Effect]]:
    """Every registered effect class in signal-path order."""
    return sorted(REGISTRY.values(), key=lambda c: c.position)


def candidates() -> list[type[Effect]]:
    """The effects the diagnosis may select, in registry order."""
    return [c for c in REGISTRY.values() if c.candidate]


def by_block_key() -> dict[str, type[Effect]]:
    """Which class owns each block key of a model file."""
    return {k: c for c in REGISTRY.values() for k in c.keys}


__all__ = ["REGISTRY", "Effect", "register", "unregister", "path_order", "candidates", "by_block_key"]
