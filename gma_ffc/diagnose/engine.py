"""`diagnose(model, recordings)`: the whole diagnosis in one call, as the CLI and the report use it.

A thin wrapper of `selection.EffectSelector` with its default thresholds; see `selection` for the
selection rule and `results` for what comes back.
"""

from __future__ import annotations

from typing import Any, Callable, Mapping, Sequence

from ..recordings import Recording
from .results import OUTCOMES, Candidate, Diagnosis
from .selection import EffectSelector

__all__ = ["OUTCOMES", "Candidate", "Diagnosis", "EffectSelector", "diagnose"]


def diagnose(model: Any, recordings: Sequence[Recording], max_effects: int = 3,
             progress: Callable[[str], None] | None = None, initial_state: Any = "estimate",
             identification: Sequence[Recording] = (),
             fingerprints: Sequence[Mapping[str, Any]] | None = None,
             drive_limits: tuple[float, float] | None = None) -> Diagnosis:
    """Run the whole diagnosis (no I/O) with the default thresholds. `identification`: the
    recordings the model was identified on (checked against its record: by their files'
    `fingerprints` when given, else by name). `drive_limits`: the drive the rig's controller
    allows, which no advice on what to record goes beyond."""
    selector = EffectSelector(max_effects=max_effects, initial_state=initial_state, drive_limits=drive_limits)
    return selector.fit(model, recordings, progress, identification=identification,
                        fingerprints=fingerprints).diagnosis_
