"""Clocks and the absolute-deadline scheduler, with allocation-free timing statistics.

The clock is injectable: `MonotonicClock` sleeps (coarse sleep, then a short spin for the last
few hundred microseconds, which keeps jitter under 100 us on an idle Linux box) and
`SimulatedClock` never sleeps, so the same loop code runs in the service and in fast tests.
Deadlines are absolute (``next += period``), so the loop never drifts; a tick that starts after
its successor's deadline is an overrun, and the deadlines it missed are skipped whole, keeping
the phase.
"""

from __future__ import annotations

import math
import time
from typing import Protocol

import numpy as np


class Clock(Protocol):
    simulated: bool

    def now(self) -> float: ...

    def sleep_until(self, deadline: float) -> None: ...


class MonotonicClock:
    """The real monotonic clock; sleeps, then spins the last `spin_s` for precision."""

    simulated = False

    def __init__(self, spin_s: float = 300e-6) -> None:
        self.spin_s = spin_s
        self._now = time.perf_counter

    def now(self) -> float:
        return self._now()

    def sleep_until(self, deadline: float) -> None:
        now = self._now
        remaining = deadline - now()
        if remaining > self.spin_s:
            time.sleep(remaining - self.spin_s)
        while now() < deadline:
            pass


class SimulatedClock:
    """Time advances only when the loop sleeps (or `advance` is called): no real waiting."""

    simulated = True

    def __init__(self, start: float = 0.0) -> None:
        self.t = start

    def now(self) -> float:
        return self.t

    def sleep_until(self, deadline: float) -> None:
        if deadline > self.t:
            self.t = deadline

    def advance(self, dt: float) -> None:
        self.t += dt


class TickStats:
    """Per-tick start times and compute times in preallocated rings; percentiles on demand."""

    def __init__(self, period_s: float, window_s: float) -> None:
        self.period_s = period_s
        n = max(16, int(window_s / period_s))
        self._start = np.zeros(n)
        self._compute = np.zeros(n)
        self._n = n
        self.count = 0
        self.overruns = 0
        self.missed = 0
        self.first_start = math.nan
        self.last_start = math.nan

    def record(self, start: float, compute_s: float) -> None:
        i = self.count % self._n
        self._start[i] = start
        self._compute[i] = compute_s
        if self.count == 0:
            self.first_start = start
        self.last_start = start
        self.count += 1

    def summary(self) -> dict[str, float | int | None]:
        """Achieved rate, period jitter |T_i - T| p50/p99/max, compute time p50/p99/max (us)."""
        n = min(self.count, self._n)
        out: dict[str, float | int | None] = {
            "ticks": self.count, "overruns": self.overruns, "missed_deadlines": self.missed,
            "achieved_rate_hz": None, "jitter_p50_us": None, "jitter_p99_us": None,
            "jitter_max_us": None, "compute_p50_us": None, "compute_p99_us": None, "compute_max_us": None,
        }
        if self.count > 1 and self.last_start > self.first_start:
            out["achieved_rate_hz"] = (self.count - 1) / (self.last_start - self.first_start)
        if n >= 1:
            comp = np.roll(self._compute, -(self.count % self._n))[-n:] if self.count > self._n \
                else self._compute[:n].copy()
            out["compute_p50_us"], out["compute_p99_us"] = (float(v) * 1e6 for v in np.percentile(comp, [50, 99]))
            out["compute_max_us"] = float(comp.max()) * 1e6
        if n >= 2:
            starts = np.roll(self._start, -(self.count % self._n))[-n:] if self.count > self._n \
                else self._start[:n].copy()
            periods = np.diff(starts)
            # A skipped deadline is counted as an overrun, not as jitter of k periods.
            k = np.maximum(1.0, np.round(periods / self.period_s))
            jitter = np.abs(periods - k * self.period_s)
            p50, p99 = np.percentile(jitter, [50, 99])
            out["jitter_p50_us"], out["jitter_p99_us"] = float(p50) * 1e6, float(p99) * 1e6
            out["jitter_max_us"] = float(jitter.max()) * 1e6
        return out


class Scheduler:
    """Absolute deadlines at a fixed period: ``wait()`` returns the tick's nominal deadline."""

    def __init__(self, clock: Clock, period_s: float) -> None:
        self.clock = clock
        self.period_s = period_s
        self.next_deadline = math.nan
        self.overruns = 0
        self.missed = 0

    def start(self) -> float:
        self.next_deadline = self.clock.now()
        return self.next_deadline

    def wait(self) -> float:
        """Sleep until the next deadline (skipping whole missed periods) and return it."""
        deadline = self.next_deadline
        now = self.clock.now()
        if now > deadline:
            # Overrun: the previous tick ended after this deadline. Run at once; deadlines
            # missed entirely are skipped whole so the phase is kept.
            self.overruns += 1
            late = int((now - deadline) / self.period_s)
            if late:
                self.missed += late
                deadline += late * self.period_s
        else:
            self.clock.sleep_until(deadline)
        self.next_deadline = deadline + self.period_s
        return deadline
