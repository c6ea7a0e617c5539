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


class _Histogram:
    """Fixed bins, 0.1 us wide up to 1 ms, then 10 us wide up to 100 ms (the last bin is open):
    recording is one index increment, percentiles are a cumulative sum over 20k bins, so a
    status request never holds the GIL long enough to delay the loop."""

    FINE, COARSE = 10_000, 9_900

    def __init__(self) -> None:
        self.counts = np.zeros(self.FINE + self.COARSE, dtype=np.int64)
        self.n = 0
        self.max_us = 0.0
        edges = np.concatenate([np.arange(1, self.FINE + 1) * 0.1,
                                1000.0 + np.arange(1, self.COARSE + 1) * 10.0])
        edges[-1] = np.inf
        self.upper_edges = edges

    def add(self, us: float) -> None:
        if us < 1000.0:
            i = int(us * 10.0)
        else:
            i = self.FINE + int((us - 1000.0) * 0.1)
            if i >= self.FINE + self.COARSE:
                i = self.FINE + self.COARSE - 1
        self.counts[i] += 1
        self.n += 1
        if us > self.max_us:
            self.max_us = us

    def percentile(self, q: float) -> float | None:
        """Upper edge of the bin holding the q-th percentile (a bound, never an underestimate)."""
        cum = np.cumsum(self.counts)
        n = int(cum[-1])          # not self.n: the loop may add a tick while a status request reads
        if n == 0:
            return None
        i = min(int(np.searchsorted(cum, q / 100.0 * n)), cum.size - 1)
        return float(min(self.upper_edges[i], self.max_us))


class TickStats:
    """Period jitter and compute time per tick as histograms over the whole run; O(1) per tick.

    Jitter is |interval between tick starts - k periods|, k = 1 except after an overrun that
    skipped deadlines (those are counted as overruns, not as jitter of k periods).
    """

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.jitter = _Histogram()
        self.compute = _Histogram()
        self.count = 0
        self.overruns = 0
        self.missed = 0
        self.first_start = math.nan
        self.last_start = math.nan

    def record(self, start: float, compute_s: float) -> None:
        if self.count == 0:
            self.first_start = start
        else:
            interval = start - self.last_start
            k = interval / self.period_s
            k = 1.0 if k < 1.5 else float(round(k))
            self.jitter.add(abs(interval - k * self.period_s) * 1e6)
        self.compute.add(compute_s * 1e6)
        self.last_start = start
        self.count += 1

    def summary(self) -> dict[str, float | int | None]:
        """Achieved rate, period jitter p50/p99/max, compute time p50/p99/max (us)."""
        rate = None
        if self.count > 1 and self.last_start > self.first_start:
            rate = (self.count - 1) / (self.last_start - self.first_start)
        j, c = self.jitter, self.compute
        return {
            "ticks": self.count, "overruns": self.overruns, "missed_deadlines": self.missed,
            "achieved_rate_hz": rate,
            "jitter_p50_us": j.percentile(50), "jitter_p99_us": j.percentile(99),
            "jitter_max_us": j.max_us if j.n else None,
            "compute_p50_us": c.percentile(50), "compute_p99_us": c.percentile(99),
            "compute_max_us": c.max_us if c.n else None,
        }


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
