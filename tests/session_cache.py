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


def memoised_score_round(folder: Path) -> Callable[..., Any]:
    """`selection.score_round`, its results computed once per session in `folder` and shared by
    every caller with the same inputs. A round's search is a pure function of the fitter's data and
    loss, the effects already in the model, the loss without them and the effects tried (the
    thresholds decide on its results; `huber_k` alone changes its inputs, through the loss's scale
    `fitter.delta`): test_diagnose_thresholds' moves that take the default path, and the `diagnosed`
    fixture's diagnoses with the default thresholds of the same cases, search each round once."""
    from gma_ffc.diagnose import scoring

    def score_round(fitter, base, loss_without, names, rnd, workers):
        key = (fitter.delta, fitter.y_rows.size, float(fitter.y_rows.sum()), loss_without, repr(base), tuple(names), rnd)
        return once_per_session(folder / "rounds", repr(key),
                                lambda: scoring.score_round(fitter, base, loss_without, names, rnd, workers))
    return score_round


def memoised_reidentify(folder: Path) -> Callable[..., Any]:
    """`selection.reidentify_through`, its cores computed once per session in `folder`. The core
    identified again through a named delay or lag is a pure function of the base model, the input-side
    effects with their fitted parameters, and the base's loops: the moves of test_diagnose_thresholds
    that end on the same effects identify the same core (5-6 s each for the delay case, most of what
    such a move cost once its rounds were memoised)."""
    from gma_ffc.diagnose import rebase

    def reidentify_through(model, inputs, loops):
        digest = hashlib.sha256(repr((model.to_dict(), [e.to_blocks() for e in inputs])).encode())
        for d in loops:
            digest.update(d.name.encode() + repr(d.dt_med).encode())
            for a in (d.t, d.u, d.y, d.s, d.dt):
                digest.update(a.tobytes())
        return once_per_session(folder / "cores", digest.hexdigest(),
                                lambda: rebase.reidentify_through(model, inputs, loops))
    return reidentify_through
