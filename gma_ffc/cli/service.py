"""`gma-ffc start` / `stop` / `status`: the controller as a background service."""

from __future__ import annotations

import argparse
import json
import sys

from .run import add_runtime_dir, positive_seconds


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("start", help="start the controller as a background service",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Start 'gma-ffc run' in the background (own session, pid file "
                                   "and log in the runtime directory) and return once it reports "
                                   "ready, or fail with its reason.",
                       epilog="examples:\n"
                              "  gma-ffc start --config config/sim.yaml      # the simulated rig, as shipped\n"
                              "  gma-ffc start --config rig.yaml --duration 600\n"
                              "  gma-ffc status; gma-ffc stop")
    p.add_argument("--config", required=True, metavar="CFG.yaml", help="controller configuration")
    p.add_argument("--duration", type=positive_seconds, metavar="S",
                   help="stop after S seconds (default: run until 'gma-ffc stop')")
    p.add_argument("--timeout", type=positive_seconds, default=60.0, metavar="S",
                   help="how long to wait for the controller to be ready (default 60)")
    add_runtime_dir(p)
    p.set_defaults(func=_start)

    p = sub.add_parser("stop", help="stop the background controller",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Ask the controller to stop over its socket (it puts the "
                                   "amplifier at its safe current first), wait, and escalate to "
                                   "SIGTERM if it does not stop.",
                       epilog="example:\n  gma-ffc stop            # prints how it stopped and any active faults")
    p.add_argument("--timeout", type=positive_seconds, default=10.0, metavar="S",
                   help="how long to wait before SIGTERM (default 10)")
    add_runtime_dir(p)
    p.set_defaults(func=_stop)

    p = sub.add_parser("status", help="show the running controller's status",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="State, achieved rate, period jitter p50/p99/max, overruns, "
                                   "last stress, current and reference, active faults, learning "
                                   "feedforward, and whether the model is used outside its range.",
                       epilog="examples:\n"
                              "  gma-ffc status\n"
                              "  gma-ffc status --json | jq .state     # JSON always, also when nothing runs")
    p.add_argument("--json", action="store_true", help="machine-readable JSON")
    add_runtime_dir(p)
    p.set_defaults(func=_status)


def _start(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..service.daemon import start
    from ..service.paths import runtime_paths

    runtime = runtime_paths(args.runtime_dir)
    started = start(Path(args.config), runtime, duration_s=args.duration, timeout_s=args.timeout)
    print(f"started: pid {started.pid}, socket {runtime.socket}, log {runtime.log_file}")
    if started.status:
        print(started.status)
    return 0


def _stop(args: argparse.Namespace) -> int:
    from ..service.daemon import stop
    from ..service.paths import runtime_paths
    from ..service.status import faults_of

    result = stop(runtime_paths(args.runtime_dir), timeout_s=args.timeout)
    faults = faults_of(result.final_status or {})
    print(f"{result.how} (pid {result.pid or '?'})"
          + (f"; active faults were: {', '.join(faults)}" if faults else ""))
    return 0


def _status(args: argparse.Namespace) -> int:
    from ..service.control_socket import ask, jsonable
    from ..service.paths import runtime_paths
    from ..service.status import format_table

    from ..errors import NotRunningError

    runtime = runtime_paths(args.runtime_dir)
    try:
        status = ask(runtime.socket, {"cmd": "status"})["status"]
    except NotRunningError as exc:
        if not args.json:
            raise
        # machine readers always get JSON: say that nothing runs there, and exit as before (1)
        json.dump({"state": "not running", "socket": str(runtime.socket), "message": str(exc)}, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 1
    if args.json:
        json.dump(status, sys.stdout, indent=2, default=jsonable)
        sys.stdout.write("\n")
    else:
        print(format_table(status))
    return 0
