"""A transport delay in the amplifier, sensor or acquisition: the whole response shifts in time."""

from __future__ import annotations

import math
from typing import Any, ClassVar, Mapping

import numpy as np

from ..errors import ModelError
from . import kernels as K
from .base import EffectBase, FitData, StepSignals, geom_refine, grid_ratio, is_number

# The longest delay a model file may hold. A transport delay in an actuator's path is micro- to
# milliseconds, and diagnose's grid stops at 0.2 s, or a quarter sample at slower rates (15 s at a
# 1-minute sample). A longer one is an edit, and the stepper's ring buffer holds delay / dt samples:
# 60 s at a 10 kHz controller is 600,000; 1e30 s is no buffer at all (an OverflowError).
MAX_DELAY_S = 60.0


class Delay(EffectBase):
    name: ClassVar[str] = "time_delay"
    keys: ClassVar[tuple[str, ...]] = ("delay",)
    block_keys: ClassVar[Mapping[str, tuple[str, ...]]] = {"delay": ("delay_s",)}
    stage: ClassVar[str] = "input"
    follows_drive: ClassVar[bool] = True
    position: ClassVar[int] = 20
    inverted: ClassVar[Mapping[str, str]] = {
        "delay": "by preview of the known reference (batch invert); inverse_stepper expects reference(t + preview_s)"}
    physics: ClassVar[str] = (
        "a transport delay in the amplifier, sensor or acquisition: the whole response shifts in time, "
        "so its phase lag grows in proportion to frequency")
    n_params: ClassVar[int] = 1
    joint_with: ClassVar[tuple[str, ...]] = ("rate_dependence", "mechanical_dynamics")
    told_by_frequency: ClassVar[bool] = True
    deciders: ClassVar[Mapping[str, str]] = {
        "rate_dependence": "a delay's phase lag grows in proportion to frequency while a first-order lag's (rate_dependence) "
                           "saturates at 90 degrees: record sine sweeps at several frequencies spanning "
                           "1/(2 pi tau) to decide"}

    def __init__(self, block: Mapping[str, Any]) -> None:
        super().__init__(block)
        d = block.get("delay_s")
        if not is_number(d) or d < 0 or d > MAX_DELAY_S:
            raise ModelError(f"extended model: delay.delay_s must be a number of seconds from 0 to {MAX_DELAY_S:g}, "
                             f"got {d!r}")
        self.delay_s = float(d)

    @property
    def preview_s(self) -> float:
        return self.delay_s

    def apply_input(self, u: np.ndarray, dt: np.ndarray, dt_med: float, u0: float) -> np.ndarray:
        return K.delay_filter(u, self.delay_s / dt_med, u0) if self.delay_s > 0 else u

    def state(self, dt: float, stress_ref: float, inverse: bool) -> "_DelayState":
        return _DelayState(self.delay_s / dt)

    # ---- diagnosis
    @classmethod
    def grid(cls, fitter: FitData) -> np.ndarray:
        return np.geomspace(0.25 * fitter.dt_min, min(0.2, max(fitter.duration_max / 10, 2 * fitter.dt_min)), 16)

    @classmethod
    def refine(cls, fitter: FitData, p: Any, level: int) -> list[float]:
        return geom_refine(p, grid_ratio(1, 3000, 16), level)

    @classmethod
    def filter_input(cls, u: np.ndarray, d: Any, p: Any) -> np.ndarray:
        return K.delay_filter(u, p / d.dt_med, float(u[0]))

    @classmethod
    def fitted_params(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, float]:
        return {"delay_s": p}

    @classmethod
    def fitted_blocks(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, dict[str, Any]]:
        return {"delay": {"delay_s": p}}

    @staticmethod
    def describe(params: Mapping[str, float], unit: str) -> str:
        return f"a transport delay of {params['delay_s'] * 1e3:.3g} ms"


class _DelayState:
    """Fractional delay on a ring buffer; the inverse cannot undo it (the caller previews instead)."""

    def __init__(self, delay_samples: float) -> None:
        self.whole = int(math.floor(delay_samples))
        self.frac = delay_samples - self.whole
        self.buf = [0.0] * (self.whole + 2)
        self.head = 0

    def reset(self, initial_drive: float) -> None:
        for k in range(len(self.buf)):
            self.buf[k] = float(initial_drive)
        self.head = 0

    def step(self, x: StepSignals) -> None:
        if not (self.whole or self.frac):
            return
        n = len(self.buf)
        self.head = (self.head + 1) % n
        self.buf[self.head] = x.u3
        v0 = self.buf[(self.head - self.whole) % n]
        v1 = self.buf[(self.head - self.whole - 1) % n]
        x.u3 = (1.0 - self.frac) * v0 + self.frac * v1

    def inverse_step(self, x: StepSignals) -> None:
        pass

    def commit(self, x: StepSignals) -> None:
        pass
