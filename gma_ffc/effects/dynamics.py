"""Mechanical dynamics: rod and load mass on the rod's stiffness, a resonance that moves with the load.

The block the diagnosis writes is the physical one (``form: rod_load``, see `rod_load`): the load
on the rod's stiffness driven by the core's free stroke, discretised exactly, its resonance set by
the load's *static* stress (the load-cell stress low-passed, as that reading carries the load's
inertial force). The same static stress is what the core and the static map see: this effect is
the model's stress transform (`seen_stress`, called before the core). Blocks without ``form``
(files written before it) load as the older output filter and run as they did.
"""

from __future__ import annotations

import math
from typing import Any, Callable, ClassVar, Mapping, Sequence

import numpy as np

from ..errors import ModelError
from . import kernels as K
from . import rod_load as RL
from .base import (BatchSignals, EffectBase, FitData, Regressors, SignatureCheck, SignatureFailure, StepSignals,
                   is_number, polish_factor, positive)

MAX_ZETA = 0.5   # a resonance must peak; heavier damping is a lag/delay look-alike and is left to those
RUN_TO_BOUND = 0.03   # a fit within 3 % of a bound it is clipped at (MAX_ZETA, _f_max) ran to it: the
                      # search's polish starts with 3 % moves (diagnose.search.POLISH_STEP) and stops after a
                      # few evaluations, short of the bound (the development set's eddy-and-resonance pair
                      # at 0.4 of its length: damping 0.496, the rig's 0.232, the lag left out and 4x the
                      # error left)
PEAK_ZETA_MAX = MAX_ZETA * (1.0 - RUN_TO_BOUND)   # the heaviest damping a fit that peaks may have
LAW_SWEEP = 1.2    # after the polish, moving masses over LAW_SPREAD's range about 20 % apart: with frequency and
                   # damping close, the held-out error against the law has basins only +-20 % wide (the ninth
                   # general draw's resonance: 0.13 um at the plant's mass, 0.29 um 25 % above it)
LAW_SPREAD = (0.01, 0.05, 0.15, 0.5, 1.5, 5.0)   # moving masses tried from a load-independent resonance, in
                                                 # units of the loads' stress extent: from loads 100 times the
                                                 # fixture (frequency ratio 0.1 end to end) to loads that barely
                                                 # move it (0.91); hil_sim's own rig, 1.5 kg under loads to 50 kg,
                                                 # is 0.17, beyond the 0.05 (0.22) this began at
# the lowest heaviest/lightest frequency ratio a law may take: LAW_SPREAD's lightest mass's, sqrt(m / (m + 1)) in
# units of the extent (0.0995). With the resonance at the lightest load beyond what the sampling resolves, a fit
# runs the law steeper than the rig's (hil_sim's rig: 0.107 for its 0.17, the top held at _f_max)
MIN_LOAD_RATIO = math.sqrt(min(LAW_SPREAD) / (min(LAW_SPREAD) + 1.0))
TOP_OF_NYQUIST = 0.8   # the highest resonance searched, as a fraction of the Nyquist frequency: above
                       # it a few samples per period cannot show a peak, only a lag


class Dynamics(EffectBase):
    name: ClassVar[str] = "mechanical_dynamics"
    keys: ClassVar[tuple[str, ...]] = ("dynamics",)
    block_keys: ClassVar[Mapping[str, tuple[str, ...]]] = {
        "dynamics": ("form", "f_ref_hz", "zeta", "beta_per_MPa", "stress_ref_MPa", "stress_lowpass_hz") + RL.HELD_KEYS}
    stage: ClassVar[str] = "filter"
    follows_drive: ClassVar[bool] = True
    position: ClassVar[int] = 70
    inverted: ClassVar[Mapping[str, str]] = {"dynamics": "exact inverse filter (3-tap FIR on the reference)"}
    inverted_rod_load: ClassVar[Mapping[str, str]] = {
        "dynamics": "exact state inverse of the load dynamics (the free stroke that puts the load at the reference)"}
    physics: ClassVar[str] = (
        "rod and load mass on the rod's stiffness with damping, driven by the actuator's free stroke: a "
        "second-order resonance whose frequency falls as the load mass (the static compressive stress the "
        "load cell reads, its inertial force filtered out) grows")
    physics_without_stress: ClassVar[str | None] = (
        "the moving mass (the actuator's own and its load's) on the actuator's stiffness with damping, driven "
        "by its free stroke: a second-order resonance; the recordings carry no stress, so the load is taken "
        "as one constant mass and the resonance as fixed")
    n_params: ClassVar[int] = 3
    transforms_stress: ClassVar[bool] = True     # the model sees the load's static stress (rod_load)
    # a lag or delay already in the model takes the resonance's phase too (a delay stood in for eddy
    # currents and a resonance together): it is re-searched, scaled down, with the resonance
    joint_with: ClassVar[tuple[str, ...]] = ("time_delay", "rate_dependence")
    told_by_frequency: ClassVar[bool] = True
    joint_scales: ClassVar[tuple[float, ...]] = (0.5, 1.0)   # two, not four: its grid is 90 points already
    joint_refit: ClassVar[bool] = True   # beside a lag or delay its frequency and load law move too, not only
                                         # its damping: searched again whole (`scoring._descend`)
    # a sharp resonance needs its frequency, damping and load law to about a percent (steps halve per level)
    zoom_levels: ClassVar[int] = 6
    deciders: ClassVar[Mapping[str, str]] = {
        "rate_dependence": "a resonance peaks and moves with load mass, a lag does not: drive near the fitted "
                           "resonance at two loads",
        "time_delay": "a resonance peaks and moves with load mass, a delay does not: drive near the fitted "
                      "resonance at two loads"}

    def __init__(self, block: Mapping[str, Any]) -> None:
        super().__init__(block)
        self.f_ref_hz = positive(block, "f_ref_hz", "dynamics")
        self.zeta = positive(block, "zeta", "dynamics")
        if "form" in block and not RL.is_rod_load(block):
            raise ModelError(f"extended model: dynamics.form must be '{RL.FORM}' (or left out: the older output "
                             f"filter), got {block['form']!r}")
        self.rod_load = RL.is_rod_load(block)      # False: the older output filter (files without 'form')
        for key in ("beta_per_MPa", "stress_ref_MPa"):
            if key in block and not is_number(block[key]):
                raise ModelError(f"extended model: dynamics.{key} must be a finite number, got {block[key]!r}")
        self.beta = float(block.get("beta_per_MPa", 0.0))
        self.stress_ref = float(block.get("stress_ref_MPa", 0.0))
        if self.rod_load and RL.check_block(block):
            raise ModelError(f"extended model: {RL.check_block(block)}")

    def inverted_text(self) -> Mapping[str, str]:
        """Old files (the output filter) keep their words; the physical block has its own."""
        return self.inverted_rod_load if self.rod_load else self.inverted

    def seen_stress(self, stress_MPa: Any, t: np.ndarray, dt: np.ndarray) -> Any:
        """The stress transform (called before the core): the load's static stress under rod_load
        (without a reading, the reference load's), the stress as given for the older filter."""
        if not self.rod_load:
            return stress_MPa
        s = np.full(t.size, self.stress_ref) if stress_MPa is None else np.asarray(stress_MPa, dtype=float)
        if s.ndim == 0:
            s = np.full(t.size, float(s))
        if s.shape != t.shape:
            raise ModelError(f"stress_MPa has {s.size} values but the drive has {t.size}")
        return RL.static_stress(s, dt, float(self.block["stress_lowpass_hz"]))

    def apply(self, y: np.ndarray, sig: BatchSignals) -> np.ndarray:
        if self.rod_load:
            return RL.forward(y, sig.dt, sig.stress, self.block)
        return K.msd_filter(np.ascontiguousarray(y), sig.dt, sig.stress, 2 * math.pi * self.f_ref_hz, self.zeta,
                            self.beta, self.stress_ref, float(y[0]))

    def state(self, dt: float, stress_ref: float, inverse: bool) -> "_DynamicsState | _RodLoadState":
        return _RodLoadState(self, dt) if self.rod_load else _DynamicsState(self, dt)

    # ---- diagnosis
    @classmethod
    def grid(cls, fitter: FitData) -> list[tuple[float, float, float]]:
        """Resonance frequency x damping, load-independent; the load dependence is refined afterwards."""
        f_hi = _f_max(fitter)
        f_lo = max(2.0, 20.0 / max(fitter.duration_max, 1e-9))
        freqs = np.geomspace(f_lo, f_hi, 18) if f_hi > f_lo else np.array([f_hi])
        zetas = (0.02, 0.05, 0.12, 0.25, 0.45)
        return [(float(fr), z, 0.0) for fr in freqs for z in zetas]

    @classmethod
    def refine(cls, fitter: FitData, p: Any, level: int) -> list[tuple[float, float, float]]:
        """Zoom on (resonance frequency, damping, load law). The load law moves in its physical
        parameter, the moving mass at the least compressive load in stress units (`_mass_stress`),
        with the resonance held where the data show it: at the stress where the drive excites it
        most (`_stress_excited`), or at either end (the fast drive may sit at one load only). Held
        at the least compressive end alone, frequency and law trade off along a narrow valley."""
        fr, z, b = p[:3]

        # steps halve per level (not a third): a sharp resonance's damping and load law are coupled to its
        # frequency, and the grid's coarse frequency first pins the damping far from its value
        def near(ratio_: float) -> list[float]:
            step = 2.0 ** -level
            return [ratio_ ** (e * step) for e in (-2.0, -1.0, 1.0, 2.0)]

        ratio = _load_ratio(fitter, b)          # the law kept: f(most compressive) / f(least compressive)
        out = [_point(fitter, fr * k, z, ratio) for k in near(1.4)]
        out += [_point(fitter, fr, z * k, ratio) for k in near(2.4)]
        # diagonal moves: frequency and damping trade off along a narrow valley near a sharp resonance
        out += [_point(fitter, fr * a, z * c, ratio) for a in near(1.4)[1:3] for c in near(2.4)[1:3]]
        if fitter.stress_varies:
            out += _law_moves(fitter, p, near(3.0))
        return out

    @classmethod
    def after_polish(cls, fitter: FitData, p: Any) -> list[tuple[float, float, float]]:
        """The load law swept over the whole range of moving masses, about LAW_SWEEP apart (whole steps
        over the range), the resonance held where the drive excites it at the polished frequency and damping."""
        if not fitter.stress_varies:
            return []
        lo, hi = min(LAW_SPREAD), max(LAW_SPREAD)
        masses = _stress_extent(fitter) * np.geomspace(lo, hi, int(math.log(hi / lo) / math.log(LAW_SWEEP)) + 1)
        return _laws_held(fitter, p, _stress_excited(fitter), [float(m) for m in masses])

    @classmethod
    def scaled_for_partner(cls, p: Any, k: float) -> Any:
        """Fitted alone, a resonance beside eddy currents or a delay takes their phase lag as extra
        damping (a damping ratio of 0.38 where the rig's is 0.1): tried beside it, a lag or delay has
        the damping re-searched, scaled by k."""
        fr, z, b = p[:3]
        return (fr, min(z * k, MAX_ZETA), b)

    @classmethod
    def polish(cls, fitter: FitData, p: Any) -> tuple[int, Callable[[np.ndarray], Any]]:
        """The zoom leaves the damping of a sharp resonance a few percent off, and its residual
        ringing is then several times the noise: a local search over log(frequency where the drive
        excites it), log(damping) and, for a load law, log(moving mass) finishes the job."""
        fr, z, b = p[:3]
        held = _stress_excited(fitter)
        f_held, s0 = _f_at(fr, b, fitter.stress_top, held), _mass_stress(b)
        law = fitter.stress_varies and not math.isinf(s0)

        def at(x: np.ndarray) -> tuple[float, float, float]:
            k = polish_factor(x)
            return _point_held(fitter, f_held * k[0], held, z * k[1], s0 * k[2] if law else s0)

        return (3 if law else 2), at

    @classmethod
    def signature(cls, check: SignatureCheck) -> SignatureFailure | None:
        """A resonance the data show peaks: a fit that runs to the heaviest damping searched (or to the
        highest frequency the sampling resolves) wants a low-pass, a lag that a leftover of eddy
        currents, a delay or the core's shape gives as well."""
        f, zeta = check.result.specs[2][cls.name][:2]
        if zeta >= PEAK_ZETA_MAX:
            return SignatureFailure(
                f"its fit runs to the heaviest damping of a resonance that peaks (damping ratio {zeta:.3g}, "
                f"within {RUN_TO_BOUND:.0%} of the cap {MAX_ZETA:.2g}): "
                "the gain is a low-pass's, a lag that a leftover of another effect gives as well")
        if f >= _f_max(check.fitter) * (1.0 - RUN_TO_BOUND):
            return SignatureFailure(
                f"its fit runs to the highest frequency the sampling resolves ({f:.4g} Hz, within "
                f"{RUN_TO_BOUND:.0%} of {TOP_OF_NYQUIST:.0%} of Nyquist): no peak is seen, only a lag")
        return None

    @classmethod
    def fit_stress(cls, d: Any) -> np.ndarray:
        """The stress transform on a recording (the diagnosis' `RecData`): the load's static stress
        from the stress as recorded (not clamped; the fitter clamps what the core sees)."""
        return RL.static_stress(d.recorded_stress, d.dt)

    @classmethod
    def columns(cls, fitter: FitData, r: Regressors, p: Any) -> None:
        """The load dynamics take every regressor so far (a term of the free stroke) except the offset
        (the dynamics are linear, and a unity-gain system at rest leaves a constant alone)."""
        f, zeta, beta = p[:3]
        held = law_held(p)
        d = r.d
        idx = [j for j, name in enumerate(r.names) if name != "offset"]
        P = fitter.cached_table(d, ("resonance", f, zeta, beta) + held, lambda: RL.transitions(
            d.dt, fitter.static_stress(d), f, zeta, beta, fitter.stress_top, held))  # shared by a search's specs
        filt = RL.regressors(np.array([r.cols[j] for j in idx]), P)
        for k, j in enumerate(idx):
            r.cols[j] = filt[k]

    @classmethod
    def fitted_params(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, float]:
        f, z, b = p[:3]
        held = law_held(p)
        out = {"f_ref_hz": f, "zeta": z, "beta_per_MPa": b, "stress_ref_MPa": fitter.stress_top}
        if b > 0:
            s_lo = min(float(fitter.static_stress(d, clamped=True).min()) for d in fitter.data)  # the static stress
            out["f_at_most_compressive_hz"] = _f_at(f, b, fitter.stress_top, max(s_lo, held[0]))
        out.update({key: end for key, end in zip(RL.HELD_KEYS, held) if math.isfinite(end)})
        return out

    @classmethod
    def fitted_blocks(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, dict[str, Any]]:
        f, z, b = p[:3]
        held = law_held(p)
        return {"dynamics": RL.make_block(f, z, b, fitter.stress_top, held=held)}    # the load dynamics (rod_load)

    @staticmethod
    def describe(params: Mapping[str, float], unit: str) -> str:
        txt = f"a resonance at {params['f_ref_hz']:.4g} Hz (damping ratio {params['zeta']:.2g})"
        if "f_at_most_compressive_hz" in params:
            txt += f" that moves down to {params['f_at_most_compressive_hz']:.4g} Hz at the most compressive load"
        if "law_held_below_MPa" in params:
            txt += f", held at its value at {params['law_held_below_MPa']:.3g} MPa under more compressive loads"
        if "law_held_above_MPa" in params:
            txt += f", held at its value at {params['law_held_above_MPa']:.3g} MPa under less compressive loads"
        return txt


FREE_LAW = (-math.inf, math.inf)    # the law over every load (no `law_held_*` keys)


def law_held(p: Sequence[float]) -> tuple[float, float]:
    """The static stresses a resonance parameter's law runs over: (f, zeta, beta) runs over every
    load; (f, zeta, beta, lo, hi), which the diagnosis makes when the law was measured over a narrow
    band of loads only (`diagnose.load_law`), holds it beyond lo..hi (`rod_load`; an infinite end
    is not held)."""
    return (float(p[3]), float(p[4])) if len(p) == 5 else FREE_LAW


def with_law_held(p: Sequence[float], held: tuple[float, float]) -> tuple[float, ...]:
    """Parameter p with its law held beyond the static stresses `held`."""
    return tuple(float(v) for v in p[:3]) + (float(held[0]), float(held[1]))


def _law_moves(fitter: FitData, p: tuple[float, float, float], zoom: Sequence[float]
               ) -> list[tuple[float, float, float]]:
    """The load law's moves from point p: the whole range of moving masses at every level, the
    frequency held where the drive excites it (a sharp resonance's law shows only once its frequency
    and damping are close, which the grid's coarse steps are not); from the grid's load-independent
    point also held at either end (the fast drive may sit at one load only); from a law, a zoom by
    the factors `zoom` on its mass, held at any of the three."""
    s0 = _mass_stress(p[2])
    excited = _stress_excited(fitter)
    spread = [_stress_extent(fitter) * k for k in LAW_SPREAD] + [math.inf]
    ends = (fitter.stress_top, fitter.stress_bottom)
    out = _laws_held(fitter, p, excited, spread)
    if math.isinf(s0):
        for held in ends:
            out += _laws_held(fitter, p, held, spread)
    else:
        for held in (excited,) + ends:
            out += _laws_held(fitter, p, held, [s0 * k for k in zoom])
    return out


def _laws_held(fitter: FitData, p: tuple[float, float, float], held: float, masses: Sequence[float]
               ) -> list[tuple[float, float, float]]:
    """Point p's resonance at the static stress `held`, with each of the moving masses `masses`."""
    fr, z, b = p
    return [_point_held(fitter, _f_at(fr, b, fitter.stress_top, held), held, z, m) for m in masses]


def _load_ratio(fitter: FitData, beta: float) -> float:
    """f(most compressive) / f(least compressive) of a resonance law with `beta`."""
    return 1.0 / math.sqrt(1.0 + beta * _stress_extent(fitter))


def _mass_stress(beta: float) -> float:
    """The load law's physical parameter: the moving mass (load, fixture and rod) at the least
    compressive load, as the stress its weight puts on the rod, m g / A in MPa (`rod_load`:
    beta = 1 / it); infinite for a resonance that does not move with the load."""
    return math.inf if beta <= 0.0 else 1.0 / beta


def _f_at(f_top: float, beta: float, stress_top: float, stress: float) -> float:
    """The law's resonance at a static stress, from the one at the least compressive load."""
    return RL.resonance_hz(f_top, beta, stress_top, stress)


def _point_held(fitter: FitData, f_held: float, held: float, zeta: float, mass_stress: float
                ) -> tuple[float, float, float]:
    """The parameter point whose resonance at the static stress `held` is `f_held`, with a moving
    mass of `mass_stress` (m g / A, MPa) at the least compressive load."""
    beta = 0.0 if math.isinf(mass_stress) else 1.0 / max(mass_stress, 1e-9)
    f_top = f_held * math.sqrt(1.0 + beta * (fitter.stress_top - held))
    return _point(fitter, f_top, zeta, _load_ratio(fitter, beta))


def _stress_excited(fitter: FitData) -> float:
    """The static stress at which the drive excites a resonance most: its mean weighted by the
    drive's squared rate (a resonance answers a drive's fast part). The data pin the resonance's
    frequency there; the load law then only moves it elsewhere."""
    num = den = 0.0
    for d in fitter.data:
        w = np.square(np.diff(d.u) / d.dt[1:]) if d.u.size > 1 else np.zeros(0)
        num += float(w @ fitter.static_stress(d)[1:])
        den += float(w.sum())
    s = num / den if den > 0 else fitter.stress_ref
    return min(max(s, fitter.stress_bottom), fitter.stress_top)


def _point(fitter: FitData, f_top: float, zeta: float, ratio: float) -> tuple[float, float, float]:
    """The parameter point (resonance at the least compressive load, damping, beta) of a frequency,
    a damping (at most MAX_ZETA) and a heaviest/lightest frequency ratio (MIN_LOAD_RATIO..1)."""
    ratio = min(max(ratio, MIN_LOAD_RATIO), 1.0)
    return (float(min(f_top, _f_max(fitter))), float(min(zeta, MAX_ZETA)),
            float((ratio ** -2 - 1.0) / _stress_extent(fitter)) if fitter.stress_varies else 0.0)


def _f_max(fitter: FitData) -> float:
    """The highest resonance (at the least compressive load) the recordings' sampling resolves."""
    return TOP_OF_NYQUIST * 0.5 / fitter.dt_min


def _stress_extent(f: FitData) -> float:
    return max(f.stress_top - f.stress_bottom, 1e-9)      # the loads' static stresses (rod_load)


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


class _RodLoadState:
    """The load dynamics stepped (`rod_load.RodLoadStepper`): the static stress first (`seen_stress`,
    which also sets the resonance), then forward on the output, or its exact inverse on the reference."""

    def __init__(self, m: Dynamics, dt: float) -> None:
        self.rl = RL.RodLoadStepper(m.block, dt)

    def reset(self, initial_drive: float) -> None:
        self.rl.reset()

    def seen_stress(self, stress_MPa: float | None) -> float:
        return self.rl.static(stress_MPa)

    def step(self, x: StepSignals) -> None:
        x.y = self.rl.forward(x.y)

    def inverse_step(self, x: StepSignals) -> None:
        x.target = self.rl.inverse(x.target)

    def commit(self, x: StepSignals) -> None:
        pass
