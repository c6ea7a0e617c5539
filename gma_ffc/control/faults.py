"""Fault bookkeeping: which faults are active, the recent history, and a tick's exception as a fault.

The loop raises and clears faults; the service's status requests read them from other threads,
so every change and every read holds one lock. What a fault makes the runner do is not here:
that is the fault table (`safety.FAULT_ACTIONS`), which the runner (`manager`) executes.
"""

from __future__ import annotations

import collections
import threading
import time
from typing import Any

from ..drivers import REFUSED, DriverError
from . import safety
from .scheduler import TickStats

FAULT_HISTORY = 200     # most recent faults kept for the status (bounded for long service lives)


class TickFault(Exception):
    """Raised inside a tick to leave it for the fault path (only on the rare fault branch)."""

    def __init__(self, name: str, message: str, reason: str | None = None) -> None:
        super().__init__(message)
        self.name = name
        self.reason = message if reason is None else reason     # the exit reason, when it ends the run


class FaultLog:
    """Active faults (name -> message) and the last `FAULT_HISTORY` raised, thread-safe.

    `active` is read without the lock by the loop's membership tests (a dict lookup is atomic
    under the GIL); every change, and every copy for a status, takes the lock.
    """

    def __init__(self, stats: TickStats) -> None:
        self._stats = stats             # for the tick a fault was raised at
        self._lock = threading.Lock()
        self.active: dict[str, str] = {}
        self.history: collections.deque[dict[str, Any]] = collections.deque(maxlen=FAULT_HISTORY)
        self.counts: collections.Counter[str] = collections.Counter()     # raised since the start, by name (metrics)

    def raise_fault(self, name: str, message: str) -> None:
        with self._lock:
            self.active[name] = message
            self.counts[name] += 1
            self.history.append({"fault": name, "message": message, "at_unix_s": time.time(),
                                 "tick": self._stats.count})

    def clear(self, name: str) -> None:
        with self._lock:
            self.active.pop(name, None)

    def snapshot(self) -> tuple[dict[str, str], list[dict[str, Any]]]:
        """Copies of the active faults and the history, for a status."""
        with self._lock:
            return dict(self.active), list(self.history)

    def counted(self) -> dict[str, int]:
        """How often each fault was raised since the start (a copy)."""
        with self._lock:
            return dict(self.counts)


def driver_fault(exc: DriverError) -> str:
    """The fault a driver's error is: a register the device refuses, a timeout, or a comms error."""
    return {REFUSED: safety.REGISTER_REFUSED, "timeout": safety.COMMS_TIMEOUT}.get(exc.reason, safety.COMMS_ERROR)


def classify(exc: Exception) -> tuple[str, str, str]:
    """A tick's exception as (fault name, fault message, exit reason)."""
    if isinstance(exc, TickFault):
        return exc.name, str(exc), exc.reason
    if isinstance(exc, DriverError):
        return driver_fault(exc), str(exc), str(exc)
    message = f"{type(exc).__name__}: {exc}"
    return safety.EXCEPTION, message, f"exception in the tick: {message}"
