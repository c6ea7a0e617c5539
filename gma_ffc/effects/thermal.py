"""Joule heating of the coil and rod: an offset that follows the drive squared through a thermal lag."""

from __future__ import annotations

import math
from typing import Any, ClassVar, Mapping

import numpy as np

from . import kernels as K
from .base import (BatchSignals, EffectBase, FitData, Regressors, SignatureCheck, SignatureFailure, StepSignals,
                   finite, geom_refine, grid_ratio, positive)

THERMAL_FAST_RATIO = 0.125   # the fast heating part's time constant relative to the slow one (coil vs rod)
MIN_FAST_HEAT_S = 10.0       # no thermal part is quicker than this (thermal mass); faster drift is creep-like
MIN_THERMAL_TAU_S = 10.0     # thermal time constant of a coil and rod: tens of seconds and more


class Thermal(EffectBase):
    name: ClassVar[str] = "thermal_drift"
    keys: ClassVar[tuple[str, ...]] = ("thermal",)
    block_keys: ClassVar[Mapping[str, tuple[str, ...]]] = {"thermal": ("tau_s", "gain_um_per_A2", "fast_tau_s", "fast_gain_um_per_A2")}
    stage: ClassVar[str] = "after"
    position: ClassVar[int] = 80
    inverted: ClassVar[Mapping[str, str]] = {"thermal": "offset model driven by the commanded drive of the previous sample"}
    physics: ClassVar[str] = (
        "Joule heating of the coil and rod: an offset that follows the drive squared through a thermal "
        "time constant (plus a part 8x faster, if still slower than 10 s: the coil heats quicker than the rod) and "
        "cools back at zero current")
    physics_voltage: ClassVar[str | None] = (
        "a voltage-driven actuator has no coil current to heat it: a drift that follows the drive "
        "squared through a thermal time constant is self-heating of the stack (dielectric loss) or "
        "the ambient temperature; a temperature_C column would tell which")
    n_params: ClassVar[int] = 3
    slow: ClassVar[bool] = True
    deciders: ClassVar[Mapping[str, str]] = {
        "creep": "heating follows the integral of the drive squared and recovers at zero drive, creep follows the "
                 "direction of the last step: record steps up and down with long holds and a pause at zero drive"}

    def __init__(self, block: Mapping[str, Any]) -> None:
        super().__init__(block)
        self.tau_s = positive(block, "tau_s", "thermal")
        self.gain = finite(block, "gain_um_per_A2", "thermal")
        self.fast = "fast_tau_s" in block or "fast_gain_um_per_A2" in block
        if self.fast:
            self.fast_tau_s = positive(block, "fast_tau_s", "thermal")
            self.fast_gain = finite(block, "fast_gain_um_per_A2", "thermal")

    def apply(self, y: np.ndarray, sig: BatchSignals) -> np.ndarray:
        u2 = np.asarray(sig.drive, dtype=float) ** 2
        y = y + self.gain * K.lag_filter(u2, sig.dt, self.tau_s, 0.0)
        if self.fast:
            y = y + self.fast_gain * K.lag_filter(u2, sig.dt, self.fast_tau_s, 0.0)
        return y

    def state(self, dt: float, stress_ref: float, inverse: bool) -> "_ThermalState":
        return _ThermalState(self, dt)

    # ---- diagnosis
    @classmethod
    def grid(cls, fitter: FitData) -> np.ndarray:
        # a coil and rod heat up over tens of seconds at least (thermal mass); faster "heating" is creep-like
        lo = max(50 * fitter.dt_min, MIN_THERMAL_TAU_S)
        hi = max(5 * fitter.duration_max, 2 * lo)
        return np.geomspace(lo, hi, 12)

    @classmethod
    def refine(cls, fitter: FitData, p: Any, level: int) -> list[float]:
        return [max(q, MIN_THERMAL_TAU_S) for q in geom_refine(p, grid_ratio(1, 10, 12), level)]

    @classmethod
    def scaled_for_partner(cls, p: Any, k: float) -> Any:
        """Its time constant scaled by k beside creep (`Creep.rescales`), no faster than heating is."""
        return max(p * k, MIN_THERMAL_TAU_S)

    @classmethod
    def columns(cls, fitter: FitData, r: Regressors, p: Any) -> None:
        d = r.d
        r.cols.append(K.lag_filter(d.u * d.u, d.dt, p, 0.0))
        r.names.append("thermal_gain")
        # coil and rod heat with different time constants: a faster part with its own gain, where it
        # is still slow enough to be thermal. On a one-sided drive the drive squared and the core
        # output rise and fall together, so that fast part and creep are look-alikes: a model with
        # creep keeps the single heating time constant, and creep is judged as the fast part's rival
        if p * THERMAL_FAST_RATIO >= MIN_FAST_HEAT_S and "creep" not in r.spec:
            r.cols.append(K.lag_filter(d.u * d.u, d.dt, p * THERMAL_FAST_RATIO, 0.0))
            r.names.append("thermal_fast_gain")

    @classmethod
    def fitted_params(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, float]:
        out = {"tau_s": p, "gain_um_per_A2": coef.get("thermal_gain", float("nan"))}
        if "thermal_fast_gain" in coef:
            out.update(fast_tau_s=p * THERMAL_FAST_RATIO, fast_gain_um_per_A2=coef["thermal_fast_gain"])
        return out

    @classmethod
    def fitted_blocks(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, dict[str, Any]]:
        block = {"gain_um_per_A2": coef["thermal_gain"], "tau_s": p}
        if "thermal_fast_gain" in coef:
            block.update(fast_gain_um_per_A2=coef["thermal_fast_gain"], fast_tau_s=p * THERMAL_FAST_RATIO)
        return {"thermal": block}

    @classmethod
    def signature(cls, check: SignatureCheck) -> SignatureFailure | None:
        """Heating is monotone: under a constant drive the drift never turns round.

        Temperatures in a passive thermal network heated from rest rise monotonically (its state
        matrix is Metzler: the rates start non-negative and stay so), and one expansion mechanism
        maps them to a drift of one direction. Two parts of opposite sign whose sum turns round
        within the recording are a band-pass, not heating: the leftover of another effect.

        A fit whose time constant runs to the fastest heating may have (`grid`'s lower end) wants a
        quicker drift than a coil and rod can heat: creep's or a lag's look-alike, and a law not
        determined by the data (as creep's own rule, `Creep.signature`). On two short runs of a
        creeping actuator (2.8 s in all) heating was named at 10 s and drifted 2x worse than the base
        at other loads and rates.
        """
        fastest = float(cls.grid(check.fitter)[0])
        if check.params["tau_s"] <= fastest * (1.0 + 1e-9):
            return SignatureFailure(
                f"its fit runs to the fastest time constant heating may have ({fastest:.3g} s): the drift the data "
                "want is quicker than a coil and rod heat, a look-alike that creep or a lag gives as well")
        reversal = reversal_time_s(check.params)
        duration = check.fitter.duration_max
        if reversal is None or reversal >= duration:
            return None
        return SignatureFailure(
            f"its two heating parts have opposite signs and their sum turns round {reversal:.3g} s into a constant "
            f"drive (the recording lasts {duration:.3g} s): heating from rest is monotone, so this drift is the "
            "leftover of another effect")

    @staticmethod
    def describe(params: Mapping[str, float], unit: str) -> str:
        what = "heating" if unit == "A" else "a thermal drift (self-heating or ambient)"
        txt = (f"{what} with a thermal time constant of {params['tau_s']:.3g} s ({params['gain_um_per_A2']:+.3g} um "
               f"per {unit}^2 at equilibrium)")
        fast = params.get("fast_gain_um_per_A2", math.nan)
        if math.isfinite(fast):
            txt += f" and a faster part at {params['fast_tau_s']:.3g} s ({fast:+.3g} um per {unit}^2)"
        return txt


def reversal_time_s(params: Mapping[str, float]) -> float | None:
    """When the step response g (1 - exp(-t/tau)) + g_f (1 - exp(-t/tau_f)) turns round (its slope
    changes sign), or None if it never does (one part, or both of one sign)."""
    g, tau = params.get("gain_um_per_A2", math.nan), params.get("tau_s", math.nan)
    gf, tf = params.get("fast_gain_um_per_A2", math.nan), params.get("fast_tau_s", math.nan)
    if not all(math.isfinite(v) for v in (g, tau, gf, tf)) or g * gf >= 0 or tf >= tau:
        return None
    # slope g/tau e^(-t/tau) + g_f/tau_f e^(-t/tau_f) = 0; the fast part dominates at t = 0
    ratio = abs(gf) * tau / (abs(g) * tf)
    if ratio <= 1.0:
        return None           # the slow part's slope dominates from the start: monotone
    return math.log(ratio) / (1.0 / tf - 1.0 / tau)


class _ThermalState:
    """Forward: heating from this sample's drive. Inverse: from the drive already commanded (one
    sample behind: tau_s >> dt), subtracted from the reference first."""

    def __init__(self, m: Thermal, dt: float) -> None:
        self.m = m
        self.a = K.lag_coeff(dt, m.tau_s)
        self.a_fast = K.lag_coeff(dt, m.fast_tau_s) if m.fast else 0.0
        self.theta = self.theta_fast = 0.0

    def reset(self, initial_drive: float) -> None:
        self.theta = self.theta_fast = 0.0

    def _heat(self, u: float) -> float:
        m = self.m
        self.theta = self.a * self.theta + (1.0 - self.a) * u * u
        out = m.gain * self.theta
        if m.fast:
            self.theta_fast = self.a_fast * self.theta_fast + (1.0 - self.a_fast) * u * u
            out += m.fast_gain * self.theta_fast
        return out

    def step(self, x: StepSignals) -> None:
        x.y += self._heat(x.u1)

    def inverse_step(self, x: StepSignals) -> None:
        x.target -= self._heat(x.drive_prev)

    def commit(self, x: StepSignals) -> None:
        pass
