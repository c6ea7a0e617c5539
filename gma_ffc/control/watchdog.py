"""The watchdog: a thread that trips when the loop makes no progress (a hung driver call, a stall).

The loop stamps `heartbeat` at the start of every tick; the watchdog checks it every quarter of
its limit and, past the limit, raises the fault `watchdog` and sets `tripped`, which the loop's
next tick turns into the fault table's row. While the amplifier already sits at its safe current
(a fault being handled, a reconnect), the loop pauses it: those waits are bounded elsewhere.
"""

from __future__ import annotations

import contextlib
import math
import os
import threading

from . import safety
from .faults import FaultLog
from .scheduler import Clock


class Watchdog:
    """Guards one loop; `start`/`stop` around a run on the real clock."""

    def __init__(self, limit_s: float, clock: Clock, faults: FaultLog, loop_priority: int = 0) -> None:
        self.limit_s = limit_s
        self.clock = clock
        self.faults = faults
        self.loop_priority = loop_priority
        self.heartbeat = math.nan       # the start of the loop's last tick; NaN: paused
        self.tripped = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self.tripped = False
        self.heartbeat = math.nan
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="gma-ffc-watchdog", daemon=True)
        self._thread.start()

    def pause(self) -> None:
        """Until the next tick's heartbeat (the output is already safe; the wait is bounded)."""
        self.heartbeat = math.nan

    def stop(self) -> None:
        """Stand down at once (the run is ending); `join` waits for the thread afterwards."""
        self._stop.set()

    def join(self) -> None:
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def _run(self) -> None:
        if self.loop_priority > 1:
            # A normal-priority thread preempted while it holds the GIL would stall an RT loop.
            with contextlib.suppress(OSError, AttributeError):
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.loop_priority - 1))
        limit = self.limit_s
        while not self._stop.wait(limit / 4.0):
            hb = self.heartbeat
            idle = self.clock.now() - hb
            if idle > limit and not self.tripped:
                self.tripped = True
                self.faults.raise_fault(safety.WATCHDOG, f"the loop made no progress for {idle:.3f} s "
                                                         f"(a period and watchdog_s: {limit:g} s)")
