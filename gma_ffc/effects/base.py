"""What every effect class offers: the `Effect` protocol, the signals its steppers share, and helpers.

An effect is one physical mechanism the SDPI/MPI core lacks (eddy currents, a delay, heating...).
Its class carries both sides of it, so that adding an effect means adding one file:

* the model side (instances hold the block's parameters): validation from the file's blocks,
  the batch filter, and a stepper state for the forward and the inverse sample-by-sample paths;
* the diagnosis side (class methods, no instance): when the data can test it, the grid of its
  nonlinear parameter, its least-squares regressors once that parameter is fixed, and how the
  fitted coefficients become the block's parameters.

This package never imports `gma_ffc.diagnose`: the diagnosis hands its fitter in as an argument
(typed here as `FitData`), so data flow stays one-way.
"""

from __future__ import annotations

import difflib
import functools
import math
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Iterable, Mapping, Protocol, Sequence, TypeGuard, TypeVar

import numpy as np

from ..errors import ModelError
from ..model import PARAMETER_BOUND
from . import kernels as K

# Where an effect sits on the signal path drive -> [input] -> core -> [sum] -> [filter] -> [after]:
#   input  changes the drive the core sees (eddy lag, delay); inverted after the core's inverse
#   sum    adds a term to the recalibrated core output (static map, plays, saturation, creep);
#          inverted together in closed form by the static map's quadratic root
#   filter filters everything summed so far (the resonance); inverted before the sum
#   after  adds a term after the filter (heating offset); inverted first
STAGES = ("input", "sum", "filter", "after")
_T = TypeVar("_T")                # what a fitter's cache holds for an effect (`FitData.cached`)


class StepSignals:
    """One sample's signals, shared by the stepper states of a model (allocated once per stepper,
    so a step allocates nothing: states read and write these floats in place)."""

    __slots__ = ("u1", "u3", "s", "ds", "yc", "y", "target", "const", "lin", "u3_prev", "drive_prev", "u3_at",
                 "drive_at")

    def __init__(self) -> None:
        self.u1 = self.u3 = self.s = self.ds = self.yc = self.y = 0.0   # drive, core input, stress, s - s_ref
        self.target = self.const = self.lin = 0.0     # inverse: reference left to explain; sum terms c + l * yc
        self.u3_prev = self.drive_prev = 0.0          # inverse: the previous sample's core input and drive
        self.u3_at = self.drive_at = 0.0              # inverse: the core input and drive this sample is tried at


@dataclass
class BatchSignals:
    """The arrays a batch filter of the output side may read."""

    t: np.ndarray
    dt: np.ndarray                 # dt[k] = t[k] - t[k-1], dt[0] the median step
    drive: np.ndarray              # the drive as commanded
    u3: np.ndarray                 # the drive as the core sees it
    yc: np.ndarray                 # the core's displacement
    stress: np.ndarray             # stress per sample (zeros without stress)
    ds: np.ndarray                 # stress - the static map's reference stress
    stress_arg: Any                # stress as the caller gave it (None, scalar or array), for core re-runs
    initial_drive: float | None    # at rest at this drive before the first sample, if given
    play_start: "PlayStart | None" = None    # the core's plays at the first sample (None: relaxed)


@dataclass(frozen=True)
class PlayStart:
    """The core's plays at the first sample, as each one's offset from the input against its
    threshold. Other plays on the same input (a recalibration's, stress play's) start from the
    same history rather than relaxed: a minor loop never sweeps a wide play, so an arbitrary
    start would stay in the output for the whole run."""

    thresholds: np.ndarray     # the core's (drive units, ascending)
    offsets: np.ndarray        # play output minus input at the first sample, per core threshold

    @classmethod
    def of_core(cls, core: Any, first_input: float, play_state: Any) -> "PlayStart | None":
        """From a core's play state (its own coordinates) at input `first_input` (None: a core
        without plays)."""
        sdpi = getattr(core, "base", core)
        r = getattr(sdpi, "play_thresholds", None)
        if r is None or play_state is None:
            return None
        v0 = float(first_input) - float(getattr(sdpi, "input_offset", 0.0))
        return cls(np.asarray(r, dtype=float), np.asarray(play_state, dtype=float) - v0)

    @classmethod
    def of_core_rule(cls, core: Any, first_input: float) -> "PlayStart | None":
        """The start a core's stepper takes at rest at `first_input` (its `initial_state` field)."""
        sdpi = getattr(core, "base", core)
        r = getattr(sdpi, "play_thresholds", None)
        if r is None:
            return None
        r = np.asarray(r, dtype=float)
        return cls(r, r.copy() if getattr(sdpi, "initial_state", "relaxed") == "descending" else np.zeros_like(r))

    def outputs(self, thresholds: np.ndarray, first_input: float) -> np.ndarray:
        """Initial outputs of plays with `thresholds` at `first_input` (beyond the core's widest
        play, its offset is held)."""
        th = np.asarray(thresholds, dtype=float)
        d = np.interp(th, self.thresholds, self.offsets)
        return float(first_input) + np.clip(d, -th, th)


def first_play_outputs(start: PlayStart | None, thresholds: np.ndarray, first_input: float) -> np.ndarray:
    """Where plays of `thresholds` start at `first_input`: as the core's (`start`), else relaxed."""
    th = np.asarray(thresholds, dtype=float)
    return np.full(th.size, float(first_input)) if start is None else start.outputs(th, first_input)


class EffectState(Protocol):
    """An effect's state in a forward or inverse stepper (built once per sample period)."""

    def reset(self, initial_drive: float) -> None: ...

    def step(self, x: StepSignals) -> None:
        """Forward: input stage maps x.u3 in place; output stages update x.y."""

    def inverse_step(self, x: StepSignals) -> None:
        """Inverse: input stage maps x.u3 back towards the drive; filter and after stages update
        x.target; sum stage adds its term's constant and yc-coefficient to x.const and x.lin.

        A sum-stage term that depends on this sample's core input or drive (not only on y_c) reads
        them from x.u3_at and x.drive_at without moving its state, and its state class sets
        ``reads_input = True``: the inverse then calls it at several trial inputs and solves for
        the one the core's inverse returns (exact, not lagged by a sample)."""

    def commit(self, x: StepSignals) -> None:
        """Inverse, sum stage: update the state once x.yc and x.u3 of this sample are known."""


class FitData(Protocol):
    """What the diagnosis' fitter offers an effect class (see `gma_ffc.diagnose.fitting.Fitter`)."""

    model: Any
    data: list[Any]
    drive_lo: float
    drive_hi: float
    drive_span: float
    drive_margin: float            # a drive further than this beyond the identified range is beyond it
    drive_limits: tuple[float, float] | None    # the drive the rig's controller allows (`diagnose --drive-limits`)
    dt_min: float
    duration_max: float
    stress_ref: float
    stress_top: float              # the least compressive stress the model sees (the loads' static stress)
    stress_bottom: float           # the most compressive one
    stress_varies: bool
    play_thresholds: np.ndarray
    identification: list[Any]      # the measured identification loops (`diagnose --ident`), or none

    def stress(self, d: Any, spec: Any) -> np.ndarray:
        """The stress the model under `spec` sees on a recording (clamped to the model's range)."""

    def static_stress(self, d: Any, clamped: bool = False) -> np.ndarray:
        """A recording's stress as a stress-transforming effect makes it (the load's static stress),
        raw or clamped to the model's stress range (what the core sees)."""

    @property
    def yc_center(self) -> float: ...

    def cached(self, key: tuple, compute: Callable[[], _T]) -> _T:
        """compute() once per key (the fitter's cache, bounded)."""

    def cached_table(self, d: Any, key: tuple, compute: Callable[[], np.ndarray]) -> np.ndarray:
        """compute() once per recording and key: a per-sample table (e.g. a resonance's transitions)
        shared across specs (its own bounded cache)."""

    def stress_levels(self) -> list[float]:
        """Distinct stress levels the recordings dwell at."""

    def identification_levels(self) -> list[float]:
        """Distinct stress levels of the identification loops (`diagnose --ident`; none without)."""

    def identified_core(self, loop_width: tuple[float, float] | None = None,
                        creep: tuple[float, float] | None = None) -> Any:
        """The base identified again on the measured identification recordings (`diagnose --ident`),
        with a loop width (kappa per MPa, reference MPa) or through a creep (gain, tau s) when given;
        None without those recordings."""


@dataclass
class Regressors:
    """One recording's least-squares regressors as the effects of a spec build them up, in
    signal-path order (the static map's first)."""

    d: Any                         # the recording (gma_ffc.diagnose.data.RecData)
    u3: np.ndarray                 # the core's input after the spec's input-side effects
    yc: np.ndarray                 # the core's output for it
    input_key: tuple               # identifies u3 (for caches)
    spec: Any                      # the whole spec (an effect may depend on another's presence)
    cols: list[np.ndarray]
    names: list[str]
    shared: dict[str, Any]         # computed once per recording and call (e.g. the play bank)


@dataclass
class SignatureCheck:
    """What an effect's signature check may look at once it has won a round (see `Effect.signature`)."""

    fitter: Any                    # the diagnosis' Fitter
    model: Any                     # the base model
    before: tuple                  # specs (fold A, fold B, all) before the effect was added
    result: Any                    # the effect's SearchResult
    params: dict[str, float]       # its reported parameters
    noise: float                   # the noise floor (um)
    slow_ratio_max: float          # the selector's thresholds the checks use
    model_error_factor: float
    min_samples: int = 400         # the selector's: fewer rows than a diagnosis scores at all judge nothing

    SLOW_SHARE: ClassVar[int] = 40   # the slowest 40 % of samples: where the drive turns round or holds

    def slow_ratio(self, holds: bool = True) -> float:
        """Held-out mean-square error with the effect over that without it, on the slowest
        `SLOW_SHARE` % of samples (by the drive's rate): where the drive turns round or holds.
        `holds=False`: of the samples where the drive moves (`drive.held`), so where it turns round;
        fewer such slow rows than `min_samples` show no gain (1.0)."""
        f = self.fitter
        moving = np.ones(f.rate_rows.size, dtype=bool) if holds else ~f.held_rows
        if not holds and self.SLOW_SHARE / 100 * np.count_nonzero(moving) < self.min_samples:
            return 1.0       # too few turns to tell a gain from chance: none shown
        slow = moving & (f.rate_rows <= np.percentile(f.rate_rows[moving], self.SLOW_SHARE))
        r0, r1 = (r[slow] for r in self._held_out)
        return float(np.mean(r1 * r1) / max(float(np.mean(r0 * r0)), 1e-300))

    @functools.cached_property
    def _held_out(self) -> tuple[np.ndarray, np.ndarray]:
        """Held-out residuals at the fitter's rows, before and with the effect (fitted once, however
        many parts of the drive are judged)."""
        return self.fitter.test_residuals(self.before), self.fitter.test_residuals(self.result.specs)

    def gain_from_fast_parts(self, because: str, turns_alone: bool = False) -> "SignatureFailure | None":
        """A failure when the effect's held-out gain does not hold where the drive is slow (the
        error there falls to no less than `slow_ratio_max` of before), saying `because`; else None.
        `turns_alone`: the gain may also show on the slowest samples of those where the drive moves
        (its turns, `slow_ratio(holds=False)`) instead."""
        ratio = self.slow_ratio()
        if ratio <= self.slow_ratio_max:
            return None
        where = "where the drive turns round or holds"
        if turns_alone:
            at_turns = self.slow_ratio(holds=False)
            if at_turns <= self.slow_ratio_max:
                return None
            where, ratio = "where the drive turns round or holds, or of those where it moves", min(ratio, at_turns)
        return SignatureFailure(
            f"its held-out gain comes from the fast parts of the drive (on the slowest {self.SLOW_SHARE} % of "
            f"samples, {where}, the error only falls to {ratio:.0%} of before): " + because)


@dataclass
class SignatureFailure:
    """Why a winning effect is not that effect; `outside_class` marks a drive the model's class
    cannot follow at all (then nothing is named)."""

    reason: str
    outside_class: bool = False
    # a form of the effect's search point the fit may take instead, searched again before the effect is
    # set aside (creep from rest, `creep.FromRest`); None: none
    variant: Callable[[Any], Any] | None = None


class Effect(Protocol):
    """One physical effect: its block in the extended model and how the diagnosis fits it."""

    name: ClassVar[str]                     # the diagnosis' word for it, e.g. "rate_dependence"
    keys: ClassVar[tuple[str, ...]]         # its block(s) in model files, e.g. ("eddy_lag",)
    block_keys: ClassVar[Mapping[str, tuple[str, ...]]]   # per block, every key it reads (docs/extended-model.md)
    stage: ClassVar[str]                    # one of STAGES
    position: ClassVar[int]                 # order along the signal path (lower: nearer the drive)
    inverted: ClassVar[Mapping[str, str]]   # per block key: how the inverse undoes it (written to files)
    physics: ClassVar[str]                  # what it is, for a current-driven actuator
    physics_voltage: ClassVar[str | None]   # the same for a voltage-driven one, where it differs
    physics_without_stress: ClassVar[str | None]   # the same for recordings without a stress column
                                            # (no load cell), where it differs; wins over the two above
    candidate: ClassVar[bool]               # False: always present, never selected (the static map)
    n_params: ClassVar[int]                 # parameters the block adds (nonlinear + gains): the penalty
    slow: ClassVar[bool]                    # a slow effect (needs long recordings to separate)
    follows_drive: ClassVar[bool]           # True: a function of the drive loop, pinned by the base's own
                                            # identification loops (`diagnose.anchor`); False: a disturbance
                                            # or slow state, held at its reference on those loops
    joint_with: ClassVar[tuple[str, ...]]   # look-alikes: the first accepted has its parameter re-searched with this one
                                            # (scaled by the look-alike's `scaled_for_partner`)
    rescales: ClassVar[tuple[str, ...]]     # not look-alikes, but accepted effects whose fit changes shape when this
                                            # one joins: their parameter is re-searched with it, as a look-alike's is
                                            # (no swap-pass rivalry follows from it)
    joint_scales: ClassVar[tuple[float, ...]]   # the grid's scales of that parameter (the zoom refines them)
    rest_form: ClassVar[Callable[[Any], Any] | None]   # a search point's form with nothing under way at any
                                            # recording's start (creep's `FromRest`); None: no start terms
    joint_refit: ClassVar[bool]             # True: beside a look-alike tried with it, its own parameters are
                                            # searched again as well (`scoring._descend`): one scale is not enough
    deciders: ClassVar[Mapping[str, str]]   # per look-alike: the experiment that tells the two apart
    told_by_frequency: ClassVar[bool]       # True: a phase lag whose form (a delay, a lag, a resonance) shows only
                                            # in how the lag changes with frequency: at one drive frequency
                                            # the others with this flag fit it as well (`EffectSelector`)
    transforms_stress: ClassVar[bool]       # True: it supplies the stress the core (and every stage) sees
    shapes_core: ClassVar[bool]             # True: its parameter changes the core itself (`fit_core`);
                                            # `reshapes` says whether it does on a given diagnosis
    zoom_levels: ClassVar[int]              # refinement levels of its parameter search
    without_identification: ClassVar[str]   # what it cannot do without the identification recordings ('' nothing)

    # ---- model side
    @classmethod
    def from_blocks(cls, blocks: Mapping[str, Any], base: Any) -> "Effect | None":
        """The effect from a model file's blocks (None when none of its keys is there); raises ModelError."""

    def to_blocks(self) -> dict[str, dict[str, Any]]: ...

    def inverted_text(self) -> Mapping[str, str]:
        """`inverted` for this block (an effect with two forms words each its own way)."""

    @property
    def preview_s(self) -> float:
        """How far ahead an inverse must see the reference because of this effect (delays)."""

    def wrap_core(self, core: Any) -> Any:
        """The core the model runs with this effect (the given one, unless the effect reshapes it):
        an object with the core's simulate, forward_stepper and inverse_stepper."""

    def seen_stress(self, stress_MPa: Any, t: np.ndarray, dt: np.ndarray) -> Any:
        """The stress transform hook, batch: the stress the core and the later stages see (called
        before the core; as given unless `transforms_stress`). Its stepper state then offers
        `seen_stress(stress_MPa) -> float`, called on each sample's stress before the clamp."""

    def apply_input(self, u: np.ndarray, dt: np.ndarray, dt_med: float, u0: float) -> np.ndarray:
        """Input stage, batch: the drive after this effect."""

    def apply(self, y: np.ndarray, sig: BatchSignals) -> np.ndarray:
        """Output stages, batch: the displacement after this effect."""

    def state(self, dt: float, stress_ref: float, inverse: bool) -> EffectState: ...

    # ---- diagnosis side
    @classmethod
    def testable(cls, fitter: FitData) -> tuple[bool, str]: ...

    @classmethod
    def count_params(cls, fitter: FitData) -> int:
        """Parameters the block adds on this diagnosis (nonlinear and gains): the likelihood penalty."""

    @classmethod
    def grid_like(cls, fitter: FitData, p: Any) -> Any:
        """Its grid in the form of the search point `p` (its `rest_form`, or a `SignatureFailure.variant`)."""

    @classmethod
    def lost_without_identification(cls, fitter: FitData) -> str:
        """What the diagnosis could not do for this effect without the identification recordings
        (`diagnose --ident`); '' when they would change nothing."""

    @classmethod
    def fitted_on_loops(cls, fitter: FitData) -> bool:
        """True when, on this diagnosis, its law and the core it runs are both fitted on the
        identification loops (`diagnose --ident`), so it adds no column to these recordings."""

    @classmethod
    def grid(cls, fitter: FitData) -> Iterable[Any]: ...

    @classmethod
    def refine(cls, fitter: FitData, p: Any, level: int) -> Sequence[Any] | None:
        """Points around p at zoom level 1, 2, ... (None: the grid is all there is)."""

    @classmethod
    def polish(cls, fitter: FitData, p: Any) -> tuple[int, Callable[[np.ndarray], Any]] | None:
        """After the zoom, for a parameter it leaves too coarse (a sharp resonance): the number of
        free coordinates and a map from log-moves about p (zeros: p itself) to parameter points,
        for a continuous local search (None: the zoom is all there is)."""

    @classmethod
    def after_polish(cls, fitter: FitData, p: Any) -> Sequence[Any]:
        """Points worth scoring from the polished point p beside the zoom's first level: a parameter
        the data show only once the others are close (a resonance's load law), swept whole."""

    @classmethod
    def scaled_for_partner(cls, p: Any, k: float) -> Any:
        """Its parameter scaled by k, beside a look-alike that names it in `joint_with`."""

    @classmethod
    def fit_stress(cls, d: Any) -> np.ndarray:
        """`transforms_stress` only: the transformed stress of a recording (unclamped)."""

    @classmethod
    def reshapes(cls, fitter: FitData) -> bool:
        """Whether its parameter changes the core on this diagnosis (`fit_core` is then called)."""

    @classmethod
    def fit_core(cls, fitter: FitData, core: Any, p: Any) -> Any:
        """`reshapes` only: the core the diagnosis runs for parameter p."""

    @classmethod
    def columns(cls, fitter: FitData, r: Regressors, p: Any) -> None:
        """Add (or transform) least-squares regressors of one recording for parameter p."""

    @classmethod
    def filter_input(cls, u: np.ndarray, d: Any, p: Any) -> np.ndarray:
        """Input stage: the diagnosis' core input through this effect (a recording's time steps)."""

    @classmethod
    def fitted_params(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, float]:
        """The parameters reported for it (nan where a coefficient is missing)."""

    @classmethod
    def fitted_blocks(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, dict[str, Any]]:
        """Its block(s) of the extended model from the fitted coefficients."""

    @classmethod
    def signature(cls, check: SignatureCheck) -> SignatureFailure | None:
        """A check that the win has the effect's signature (None: it has, or there is no check)."""

    @staticmethod
    def describe(params: Mapping[str, float], unit: str) -> str: ...


# --------------------------------------------------------------------------- shared helpers

class NoState:
    """A stepper state with nothing to remember (defaults every hook to 'leave the signals')."""

    def reset(self, initial_drive: float) -> None:
        pass

    def step(self, x: StepSignals) -> None:
        pass

    def inverse_step(self, x: StepSignals) -> None:
        pass

    def commit(self, x: StepSignals) -> None:
        pass


class EffectBase:
    """Defaults for the optional parts of the protocol, so each effect file states only what it does.

    A one-block effect is built from its block's mapping (checked by the subclass's constructor)
    and writes it back as given."""

    keys: ClassVar[tuple[str, ...]]
    inverted: ClassVar[Mapping[str, str]]
    n_params: ClassVar[int]
    physics_voltage: ClassVar[str | None] = None
    physics_without_stress: ClassVar[str | None] = None
    candidate: ClassVar[bool] = True
    slow: ClassVar[bool] = False
    follows_drive: ClassVar[bool] = False
    joint_with: ClassVar[tuple[str, ...]] = ()
    rescales: ClassVar[tuple[str, ...]] = ()
    joint_scales: ClassVar[tuple[float, ...]] = (0.3, 0.55, 0.8, 1.0)   # the look-alike's parameter, scaled
    rest_form: ClassVar[Callable[[Any], Any] | None] = None
    joint_refit: ClassVar[bool] = False
    deciders: ClassVar[Mapping[str, str]] = {}
    told_by_frequency: ClassVar[bool] = False
    transforms_stress: ClassVar[bool] = False
    shapes_core: ClassVar[bool] = False
    zoom_levels: ClassVar[int] = 3
    without_identification: ClassVar[str] = ""    # what it cannot do without the identification recordings

    @classmethod
    def scaled_for_partner(cls, p: Any, k: float) -> Any:
        """This effect's parameter when a look-alike tried beside it (`joint_with`) may take over part of
        what it stood in for: scaled by k (a lag's time constant, a delay)."""
        return p * k

    def __init__(self, block: Mapping[str, Any]) -> None:
        self.block = dict(block)

    @classmethod
    def from_blocks(cls, blocks: Mapping[str, Any], base: Any) -> Any:
        b = block_of(blocks, cls.keys[0])
        return None if b is None else cls(b)

    def to_blocks(self) -> dict[str, dict[str, Any]]:
        return {self.keys[0]: dict(self.block)}

    def inverted_text(self) -> Mapping[str, str]:
        return self.inverted

    @property
    def preview_s(self) -> float:
        return 0.0

    def wrap_core(self, core: Any) -> Any:
        return core

    def seen_stress(self, stress_MPa: Any, t: np.ndarray, dt: np.ndarray) -> Any:
        return stress_MPa

    def apply_input(self, u: np.ndarray, dt: np.ndarray, dt_med: float, u0: float) -> np.ndarray:
        return u

    def apply(self, y: np.ndarray, sig: BatchSignals) -> np.ndarray:
        return y

    @classmethod
    def testable(cls, fitter: FitData) -> tuple[bool, str]:
        return True, ""

    @classmethod
    def count_params(cls, fitter: FitData) -> int:
        """Parameters the block adds on this diagnosis (the likelihood penalty): `n_params`."""
        return cls.n_params

    @classmethod
    def grid(cls, fitter: FitData) -> Any:
        """Its search points: every candidate effect gives its own."""
        raise NotImplementedError(f"{cls.__name__} has no search grid")

    @classmethod
    def grid_like(cls, fitter: FitData, p: Any) -> Any:
        """Its grid in the form of the search point `p` (its `rest_form`, or a `SignatureFailure.variant`)."""
        return cls.grid(fitter)

    @classmethod
    def lost_without_identification(cls, fitter: FitData) -> str:
        """`without_identification`, when the effect could be tested on these recordings."""
        return cls.without_identification if cls.testable(fitter)[0] else ""

    @classmethod
    def fitted_on_loops(cls, fitter: FitData) -> bool:
        return False

    @classmethod
    def refine(cls, fitter: FitData, p: Any, level: int) -> Sequence[Any] | None:
        return None

    @classmethod
    def polish(cls, fitter: FitData, p: Any) -> tuple[int, Callable[[np.ndarray], Any]] | None:
        return None

    @classmethod
    def after_polish(cls, fitter: FitData, p: Any) -> Sequence[Any]:
        return []

    @classmethod
    def signature(cls, check: SignatureCheck) -> SignatureFailure | None:
        return None

    @classmethod
    def columns(cls, fitter: FitData, r: Regressors, p: Any) -> None:
        pass                            # input-side effects change the core input, not the columns

    @classmethod
    def filter_input(cls, u: np.ndarray, d: Any, p: Any) -> np.ndarray:
        return u

    @classmethod
    def fit_stress(cls, d: Any) -> np.ndarray:
        return np.asarray(d.s)

    @classmethod
    def reshapes(cls, fitter: FitData) -> bool:
        return cls.shapes_core

    @classmethod
    def fit_core(cls, fitter: FitData, core: Any, p: Any) -> Any:
        return core


class CoreAround:
    """A core with something around it (an effect that reshapes the core): the plain core's
    stress range, drive range and output sign, which the wrapping does not change."""

    base: Any

    @property
    def stress_range_MPa(self) -> Any:
        return self.base.stress_range_MPa

    @property
    def drive_range(self) -> Any:
        return self.base.drive_range

    @property
    def output_sign(self) -> int:
        return int(self.base.output_sign)


def time_steps(time_s: Any) -> tuple[np.ndarray, float]:
    """(dt, median dt) of a recording's time stamps: dt[k] = t[k] - t[k-1], dt[0] the median step."""
    t = np.asarray(time_s, dtype=float)
    if t.size < 2:
        return np.ones(t.size), 1.0
    d = np.diff(t)
    med = float(np.median(d))
    return np.concatenate(([med], d)), med


def refuse_unknown_keys(name: str, block: Any, known: Sequence[str]) -> None:
    """ModelError for a key of block `name` that its effect does not read: a misspelt optional key
    ('law_held_belwo_MPa', 'gian') would be ignored, and the model would run without it."""
    if not isinstance(block, Mapping):
        return              # `block_of` names that fault
    for key in block:
        if key in known:
            continue
        close = difflib.get_close_matches(str(key), known, n=1, cutoff=0.6)
        hint = f" (did you mean '{name}.{close[0]}'?): rename it" if close else \
            f": the {name} block reads only {', '.join(known)}; remove it"
        raise ModelError(f"extended model: unknown key '{name}.{key}'{hint} (docs/extended-model.md)")


def block_of(blocks: Mapping[str, Any], key: str) -> dict[str, Any] | None:
    """A block of a model file as a fresh dict (None when absent)."""
    v = blocks.get(key)
    if v is None:
        return None
    if not isinstance(v, Mapping):
        raise ModelError(f"extended model: {key} must be a mapping, got {v!r}")
    return dict(v)


def is_number(v: Any) -> TypeGuard[float]:
    """A finite number within PARAMETER_BOUND (true/false are not numbers here, though Python's bool is an int)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and abs(v) <= PARAMETER_BOUND


def positive(block: Mapping[str, Any], key: str, name: str) -> float:
    v = block.get(key)
    if not is_number(v) or v <= 0:
        raise ModelError(f"extended model: {name}.{key} must be a positive number up to {PARAMETER_BOUND:g}, got {v!r}")
    return float(v)


def finite(block: Mapping[str, Any], key: str, name: str) -> float:
    v = block.get(key)
    if not is_number(v):
        raise ModelError(f"extended model: {name}.{key} must be a finite number within +-{PARAMETER_BOUND:g}, "
                         f"got {v!r}")
    return float(v)


def play_weights(block: Mapping[str, Any], key: str, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(thresholds, coefficients) of a play-bank block, checked."""
    try:
        th = np.asarray(block.get("thresholds", []), dtype=float)
        co = np.asarray(block.get(key, []), dtype=float)
    except (TypeError, ValueError):
        raise ModelError(f"extended model: {name} thresholds and {key} must be numbers") from None
    if th.shape != co.shape or th.ndim != 1 or not np.all(np.isfinite(th)) or not np.all(np.isfinite(co)) \
            or np.any(th < 0) or np.any(np.abs(th) > PARAMETER_BOUND) or np.any(np.abs(co) > PARAMETER_BOUND):
        raise ModelError(f"extended model: {name} needs equal-length finite thresholds (>= 0) and {key}, "
                         f"each within +-{PARAMETER_BOUND:g}")
    return th, co


def play_sum(sig: BatchSignals, thresholds: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """sum_j c_j (H_rj[u3] - u3) over a batch, the plays starting as the core's (`PlayStart`;
    relaxed at the run's start without one)."""
    u3 = sig.u3
    u0 = float(u3[0]) if sig.initial_drive is None else float(sig.initial_drive)
    p0 = first_play_outputs(sig.play_start, thresholds, u0)
    return np.asarray((K.play_bank_from(u3, thresholds, p0) - u3[:, None]) @ coefficients)


class PlayBankState:
    """Play operators stepped in plain floats (a step allocates nothing): sum_j c_j (H_rj[u] - u)."""

    def __init__(self, thresholds: np.ndarray, coefficients: np.ndarray) -> None:
        self.th = [float(v) for v in thresholds]
        self.c = [float(v) for v in coefficients]
        self.p = [0.0] * len(self.th)

    def reset(self, u: float, start: "PlayStart | None" = None) -> None:
        """Relaxed at u, or as the core's plays start (`PlayStart`)."""
        for j, p in enumerate(first_play_outputs(start, np.asarray(self.th), u)):
            self.p[j] = float(p)

    def advance(self, u: float) -> float:
        """Move the plays to input u and return sum_j c_j (p_j - u)."""
        acc = 0.0
        for j in range(len(self.p)):
            p = min(max(self.p[j], u - self.th[j]), u + self.th[j])
            self.p[j] = p
            acc += self.c[j] * (p - u)
        return acc

    def peek(self, u: float) -> float:
        """The same sum if the plays moved to u, without moving them."""
        acc = 0.0
        for j in range(len(self.p)):
            acc += self.c[j] * (min(max(self.p[j], u - self.th[j]), u + self.th[j]) - u)
        return acc


class OwnPlays:
    """A stepper state with play operators of its own (`plays`): the stepper calls `start_plays`
    after `reset`, so they start as the core's do."""

    plays: PlayBankState | None

    def start_plays(self, initial_drive: float, start: PlayStart | None) -> None:
        if self.plays is not None:
            self.plays.reset(float(initial_drive), start)


POLISH_LOG_REACH = 0.7   # a polish's log-moves, clipped: e^0.7 ~ 2x either way; it refines the zoom's point,
                         # it does not search anew (that is the grid's job)


def polish_factor(x: Any) -> Any:
    """The multiplier a polish coordinate (a log-move, clipped to POLISH_LOG_REACH) stands for."""
    return np.exp(np.clip(x, -POLISH_LOG_REACH, POLISH_LOG_REACH))


def geom_refine(p: float, ratio: float, level: int = 1) -> list[float]:
    """Points around p on a log scale for zoom level 1, 2, ... of a grid of spacing `ratio`."""
    step = 3.0 ** -level
    return [p * ratio ** (e * step) for e in (-2.0, -1.0, 1.0, 2.0)]


def grid_ratio(grid_lo: float, grid_hi: float, n: int) -> float:
    """Spacing of a geometric grid of n points from grid_lo to grid_hi."""
    return (grid_hi / grid_lo) ** (1.0 / (n - 1))
