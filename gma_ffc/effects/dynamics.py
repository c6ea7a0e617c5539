"""Mechanical dynamics: rod and load mass on the rod's stiffness, a resonance that moves with the load."""

from __future__ import annotations

import math
from typing import Any, ClassVar, Mapping

import numpy as np

from . import kernels as K
from .base import BatchSignals, EffectBase, FitData, Regressors, StepSignals, geom_refine, positive

MAX_ZETA = 0.5   # a resonance must peak; heavier damping is a lag/delay look-alike and is left to those


class Dynamics(EffectBase):
    name: ClassVar[str] = "mechanical_dynamics"
    keys: ClassVar[tuple[str, ...]] = ("dynamics",)
    stage: ClassVar[str] = "filter"
    position: ClassVar[int] = 70
    inverted: ClassVar[Mapping[str, str]] = {"dynamics": "exact inverse filter (3-tap FIR on the reference)"}
    physics: ClassVar[str] = (
        "rod and load mass on the rod's stiffness with damping: a second-order resonance whose frequency "
        "falls as the load mass (and so the compressive stress) grows")
    n_params: ClassVar[int] = 3
    deciders: ClassVar[Mapping[str, str]] = {
        "rate_dependence": "a resonance peaks and moves with load mass, a lag does not: drive near the fitted "
                           "resonance at two loads",
        "time_delay": "a resonance peaks and moves with load mass, a delay does not: drive near the fitted "
                      "resonance at two loads"}

    def __init__(self, block: Mapping[str, Any]) -> None:
        super().__init__(block)
        self.f_ref_hz = positive(block, "f_ref_hz", "dynamics")
        self.zeta = positive(block, "zeta", "dynamics")
        self.beta = float(block.get("beta_per_MPa", 0.0))
        self.stress_ref = float(block.get("stress_ref_MPa", 0.0))

    def apply(self, y: np.ndarray, sig: BatchSignals) -> np.ndarray:
        return K.msd_filter(np.ascontiguousarray(y), sig.dt, sig.stress, 2 * math.pi * self.f_ref_hz, self.zeta,
                            self.beta, self.stress_ref, float(y[0]))

    def state(self, dt: float, stress_ref: float, inverse: bool) -> "_DynamicsState":
        return _DynamicsState(self, dt)

    # ---- diagnosis
    @classmethod
    def grid(cls, fitter: FitData) -> list[tuple[float, float, float]]:
        """Resonance frequency x damping, load-independent; the load dependence is refined afterwards."""
        nyq = 0.5 / fitter.dt_min
        f_lo = max(2.0, 20.0 / max(fitter.duration_max, 1e-9))
        freqs = np.geomspace(f_lo, 0.8 * nyq, 18) if 0.8 * nyq > f_lo else np.array([0.8 * nyq])
        zetas = (0.02, 0.05, 0.12, 0.25, 0.45)
        return [(float(fr), z, 0.0) for fr in freqs for z in zetas]

    @classmethod
    def refine(cls, fitter: FitData, p: Any, level: int) -> list[tuple[float, float, float]]:
        """Zoom on (resonance at the lightest load, damping, frequency ratio heaviest/lightest load)."""
        fr, z, b = p
        span = _stress_extent(fitter)
        ratio = 1.0 / math.sqrt(1.0 + b * span)          # f(most compressive) / f(least compressive)

        def point(f_top: float, zeta: float, rat: float) -> tuple[float, float, float]:
            rat = min(max(rat, 0.15), 1.0)
            return (float(f_top), float(min(zeta, MAX_ZETA)),
                    float((rat ** -2 - 1.0) / span) if fitter.stress_varies else 0.0)

        out = [point(fr * k, z, ratio) for k in geom_refine(1.0, 1.4, level)]
        out += [point(fr, z * k, ratio) for k in geom_refine(1.0, 2.4, level)]
        if fitter.stress_varies:
            out += [point(fr * math.sqrt(ratio / min(ratio * k, 1.0)), z, ratio * k)
                    for k in geom_refine(1.0, 1.5, level)]
            if level == 1 and b == 0.0:
                # load-dependent resonance: keep the geometric-mean frequency, spread the ends apart
                out += [point(fr / math.sqrt(r), z, r) for r in (0.8, 0.63, 0.5, 0.4, 0.3)]
        return out

    @classmethod
    def columns(cls, fitter: FitData, r: Regressors, p: Any) -> None:
        """The resonance filters every regressor so far except the offset (the filter is linear)."""
        f, zeta, beta = p
        d = r.d
        idx = [j for j, name in enumerate(r.names) if name != "offset"]
        filt = K.msd_filter_columns(np.column_stack([r.cols[j] for j in idx]), d.dt, d.s, 2 * math.pi * f,
                                    zeta, beta, fitter.stress_top)
        for k, j in enumerate(idx):
            r.cols[j] = filt[:, k]

    @classmethod
    def fitted_params(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, float]:
        f, z, b = p
        out = {"f_ref_hz": f, "zeta": z, "beta_per_MPa": b, "stress_ref_MPa": fitter.stress_top}
        if b > 0:
            s_lo = min(float(d.s.min()) for d in fitter.data)
            out["f_at_most_compressive_hz"] = f / math.sqrt(1 + b * (fitter.stress_top - s_lo))
        return out

    @classmethod
    def fitted_blocks(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, dict[str, Any]]:
        f, z, b = p
        return {"dynamics": {"f_ref_hz": f, "zeta": z, "beta_per_MPa": b, "stress_ref_MPa": fitter.stress_top}}

    @staticmethod
    def describe(params: Mapping[str, float], unit: str) -> str:
        txt = f"a resonance at {params['f_ref_hz']:.4g} Hz (damping ratio {params['zeta']:.2g})"
        if "f_at_most_compressive_hz" in params:
            txt += f" that moves down to {params['f_at_most_compressive_hz']:.4g} Hz at the most compressive load"
        return txt


def _stress_extent(f: FitData) -> float:
    return max(f.stress_top - min(float(d.s.min()) for d in f.data), 1e-9)


class _DynamicsState:
    """Forward: the matched-pole filter. Inverse: its exact 3-tap FIR on the reference."""

    def __init__(self, m: Dynamics, dt: float) -> None:
        self.dt = dt
        self.omega_ref = 2 * math.pi * m.f_ref_hz
        self.zeta, self.beta, self.stress_ref = m.zeta, m.beta, m.stress_ref
        self.v1 = self.v2 = 0.0        # forward: previous outputs; inverse: previous references
        self.first = True

    def reset(self, initial_drive: float) -> None:
        self.v1 = self.v2 = 0.0
        self.first = True

    def step(self, x: StepSignals) -> None:
        if self.first:
            self.v1 = self.v2 = x.y
            self.first = False
        w = K.msd_omega(self.omega_ref, self.beta, x.s, self.stress_ref)
        a1, a2, kk = K.msd_coeffs(self.dt, w, self.zeta)
        y = kk * x.y - a1 * self.v1 - a2 * self.v2
        self.v2 = self.v1
        self.v1 = y
        x.y = y

    def inverse_step(self, x: StepSignals) -> None:
        target = x.target
        if self.first:
            self.v1 = self.v2 = target
            self.first = False
        w = K.msd_omega(self.omega_ref, self.beta, x.s, self.stress_ref)
        a1, a2, kk = K.msd_coeffs(self.dt, w, self.zeta)
        x.target = (target + a1 * self.v1 + a2 * self.v2) / kk
        self.v2 = self.v1
        self.v1 = target

    def commit(self, x: StepSignals) -> None:
        pass
