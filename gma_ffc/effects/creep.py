"""Creep: slow, distributed relaxation of the displacement after the drive changes."""

from __future__ import annotations

from typing import Any, ClassVar, Mapping

import numpy as np

from . import kernels as K
from .base import (BatchSignals, EffectBase, FitData, Regressors, StepSignals, finite, geom_refine, grid_ratio,
                   positive)

CREEP_SPREAD = (0.1, 1.0, 10.0)   # time constants relative to tau_s: a distributed (log-like) relaxation
MIN_CREEP_TAU_S = 1.0             # creep's central time constant (its components span 0.1x..10x of it)


class Creep(EffectBase):
    name: ClassVar[str] = "creep"
    keys: ClassVar[tuple[str, ...]] = ("creep",)
    stage: ClassVar[str] = "sum"
    follows_drive: ClassVar[bool] = True    # lag(y_c) - y_c: at a loop's rate, a loss of gain the base absorbed
    position: ClassVar[int] = 60
    inverted: ClassVar[Mapping[str, str]] = {"creep": "exact (closed form with the static map)"}
    physics: ClassVar[str] = "slow relaxation of the displacement after the drive changes, in the direction of the last change"
    n_params: ClassVar[int] = 2
    slow: ClassVar[bool] = True

    def __init__(self, block: Mapping[str, Any]) -> None:
        super().__init__(block)
        self.gain = finite(block, "gain", "creep")
        self.tau_s = positive(block, "tau_s", "creep")

    def apply(self, y: np.ndarray, sig: BatchSignals) -> np.ndarray:
        return y + self.gain * relaxation(sig.yc, sig.dt, self.tau_s)

    def state(self, dt: float, stress_ref: float, inverse: bool) -> "_CreepState":
        return _CreepState(self.gain, [K.lag_coeff(dt, self.tau_s * k) for k in CREEP_SPREAD])

    # ---- diagnosis
    @classmethod
    def grid(cls, fitter: FitData) -> np.ndarray:
        # creep is slow: its fastest component (tau / 10) is no quicker than 0.1 s, else it is a lag look-alike
        lo = max(20 * fitter.dt_min, MIN_CREEP_TAU_S)
        hi = max(fitter.duration_max / 2, 2 * lo)
        return np.geomspace(lo, hi, 12)

    @classmethod
    def refine(cls, fitter: FitData, p: Any, level: int) -> list[float]:
        g = cls.grid(fitter)            # zoom by the spacing of creep's own grid, which follows the recording
        return [max(q, MIN_CREEP_TAU_S) for q in geom_refine(p, grid_ratio(g[0], g[-1], g.size), level)]

    @classmethod
    def columns(cls, fitter: FitData, r: Regressors, p: Any) -> None:
        r.cols.append(relaxation(r.yc, r.d.dt, p))
        r.names.append("creep_gain")

    @classmethod
    def fitted_params(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, float]:
        return {"tau_s": p, "gain": coef.get("creep_gain", float("nan"))}

    @classmethod
    def fitted_blocks(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, dict[str, Any]]:
        return {"creep": {"gain": coef["creep_gain"], "tau_s": p}}

    @staticmethod
    def describe(params: Mapping[str, float], unit: str) -> str:
        return (f"creep of {params['gain'] * 100:+.3g} % of each step relaxing over time constants around "
                f"{params['tau_s']:.3g} s (0.1x to 10x)")


def relaxation(yc: np.ndarray, dt: np.ndarray, tau_s: float) -> np.ndarray:
    """mean_k (lag(y_c, tau s_k) - y_c): the creep term per unit gain."""
    acc = np.zeros_like(yc)
    for k in CREEP_SPREAD:
        acc += K.lag_filter(yc, dt, tau_s * k, float(yc[0])) - yc
    return acc / len(CREEP_SPREAD)


class _CreepState:
    """Forward: the lags of y_c. Inverse: their term g mean_k a_k (z_k - yc) is linear in this sample's
    y_c, so it joins the static map's closed-form root (exact)."""

    def __init__(self, gain: float, a: list[float]) -> None:
        self.g = gain
        self.a = a
        self.z = [0.0] * len(a)
        self.first = True

    def reset(self, initial_drive: float) -> None:
        for k in range(len(self.z)):
            self.z[k] = 0.0
        self.first = True

    def step(self, x: StepSignals) -> None:
        yc = x.yc
        acc = 0.0
        for k in range(len(self.z)):
            z = yc if self.first else self.a[k] * self.z[k] + (1.0 - self.a[k]) * yc
            self.z[k] = z
            acc += z - yc
        x.y += self.g * acc / len(self.z)
        self.first = False

    def inverse_step(self, x: StepSignals) -> None:
        if self.first:
            return
        n = len(self.z)
        ga = 0.0
        zc = 0.0
        for k in range(n):
            ga += self.g * self.a[k] / n
            zc += self.g * self.a[k] * self.z[k] / n
        x.const += zc
        x.lin -= ga

    def commit(self, x: StepSignals) -> None:
        yc = x.yc
        for k in range(len(self.z)):
            self.z[k] = yc if self.first else self.a[k] * self.z[k] + (1.0 - self.a[k]) * yc
        self.first = False
