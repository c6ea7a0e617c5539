"""A test-only effect, written as a new effect would be: one file, registered with one line.

Mains pickup: the displacement sensor picks up the mains (50 or 60 Hz) as a sinusoid of fixed
amplitude and phase, whatever the actuator does. A sum-stage term a sin(2 pi f t) + b cos(2 pi f t):
linear in (a, b) once f is chosen, known at every sample, so the inverse subtracts it exactly.
Time is counted from the first sample (batch: t - t[0]; stepper: from its reset).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Mapping

import numpy as np

from gma_ffc.effects.base import (BatchSignals, EffectBase, FitData, Regressors, StepSignals, finite,
                                  positive)


class MainsPickup(EffectBase):
    name: ClassVar[str] = "mains_pickup"
    keys: ClassVar[tuple[str, ...]] = ("mains_pickup",)
    block_keys: ClassVar[Mapping[str, tuple[str, ...]]] = {"mains_pickup": ("f_hz", "sin_um", "cos_um")}
    stage: ClassVar[str] = "sum"
    position: ClassVar[int] = 55
    inverted: ClassVar[Mapping[str, str]] = {"mains_pickup": "exact (a known sinusoid, subtracted)"}
    physics: ClassVar[str] = "the sensor picks up the mains as a sinusoid of fixed amplitude and phase"
    n_params: ClassVar[int] = 3

    def __init__(self, block: Mapping[str, Any]) -> None:
        super().__init__(block)
        self.f_hz = positive(block, "f_hz", "mains_pickup")
        self.a = finite(block, "sin_um", "mains_pickup")
        self.b = finite(block, "cos_um", "mains_pickup")

    def apply(self, y: np.ndarray, sig: BatchSignals) -> np.ndarray:
        w = 2 * math.pi * self.f_hz * (sig.t - sig.t[0])
        return y + self.a * np.sin(w) + self.b * np.cos(w)

    def state(self, dt: float, stress_ref: float, inverse: bool) -> "_State":
        return _State(self, dt)

    @classmethod
    def grid(cls, fitter: FitData) -> list[float]:
        return [50.0, 60.0]

    @classmethod
    def columns(cls, fitter: FitData, r: Regressors, p: Any) -> None:
        w = 2 * math.pi * p * (r.d.t - r.d.t[0])
        r.cols += [np.sin(w), np.cos(w)]
        r.names += ["mains_sin", "mains_cos"]

    @classmethod
    def fitted_params(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, float]:
        return {"f_hz": p, "sin_um": coef.get("mains_sin", math.nan), "cos_um": coef.get("mains_cos", math.nan)}

    @classmethod
    def fitted_blocks(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, dict[str, Any]]:
        return {"mains_pickup": {"f_hz": p, "sin_um": coef["mains_sin"], "cos_um": coef["mains_cos"]}}

    @staticmethod
    def describe(params: Mapping[str, float], unit: str) -> str:
        return f"mains pickup at {params['f_hz']:g} Hz of {math.hypot(params['sin_um'], params['cos_um']):.3g} um"


class _State:
    def __init__(self, m: MainsPickup, dt: float) -> None:
        self.m = m
        self.dw = 2 * math.pi * m.f_hz * dt
        self.k = 0

    def reset(self, initial_drive: float) -> None:
        self.k = 0

    def _term(self) -> float:
        w = self.dw * self.k
        self.k += 1
        return self.m.a * math.sin(w) + self.m.b * math.cos(w)

    def step(self, x: StepSignals) -> None:
        x.y += self._term()

    def inverse_step(self, x: StepSignals) -> None:
        x.const += self._term()

    def commit(self, x: StepSignals) -> None:
        pass
