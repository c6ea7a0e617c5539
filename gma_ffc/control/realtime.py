"""The loop thread's real-time setting, for a run on the real clock, restored afterwards.

A short GIL switch interval (the loop gets the GIL back quickly from the telemetry and service
threads), the garbage collector frozen (no long collections of start-up objects), and SCHED_FIFO
for the loop thread when `scheduler.realtime_priority` asks for it.
"""

from __future__ import annotations

import contextlib
import gc
import os
import sys
from typing import Any, Callable, Iterator


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
    try:
        yield
    finally:
        if old_policy is not None:
            with contextlib.suppress(OSError):
                os.sched_setscheduler(0, old_policy[0], old_policy[1])
        gc.unfreeze()
        sys.setswitchinterval(old_interval)
