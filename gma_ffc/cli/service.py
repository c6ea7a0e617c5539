"""`gma-ffc start` / `stop` / `status` / `reload`: the controller as a background service."""

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

    p = sub.add_parser("reload", help="re-read the running controller's config and model",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Ask the running controller to re-read its config file (as SIGHUP does), "
                                   "or to run another model with it (--model). The new model and config get "
                                   "every check a start does; a refused one leaves the running one in place. "
                                   "The switch is bumpless: the new inverse starts at the current command.",
                       epilog="examples:\n"
                              "  gma-ffc reload                       # after editing the config file\n"
                              "  gma-ffc reload --model /var/lib/gma-ffc/diagnoses/20260301-101500/extended_model.yaml\n"
                              "                                       # adopt what a background diagnosis found")
    p.add_argument("--model", metavar="MODEL.yaml",
                   help="run this model instead of the config's (kept by later reloads until the config's "
                        "model key changes; a restart runs the config's model)")
    add_runtime_dir(p)
    p.set_defaults(func=_reload)


def _start(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..service.daemon import StartInterrupted, start
    from ..service.paths import runtime_paths

    runtime = runtime_paths(args.runtime_dir)
    try:
        started = start(Path(args.config), runtime, duration_s=args.duration, timeout_s=args.timeout)
    except StartInterrupted:        # start() has stopped the controller it was starting
        print("gma-ffc start: interrupted; the controller it was starting was stopped (SIGTERM)", file=sys.stderr)
        return 130
    print(f"started: pid {started.pid}, socket {runtime.socket}, log {runtime.log_file}")
    if started.status:
        print(started.status)
    return 0


def _stop(args: argparse.Namespace) -> int:
    from ..errors import NotRunningError
    from ..service import last_exit
    from ..service.daemon import stop
    from ..service.paths import runtime_paths
    from ..service.status import faults_of, since_start_clause

    runtime = runtime_paths(args.runtime_dir)
    try:
        result = stop(runtime, timeout_s=args.timeout)
    except NotRunningError as exc:
        raise _nothing_runs(runtime, exc) from None
    record = last_exit.read(runtime)
    final = result.final_status or {}
    if record and record.get("pid") == result.pid and record.get("how") != "running":
        # how the run itself ended: the faults still active at its end, and the safe current
        faults = list(record.get("faults") or {})
        learned = last_exit.learned_words(record)
        tail = f"; {last_exit.safe_words(record)}" + (f"; {learned}" if learned else "")
        counted = since_start_clause(record.get("fault_counts") or final.get("fault_counts"))
    else:                                       # no record of this run: the status just before the stop
        faults, tail, counted = faults_of(final), "", since_start_clause(final.get("fault_counts"))
    print(f"{result.how} (pid {result.pid or '?'})"
          + (f"; faults active at the end: {', '.join(faults)}" if faults else "")
          + counted + tail)
    return 0


def _status(args: argparse.Namespace) -> int:
    from ..errors import NotRunningError
    from ..service.control_socket import ask, jsonable
    from ..service.paths import runtime_paths
    from ..service.status import SNAPSHOT_STALE_S, format_table, snapshot_age_s

    runtime = runtime_paths(args.runtime_dir)
    try:
        status = ask(runtime.socket, {"cmd": "status"})["status"]
    except NotRunningError as exc:
        return _not_running(args, runtime, exc)
    age = snapshot_age_s(status)
    if age is not None and isinstance(status.get("service"), dict):    # docs/service.md: a snapshot too old
        status["service"].update(snapshot_age_s=round(age, 3), responding=age <= SNAPSHOT_STALE_S)
    if args.json:
        json.dump(status, sys.stdout, indent=2, default=jsonable)
        sys.stdout.write("\n")
    else:
        print(format_table(status))
    return 0


def _nothing_runs(runtime, exc: Exception) -> Exception:
    """What `status`, `stop` and `reload` say when nothing answers: that, how the last run ended when it
    left a record (a run killed before its end needs a look at the amplifier), and where the system
    service's controller answers when its folder is another user's (exit 1 as before)."""
    from ..errors import NotRunningError
    from ..service import last_exit
    from ..service.paths import system_service_hint

    record = last_exit.read(runtime)
    said = f"{exc}; {last_exit.describe(record)}" if record else str(exc)
    return NotRunningError(said + system_service_hint(runtime))


def _not_running(args: argparse.Namespace, runtime, exc: Exception) -> int:
    """Nothing answers: say so (`_nothing_runs`); JSON always for `--json` (exit 1 as before)."""
    from ..service import last_exit

    if not args.json:
        raise _nothing_runs(runtime, exc)
    record = last_exit.read(runtime)
    # machine readers always get JSON: say that nothing runs there, and exit as before (1)
    doc: dict[str, object] = {"state": "not running", "socket": str(runtime.socket), "message": str(exc)}
    if record:
        doc.update(last_exit=record, last_exit_text=last_exit.describe(record))
    json.dump(doc, sys.stdout, indent=2)
    sys.stdout.write("\n")
    return 1


def _reload(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..errors import InputError, NotRunningError
    from ..service.control_socket import request
    from ..service.paths import runtime_paths

    message: dict[str, str] = {"cmd": "reload"}
    if args.model is not None:
        model = Path(args.model).expanduser().resolve()      # the service's working directory is not ours
        if model.is_dir():     # a background diagnosis' folder, as status names its report's
            inside = model / "extended_model.yaml"
            raise InputError(f"--model {args.model} is a folder, not a model file: give "
                             + (f"{inside}" if inside.is_file() else "the model file in it"))
        if not model.is_file():
            raise InputError(f"--model {args.model}: no such file")
        message["model"] = str(model)
    runtime = runtime_paths(args.runtime_dir)
    try:
        reply = request(runtime.socket, message, timeout_s=60.0)
    except NotRunningError as exc:      # as status says it: a controller that ended on a fault is named
        raise _nothing_runs(runtime, exc) from None
    if not reply.get("ok"):
        raise InputError(str(reply.get("error") or reply.get("message") or "the controller refused the reload"))
    print(reply.get("message", "reloaded"))
    return 0
