"""Play weights and loop width (coercive current) that change with stress, which the SDPI assumes they do not.

Two blocks. `stress_play`: each play's weight changes linearly with stress (a sum-stage term).
`loop_width`: the core's play thresholds, the loop's width in drive units, scale with stress,
g(sigma) = 1 + kappa (sigma_w - sigma), as pinning grows with compression. That is a different
core, not a term beside it: the core is run with the widened thresholds (`WidenedCore`, exactly
inverted by the widened kernels of `gma_ffc.operators`). Files written before it carry the older
`stress_width` block (a chord linearisation of the widening in its size), which still loads and runs.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar, Mapping

import numpy as np

from .. import operators as ops
from ..errors import ModelError
from ..initial_state import ResolvedInitialState, settled_index
from .base import (BatchSignals, CoreAround, EffectBase, FitData, OwnPlays, PlayBankState, Regressors,
                   SignatureCheck, SignatureFailure, StepSignals, block_of, finite, geom_refine, play_sum,
                   play_weights)

# the loop-width search: relative width changes per MPa of 1 % to 30 %, either sign (a few % per MPa
# is what pinning in Terfenol-D does; past 30 % per MPa the width would halve or double within 2-3 MPa)
WIDTH_GRID = (-0.3, -0.1, -0.03, -0.01, 0.0, 0.01, 0.03, 0.1, 0.3)
WIDTH_RATIO = 10.0 ** 0.5            # the grid's spacing, for the local refinement


def widened_core(base: Any, eps: float) -> Any:
    """The core with every play threshold scaled by 1 + eps (the older `stress_width` block's chord)."""
    th = getattr(base, "play_thresholds", None)
    if th is None or not dataclasses.is_dataclass(base):
        raise ModelError("extended model: stress_width needs an SDPI/MPI core with play thresholds")
    return dataclasses.replace(base, play_thresholds=np.asarray(th, dtype=float) * (1.0 + eps))  # type: ignore[type-var]


class WidenedCore(CoreAround):
    """An SDPI core whose play thresholds are scaled by g(sigma) = max(1 + kappa (sigma_w - sigma), 0.05)
    at each sample's (clamped) stress: the loop widens by kappa per MPa of extra compression.

    It runs where the plain core runs (batch, steppers, inverse). Its initial state is the plain
    core's rule applied to the core as it is where the run starts (`at_stress`)."""

    def __init__(self, base: Any, kappa: float, sigma_w: float) -> None:
        if getattr(base, "stress_range_MPa", None) is None or not hasattr(base, "_packed"):
            raise ModelError("extended model: loop_width needs an SDPI core (a model with stress terms)")
        self.base = base
        self.kappa = float(kappa)
        self.sigma_w = float(sigma_w)

    def state(self, initial_drive: float, play_state: Any = None) -> np.ndarray:
        """Kernel state: the plain core's forward state, plus the widened inverse's scratch."""
        return self._widen_state(self.base.forward_state(initial_drive, play_state))

    def _widen_state(self, plain: np.ndarray) -> np.ndarray:
        st = np.zeros(ops.widened_state_size(self.base.n_play, self.base.n_deadzone))
        st[: plain.size] = plain
        return st

    def at_stress(self, stress_MPa: float) -> Any:
        """The plain core this one is at one (clamped) stress: every play threshold scaled by g, the
        kernels' own `width_factor`."""
        return widened_core(self.base, ops.width_factor(float(stress_MPa), self.kappa, self.sigma_w) - 1.0)

    def resolve_initial_state(self, drive: Any, stress_MPa: Any = None, initial_state: Any = None,
                              measured_um: Any = None, time_s: Any = None) -> Any:
        """The `gma_ffc.initial_state` rule, applied to the core at the run's starting stress (the
        median of the clamped stress until the plain core settles). The play states then hold the
        loop width this core runs with. The plain core's estimate fits the start through loops of
        another width, and misses: the twenty-seventh never-tuned draw's run 12 MPa beyond the
        reference stress started 1.7 um off, and its whole run stayed 0.6 um off."""
        if stress_MPa is None or isinstance(initial_state, ResolvedInitialState):
            return self.base.resolve_initial_state(drive, stress_MPa, initial_state, measured_um, time_s)
        x = np.asarray(drive, dtype=float)
        s = self.base._stress_array(stress_MPa, x.size)            # checked, clamped to the model's range
        end = max(1, settled_index(self.base, x))
        return self.at_stress(float(np.median(s[:end]))).resolve_initial_state(drive, s, initial_state,
                                                                                measured_um, time_s)

    def simulate(self, time_s: Any, drive: Any, stress_MPa: Any = None, initial_drive: float | None = None,
                 initial_play_state: Any = None, initial_state: Any = None, measured_um: Any = None) -> np.ndarray:
        """As `SDPIModel.simulate` (the same checks and start), with the widened thresholds."""
        x, s, plain = self.base.batch_start(time_s, drive, stress_MPa, initial_drive, initial_play_state,
                                            initial_state, measured_um)
        out = np.empty_like(x)
        ops.forward_batch_widened(x, s, self.kappa, self.sigma_w, self.base._packed, self._widen_state(plain), out)
        if self.base.output_sign < 0:
            np.negative(out, out=out)
        return out

    def forward_stepper(self, dt_s: float = 0.0, initial_drive: float = 0.0) -> "WidenedForwardStepper":
        return WidenedForwardStepper(self, initial_drive)

    def inverse_stepper(self, dt_s: float = 0.0, initial_drive: float = 0.0) -> "WidenedInverseStepper":
        return WidenedInverseStepper(self, initial_drive)


class WidenedForwardStepper:
    """One sample in, one displacement out; nothing allocated per step."""

    __slots__ = ("_core", "_p", "_k", "_sw", "_sign", "_state")

    def __init__(self, core: WidenedCore, initial_drive: float = 0.0) -> None:
        self._core = core
        self._p = core.base._packed
        self._k, self._sw = core.kappa, core.sigma_w
        self._sign = float(core.base.output_sign)
        self._state = core.state(initial_drive)

    def reset(self, initial_drive: float = 0.0, play_state: Any = None) -> None:
        self._state[:] = self._core.state(initial_drive, play_state)

    def step(self, drive: float, stress_MPa: float = 0.0) -> float:
        return self._sign * ops.forward_step_widened(drive, stress_MPa, self._k, self._sw, self._p, self._state)


class WidenedInverseStepper(WidenedForwardStepper):
    """One reference sample in, one drive out: the exact inverse of `WidenedForwardStepper`."""

    __slots__ = ()

    def step(self, reference_um: float, stress_MPa: float = 0.0) -> float:
        return ops.inverse_step_widened(self._sign * reference_um, stress_MPa, self._k, self._sw, self._p,
                                        self._state)

    def peek(self, reference_um: float, stress_MPa: float = 0.0) -> float:
        """What `step` would return, without moving the state."""
        return ops.inverse_peek_widened(self._sign * reference_um, stress_MPa, self._k, self._sw, self._p,
                                        self._state)


class StressPlay(EffectBase):
    name: ClassVar[str] = "stress_dependent_play"
    keys: ClassVar[tuple[str, ...]] = ("stress_play", "loop_width", "stress_width")
    block_keys: ClassVar[Mapping[str, tuple[str, ...]]] = {
        "stress_play": ("thresholds", "coefficients_per_MPa"), "loop_width": ("kappa_per_MPa", "stress_ref_MPa"),
        "stress_width": ("eps", "coef_per_MPa")}
    stage: ClassVar[str] = "sum"
    follows_drive: ClassVar[bool] = True
    position: ClassVar[int] = 40
    inverted: ClassVar[Mapping[str, str]] = {
        "stress_play": "exactly: solved together with the core's inverse for each sample's core input",
        "loop_width": "exactly: the widened core's own inverse (each sample's piecewise-linear play sum solved)",
        "stress_width": "exactly: the widened core's output solved together with the core's inverse"}
    physics: ClassVar[str] = (
        "the play-operator weights and the loop width (the play thresholds, the 'coercive current') change "
        "with stress, which the SDPI assumes they do not")
    physics_voltage: ClassVar[str | None] = (
        "the play-operator weights and the loop width (the play thresholds, the 'coercive voltage') change "
        "with stress, which the SDPI assumes they do not")
    n_params: ClassVar[int] = 4          # the width law's slope and a weight slope for each of the 3 plays
    shapes_core: ClassVar[bool] = True
    without_identification: ClassVar[str] = (
        "its loop-width law was fitted to these recordings alone; with the identification recordings (--ident) "
        "the core would be identified again through it on the loops at every load the model was identified at")

    def __init__(self, base: Any, stress_play: Mapping[str, Any] | None = None,
                 stress_width: Mapping[str, Any] | None = None, loop_width: Mapping[str, Any] | None = None) -> None:
        self.stress_play = None if stress_play is None else dict(stress_play)
        self.stress_width = None if stress_width is None else dict(stress_width)
        self.loop_width = None if loop_width is None else dict(loop_width)
        if loop_width is not None:
            self.kappa = finite(loop_width, "kappa_per_MPa", "loop_width")
            self.sigma_w = finite(loop_width, "stress_ref_MPa", "loop_width")
            WidenedCore(base, self.kappa, self.sigma_w)        # refuses a core without stress terms
        self.thresholds: np.ndarray
        self.coefficients: np.ndarray
        self.thresholds, self.coefficients = (np.zeros(0), np.zeros(0)) if stress_play is None else \
            play_weights(stress_play, "coefficients_per_MPa", "stress_play")
        self.wide = None
        if stress_width is not None:
            e = stress_width.get("eps")
            if not isinstance(e, (int, float)) or not math.isfinite(e) or e == 0 or e <= -0.9:
                raise ModelError(f"extended model: stress_width.eps must be a non-zero number above -0.9, got {e!r}")
            self.k = finite(stress_width, "coef_per_MPa", "stress_width")
            self.eps = float(e)
            self.wide = widened_core(base, self.eps)

    @classmethod
    def from_blocks(cls, blocks: Mapping[str, Any], base: Any) -> "StressPlay | None":
        sp, sw, lw = (block_of(blocks, k) for k in ("stress_play", "stress_width", "loop_width"))
        return None if sp is None and sw is None and lw is None else cls(base, sp, sw, lw)

    def to_blocks(self) -> dict[str, dict[str, Any]]:
        out = {}
        for key, block in (("stress_play", self.stress_play), ("loop_width", self.loop_width),
                           ("stress_width", self.stress_width)):
            if block is not None:
                out[key] = dict(block)
        return out

    def inverted_text(self) -> Mapping[str, str]:
        return {k: self.inverted[k] for k in self.to_blocks()}

    def wrap_core(self, core: Any) -> Any:
        return core if self.loop_width is None else WidenedCore(core, self.kappa, self.sigma_w)

    def apply(self, y: np.ndarray, sig: BatchSignals) -> np.ndarray:
        if self.thresholds.size:
            y = y + sig.ds * play_sum(sig, self.thresholds, self.coefficients)
        if self.wide is not None:
            if sig.initial_drive is None:
                yw = np.asarray(self.wide.simulate(sig.t, sig.u3, sig.stress_arg), dtype=float)
            else:
                yw = np.asarray(self.wide.simulate(sig.t, sig.u3, sig.stress_arg,
                                                   initial_drive=float(sig.initial_drive)), dtype=float)
            y = y + self.k * sig.ds * (yw - sig.yc) / self.eps
        return y

    def state(self, dt: float, stress_ref: float, inverse: bool) -> "_StressPlayState":
        return _StressPlayState(self, dt)

    # ---- diagnosis
    @classmethod
    def testable(cls, fitter: FitData) -> tuple[bool, str]:
        if fitter.model.stress_range_MPa is None:
            return False, ("the model is stress-independent (MPI), so a stress dependence of the play weights "
                           "cannot be tested; identify an SDPI from recordings at several loads")
        if not fitter.stress_varies:
            return False, ("all recordings are at (nearly) one stress, so play weights that change with stress "
                           "cannot be told from ordinary hysteresis error; record loops at three or more loads "
                           "spanning the model's stress range")
        levels = fitter.stress_levels()
        if len(levels) < 3 and len(fitter.identification_levels()) >= 3:
            # the width law is fitted on the identification loops, at their three or more loads, not on
            # the differences between these recordings' few levels: they only judge it
            return True, ""
        if len(levels) < 3:
            return False, (f"the recordings dwell at only {len(levels)} distinct stress level(s) "
                           f"({', '.join(f'{v:.3g}' for v in levels)} MPa): anything else that differs between those "
                           "parts of the data (temperature, drive content, a leftover of another effect) would look "
                           "like a stress dependence; record loops at three or more loads spanning the model's "
                           "stress range")
        return True, ""

    @classmethod
    def lost_without_identification(cls, fitter: FitData) -> str:
        """What --ident would have added: the law fitted on the identification loops, and (when these
        recordings dwell at fewer than three loads) the test itself."""
        if fitter.model.stress_range_MPa is None or not fitter.stress_varies:
            return ""
        if len(fitter.stress_levels()) < 3:
            return ("with the identification recordings (--ident), at the loads the model was identified at, its "
                    "loop-width law could be fitted on those loops and tested on these recordings' few loads")
        return cls.without_identification

    @classmethod
    def count_params(cls, fitter: FitData) -> int:
        """With the identification loops, the width law alone (the core identified again through it
        carries the stress dependence those loops show); else its slope and the plays' weight slopes."""
        return 1 if fitter.identification else cls.n_params

    @classmethod
    def fitted_on_loops(cls, fitter: FitData) -> bool:
        """With the identification loops: the width law is fitted on them, the core identified again
        on them through it, and no weight slope is fitted on these recordings (`columns`)."""
        return bool(fitter.identification)

    @classmethod
    def grid(cls, fitter: FitData) -> list[float]:
        """The loop-width law: fitted on the identification loops when the diagnosis has them (one
        point: the core is identified again through it), else searched on these recordings."""
        if fitter.identification:
            return [width_law(fitter)]
        return list(WIDTH_GRID)

    @classmethod
    def refine(cls, fitter: FitData, p: Any, level: int) -> list[float] | None:
        """Around p, within the grid's range: a width law beyond 30 % per MPa is not the physics
        searched for (the refinement of an edge point would otherwise leave it). None when the law
        was fitted on the identification loops."""
        if fitter.identification:
            return None
        top = max(abs(v) for v in WIDTH_GRID)
        return [v for v in geom_refine(float(p), WIDTH_RATIO, level) if abs(v) <= top]

    @classmethod
    def fit_core(cls, fitter: FitData, core: Any, p: Any) -> WidenedCore:
        """The core the diagnosis runs for loop-width change p (per MPa): the base's widened about the
        data's mean stress, or, with the identification loops, the core identified again on them
        through the width law about the model's reference stress."""
        ref = width_reference(fitter)
        again = fitter.identified_core((float(p), ref))
        return WidenedCore(core if again is None else again, float(p), ref)

    @classmethod
    def columns(cls, fitter: FitData, r: Regressors, p: Any) -> None:
        # each play's weight may change linearly with stress (loop shape); the loop's width is in
        # the core the spec runs (fit_core). With the identification loops, the core identified again
        # through the width law carries what they show of the stress dependence: no weight slopes
        # fitted to these recordings' few loads beside it
        if fitter.identification:
            return
        ds = fitter.stress(r.d, r.spec) - fitter.stress_ref      # the stress the model sees
        plays = r.shared["plays"]
        for j in range(fitter.play_thresholds.size):
            r.cols.append(ds * (plays[:, j] - r.u3))
            r.names.append(f"stress_play_{j}")

    @classmethod
    def fitted_params(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, float]:
        out = {f"coef_{j}_um_per_A_MPa": coef[f"stress_play_{j}"]
               for j in range(fitter.play_thresholds.size) if f"stress_play_{j}" in coef}
        out["loop_width_change_per_MPa"] = float(p)
        return out

    @classmethod
    def fitted_blocks(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, dict[str, Any]]:
        out: dict[str, dict[str, Any]] = {}
        if "stress_play_0" in coef:
            out["stress_play"] = {"thresholds": [float(v) for v in fitter.play_thresholds],
                                  "coefficients_per_MPa": [coef[f"stress_play_{j}"]
                                                           for j in range(fitter.play_thresholds.size)]}
        out["loop_width"] = {"kappa_per_MPa": float(p), "stress_ref_MPa": float(width_reference(fitter))}
        return out

    @classmethod
    def signature(cls, check: SignatureCheck) -> SignatureFailure | None:
        """Play weights are rate-independent, so the gain must hold where the drive is slow: at its
        holds, or at its turns alone. After a step the core's minor loops may miss by more than the
        width law changes (the sixteenth never-tuned draw: an MPI fitted to each load alone misses
        its steps by 0.5 um, its loops by 0.1-0.25 um), so the holds may keep their error while the
        turns gain; on other recordings the gain is at the holds. A rate effect's leftover vanishes
        at both."""
        return check.gain_from_fast_parts("rate-independent play weights cannot be the cause, so this is the "
                                          "leftover of another effect that changes with the load", turns_alone=True)

    @staticmethod
    def describe(params: Mapping[str, float], unit: str) -> str:
        k = params.get("loop_width_change_per_MPa", math.nan)
        if not math.isfinite(k):
            return "play weights (loop width) that change with stress"
        coercive = "coercive current" if unit == "A" else "coercive voltage"
        return (f"play weights and a loop width ({coercive}) that change with stress: the width "
                f"{'grows' if k > 0 else 'shrinks'} by {abs(k) * 100:.2g} % per MPa of extra compression")


def width_reference(fitter: FitData) -> float:
    """The stress at which the loop width is the core's own: the model's reference stress (that of
    its identification's first step) when the core is identified again through the law, else the
    data's mean stress (the base's loops are kept where the data are)."""
    if fitter.identification:
        ref = getattr(fitter.model, "reference_stress_MPa", None)
        if ref is not None:
            return float(ref)
    return float(fitter.stress_ref)


WIDTH_LAW_ROUNDS = 3      # halvings of the step about the best grid point (to 1/8 of the grid's spacing)


def width_law(fitter: FitData) -> float:
    """The loop width's change per MPa that best fits the identification loops, the core identified
    again through it at each value tried (the grid, then steps halved about the best): the loops
    were recorded at every load, so the law follows stress where the diagnosis recordings' few
    loads cannot say."""
    ref = width_reference(fitter)

    def error(k: float) -> float:
        core = fitter.identified_core((k, ref))
        fit = getattr(core, "provenance", {}).get("reidentified", {}).get("fit_rms_um", {}) if core else {}
        vals = [float(v) for v in fit.values()]
        return float(np.sqrt(np.mean(np.square(vals)))) if vals else math.inf

    tried = {k: error(k) for k in WIDTH_GRID}
    best = min(tried, key=lambda k: (tried[k], abs(k)))
    step = min((abs(a - b) for a in WIDTH_GRID for b in WIDTH_GRID if a != b and (a == best or b == best)))
    for _ in range(WIDTH_LAW_ROUNDS):
        step /= 2
        for k in (best - step, best + step):
            if abs(k) <= max(abs(v) for v in WIDTH_GRID) and k not in tried:
                tried[k] = error(k)
        best = min(tried, key=lambda k: (tried[k], abs(k)))
    return float(best)


class _StressPlayState(OwnPlays):
    def __init__(self, m: StressPlay, dt: float) -> None:
        self.m = m
        self.dt = dt
        self.plays = PlayBankState(m.thresholds, m.coefficients) if m.thresholds.size else None
        self.wide: Any = None
        self.reads_input = self.plays is not None or m.wide is not None

    def reset(self, initial_drive: float) -> None:
        u1 = float(initial_drive)
        if self.plays is not None:
            self.plays.reset(u1)
        if self.m.wide is not None:
            if self.wide is None:
                self.wide = self.m.wide.forward_stepper(self.dt, initial_drive=u1)
            else:
                self.wide.reset(u1)

    def step(self, x: StepSignals) -> None:
        if self.plays is not None:
            x.y += x.ds * self.plays.advance(x.u3)
        if self.wide is not None:
            x.y += self.m.k * x.ds * (float(self.wide.step(x.u3, x.s)) - x.yc) / self.m.eps

    def inverse_step(self, x: StepSignals) -> None:
        if self.plays is not None:
            x.const += x.ds * self.plays.peek(x.u3_at)
        if self.wide is not None:        # k ds (y_c,wide - y_c) / eps: its y_c part is linear in this sample's y_c
            c = self.m.k * x.ds / self.m.eps
            x.const += c * float(self.wide.peek(x.u3_at, x.s))
            x.lin -= c

    def commit(self, x: StepSignals) -> None:
        if self.wide is not None:
            self.wide.step(x.u3, x.s)
        if self.plays is not None:
            self.plays.advance(x.u3)
