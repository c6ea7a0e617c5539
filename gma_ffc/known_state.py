"""The play-state file: a known hysteresis state at a recording's first sample (``--initial-state
plays:FILE``), written beside the recording and read back into an `InitialStateSpec`.

The service's background diagnosis writes one beside each window.csv: the model-fit monitor has
followed the base model's plays along the drive since the run started at rest at the safe
current (`control/play_memory.py`), so the state at the window's first sample is known, not
guessed, and diagnose scores the window from its first sample. A small JSON object::

    {"format": "gma-ffc play state", "version": 1,
     "plays": [...],            # the base model's play outputs at the first sample (drive - input_offset)
     "time_s": 112.4, "drive": 0.81, "stress_MPa": -15.2,     # that sample, for a reader's check
     "how": "followed along the commanded drive since the run started"}

Only `plays` is read; the rest says where the numbers come from. This module does the file's
I/O and nothing else: `gma_ffc.initial_state` uses the numbers.
"""

from __future__ import annotations

import json
import math
import os
from typing import Any, Sequence

from .initial_state import InitialStateSpec

FORMAT = "gma-ffc play state"
VERSION = 1
MAX_BYTES = 1 << 20     # a state is a few hundred bytes; a bigger file is not one (and is not read whole)


def write_play_state(path: str | os.PathLike, plays: Sequence[float], *, time_s: float, drive: float,
                     stress_MPa: float, how: str) -> None:
    """Write the file (atomically: a diagnosis never reads half of one)."""
    from .atomic import atomic_write

    doc = {"format": FORMAT, "version": VERSION, "plays": [float(v) for v in plays], "time_s": float(time_s),
           "drive": float(drive), "stress_MPa": _number_or_none(stress_MPa), "how": how}
    with atomic_write(path) as f:
        f.write(json.dumps(doc, indent=1) + "\n")


def read_play_state(path: str | os.PathLike) -> InitialStateSpec:
    """The `plays` spec the file holds; ValueError (one line, naming the file) for a missing or
    unreadable file, one that is not a play state, or plays that are not all finite numbers.
    The count is checked against the model where the model is known (`initial_state.given_state`)."""
    where = f"plays:{os.fspath(path)}"
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_BYTES + 1)
    except OSError as exc:
        raise ValueError(f"{where}: cannot read it ({exc.strerror or exc})") from None
    if len(raw) > MAX_BYTES:
        raise ValueError(f"{where}: over {MAX_BYTES} bytes, not a play-state file")
    try:
        doc = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"{where}: not JSON ({exc})") from None
    plays = doc.get("plays") if isinstance(doc, dict) else None
    if not isinstance(plays, list) or not plays:
        raise ValueError(f"{where}: no \"plays\" list (a play-state file is a JSON object with the play "
                         "outputs at the first sample; see docs/cli.md)")
    if not all(_is_finite_number(v) for v in plays):
        raise ValueError(f"{where}: the plays must all be finite numbers")
    return InitialStateSpec("plays", plays=tuple(float(v) for v in plays), source=os.fspath(path))


def _is_finite_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _number_or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None
