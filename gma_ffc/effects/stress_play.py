"""Play weights and loop width (coercive current) that change with stress, which the SDPI assumes they do not."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar, Mapping

import numpy as np

from ..errors import ModelError
from .base import (BatchSignals, EffectBase, FitData, PlayBankState, Regressors, SignatureCheck, SignatureFailure,
                   StepSignals, block_of, finite, play_sum, play_weights)

# relative play-threshold steps at which the core's loop widening is linearised (a chord, not only the
# tangent: a loop that widens by tens of percent across the loads is not linear in the scale)
WIDTH_STEPS = (-0.3, 0.1, 0.3, 1.0)


def widened_core(base: Any, eps: float) -> Any:
    """The core with every play threshold (loop width, coercive current) scaled by 1 + eps."""
    th = getattr(base, "play_thresholds", None)
    if th is None or not dataclasses.is_dataclass(base):
        raise ModelError("extended model: stress_width needs an SDPI/MPI core with play thresholds")
    return dataclasses.replace(base, play_thresholds=np.asarray(th, dtype=float) * (1.0 + eps))  # type: ignore[type-var]


class StressPlay(EffectBase):
    name: ClassVar[str] = "stress_dependent_play"
    keys: ClassVar[tuple[str, ...]] = ("stress_play", "stress_width")
    stage: ClassVar[str] = "sum"
    position: ClassVar[int] = 40
    inverted: ClassVar[Mapping[str, str]] = {
        "stress_play": "using the play states of the previous sample",
        "stress_width": "using the widened core's output at the previous sample's core input"}
    physics: ClassVar[str] = (
        "the play-operator weights and the loop width (the play thresholds, the 'coercive current') change "
        "with stress, which the SDPI assumes they do not")
    n_params: ClassVar[int] = 5

    def __init__(self, base: Any, stress_play: Mapping[str, Any] | None = None,
                 stress_width: Mapping[str, Any] | None = None) -> None:
        self.stress_play = None if stress_play is None else dict(stress_play)
        self.stress_width = None if stress_width is None else dict(stress_width)
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
        sp, sw = block_of(blocks, "stress_play"), block_of(blocks, "stress_width")
        return None if sp is None and sw is None else cls(base, sp, sw)

    def to_blocks(self) -> dict[str, dict[str, Any]]:
        out = {}
        if self.stress_play is not None:
            out["stress_play"] = dict(self.stress_play)
        if self.stress_width is not None:
            out["stress_width"] = dict(self.stress_width)
        return out

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
        if len(levels) < 3:
            return False, (f"the recordings dwell at only {len(levels)} distinct stress level(s) "
                           f"({', '.join(f'{v:.3g}' for v in levels)} MPa): anything else that differs between those "
                           "parts of the data (temperature, drive content, a leftover of another effect) would look "
                           "like a stress dependence; record loops at three or more loads spanning the model's "
                           "stress range")
        return True, ""

    @classmethod
    def grid(cls, fitter: FitData) -> list[float]:
        return list(WIDTH_STEPS)

    @classmethod
    def columns(cls, fitter: FitData, r: Regressors, p: Any) -> None:
        # each play's weight may change linearly with stress (loop shape), and the core's loop may
        # widen with stress (its play thresholds - the coercive current - scaled by 1 + k (s - s_ref))
        ds = fitter.stress(r.d, r.spec) - fitter.stress_ref      # the stress the model sees
        plays = r.shared["plays"]
        for j in range(fitter.play_thresholds.size):
            r.cols.append(ds * (plays[:, j] - r.u3))
            r.names.append(f"stress_play_{j}")
        r.cols.append(ds * cls._width_derivative(fitter, r, float(p)))
        r.names.append("stress_width")

    @staticmethod
    def _width_derivative(fitter: FitData, r: Regressors, eps: float) -> np.ndarray:
        """(y_c with play thresholds x (1 + eps) - y_c) / eps: how the core's output moves as its loop widens."""
        d = r.d

        def compute() -> np.ndarray:
            model = fitter.model
            wide = widened_core(model, eps)
            s = fitter.stress(d, r.spec) if model.stress_range_MPa is not None else None
            return (np.asarray(wide.simulate(d.t, r.u3, s, initial_play_state=d.start.play_state), dtype=float)
                    - r.yc) / eps

        return fitter.cached(("stress_width", id(d), r.input_key, eps), compute)

    @classmethod
    def fitted_params(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, float]:
        out = {f"coef_{j}_um_per_A_MPa": coef.get(f"stress_play_{j}", math.nan)
               for j in range(fitter.play_thresholds.size)}
        out["loop_width_change_per_MPa"] = coef.get("stress_width", math.nan)
        out["width_chord_step"] = float(p)
        return out

    @classmethod
    def fitted_blocks(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, dict[str, Any]]:
        out: dict[str, dict[str, Any]] = {
            "stress_play": {"thresholds": [float(v) for v in fitter.play_thresholds],
                            "coefficients_per_MPa": [coef[f"stress_play_{j}"]
                                                     for j in range(fitter.play_thresholds.size)]}}
        if "stress_width" in coef:
            out["stress_width"] = {"coef_per_MPa": coef["stress_width"], "eps": float(p)}
        return out

    @classmethod
    def signature(cls, check: SignatureCheck) -> SignatureFailure | None:
        """Play weights are rate-independent, so the gain must hold where the drive is slow."""
        f = check.fitter
        slow = f.rate_rows <= np.percentile(f.rate_rows, 40)
        r0 = f.test_residuals(check.before)[slow]
        r1 = f.test_residuals(check.result.specs)[slow]
        ratio = float(np.mean(r1 * r1) / max(float(np.mean(r0 * r0)), 1e-300))
        if ratio <= check.slow_ratio_max:
            return None
        return SignatureFailure(
            f"its held-out gain comes from the fast parts of the drive (on the slowest 40 % of samples the error "
            f"only falls to {ratio:.0%} of before), where rate-independent play weights cannot be the cause: a "
            "leftover of another effect that changes with the load")

    @staticmethod
    def describe(params: Mapping[str, float], unit: str) -> str:
        k = params.get("loop_width_change_per_MPa", math.nan)
        if not math.isfinite(k):
            return "play weights (loop width) that change with stress"
        return (f"play weights and a loop width (coercive current) that change with stress: the width grows by "
                f"{-k * 100:.2g} % per MPa of extra compression")


class _StressPlayState:
    def __init__(self, m: StressPlay, dt: float) -> None:
        self.m = m
        self.dt = dt
        self.plays = PlayBankState(m.thresholds, m.coefficients) if m.thresholds.size else None
        self.wide: Any = None
        self.width_prev = 0.0          # inverse: (y_c,wide - y_c) / eps at the previous sample

    def reset(self, initial_drive: float) -> None:
        u1 = float(initial_drive)
        if self.plays is not None:
            self.plays.reset(u1)
        if self.m.wide is not None:
            if self.wide is None:
                self.wide = self.m.wide.forward_stepper(self.dt, initial_drive=u1)
            else:
                self.wide.reset(u1)
        self.width_prev = 0.0

    def step(self, x: StepSignals) -> None:
        if self.plays is not None:
            x.y += x.ds * self.plays.advance(x.u3)
        if self.wide is not None:
            x.y += self.m.k * x.ds * (float(self.wide.step(x.u3, x.s)) - x.yc) / self.m.eps

    def inverse_step(self, x: StepSignals) -> None:
        if self.plays is not None:
            x.const += x.ds * self.plays.peek(x.u3_prev)
        if self.wide is not None:
            x.const += self.m.k * x.ds * self.width_prev

    def commit(self, x: StepSignals) -> None:
        if self.wide is not None:
            self.width_prev = (float(self.wide.step(x.u3, x.s)) - x.yc) / self.m.eps
        if self.plays is not None:
            self.plays.advance(x.u3)
