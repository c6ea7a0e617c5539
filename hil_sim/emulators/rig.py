"""The emulated rig behind every protocol: amplifier state, the simulated GMA advancing in real
time, the sensors as a device would report them (faults applied), and a log of what was received.

Protocol front ends (Modbus TCP/RTU, SCPI serial) only translate; the behaviour lives here once,
so the three emulators cannot drift apart.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Protocol

from gma_ffc.errors import InputError

from .faults import SENSOR_CHANNELS, FaultSet


class Plant(Protocol):
    """What the rig needs of hil_sim.plant.GMAPlant (see docs/ARCHITECTURE.md)."""

    current_A: float
    force_N: float
    displacement_um: float

    def step(self, current_cmd_A: float, dt_s: float) -> Any: ...


class SetpointOutOfRange(InputError):
    """A commanded current beyond the amplifier's rating (the device refuses it)."""


@dataclass(frozen=True)
class Command:
    """One command the emulator received: when (s since start, monotonic), what, which value."""

    time_s: float
    kind: str  # "setpoint" | "output_enable"
    value: float


class EmulatedRig:
    """Amplifier + GMA + sensors, stepped by the wall-clock time between requests.

    The plant advances in fixed `dt_s` chunks with the current setpoint held (0 A while the output
    is disabled). After a long idle gap at most `max_catch_up_s` is simulated and the rest skipped,
    so a request never stalls for long; `skipped_s` counts what was skipped.
    """

    def __init__(
        self,
        plant: Plant,
        *,
        dt_s: float = 1e-3,
        max_catch_up_s: float = 0.5,
        max_current_A: float = 2.0,
        clock: Callable[[], float] = time.monotonic,
        identity: str = "GMA-FFC,HIL-AMP-1,0,1.0",
    ) -> None:
        if not dt_s > 0 or not max_catch_up_s >= dt_s or not max_current_A > 0:
            raise InputError("rig: dt_s and max_current_A must be > 0 and max_catch_up_s >= dt_s")
        self.plant = plant
        self.dt_s = float(dt_s)
        self.max_steps = int(max_catch_up_s / dt_s)
        self.max_current_A = float(max_current_A)
        self.identity = identity
        self.faults = FaultSet()
        self._clock = clock
        self._lock = threading.RLock()
        self._t0 = clock()
        self._t_sim = self._t0  # wall-clock instant the plant state corresponds to
        self._setpoint = 0.0
        self._enabled = False
        self._history: list[Command] = []
        self._stuck: dict[str, float] = {}
        self.steps = 0
        self.skipped_s = 0.0
        self.requests = 0
        self.faults.add_listener(self._on_fault)

    # ---- commands ----------------------------------------------------------------------------
    def set_current(self, amps: float) -> None:
        """Hold a new current setpoint; refuses NaN and values beyond the amplifier's rating."""
        value = float(amps)
        if not math.isfinite(value) or abs(value) > self.max_current_A:
            raise SetpointOutOfRange(
                f"current setpoint {amps!r} A is outside the amplifier's +-{self.max_current_A:g} A"
            )
        with self._lock:
            self.advance()
            self._setpoint = value
            self._history.append(Command(self._clock() - self._t0, "setpoint", value))

    def set_output(self, enabled: bool) -> None:
        with self._lock:
            self.advance()
            self._enabled = bool(enabled)
            self._history.append(Command(self._clock() - self._t0, "output_enable", float(self._enabled)))

    def set_load_mass(self, kg: float) -> None:
        """Change the load on the rod (the stress follows), as when a mass is put on the rig."""
        setter = getattr(self.plant, "set_load_mass", None)
        if setter is None:
            raise InputError("this plant has no load mass to change")
        with self._lock:
            self.advance()
            setter(float(kg))

    @property
    def setpoint_A(self) -> float:
        return self._setpoint

    @property
    def output_enabled(self) -> bool:
        return self._enabled

    @property
    def last_setpoint_A(self) -> float | None:
        """The last setpoint written (None before any), for 'was the last command safe?' tests."""
        with self._lock:
            for cmd in reversed(self._history):
                if cmd.kind == "setpoint":
                    return cmd.value
        return None

    def history(self, kind: str | None = None) -> list[Command]:
        with self._lock:
            return [c for c in self._history if kind is None or c.kind == kind]

    # ---- simulation ---------------------------------------------------------------------------
    def advance(self) -> None:
        """Step the plant up to now in dt chunks (bounded catch-up)."""
        with self._lock:
            now = self._clock()
            n = int((now - self._t_sim) / self.dt_s)
            if n <= 0:
                return
            if n > self.max_steps:
                skipped = (n - self.max_steps) * self.dt_s
                self.skipped_s += skipped
                self._t_sim += skipped
                n = self.max_steps
            drive = self._setpoint if self._enabled else 0.0
            for _ in range(n):
                self.plant.step(drive, self.dt_s)
            self._t_sim += n * self.dt_s
            self.steps += n

    def true_value(self, channel: str) -> float:
        """The plant's measured value now, without device faults (what a healthy sensor would say)."""
        if channel not in SENSOR_CHANNELS:
            raise InputError(f"unknown sensor channel '{channel}' (use one of {', '.join(SENSOR_CHANNELS)})")
        with self._lock:
            self.advance()
            return float(getattr(self.plant, channel))

    def read(self, channel: str) -> float:
        """What the device reports for a sensor now: plant advanced to now, faults applied."""
        with self._lock:
            value = self.true_value(channel)
            if self.faults.get("nan", channel):
                return math.nan
            fault = self.faults.get("out_of_range", channel)
            if fault is not None:
                return fault.number
            if channel in self._stuck:
                return self._stuck[channel]
            return value

    def status_word(self) -> int:
        """bit 0 output enabled, bit 1 device failure (the exception fault). Sensor and link faults
        are not flagged: a real device does not know its sensor is stuck."""
        return (1 if self._enabled else 0) | (2 if self.faults.has("exception") else 0)

    def _on_fault(self, fault, active: bool) -> None:
        if fault.kind != "stuck":
            return
        with self._lock:
            if active:
                self._stuck[fault.channel] = self.true_value(fault.channel)
            else:
                self._stuck.pop(fault.channel, None)

    def snapshot(self) -> dict[str, Any]:
        """Plain data for the control socket and logs."""
        with self._lock:
            return {
                "setpoint_A": self._setpoint,
                "output_enabled": self._enabled,
                "last_setpoint_A": self.last_setpoint_A,
                "faults": [str(f) for f in self.faults.active()],
                "plant": {ch: self.true_value(ch) for ch in SENSOR_CHANNELS},
                "stress_MPa": float(getattr(self.plant, "stress_MPa", math.nan)),
                "history": [[c.time_s, c.kind, c.value] for c in self._history[-50:]],
                "commands_received": len(self._history),
                "requests": self.requests,
                "simulated_steps": self.steps,
                "skipped_s": self.skipped_s,
            }
