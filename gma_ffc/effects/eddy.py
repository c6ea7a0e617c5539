"""Eddy currents / magnetic diffusion: the field in the rod lags the coil current (first-order lag)."""

from __future__ import annotations

from typing import Any, ClassVar, Mapping

import numpy as np

from . import kernels as K
from .base import EffectBase, FitData, StepSignals, geom_refine, grid_ratio, positive


class EddyLag(EffectBase):
    name: ClassVar[str] = "rate_dependence"
    keys: ClassVar[tuple[str, ...]] = ("eddy_lag",)
    block_keys: ClassVar[Mapping[str, tuple[str, ...]]] = {"eddy_lag": ("tau_s",)}
    stage: ClassVar[str] = "input"
    follows_drive: ClassVar[bool] = True
    position: ClassVar[int] = 10
    inverted: ClassVar[Mapping[str, str]] = {"eddy_lag": "exact inverse filter"}
    physics: ClassVar[str] = (
        "eddy currents / magnetic diffusion: the field in the rod lags the coil current by a time constant "
        "(first-order lag), so loops widen and tilt as the drive gets faster")
    physics_voltage: ClassVar[str | None] = (
        "a first-order lag between the drive voltage and the actuator's response (the amplifier charging the "
        "stack's capacitance through its output resistance, or a filter in the drive or sensor path), so "
        "loops widen and tilt as the drive gets faster")
    n_params: ClassVar[int] = 1
    joint_with: ClassVar[tuple[str, ...]] = ("time_delay", "mechanical_dynamics")
    told_by_frequency: ClassVar[bool] = True

    def __init__(self, block: Mapping[str, Any]) -> None:
        super().__init__(block)
        self.tau_s = positive(block, "tau_s", "eddy_lag")

    def apply_input(self, u: np.ndarray, dt: np.ndarray, dt_med: float, u0: float) -> np.ndarray:
        return K.lag_filter(u, dt, self.tau_s, u0)

    def state(self, dt: float, stress_ref: float, inverse: bool) -> "_LagState":
        return _LagState(K.lag_coeff(dt, self.tau_s))

    # ---- diagnosis
    @classmethod
    def grid(cls, fitter: FitData) -> np.ndarray:
        return np.geomspace(0.25 * fitter.dt_min, min(0.5, max(fitter.duration_max / 10, 2 * fitter.dt_min)), 16)

    @classmethod
    def refine(cls, fitter: FitData, p: Any, level: int) -> list[float]:
        return geom_refine(p, grid_ratio(1, 8000, 16), level)

    @classmethod
    def filter_input(cls, u: np.ndarray, d: Any, p: Any) -> np.ndarray:
        """The diagnosis' core input through this effect (a recording's time steps)."""
        return K.lag_filter(u, d.dt, p, float(u[0]))

    @classmethod
    def fitted_params(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, float]:
        return {"tau_s": p}

    @classmethod
    def fitted_blocks(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, dict[str, Any]]:
        return {"eddy_lag": {"tau_s": p}}

    @staticmethod
    def describe(params: Mapping[str, float], unit: str) -> str:
        what = "an eddy-current lag" if unit == "A" else "a first-order lag"   # a voltage drive has no coil
        return f"{what} of tau = {params['tau_s'] * 1e3:.3g} ms"


class _LagState:
    def __init__(self, a: float) -> None:
        self.a = a
        self.z = 0.0

    def reset(self, initial_drive: float) -> None:
        self.z = float(initial_drive)          # forward: the lag's state; inverse: the previous core input

    def step(self, x: StepSignals) -> None:
        self.z = self.a * self.z + (1.0 - self.a) * x.u3
        x.u3 = self.z

    def inverse_step(self, x: StepSignals) -> None:
        out = x.u3
        x.u3 = (out - self.a * self.z) / (1.0 - self.a)
        self.z = out

    def commit(self, x: StepSignals) -> None:
        pass
