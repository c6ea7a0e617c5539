"""Results several tests read, computed once per test session and shared by the xdist workers.

A diagnosis of a benchmark case takes 10-60 s, and several tests ask the same one different
questions (its verdict, its report's figures, its JSON). The first worker to ask computes it
under a file lock and pickles it into the session's shared folder. A worker asking meanwhile
waits for the lock and reads the file. Every caller gets its own unpickled copy, so no test
sees another's changes.
"""

from __future__ import annotations

import fcntl
import hashlib
import pickle
from pathlib import Path
from typing import Any, Callable


def once_per_session(folder: Path, key: str, compute: Callable[[], Any]) -> Any:
    """`compute()`'s value for `key`, computed by the first caller of this session only."""
    folder.mkdir(parents=True, exist_ok=True)
    name = hashlib.sha256(key.encode()).hexdigest()[:32]
    path = folder / f"{name}.pickle"
    with open(folder / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)                 # released when the file closes
        if not path.exists():
            part = path.with_suffix(".part")
            part.write_bytes(pickle.dumps(compute(), protocol=pickle.HIGHEST_PROTOCOL))
            part.replace(path)                           # a reader never sees half a file
        return pickle.loads(path.read_bytes())
