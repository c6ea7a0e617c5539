"""One recording: its columns keyed by unit-bearing names (docs/recordings.md), its metadata, and
the names every reader and writer agrees on. Pure data: no I/O."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..errors import RecordingError


DRIVE_COLUMNS = ("current_A", "voltage_V")
TIME = "time_s"
DISPLACEMENT = "displacement_um"
STRESS = "stress_MPa"
REFERENCE = "reference_um"

DEFAULT_TIME_STEP_S = 1e-3   # a time's resolution when none is known: a millisecond, finer than any window quoted


def time_text(t_s: float, step_s: float) -> str:
    """A recording's time as text, to `step_s` (a sample period, a window's hundredth): fixed point,
    so that a logger's absolute timestamps (1.7e9 s) keep the digits that tell two times apart,
    where a number of significant digits would print both as 1.7e+09."""
    if not math.isfinite(step_s) or step_s <= 0:
        step_s = DEFAULT_TIME_STEP_S
    # a step a hair under a power of ten is that power (a period of 0.01 s differenced from timestamps
    # near 1.7e9 s comes out 0.00999999): allow 0.1 % in the logarithm
    decimals = min(9, max(0, math.ceil(-math.log10(step_s) - 1e-3)))
    return f"{t_s:.{decimals}f}"


@dataclass
class Recording:
    """One experiment: columns of equal length keyed by their unit-bearing names, plus metadata."""

    columns: dict[str, np.ndarray]
    metadata: dict[str, Any] = field(default_factory=dict)
    source: str = "<memory>"
    notes: list[str] = field(default_factory=list)      # what reading it left out, said to the user
    header_line: int = 0            # the header's line in the file (0: no lines, .mat/.tdms/.h5); `validate` sets it
    file_rows: Any = None           # each row's data row in the file, when some were left out (telemetry); else None

    def __post_init__(self) -> None:
        self.columns = {k: np.ascontiguousarray(v, dtype=float) for k, v in self.columns.items()}
        lengths = {len(v) for v in self.columns.values()}
        if len(lengths) > 1:
            raise RecordingError(f"{self.source}: columns have different lengths {sorted(lengths)}")

    def __len__(self) -> int:
        return len(self.time_s)

    @property
    def name(self) -> str:
        return Path(self.source).name

    @property
    def time_s(self) -> np.ndarray:
        return self.columns[TIME]

    @property
    def drive_name(self) -> str:
        for name in DRIVE_COLUMNS:
            if name in self.columns:
                return name
        raise RecordingError(f"{self.source}: no drive column (one of {', '.join(DRIVE_COLUMNS)})")

    @property
    def drive(self) -> np.ndarray:
        return self.columns[self.drive_name]

    @property
    def displacement_um(self) -> np.ndarray | None:
        return self.columns.get(DISPLACEMENT)

    def column(self, name: str) -> np.ndarray:
        """A column the caller cannot do without (`read_recording(require=...)` checked it);
        RecordingError naming the file if it is missing after all."""
        if name not in self.columns:
            raise RecordingError(f"{self.source}: no {name} column")
        return self.columns[name]

    @property
    def stress_MPa(self) -> np.ndarray | None:
        return self.columns.get(STRESS)

    @property
    def sample_period_s(self) -> float:
        """Median sample period (sampling need not be uniform)."""
        return float(np.median(np.diff(self.time_s))) if len(self) > 1 else float("nan")

    def time_text(self, index: int) -> str:
        """Sample `index`'s time as text, to the sample period (`time_text`)."""
        return time_text(float(self.time_s[index]), self.sample_period_s)

    def rows(self, keep: np.ndarray, source: str | None = None) -> "Recording":
        """A copy of the samples where `keep` is True (a window of a run, a stretch cut out), named
        `source` (default: this recording's own)."""
        return Recording({k: v[keep] for k, v in self.columns.items()}, dict(self.metadata),
                         self.source if source is None else source)

    def with_column(self, name: str, values: np.ndarray) -> "Recording":
        """A copy with one column added or replaced (for predictions and drives)."""
        cols = dict(self.columns)
        cols[name] = np.asarray(values, dtype=float)
        return Recording(cols, dict(self.metadata), self.source)


def plain(value: Any) -> Any:
    """Numpy scalars/arrays and other objects -> what YAML can write (metadata never blocks a write)."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)
