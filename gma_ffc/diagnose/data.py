"""Recordings prepared for the diagnosis: arrays, time steps, stress, the held-out split, and
which samples are scored.

The split is by contiguous time blocks inside every recording (alternate blocks form the two
folds). Models are always *simulated* over the whole recording from its inputs (drive, stress)
only, so no measured output of a held-out block ever enters a fit; only the loss is masked.

A sample is scored where what is known decides the model's output there: where the band the
unknown initial state leaves (`gma_ffc.state_band`, the state the run starts from included) is
no wider than the recording's noise floor. Elsewhere a residual may be the start-up transient, and
no fit or score sees it. A state given as known (``plays:FILE``: the service followed the plays
since its run started) leaves no band at all: every sample is scored.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from ..drive import drive_unit
from ..effects.base import time_steps
from ..errors import InputError
from ..recordings import Recording
from ..initial_state import InitialStateSpec
from ..state_band import admissible_corners, output_band
from ..sensor_holds import held_samples
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
    settled: int = 0          # first scored sample: nothing before it is scored (len(t) when none is)
    jumps: Jumps = field(default_factory=Jumps)   # steps of the sensor's zero (`jumps.py`), each fitted as an offset change
    scored: np.ndarray | None = None   # per sample, is it scored (module doc); None: from `settled` on
    never_forgotten: str = ""  # why a start the measurement tells apart is never forgotten, and what to record ('' if not)
    clipped: np.ndarray | None = None   # per sample, does the sensor sit at the end of its range (`gma_ffc/sensor_holds.py`)
    stalled: np.ndarray | None = None   # per sample, has the sensor or its logger stalled inside the range

    def __post_init__(self) -> None:
        if self.scored is None:
            self.scored = np.arange(self.t.size) >= self.settled

    @property
    def state_known(self) -> np.ndarray:
        """Where the unknown initial state no longer moves the output (never None after construction)."""
        assert self.scored is not None
        return self.scored

    @property
    def mask(self) -> np.ndarray:
        """The scored samples as a boolean array: the state known, the sensor inside its range."""
        held = self.sensor_held
        return self.state_known if held is None else self.state_known & ~held

    @property
    def sensor_held(self) -> np.ndarray | None:
        """Where the reading held while the drive moved (clipped or stalled), or None when not looked for."""
        return None if self.clipped is None or self.stalled is None else self.clipped | self.stalled

    @property
    def n_scored(self) -> int:
        return int(np.count_nonzero(self.mask))

    @property
    def n_state_known(self) -> int:
        return int(np.count_nonzero(self.state_known))

    def scored_runs(self) -> list[slice]:
        """The contiguous stretches of scored samples, in order."""
        return _runs(self.mask)

    @property
    def unscored_s(self) -> float:
        """How long the recording is not scored, s (each unscored sample for its time step)."""
        return float(np.sum(self.dt[~self.mask])) if self.t.size > 1 else 0.0

    def scored_only(self, r: np.ndarray) -> np.ndarray:
        """`r` with the samples that are not scored set to zero."""
        return np.where(self.mask, r, 0.0)

    @property
    def recorded_stress(self) -> np.ndarray:
        """The stress as recorded (unclamped), or the clamped zeros of a recording without one."""
        return self.s if self.s_raw is None else self.s_raw

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0])


def prepare(recordings: Sequence[Recording], model: Any, initial_state: Any = "estimate",
            measured: bool = True, drive_limits: tuple[float, float] | None = None,
            range_margin: float = 0.02) -> list[RecData]:
    """Arrays per recording; stresses outside the model's range are clamped (and counted). The
    core's state at each first sample follows `initial_state` (`gma_ffc.initial_state`). A
    `measured` displacement is searched for a sensor at the end of its range (`gma_ffc/sensor_holds.py`);
    a placeholder (the anchor's loops, simulated afterwards) is not. Advice on what to record
    asks for no drive beyond `drive_limits` (the controller's, when given); a drive within
    `range_margin` of the range's span from an end reached it (`EffectSelector`'s setting)."""
    total = sum(len(r) for r in recordings)
    stride = max(1, int(np.ceil(total / MAX_FIT_ROWS)))
    out: list[RecData] = []
    srange = model.stress_range_MPa
    for rec in recordings:
        if rec.displacement_um is None:
            raise InputError(f"{rec.source}: no displacement_um column; diagnose compares the model with measured displacement")
        t = np.ascontiguousarray(rec.time_s, dtype=float)
        n = t.size
        dt, dt_med = time_steps(t)
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
        stress = s if srange is not None else None
        start, scored, outside = start_and_scored(core, rec.drive, stress, initial_state, rec.displacement_um, t)
        y = np.ascontiguousarray(rec.displacement_um, dtype=float)
        no = np.zeros(n, dtype=bool)
        clipped, stalled = held_samples(y, np.asarray(rec.drive, dtype=float)) if measured else (no, no)
        first = np.flatnonzero(scored)
        d = RecData(
            name=rec.name, t=t, dt=dt, dt_med=dt_med,
            u=np.ascontiguousarray(rec.drive, dtype=float),
            y=y, clipped=clipped, stalled=stalled,
            s=np.ascontiguousarray(s), s_raw=s_raw, fold=(block % 2).astype(np.int8),
            rows=np.arange(0, n, stride), clamped_fraction=clamped,
            extra={"temperature_C": rec.columns.get("temperature_C"),
                   "drive_symbol": "V" if rec.drive_name.endswith("_V") else "I"}, start=start,
            settled=int(first[0]) if first.size else n, scored=scored,
            never_forgotten=whole_range_advice(rec, core.drive_range, drive_limits, range_margin) if outside and not scored.any() else "")
        d.rows = d.rows[d.mask[d.rows]]          # the least squares' rows: every scored one, strided
        out.append(d)
    return out


def whole_range_advice(rec: Recording, drive_range: tuple[float, float],
                       drive_limits: tuple[float, float] | None = None, range_margin: float = 0.02) -> str:
    """What to record when a run starts in a state no history inside the drive range leaves (a
    demagnetised rod: the measurement fits it better than the nearest such state) and its drive
    never swings far enough to forget it: the model's whole range once, which sets every play.
    Held within `drive_limits` (the controller's, `diagnose --drive-limits`) when given: a cycle
    over less than the model's range may leave its widest plays where they started (the demo's
    rig forgets after 0..2.5 A, not after 0..2 A of 0..3 A), so the advice names the step after
    it, and a run that already spans the limits is told that step alone. A drive within
    `range_margin` of the span from a limit reached it."""
    unit = drive_unit(rec.drive_name)
    lo, hi, held = advised_range(drive_range, drive_limits, unit)
    u_min, u_max = float(np.min(rec.drive)), float(np.max(rec.drive))
    start = (f"it starts in a state that no history inside the drive range leaves (a demagnetised rod, or one "
             f"driven beyond the range: the measurement shows it), and its drive ({u_min:.3g} to {u_max:.3g} "
             f"{unit}) never spans the model's range, which would make the model forget that state; ")
    if lo >= hi:
        return start + held
    cycle = f"drive one full cycle from {lo:.3g} to {hi:.3g} {unit}{held} and back before the run, then record"
    if not held:
        return start + cycle
    narrower = (f"identify a model over the drive the controller allows ({lo:.3g} to {hi:.3g} {unit}): a cycle "
                "over a model's whole range makes it forget any start")
    tol = range_margin * (hi - lo)          # a drive this close to an end reached it
    if u_min <= lo + tol and u_max >= hi - tol:
        return start + f"this run spans the drive limits ({lo:.3g} to {hi:.3g} {unit}) and still did not: {narrower}"
    return start + cycle + f"; if it is still not scored after that cycle, the limits are too narrow: {narrower}"


def advised_range(drive_range: tuple[float, float], drive_limits: tuple[float, float] | None,
                  unit: str) -> tuple[float, float, str]:
    """The drive an advice may ask for: the model's range, held within the controller's limits
    (None: none given), and the words that say so ('' when nothing was held; with lo >= hi, the
    advice that replaces a drive no limit allows)."""
    lo, hi = (float(v) for v in drive_range)
    if drive_limits is None:
        return lo, hi, ""
    low, high = (float(v) for v in drive_limits)
    a, b = max(lo, low), min(hi, high)
    if a >= b:
        return a, b, (f"the model's range ({lo:.3g} to {hi:.3g} {unit}) lies outside the drive limits "
                      f"({low:.3g} to {high:.3g} {unit}): identify a model within the drive the controller allows")
    if (a, b) == (lo, hi):
        return lo, hi, ""
    return a, b, f" (the model's range {lo:.3g} to {hi:.3g} {unit}, held within the drive limits)"


def start_and_scored(core: Any, drive: np.ndarray, stress: Any, rule: Any, measured_um: np.ndarray,
                     time_s: np.ndarray) -> tuple[Any, np.ndarray, bool]:
    """The core's initial state by `rule`, the samples to score, and whether that state lies outside
    the admissible box and stays there (the measurement tells them apart).

    Scored (module doc): where the output band over every admissible initial state, the state the
    run starts from included, is no wider than the noise floor the measurement shows. There the
    unknown start moves the prediction by less than the sensor's own noise, which no fit can tell
    from it; a start-up transient lies outside by construction.

    The estimate is fitted to the measurement moved onto the model's zero: by the mean difference
    over the samples the drive alone decides (where any admissible state gives the same output,
    the difference is the sensor's zero, not the state), so a sensor zeroed elsewhere changes
    neither the state nor what is scored. An estimate outside the admissible box (a history
    inside the drive range cannot leave it) is held at the box's nearest state when the
    measurement cannot tell the two apart: they differ by less than the noise floor, as a mean
    square, where they differ at all (the estimate had fitted the model's own error). When it can
    (a demagnetised start's virgin curve, a history beyond the range), the estimate stays and
    the band widens to hold it, so what it leaves unknown is not scored. A known state (``plays``)
    is taken as given, and every sample is scored."""
    if InitialStateSpec.parse(rule).kind == "plays":     # known, not guessed: the band is zero everywhere
        return core.resolve_initial_state(drive, stress, rule, None, time_s), np.ones(len(drive), dtype=bool), False
    y = np.asarray(measured_um, dtype=float)
    floor = noise_floor(y)
    box = output_band(core, drive, stress)
    known = box.known(floor)
    aligned = y - float(np.mean((y - box.lower)[known])) if known.any() else y
    start = core.resolve_initial_state(drive, stress, rule, aligned, time_s)
    scored = output_band(core, drive, stress, also=start.play_state).known(floor)
    if InitialStateSpec.parse(rule).kind != "estimate" or np.array_equal(scored, known):
        return start, scored, False                    # a rule the user chose, or an estimate inside the box
    held = np.clip(start.play_state, *admissible_corners(core, drive))
    runs = [np.asarray(core.simulate(None, drive, stress, initial_play_state=p), dtype=float)
            for p in (start.play_state, held)]
    matters = ~scored                                  # where the estimate's start still shows
    gain = float(np.mean((aligned - runs[1])[matters] ** 2) - np.mean((aligned - runs[0])[matters] ** 2))
    if gain > floor ** 2:
        return start, scored, True
    return dataclasses.replace(start, play_state=held, how=start.how + "; held within the states a history "
                               "inside the drive range leaves, which the measurement does not tell from it"), known, False


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
    constant signal falls back on the plain spread of its second differences. Fewer than five
    samples give no estimate, and none is assumed (0: such a recording is too short to score)."""
    if y.size < 5:
        return 0.0
    sigma = second_difference_sigma(y)
    if sigma == 0.0:
        sigma = float(np.std(np.diff(y, 2))) / np.sqrt(6.0)
    return sigma


UNSCORED_WHY = ("there the model's output still depends, by more than the noise floor, on the unknown "
                "hysteresis state at the start (until the drive has moved far enough, or reached an end of "
                "its range, for the model to forget it)")


def unscored_note(d: RecData) -> str:
    """What the user is told about a recording's samples that are not scored ('' when all are),
    with the recording that would be scored whole."""
    if d.n_state_known == 0 and d.never_forgotten:
        return f"{d.name}: none of it is scored: {d.never_forgotten}"
    if d.n_state_known == 0:
        return (f"{d.name}: none of it is scored: everywhere the model's output still depends, by more than the "
                "noise floor, on the hysteresis state the recording starts in, which the file does not show; "
                "start a recording at rest at an end of the drive range (e.g. a sine whose amplitude grows from "
                "the drive's minimum), or record at least one full drive cycle")
    if d.n_state_known == d.t.size:
        return ""
    return f"{d.name}: {_unscored_part(d)} are not scored: {UNSCORED_WHY}"


def unscored_starts_note(data: Sequence[RecData]) -> str:
    """One note for every recording scored in part ('' when none is): several recordings' starts
    share one sentence, so a diagnosis of seven runs does not repeat it seven times."""
    partial = [d for d in data if 0 < d.n_state_known < d.t.size]
    if len(partial) <= 1:
        return unscored_note(partial[0]) if partial else ""
    listed = "; ".join(f"{d.name}: {_unscored_part(d)}" for d in partial)
    return f"the starts of {len(partial)} recordings are not scored ({listed}): {UNSCORED_WHY}"


def _unscored_part(d: RecData) -> str:
    """How much of `d` the unknown start leaves unscored (the sensor's clipping has its own note)."""
    runs = _runs(d.state_known)
    unknown_s = float(np.sum(d.dt[~d.state_known])) if d.t.size > 1 else 0.0
    return (f"the first {d.t[d.settled] - d.t[0]:.3g} s" if len(runs) == 1 and runs[0].stop == d.t.size
            else f"{unknown_s:.3g} s of it")


def unscored_spans(d: RecData) -> list[tuple[float, float]]:
    """The time spans (first to last sample) of the stretches that are not scored."""
    return [(float(d.t[r.start]), float(d.t[r.stop - 1])) for r in _runs(~d.mask)]


def _runs(mask: np.ndarray) -> list[slice]:
    """The contiguous stretches where `mask` is True, in order."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return [slice(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def none_scored(data: Sequence["RecData"]) -> bool:
    """No sample of any recording is scored: nothing was held out, and every figure is the models'
    miss over every sample (the start-up transient, perhaps all of it)."""
    return all(d.n_scored == 0 for d in data)
