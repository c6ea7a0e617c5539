"""Recordings prepared for the diagnosis: arrays, time steps, stress, the held-out split.

The split is by contiguous time blocks inside every recording (alternate blocks form the two
folds). Models are always *simulated* over the whole recording from its inputs (drive, stress)
only, so no measured output of a held-out block ever enters a fit; only the loss is masked.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from ..errors import InputError
from ..recordings import Recording
from .jumps import Jumps
from .noise import second_difference_sigma

N_BLOCKS = 16         # blocks per recording; even-numbered ones form fold A, odd ones fold B
MAX_FIT_ROWS = 20000  # rows used by the least squares (evenly strided); filters always run at full rate


@dataclass
class RecData:
    name: str
    t: np.ndarray
    dt: np.ndarray            # dt[k] = t[k] - t[k-1]; dt[0] = median step
    dt_med: float
    u: np.ndarray             # drive as recorded
    y: np.ndarray             # measured displacement
    s: np.ndarray             # stress clamped to the model's range (zeros if none)
    s_raw: np.ndarray | None  # stress as recorded
    fold: np.ndarray          # 0 (fold A) or 1 (fold B) per sample
    rows: np.ndarray          # sample indices used by the least squares
    clamped_fraction: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)
    start: Any = None         # the core's initial state, estimated from this recording (gma_ffc.initial_state)
    settled: int = 0          # first sample the unknown initial state no longer affects: nothing before is scored
    jumps: Jumps = field(default_factory=Jumps)   # steps of the sensor's zero (`jumps.py`), each fitted as an offset change

    @property
    def recorded_stress(self) -> np.ndarray:
        """The stress as recorded (unclamped), or the clamped zeros of a recording without one."""
        return self.s if self.s_raw is None else self.s_raw

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0])


def prepare(recordings: Sequence[Recording], model: Any, initial_state: Any = "estimate") -> list[RecData]:
    """Arrays per recording; stresses outside the model's range are clamped (and counted). The
    core's state at each first sample follows `initial_state` (`gma_ffc.initial_state`)."""
    total = sum(len(r) for r in recordings)
    stride = max(1, int(np.ceil(total / MAX_FIT_ROWS)))
    out: list[RecData] = []
    srange = model.stress_range_MPa
    for rec in recordings:
        if rec.displacement_um is None:
            raise InputError(f"{rec.source}: no displacement_um column; diagnose compares the model with measured displacement")
        t = np.ascontiguousarray(rec.time_s, dtype=float)
        n = t.size
        d = np.diff(t)
        dt_med = float(np.median(d)) if n > 1 else 1.0
        dt = np.concatenate(([dt_med], d))
        s_raw = None if rec.stress_MPa is None else np.ascontiguousarray(rec.stress_MPa, dtype=float)
        if srange is None:
            s = np.zeros(n)
            clamped = 0.0
        else:
            if s_raw is None:
                raise InputError(
                    f"{rec.source}: the model is stress-dependent ({model.kind}) but the recording has no "
                    "stress_MPa column; add it (load cell force / rod area, compression negative)")
            s = np.clip(s_raw, srange[0], srange[1])
            clamped = float(np.mean(np.abs(s - s_raw) > 1e-6 * max(1.0, abs(srange[0]))))
        block = np.minimum((np.arange(n) * N_BLOCKS) // max(n, 1), N_BLOCKS - 1)
        core = getattr(model, "base", model)
        start = core.resolve_initial_state(rec.drive, s if srange is not None else None, initial_state,
                                           rec.displacement_um, t)
        rows = np.arange(0, n, stride)
        rows = rows[rows >= start.settled_index]
        out.append(RecData(
            name=rec.name, t=t, dt=dt, dt_med=dt_med,
            u=np.ascontiguousarray(rec.drive, dtype=float),
            y=np.ascontiguousarray(rec.displacement_um, dtype=float),
            s=np.ascontiguousarray(s), s_raw=s_raw, fold=(block % 2).astype(np.int8),
            rows=rows, clamped_fraction=clamped,
            extra={"temperature_C": rec.columns.get("temperature_C"),
                   "drive_symbol": "V" if rec.drive_name.endswith("_V") else "I"}, start=start,
            settled=min(start.settled_index, n)))
    return out


def stress_span(data: Sequence[RecData]) -> float:
    """Spread of (clamped) stress over all recordings, MPa."""
    lo = min(float(np.percentile(d.s, 2)) for d in data)
    hi = max(float(np.percentile(d.s, 98)) for d in data)
    return hi - lo


def stress_levels(data: Sequence[RecData], gap_MPa: float = 1.0, min_share: float = 0.05) -> list[float]:
    """Distinct stress levels the recordings dwell at (>= gap apart), each held for >= min_share of
    the samples of some recording: a load-change recording's levels count beside a long run at one
    stress (pooled, each of its levels was a few per cent of all samples and none was seen)."""
    medians: list[float] = []
    for d in data:
        s = np.sort(d.s)
        if s.size == 0:
            continue
        # split the sorted stresses where they jump by more than a fifth of the gap
        cuts = np.flatnonzero(np.diff(s) > 0.2 * gap_MPa) + 1
        medians += [float(np.median(g)) for g in np.split(s, cuts) if g.size >= min_share * s.size]
    levels: list[float] = []
    for m in sorted(medians):
        if not levels or m - levels[-1] >= gap_MPa:
            levels.append(m)
    return levels


def mean_stress(data: Sequence[RecData]) -> float:
    n = sum(d.s.size for d in data)
    return float(sum(float(d.s.sum()) for d in data) / max(n, 1))


def noise_floor(y: np.ndarray) -> float:
    """Measurement noise std from the data (`noise.second_difference_sigma`); a quantised, nearly
    constant signal falls back on the plain spread of its second differences."""
    if y.size < 5:
        return float("nan")
    sigma = second_difference_sigma(y)
    if sigma == 0.0:
        sigma = float(np.std(np.diff(y, 2))) / np.sqrt(6.0)
    return sigma
