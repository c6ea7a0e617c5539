"""Mechanical dynamics as physics: the load mass on the rod's stiffness, driven by the free stroke.

Derivation. The rod (stiffness k = E A / L, plus the preload spring) would stretch by the free
stroke x_free(I, sigma) that the hysteresis core describes if nothing held it; the load mass m
(and the moving parts, m_0) sits on its end, so the rod pushes it with k (x_free - x) and::

    (m_0 + m) x'' + c x' + k x = k x_free        ->   x'' + 2 zeta w x' + w^2 x = w^2 x_free

The mass is not free to fit per recording: the load cell measures it. With no dynamics the
rod carries preload + m g, so m = (-sigma_static A - F_preload) / g is linear in the static
stress, and 1/w^2 = (m_0 + m)/k is linear in it too::

    w(sigma) = w_ref / sqrt(1 + beta (sigma_ref - sigma_static))        (beta = A / (g m_eff,ref) / 1e-6)

three parameters (f_ref, zeta, beta), the same for every load; a constant damping ratio as the
rod's internal loss is proportional to its stiffness. What is *not* identifiable separately
from a recording of (time, drive, stress, displacement) is A, F_preload, m_0 and k one by one:
only w_ref and beta are.

Which stress. The load cell also carries the load's inertial force m x'' (at a clear resonance
tens of MPa on a 7 mm rod), so the measured stress is not the static stress: a resonance set
from it moves with the very oscillation it should describe. The static stress is the measured
stress low-passed at STATIC_STRESS_HZ (two lags): a load changes as an event, and the inertial
force at a drive frequency f is (f / f_r)^2 of the rod's elastic force, so what passes a 1 Hz
low-pass is at most (1 Hz / f_r)^2 of it (< 1e-3 for any resonance above 30 Hz); a new load is
followed within a few tenths of a second. The core also sees this static stress: its stress
dependence was identified from quasi-static loops at fixed loads (how the loop changes with the
preload); the rod's response to the fast inertial force is its stiffness, already in k. (The
magnetoelastic response of the magnetisation to that fast stress is left out: a stress-dependent
PI core moves its output with stress at once, the material only as its field moves.)

Linearity. For fixed (f_ref, zeta, beta) the map from x_free to x is linear and time-varying, so
every regressor column of the static map (gain, curvature, plays, stress terms, creep) is passed
through it and the gains stay a linear least-squares problem (`regressors`); the offset is
unchanged by a unity-gain system at rest.

Discretisation (`rod_load_kernels`): exact for an input held over each sample interval, in state
form so position and velocity stay continuous when the load changes. Inverse: exact, causal
(the free stroke that puts the load at the reference), see `RodLoadStepper.inverse`.

Where the law was measured. A law fitted where the recordings excite the resonance over a narrow
band of loads only is extrapolated beyond it from its form alone (the twenty-third never-tuned
draw: fitted at 1.6 of 7.5 MPa, 3x too steep, a probe at the heaviest load 2.4x worse than the
base). The optional ``law_held_below_MPa`` holds the resonance at every more compressive static
stress at its value there, and ``law_held_above_MPa`` at every less compressive one: the static
stress the law reads is clipped (the core still sees the static stress itself). Without them the
law runs over every load, as before.

Extended-model block (``blocks.dynamics``), told apart from the older output filter by ``form``::

    {form: rod_load, f_ref_hz, zeta, beta_per_MPa, stress_ref_MPa, stress_lowpass_hz
     [, law_held_below_MPa][, law_held_above_MPa]}
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from . import rod_load_kernels as RK
from .base import is_number

FORM = "rod_load"
STATIC_STRESS_HZ = 1.0      # low-pass of the load-cell stress that leaves the load's weight (see above)
HELD_KEYS = ("law_held_below_MPa", "law_held_above_MPa")     # where the law is held (see above)


def is_rod_load(block: Mapping[str, Any] | None) -> bool:
    """True for the physical block; False for the older output filter (files written before it)."""
    return block is not None and bool(block) and block.get("form") == FORM


def make_block(f_ref_hz: float, zeta: float, beta_per_MPa: float, stress_ref_MPa: float,
               stress_lowpass_hz: float = STATIC_STRESS_HZ,
               held: tuple[float, float] = (-math.inf, math.inf)) -> dict[str, Any]:
    """The block; `held`: the static stresses the law runs over (`law_range`), an infinite end not held."""
    block: dict[str, Any] = {"form": FORM, "f_ref_hz": float(f_ref_hz), "zeta": float(zeta),
                             "beta_per_MPa": float(beta_per_MPa), "stress_ref_MPa": float(stress_ref_MPa),
                             "stress_lowpass_hz": float(stress_lowpass_hz)}
    for key, end in zip(HELD_KEYS, held):
        if math.isfinite(end):
            block[key] = float(end)
    return block


def check_block(block: Mapping[str, Any]) -> str:
    """'' if the block is valid, else what is wrong (the caller raises its own error type)."""
    for key in ("f_ref_hz", "zeta", "stress_lowpass_hz"):
        v = block.get(key)
        if not is_number(v) or v <= 0:
            return f"dynamics.{key} must be a positive number, got {v!r}"
    for key in ("beta_per_MPa", "stress_ref_MPa"):
        v = block.get(key)
        if not is_number(v):
            return f"dynamics.{key} must be a finite number, got {v!r}"
    for key in HELD_KEYS:
        if key in block and not is_number(block[key]):
            return f"dynamics.{key} must be a finite stress in MPa (or left out: the law not held), got {block[key]!r}"
    lo, hi = law_range(block)
    if lo > hi:
        return (f"dynamics.law_held_below_MPa ({lo:g}) must not be above dynamics.law_held_above_MPa ({hi:g}): "
                "the law runs between them")
    return ""


def law_range(block: Mapping[str, Any]) -> tuple[float, float]:
    """The static stresses the resonance law runs over (beyond them it is held): every load without the keys."""
    below, above = (block.get(key) for key in HELD_KEYS)
    return (-math.inf if below is None else float(below), math.inf if above is None else float(above))


def law_stress(s_static: np.ndarray, held: tuple[float, float]) -> np.ndarray:
    """The static stress the law reads: clipped to the range it runs over (a new array only when clipped)."""
    s = np.ascontiguousarray(s_static, dtype=float)
    return s if held == (-math.inf, math.inf) else np.clip(s, held[0], held[1])


def resonance_hz(f_ref_hz: float, beta_per_MPa: float, stress_ref_MPa: float, s_static: float,
                 held: tuple[float, float] = (-math.inf, math.inf)) -> float:
    """The law's resonance at a static stress as the model runs it: held beyond `held`, the mass
    factor floored at `rod_load_kernels.MIN_MASS_FACTOR` (`RodLoadStepper.static` the same, written out)."""
    s = min(max(float(s_static), held[0]), held[1])
    return RK.omega_at(2.0 * math.pi * f_ref_hz, beta_per_MPa, s, stress_ref_MPa) / (2.0 * math.pi)


def static_stress(stress: np.ndarray, dt: np.ndarray, fc_hz: float = STATIC_STRESS_HZ) -> np.ndarray:
    """The load's static stress from the load-cell stress (at rest at its first value)."""
    s = np.ascontiguousarray(stress, dtype=float)
    if s.size == 0:
        return s
    return RK.static_stress(s, np.ascontiguousarray(dt, dtype=float), float(fc_hz), float(s[0]))


def _args(block: Mapping[str, Any]) -> tuple[float, float, float, float]:
    return (2.0 * math.pi * float(block["f_ref_hz"]), float(block["zeta"]), float(block.get("beta_per_MPa", 0.0)),
            float(block.get("stress_ref_MPa", 0.0)))


def forward(x_free: np.ndarray, dt: np.ndarray, s_static: np.ndarray, block: Mapping[str, Any]) -> np.ndarray:
    """Batch: load position for the free stroke, at rest at its first value."""
    x = np.ascontiguousarray(x_free, dtype=float)
    return RK.forward(x, np.ascontiguousarray(dt, dtype=float), law_stress(s_static, law_range(block)),
                      *_args(block), float(x[0]))


def inverse(y: np.ndarray, dt: np.ndarray, s_static: np.ndarray, block: Mapping[str, Any]) -> np.ndarray:
    """Batch: exact inverse of `forward` (at rest at y[0])."""
    yy = np.ascontiguousarray(y, dtype=float)
    return RK.inverse(yy, np.ascontiguousarray(dt, dtype=float), law_stress(s_static, law_range(block)),
                      *_args(block), float(yy[0]))


def transitions(dt: np.ndarray, s_static: np.ndarray, f_ref_hz: float, zeta: float, beta_per_MPa: float,
                stress_ref_MPa: float, held: tuple[float, float] = (-math.inf, math.inf)) -> np.ndarray:
    """The load dynamics' state transition per sample, shape (4, samples): what `regressors` filters
    through. It depends on the dynamics and the recording alone, so a fit that filters several sets
    of terms through the same dynamics computes it once. `held`: the law's range (`law_range`)."""
    return RK.transitions(np.ascontiguousarray(dt, dtype=float), law_stress(s_static, held),
                          2.0 * math.pi * f_ref_hz, zeta, beta_per_MPa, stress_ref_MPa)


def regressors(X: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Every row of X (a term of the free stroke, shape (terms, samples)) through the load
    dynamics with transitions P (`transitions`), each at rest at its first value."""
    return RK.forward_rows(np.ascontiguousarray(X, dtype=float), P)


class RodLoadStepper:
    """Per-sample static stress, forward and inverse in plain float arithmetic (nothing allocated).

    Call `static(stress)` once per sample first (it also sets the resonance), then `forward` or
    `inverse`. Without a stress reading, the reference load is assumed.
    """

    def __init__(self, block: Mapping[str, Any], dt_s: float) -> None:
        self.dt = float(dt_s)
        self.w_ref, self.zeta, self.beta, self.s_ref = _args(block)
        self.law_lo, self.law_hi = law_range(block)
        self.a_lp = math.exp(-self.dt * 2.0 * math.pi * float(block["stress_lowpass_hz"]))
        self.reset()

    def reset(self) -> None:
        self.first = True
        self.z1 = self.z2 = self.s_ref
        self.x = self.v = 0.0
        self.p11, self.p12, self.p21, self.p22 = 1.0, 0.0, 0.0, 1.0
        self.w_last = -1.0

    def static(self, stress_MPa: float | None) -> float:
        s = self.s_ref if stress_MPa is None else float(stress_MPa)
        if self.first:
            self.z1 = self.z2 = s
        a = self.a_lp
        self.z1 = a * self.z1 + (1.0 - a) * s
        self.z2 = a * self.z2 + (1.0 - a) * self.z1
        s_law = min(max(self.z2, self.law_lo), self.law_hi)
        m = 1.0 + self.beta * (self.s_ref - s_law)
        if m < RK.MIN_MASS_FACTOR:
            m = RK.MIN_MASS_FACTOR
        w = self.w_ref / math.sqrt(m)
        if w != self.w_last:
            self._phi(w)
        return self.z2

    def _phi(self, w: float) -> None:
        """The transition over one period at w: the batch kernel's own `phi` (the same bits on 100,000
        random (dt, w, zeta), and 0.5 us a call from Python against 0.65 us written out here)."""
        self.p11, self.p12, self.p21, self.p22 = RK.phi(self.dt, w, self.zeta)
        self.w_last = w

    def forward(self, x_free: float) -> float:
        if self.first:
            self.x, self.v, self.first = x_free, 0.0, False
        x, v = self.x, self.v
        self.x = self.p11 * x + self.p12 * v + (1.0 - self.p11) * x_free
        self.v = self.p21 * x + self.p22 * v - self.p21 * x_free
        return self.x

    def inverse(self, y: float) -> float:
        """The free stroke that puts the load at y at this sample (exact inverse of `forward`)."""
        if self.first:
            self.x, self.v, self.first = y, 0.0, False
        x, v = self.x, self.v
        u = (y - self.p11 * x - self.p12 * v) / (1.0 - self.p11)
        self.v = self.p21 * x + self.p22 * v - self.p21 * u
        self.x = y
        return u
