"""The last run's exit record: how the controller ended, for `status` once nothing answers.

A controller that ends on a fault is gone before anyone asks `gma-ffc status`; the reason was
only in the log. The service writes `last-exit.json` in its runtime directory, atomically: a
`running` record when it starts (so a run killed with -9 is told apart from a clean end), and
on every way out the record of how it ended (pid, when, how, the faults and their messages,
whether the safe current was written). `status` with no controller answering reads it.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import time
from pathlib import Path
from typing import Any, Mapping

from .. import safe_files
from .paths import RuntimePaths
from .status import since_start_clause

NAME = "last-exit.json"
KIND = safe_files.Kind("last-exit record", "--runtime-dir", lambda head: head.lstrip().startswith(b"{"))


def path_of(runtime: RuntimePaths) -> Path:
    return runtime.directory / NAME


def write(runtime: RuntimePaths, record: Mapping[str, Any]) -> None:
    """Replace the record, whole or not at all (never through a link, never over a file not ours)."""
    with safe_files.replace(path_of(runtime), (runtime.directory,), KIND) as fh:
        json.dump(dict(record), fh, indent=2, default=str)
        fh.write("\n")


def started(config: str) -> dict[str, Any]:
    """The record while a run is on: only a run that never reached its exit leaves it."""
    return {"how": "running", "pid": os.getpid(), "config": config, "started_unix": time.time()}


def ended(config: str, started_unix: float, final: Mapping[str, Any], how: str, reason: str | None) -> dict[str, Any]:
    """The record of a run's end from its final status: `how` is 'stopped', 'fault' or 'crashed'."""
    return {"how": how, "pid": os.getpid(), "config": config, "started_unix": started_unix,
            "ended_unix": time.time(), "state": final.get("state"), "reason": reason,
            "exit_reason": final.get("exit_reason") or None, "faults": dict(final.get("fault_messages") or {}),
            "fault_counts": dict(final.get("fault_counts") or {}),      # recovered ones too (a reconnect)
            "safe_current_written": final.get("at_safe_current"), "safe_current_A": final.get("safe_current_A"),
            "learned": (final.get("learning") or {}).get("saved")}


def read(runtime: RuntimePaths) -> dict[str, Any] | None:
    """The record, or None when there is none (or it cannot be read)."""
    try:
        record = json.loads(path_of(runtime).read_text())
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def describe(record: Mapping[str, Any]) -> str:
    """One line: how the last run ended, for `status` with nothing running."""
    pid = record.get("pid", "?")
    if record.get("how") == "running":
        return (f"the last run (pid {pid}, started {_stamp(record.get('started_unix'))}) left no exit "
                "record: it was killed or the machine stopped; check the amplifier and the log")
    when = f"the last run (pid {pid}) ended at {_stamp(record.get('ended_unix'))}"
    faults = "; ".join(f"{k}: {v}" for k, v in (record.get("faults") or {}).items())
    if record.get("how") == "stopped":
        text = f"{when}: stopped ({record.get('reason') or record.get('exit_reason') or 'as asked'})"
        text += f"; faults still active: {faults}" if faults else ""
        text += since_start_clause(record.get("fault_counts"))
    else:
        what = "on a fault" if record.get("how") == "fault" else "in a crash"
        text = f"{when} {what}: {faults or record.get('exit_reason') or record.get('reason') or '?'}"
    return text + "; " + safe_words(record)


def safe_words(record: Mapping[str, Any]) -> str:
    written, amps = record.get("safe_current_written"), record.get("safe_current_A")
    at = f" ({amps:g} A)" if isinstance(amps, (int, float)) else ""
    if written is None:
        return "whether the safe current was written is unknown"
    return f"safe current{at} written" if written else f"the safe current{at} was NOT confirmed written: check the amplifier"


def learned_words(record: Mapping[str, Any]) -> str:
    """Where the run's learned correction went ('' when the run did not learn)."""
    saved = record.get("learned")
    if not isinstance(saved, Mapping):
        return ""
    if saved.get("saved"):
        return f"learned correction saved to {saved.get('file')}"
    where = f" to {saved['file']}" if saved.get("file") else ""
    return f"learned correction NOT saved{where}: {saved.get('why') or 'unknown why'}"


def _stamp(unix: Any) -> str:
    if not isinstance(unix, (int, float)):
        return "?"
    return _dt.datetime.fromtimestamp(unix).astimezone().strftime("%Y-%m-%d %H:%M:%S %Z")
