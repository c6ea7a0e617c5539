"""Bytes a hot-path call allocates, for the tests that hold steppers and the control law to
allocating nothing."""

from __future__ import annotations

import tracemalloc
from typing import Callable

WARM = 20       # calls traced but not measured: state floats allocated before tracing are replaced by traced ones
PASSES = 3


def worst_call_allocation(call: Callable[[int], object], n: int) -> tuple[int, int]:
    """(retained, transient peak) bytes of the worst of n single calls `call(k)`, k counting up
    across everything: the best of three passes. tracemalloc counts every thread of the process,
    so a thread another test left behind can allocate during one pass; a call that allocates
    does so in every pass."""
    k = 0
    passes = []
    for _ in range(PASSES):
        tracemalloc.start()
        try:
            for _ in range(WARM):
                call(k)
                k += 1
            worst = peak = 0
            for _ in range(n):
                before = tracemalloc.get_traced_memory()[0]
                tracemalloc.reset_peak()
                call(k)
                now, top = tracemalloc.get_traced_memory()
                k += 1
                worst = max(worst, now - before)
                peak = max(peak, top - before)
        finally:
            tracemalloc.stop()
        passes.append((worst, peak))
    return min(w for w, _ in passes), min(p for _, p in passes)
