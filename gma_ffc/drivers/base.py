"""The driver interface: what the controller needs from the hardware, and nothing more.

Lifecycle, as ros2_control's hardware interface: ``open()`` (configure: connect), ``activate()``
(switch the amplifier's output on, before the first command), then per tick ``read(inputs)`` and
``write(current_A)``, then ``safe(current_A)``, ``deactivate()`` (output off) and ``close()``
(cleanup). A write never switches the output on by itself. Comms failures raise `DriverError`;
the controller, not the driver, decides what is safe. ``read`` fills a preallocated `Inputs`
record, so the hot path allocates no containers.

`DriverProtocol` is the contract as a type: everything the controller and config validation use.
The `Driver` base class satisfies it (the shipped drivers subclass it and inherit its safe-write
retry, reconnect and health report); a lab's plugin may instead implement every member itself.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from ..errors import FaultError

NAN = math.nan

# Channel names a driver may provide; they double as telemetry column names.
FORCE = "force_N"
STRESS = "stress_MPa"
CURRENT = "current_A"
DISPLACEMENT = "displacement_um"
CHANNELS = (FORCE, STRESS, CURRENT, DISPLACEMENT)


REFUSED = "refused"   # DriverError reason: the device has no such register or function (a config fact)


class DriverError(FaultError):
    """A comms or device failure; `reason` is a short machine-readable cause: "comms", "timeout",
    or REFUSED (the device refuses a configured register: no reconnect mends it)."""

    def __init__(self, message: str, reason: str = "comms") -> None:
        super().__init__(message)
        self.reason = reason


class Inputs:
    """One tick's measurements; NaN where a channel is missing or was not read."""

    __slots__ = ("force_N", "stress_MPa", "current_A", "displacement_um")

    def __init__(self) -> None:
        self.force_N = NAN
        self.stress_MPa = NAN
        self.current_A = NAN
        self.displacement_um = NAN

    def clear(self) -> None:
        self.force_N = NAN
        self.stress_MPa = NAN
        self.current_A = NAN
        self.displacement_um = NAN


@runtime_checkable
class DriverProtocol(Protocol):
    """What the controller needs from a driver object, whether or not it subclasses `Driver`."""

    kind: str
    simulated_clock_ok: bool         # True only for a device simulated in-process (clock: simulated)
    channels: tuple[str, ...]        # which of CHANNELS `read` fills, set by `open()` at the latest
    last_written_A: float
    errors: int
    last_error: str                  # the controller sets it too, from a failed reconnect

    def __init__(self, cfg: dict[str, Any], period_s: float) -> None: ...

    @classmethod
    def validate_config(cls, section: dict[str, Any], prefix: str, base_dir: Path | None) -> dict[str, Any]: ...

    def open(self) -> None: ...

    def read(self, inputs: Inputs) -> None: ...

    def write(self, current_A: float) -> None: ...

    def activate(self) -> None: ...

    def safe(self, current_A: float) -> None: ...

    def deactivate(self) -> None: ...

    def close(self) -> None: ...

    def reconnect(self) -> None: ...

    def health(self) -> dict[str, Any]: ...


# Members a driver class must define itself, and those a constructed driver must have besides.
CLASS_MEMBERS = ("kind", "validate_config", "open", "activate", "read", "write", "safe", "deactivate", "close",
                 "reconnect", "health")
INSTANCE_MEMBERS = CLASS_MEMBERS + ("simulated_clock_ok", "channels", "last_written_A", "errors", "last_error")


def missing_members(obj: object, names: tuple[str, ...] = CLASS_MEMBERS) -> list[str]:
    """The contract's members `obj` (a driver class or instance) lacks, in contract order."""
    return [n for n in names if not hasattr(obj, n)]


class Driver(ABC):
    """Base class of every driver plugin.

    Subclasses set `channels` (which of CHANNELS `read` fills) after `open()` at the latest and
    implement `validate_config` for their config section (use gma_ffc.schema).
    """

    kind: str = "abstract"
    simulated_clock_ok: bool = False     # True only for drivers whose device is simulated in-process

    def __init__(self, cfg: dict[str, Any], period_s: float) -> None:
        self.cfg = cfg
        self.period_s = period_s
        self.channels: tuple[str, ...] = ()
        self.last_written_A = NAN
        self.errors = 0
        self.last_error = ""

    @classmethod
    @abstractmethod
    def validate_config(cls, section: dict[str, Any], prefix: str, base_dir: Path | None) -> dict[str, Any]:
        """Validated copy of the driver's config section (ConfigError naming the key)."""

    @classmethod
    def setpoint_range_A(cls, cfg: dict[str, Any]) -> tuple[float, float, str] | None:
        """The currents the driver's setpoint can carry, and what sets them (a register's type and
        scale), from a validated section; None when any current can be sent."""
        return None

    @classmethod
    def amplifiers(cls, cfg: dict[str, Any]) -> list[str]:
        """The amplifiers this validated section drives, each as a name unique on the machine
        ("modbus-tcp:HOST:PORT:UNIT", "serial:/dev/ttyUSB0"): a run claims them before it opens
        (`control.device_claim`), so two controllers never drive one. None for a simulated rig."""
        return []

    @abstractmethod
    def open(self) -> None:
        """Connect; raise DriverError when the device cannot be reached."""

    @abstractmethod
    def read(self, inputs: Inputs) -> None:
        """Fill `inputs` with this tick's measurements (NaN for what is missing)."""

    def activate(self) -> None:
        """Switch the amplifier's output on; called after `open()` (and after each reconnect)
        before the first command. The default does nothing: a device without an output switch
        is always on."""

    @abstractmethod
    def write(self, current_A: float) -> None:
        """Command the amplifier's current (the output stays as `activate`/`safe` left it)."""

    def safe(self, current_A: float) -> None:
        """Put the amplifier at its safe current; after a failure, reconnect once and try again,
        so a dropped link does not stop the safe command getting through."""
        try:
            self._safe_once(current_A)
        except DriverError:
            try:
                self.close()
                self.open()
            except DriverError:
                raise DriverError(f"safe current not written: {getattr(self, 'last_error', '')}") from None
            self._safe_once(current_A)

    def _safe_once(self, current_A: float) -> None:
        """One attempt at the safe current. The default writes it; drivers with an output-enable
        switch the output off too, and drivers without acknowledgements read it back."""
        self.write(current_A)

    @property
    def switches_off_on_safe(self) -> bool:
        """Whether `safe()` switches the output off, so the coil carries 0 A until `activate()`
        (an optional member: the controller's inverse follows the coil through it on a reconnect)."""
        return False

    def deactivate(self) -> None:
        """Switch the output off at the end of a run, after the safe current was written. The
        default does nothing (no output switch)."""

    @abstractmethod
    def close(self) -> None:
        """Release the connection; idempotent."""

    def reconnect(self) -> None:
        """Drop and re-open the connection after a comms fault."""
        try:
            self.close()
        finally:
            self.open()

    def health(self) -> dict[str, Any]:
        """Comms state for the status page."""
        return {"kind": self.kind, "errors": self.errors, "last_error": self.last_error,
                "last_written_A": None if math.isnan(self.last_written_A) else self.last_written_A}
