"""The loop thread's real-time setting, for a run on the real clock, restored afterwards.

A short GIL switch interval (the loop gets the GIL back quickly from the telemetry and service
threads), the garbage collector frozen (no long collections of start-up objects), and SCHED_FIFO
for the loop thread when `scheduler.realtime_priority` asks for it. With SCHED_FIFO the loop
thread is also pinned to one CPU (`scheduler.loop_cpu`), named in the environment a background
diagnosis inherits (`LOOP_CPU_ENV`), which keeps the diagnosis off it, so a CPU-bound child
never shares the loop's core and its caches. On the 2-vCPU VM it was measured on, the "on"
variant of scripts/bench_monitor.py stayed within that bench's noise either way.
"""

from __future__ import annotations

import contextlib
import gc
import os
import sys
import threading
from typing import Any, Callable, Iterator

LOOP_CPU_ENV = "GMA_FFC_LOOP_CPU"


def loop_cpu(setting: int | None) -> int | None:
    """The CPU to pin the loop to: `setting`, or (None) the last allowed one when two or more are."""
    allowed = sorted(os.sched_getaffinity(0))
    if setting is None:
        return allowed[-1] if len(allowed) >= 2 else None
    return setting if setting in allowed else None


@contextlib.contextmanager
def _pinned(cpu: int | None) -> Iterator[None]:
    """The calling thread on `cpu` (and the environment naming it), restored afterwards."""
    if cpu is None:
        yield
        return
    tid = threading.get_native_id()
    old = os.sched_getaffinity(tid)
    try:
        os.sched_setaffinity(tid, {cpu})
    except OSError:
        yield
        return
    os.environ[LOOP_CPU_ENV] = str(cpu)
    try:
        yield
    finally:
        os.environ.pop(LOOP_CPU_ENV, None)
        with contextlib.suppress(OSError):
            os.sched_setaffinity(tid, old)


@contextlib.contextmanager
def realtime(scheduler: dict[str, Any], refused: Callable[[str], None]) -> Iterator[None]:
    """Inside: the real-time setting. `refused(message)` hears when SCHED_FIFO is not permitted
    (the run goes on with normal scheduling)."""
    old_interval = sys.getswitchinterval()
    sys.setswitchinterval(min(old_interval, scheduler["gil_switch_interval_us"] * 1e-6))
    gc.collect()
    gc.freeze()
    prio = scheduler["realtime_priority"]
    old_policy = None
    if prio > 0:
        try:
            old_policy = (os.sched_getscheduler(0), os.sched_getparam(0))
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
        except (OSError, AttributeError) as exc:
            old_policy = None
            refused(f"SCHED_FIFO {prio} not permitted ({exc}); running with normal scheduling")
    cpu = loop_cpu(scheduler.get("loop_cpu")) if old_policy is not None and scheduler.get("loop_cpu") != -1 else None
    try:
        with _pinned(cpu):
            yield
    finally:
        if old_policy is not None:
            with contextlib.suppress(OSError):
                os.sched_setscheduler(0, old_policy[0], old_policy[1])
        gc.unfreeze()
        sys.setswitchinterval(old_interval)
