"""With SCHED_FIFO the loop thread has a CPU of its own, and a background diagnosis keeps off it
(issue 30: a CPU-bound child on the loop's core raised its compute per tick by about a fifth)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading

import pytest

from gma_ffc.control import realtime

ALLOWED = sorted(os.sched_getaffinity(0))


def test_the_default_is_the_last_allowed_cpu_when_there_are_two():
    assert realtime.loop_cpu(None) == (ALLOWED[-1] if len(ALLOWED) >= 2 else None)
    assert realtime.loop_cpu(ALLOWED[0]) == ALLOWED[0]
    assert realtime.loop_cpu(max(ALLOWED) + 1) is None          # a CPU the process may not use: no pinning


def test_the_loop_thread_is_pinned_and_named_then_restored():
    seen = {}

    def loop():
        tid = threading.get_native_id()
        with realtime._pinned(ALLOWED[0]):
            seen["inside"] = os.sched_getaffinity(tid)
            seen["env"] = os.environ.get(realtime.LOOP_CPU_ENV)
        seen["after"] = os.sched_getaffinity(tid)

    t = threading.Thread(target=loop)
    t.start()
    t.join()
    assert seen["inside"] == {ALLOWED[0]} and seen["env"] == str(ALLOWED[0])
    assert seen["after"] == set(ALLOWED) and realtime.LOOP_CPU_ENV not in os.environ
    assert os.sched_getaffinity(0) == set(ALLOWED)               # the other threads were never pinned


@pytest.mark.skipif(len(ALLOWED) < 2, reason="one CPU: there is no other for the diagnosis")
def test_a_background_diagnosis_keeps_off_the_loops_cpu():
    code = ("import os; from gma_ffc.service.diagnose_child import lower_priority; lower_priority(); "
            "print(sorted(os.sched_getaffinity(0)))")
    env = {**os.environ, realtime.LOOP_CPU_ENV: str(ALLOWED[-1])}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.strip() == str(ALLOWED[:-1])
