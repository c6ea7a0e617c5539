"""The background diagnosis's process: `gma-ffc diagnose`, bound to the service that started it.

    python -m gma_ffc.service.diagnose_child PARENT_PID -- diagnose --model M REC --out DIR

Before anything else it asks the kernel for SIGKILL when its parent goes (PR_SET_PDEATHSIG), and
checks that the parent is still the service (it may have died before the request was made); then
it drops to SCHED_OTHER at nice 19, so it only ever takes CPU the control loop leaves, and execs
`python -m gma_ffc.cli ...` (all three survive the exec). Doing this in the child itself keeps
`subprocess`'s thread-unsafe `preexec_fn` out of a threaded service.

The kernel sends the signal when the *thread* that forked the child exits: the service starts it
from its main thread, which lives as long as the service does.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
from typing import Sequence

from ..control.realtime import LOOP_CPU_ENV

PR_SET_PDEATHSIG = 1      # <linux/prctl.h>
NICENESS = 19             # the lowest priority there is: the loop and the lab's own work come first


def bind_to_parent(parent_pid: int) -> None:
    """SIGKILL when the parent goes; exit at once if it already has."""
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
    if os.getppid() != parent_pid:
        os._exit(3)           # orphaned before the request took effect: never outlive the service


def lower_priority() -> None:
    """SCHED_OTHER (a real-time policy is never inherited into a diagnosis) at nice 19, and off
    the CPU the control loop is pinned to (named by the service: control/realtime.py), when
    another is allowed."""
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    os.setpriority(os.PRIO_PROCESS, 0, NICENESS)
    loop = os.environ.get(LOOP_CPU_ENV, "")
    others = os.sched_getaffinity(0) - {int(loop)} if loop.isdigit() else set()
    if others:
        os.sched_setaffinity(0, others)


def main(argv: Sequence[str]) -> int:
    if len(argv) < 3 or argv[1] != "--":
        print("usage: python -m gma_ffc.service.diagnose_child PARENT_PID -- diagnose ...", file=sys.stderr)
        return 2
    bind_to_parent(int(argv[0]))
    lower_priority()
    os.execv(sys.executable, [sys.executable, "-m", "gma_ffc.cli", *argv[2:]])
    return 1      # not reached: execv replaces this process


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
