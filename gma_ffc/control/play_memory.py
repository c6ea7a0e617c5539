"""The base model's play state along the drive, from the run's start: what a background diagnosis
needs to score its window from the first sample (docs/monitor.md).

A recording starts in a hysteresis state its file does not show; `gma-ffc diagnose` only scores
the samples where that unknown state no longer matters, and a tracking run that never sweeps the
model's whole range (the shipped config/sim.yaml's sine keeps 0.36-1.8 A of 0-3 A) never gets
there. The controller knows better: it starts at rest at the safe current, in the state its
inverse starts in, and a play's output follows the drive alone (eq. (2): a clamp to within r of
each input, whatever the stress). So the telemetry writer's thread steps the plays of the model
diagnose runs on (an extended model's base) with each block's drives (the drive column the
window records, which diagnose simulates on: `model_watch.ModelWatch._drive`), and keeps an
anchor (a block's first time, the plays before it) every ANCHOR_EVERY_S. The state at any
retained row is then the nearest anchor before it, stepped over the retained rows in between
(`state_at`, off the loop in the service's thread). Nothing here runs on the loop thread.
"""

from __future__ import annotations

import collections
import math
from typing import Any

import numpy as np

from .. import operators as ops

# An anchor every 5 s of loop time: recovering a state steps at most 5 s of rows (1,250 at 250 Hz,
# 5,000 at 1 kHz: a millisecond of compiled play steps), and the anchors of the whole retained
# history (window_s + 180 s) are a few hundred small arrays.
ANCHOR_EVERY_S = 5.0


class PlayMemory:
    """The plays of `core` stepped with every finite drive; anchors to recover past states."""

    __slots__ = ("core", "r", "offset", "plays", "anchors", "last_anchor_t")

    def __init__(self, core: Any, drive: float, play_state: Any, keep_s: float) -> None:
        self.core = core
        self.r = np.ascontiguousarray(core.play_thresholds, dtype=float)
        self.offset = float(core.input_offset)
        self.plays = start_plays(core, drive, play_state)
        self.anchors: collections.deque[tuple[float, np.ndarray]] = \
            collections.deque(maxlen=int(keep_s / ANCHOR_EVERY_S) + 4)
        self.last_anchor_t = -math.inf

    @classmethod
    def of(cls, model: Any, drive: float, play_state: Any, keep_s: float) -> "PlayMemory | None":
        """For the model diagnose runs on (an extended model's base); None for a core without plays.
        `play_state` (the law's inverse's, when `model` is that core itself) is the start."""
        core = getattr(model, "base", model)
        if not hasattr(core, "play_thresholds") or not hasattr(core, "input_offset"):
            return None
        return cls(core, drive, play_state if core is model else None, keep_s)

    def follows(self, model: Any) -> bool:
        """Whether this memory is still the state of `model`'s core (a reload to a model with the
        same plays keeps it: an extended model from a diagnosis of this one)."""
        core = getattr(model, "base", model)
        r = getattr(core, "play_thresholds", None)
        return (r is not None and np.array_equal(np.asarray(r, dtype=float), self.r)
                and float(getattr(core, "input_offset", math.nan)) == self.offset)

    def advance(self, t: np.ndarray, drive: np.ndarray) -> None:
        """One block of rows (the telemetry writer's thread): an anchor when one is due, then the
        plays stepped with the block's finite drives."""
        ok = np.isfinite(drive) & np.isfinite(t)
        if not ok.any():
            return
        t0 = float(t[ok][0])
        if t0 - self.last_anchor_t >= ANCHOR_EVERY_S:
            self.anchors.append((t0, self.plays.copy()))
            self.last_anchor_t = t0
        self.plays = step_plays(self.r, self.offset, self.plays, drive[ok])

    def state_at(self, t: np.ndarray, drive: np.ndarray, t_first: float) -> np.ndarray | None:
        """The play outputs after the row at time `t_first`, from retained rows (`t`, `drive`,
        oldest first): the last anchor at or before it whose rows are all retained, stepped over
        them. None when no anchor is (the history retained no longer reaches back to one)."""
        ok = np.isfinite(t) & np.isfinite(drive)
        if not ok.any():
            return None
        oldest = float(t[ok][0])
        usable = [(ta, p) for ta, p in list(self.anchors) if oldest <= ta <= t_first]
        if not usable:
            return None
        ta, plays = usable[-1]
        between = ok & (t >= ta) & (t <= t_first)
        return step_plays(self.r, self.offset, plays, drive[between])


def start_plays(core: Any, drive: float, play_state: Any) -> np.ndarray:
    """The plays at rest at `drive`: `play_state` when given (the law's inverse's), else the start
    the law gives a core (`law.start_stepper`: consistent with a rise towards the middle of the range)."""
    if play_state is not None:
        return np.array(play_state, dtype=float)
    lo, hi = (float(v) for v in core.drive_range)
    target = 0.5 * (lo + hi) if math.isfinite(lo) and math.isfinite(hi) and 0.5 * (lo + hi) != drive else drive + 1.0
    return np.array(core.resolve_initial_state(np.array([drive, target])).play_state, dtype=float)


def step_plays(r: np.ndarray, offset: float, plays: np.ndarray, drive: np.ndarray) -> np.ndarray:
    """The play outputs after the drives `drive` from `plays` (eq. (2) sample by sample)."""
    if drive.size == 0:
        return plays.copy()
    v = np.ascontiguousarray(drive, dtype=float) - offset
    out = np.empty((v.size, r.size))
    ops.play_outputs(v, r, np.ascontiguousarray(plays), out)
    return out[-1].copy()
