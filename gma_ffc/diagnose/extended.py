"""The extended model: physical blocks the diagnosis found, wrapped around an SDPI/MPI core.

Signal path (every block optional)::

    drive -> eddy_lag (first-order lag of the effective field: eddy currents / magnetic diffusion)
          -> delay (transport delay)
          -> core SDPI/MPI (rate-independent hysteresis)           = y_c
          -> static map: offset + (gain + stress_gain (s - s_ref)) y_c + quadratic (y_c - center)^2
             + play_correction: sum_i a_i (H_ri[u] - u)             (loop-width recalibration)
             + stress_play: sum_i c_i (s - s_ref) (H_ri[u] - u)     (play weights that vary with stress)
             + stress_width: k (s - s_ref) (y_c,wide - y_c) / eps   (core loop widening with stress: the
               core re-run with its play thresholds scaled by 1 + eps, a chord of the coercive-current change)
             + saturation: a (u - hi)+ + b (u - hi)+^2 (+ the same below lo)  (beyond the identified range)
          -> creep: + g mean_k (lag(y_c, tau s_k) - y_c), s_k = 0.1, 1, 10 (distributed relaxation)
          -> dynamics: mass-spring-damper, resonance moving with the load mass the stress implies
          -> thermal: + k lag(drive^2, tau) [+ k_f lag(drive^2, tau_f)]  (Joule heating, cools at zero
             current; the optional fast part is a coil that heats quicker than the rod)

Inverse (``invert`` and ``inverse_stepper``), block by block: thermal offset from the commanded
drive, dynamics by its exact FIR inverse, static map + creep in closed form (quadratic root),
core by its own inverse, eddy lag by its exact inverse filter; the saturation term from the
drive of the previous sample. A delay
cannot be undone causally: batch ``invert`` previews the known reference by ``preview_s``;
the inverse stepper expects the caller to feed ``reference(t + preview_s)``.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from ..errors import ModelError
from . import kernels as K

KIND = "extended"

INVERTED = {
    "saturation": "correction from the drive of the previous sample",
    "eddy_lag": "exact inverse filter",
    "delay": "by preview of the known reference (batch invert); inverse_stepper expects reference(t + preview_s)",
    "static": "closed form (quadratic root)",
    "play_correction": "using the play states of the previous sample",
    "stress_play": "using the play states of the previous sample",
    "stress_width": "using the widened core's output at the previous sample's core input",
    "creep": "exact (closed form with the static map)",
    "dynamics": "exact inverse filter (3-tap FIR on the reference)",
    "thermal": "offset model driven by the commanded drive of the previous sample",
}


def widened_core(base: Any, eps: float) -> Any:
    """The core with every play threshold (loop width, coercive current) scaled by 1 + eps."""
    import dataclasses

    th = getattr(base, "play_thresholds", None)
    if th is None or not dataclasses.is_dataclass(base):
        raise ModelError("extended model: stress_width needs an SDPI/MPI core with play thresholds")
    return dataclasses.replace(base, play_thresholds=np.asarray(th, dtype=float) * (1.0 + eps))


CREEP_SPREAD = (0.1, 1.0, 10.0)
THERMAL_FAST_RATIO = 0.125        # the fast heating part's time constant relative to the slow one (coil vs rod)
MIN_FAST_HEAT_S = 10.0            # no thermal part is quicker than this (thermal mass); faster drift is creep-like   # creep time constants relative to tau_s: a distributed (log-like) relaxation


def saturation_scalar(u: float, sat: Mapping[str, float]) -> float:
    """`saturation_term` for one sample in plain float arithmetic: the steppers' form (no numpy
    scalars, so a step allocates nothing)."""
    hi = u - sat["hi"] if u > sat["hi"] else 0.0
    lo = sat["lo"] - u if u < sat["lo"] else 0.0
    return sat["lin_hi"] * hi + sat["quad_hi"] * hi * hi + sat["lin_lo"] * lo + sat["quad_lo"] * lo * lo


def saturation_term(u: Any, sat: Mapping[str, float]) -> Any:
    """Hinge correction beyond the identified drive range (arrays; see `saturation_scalar`)."""
    hi = np.maximum(np.asarray(u, dtype=float) - sat["hi"], 0.0)
    lo = np.maximum(sat["lo"] - np.asarray(u, dtype=float), 0.0)
    return sat["lin_hi"] * hi + sat["quad_hi"] * hi * hi + sat["lin_lo"] * lo + sat["quad_lo"] * lo * lo


def _stress_array(stress: Any, n: int) -> np.ndarray:
    if stress is None:
        return np.zeros(n)
    s = np.asarray(stress, dtype=float)
    if s.ndim == 0:
        return np.full(n, float(s))
    if s.shape != (n,):
        raise ModelError(f"stress_MPa has {s.size} values but the drive has {n}")
    return s


def _time_steps(time_s: np.ndarray) -> tuple[np.ndarray, float]:
    t = np.asarray(time_s, dtype=float)
    if t.size < 2:
        return np.ones(t.size), 1.0
    d = np.diff(t)
    med = float(np.median(d))
    return np.concatenate(([med], d)), med


class ExtendedModel:
    """An SDPI/MPI core with physical input- and output-side blocks (see module docstring)."""

    kind = KIND

    def __init__(self, base: Any, blocks: Mapping[str, Any] | None = None,
                 effects: list[str] | None = None) -> None:
        self.base = base
        b = {k: (dict(v) if isinstance(v, Mapping) else v) for k, v in (blocks or {}).items()}
        self.saturation: dict | None = b.get("saturation")
        self.eddy_lag: dict | None = b.get("eddy_lag")
        self.delay: dict | None = b.get("delay")
        self.static: dict = {"offset_um": 0.0, "gain": 1.0, "stress_gain_per_MPa": 0.0,
                             "quadratic_per_um": 0.0, "center_um": 0.0, "stress_ref_MPa": 0.0}
        self.static.update(b.get("static") or {})
        self.stress_play: dict | None = b.get("stress_play")
        self.play_correction: dict | None = b.get("play_correction")
        self.stress_width: dict | None = b.get("stress_width")
        self.creep: dict | None = b.get("creep")
        self.dynamics: dict | None = b.get("dynamics")
        self.thermal: dict | None = b.get("thermal")
        self.effects = list(effects or [])
        self._check()

    # ----------------------------------------------------------------- contract properties
    @property
    def stress_range_MPa(self):
        return self.base.stress_range_MPa

    @property
    def drive_range(self):
        return self.base.drive_range

    @property
    def drive_name(self) -> str:
        return getattr(self.base, "drive_name", "current_A")

    @property
    def preview_s(self) -> float:
        """How far ahead the inverse stepper's reference must be (the transport delay)."""
        return float(self.delay["delay_s"]) if self.delay else 0.0

    def blocks(self) -> dict[str, Any]:
        return {"saturation": self.saturation, "eddy_lag": self.eddy_lag, "delay": self.delay,
                "static": self.static, "play_correction": self.play_correction, "stress_play": self.stress_play,
                "stress_width": self.stress_width, "creep": self.creep,
                "dynamics": self.dynamics, "thermal": self.thermal}

    def _check(self) -> None:
        def positive(block: dict | None, key: str, name: str) -> None:
            if block is None:
                return
            v = block.get(key)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ModelError(f"extended model: {name}.{key} must be a positive number, got {v!r}")

        positive(self.eddy_lag, "tau_s", "eddy_lag")
        positive(self.creep, "tau_s", "creep")
        positive(self.thermal, "tau_s", "thermal")
        if self.thermal is not None and ("fast_tau_s" in self.thermal or "fast_gain_um_per_A2" in self.thermal):
            positive(self.thermal, "fast_tau_s", "thermal")
            g = self.thermal.get("fast_gain_um_per_A2")
            if not isinstance(g, (int, float)) or not math.isfinite(g):
                raise ModelError(f"extended model: thermal.fast_gain_um_per_A2 must be a finite number, got {g!r}")
        positive(self.dynamics, "f_ref_hz", "dynamics")
        positive(self.dynamics, "zeta", "dynamics")
        if self.delay is not None:
            d = self.delay.get("delay_s")
            if not isinstance(d, (int, float)) or not math.isfinite(d) or d < 0:
                raise ModelError(f"extended model: delay.delay_s must be >= 0, got {d!r}")
        for key, v in self.static.items():
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ModelError(f"extended model: static.{key} must be a finite number, got {v!r}")
        if abs(self.static["gain"]) < 1e-9:
            raise ModelError("extended model: static.gain must not be zero")
        th_all, c0_all, c1_all = [], [], []
        for name, key in (("play_correction", "coefficients"), ("stress_play", "coefficients_per_MPa")):
            block = getattr(self, name)
            if block is None:
                continue
            try:
                th = np.asarray(block.get("thresholds", []), dtype=float)
                co = np.asarray(block.get(key, []), dtype=float)
            except (TypeError, ValueError):
                raise ModelError(f"extended model: {name} thresholds and {key} must be numbers") from None
            if th.shape != co.shape or th.ndim != 1 or not np.all(np.isfinite(th)) or not np.all(np.isfinite(co)) \
                    or np.any(th < 0):
                raise ModelError(f"extended model: {name} needs equal-length finite thresholds (>= 0) and {key}")
            th_all.append(th)
            c0_all.append(co if name == "play_correction" else np.zeros_like(co))
            c1_all.append(co if name == "stress_play" else np.zeros_like(co))
        # one play bank for both terms: weight_j = c0_j + c1_j (s - s_ref)
        self.play_thresholds = np.concatenate(th_all) if th_all else np.zeros(0)
        self.play_c0 = np.concatenate(c0_all) if c0_all else np.zeros(0)
        self.play_c1 = np.concatenate(c1_all) if c1_all else np.zeros(0)
        self._wide = None
        if self.stress_width is not None:
            e = self.stress_width.get("eps")
            if not isinstance(e, (int, float)) or not math.isfinite(e) or e == 0 or e <= -0.9:
                raise ModelError(f"extended model: stress_width.eps must be a non-zero number above -0.9, got {e!r}")
            k = self.stress_width.get("coef_per_MPa")
            if not isinstance(k, (int, float)) or not math.isfinite(k):
                raise ModelError(f"extended model: stress_width.coef_per_MPa must be a finite number, got {k!r}")
            self._wide = widened_core(self.base, float(self.stress_width["eps"]))
        if self.saturation is not None:
            for key in ("lo", "hi", "lin_lo", "quad_lo", "lin_hi", "quad_hi"):
                v = self.saturation.get(key)
                if not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise ModelError(f"extended model: saturation.{key} must be a finite number, got {v!r}")

    # ----------------------------------------------------------------- batch forward
    def core_input(self, time_s: np.ndarray, drive: np.ndarray, initial_drive: float | None = None) -> np.ndarray:
        """The drive as the core sees it after the input-side blocks (at rest at initial_drive before)."""
        u = np.asarray(drive, dtype=float)
        u0 = float(u[0]) if initial_drive is None else float(initial_drive)
        dt, dt_med = _time_steps(time_s)
        if self.eddy_lag:
            u = K.lag_filter(u, dt, float(self.eddy_lag["tau_s"]), u0)
        if self.delay and self.delay["delay_s"] > 0:
            u = K.delay_filter(u, float(self.delay["delay_s"]) / dt_med, u0)
        return np.ascontiguousarray(u)

    def resolve_initial_state(self, drive: Any, stress_MPa: Any = None, initial_state: Any = None,
                              measured_um: Any = None, time_s: Any = None) -> Any:
        """The core's initial state (`gma_ffc.initial_state`) for the drive as the core sees it."""
        t = np.arange(len(drive), dtype=float) if time_s is None else np.asarray(time_s, dtype=float)
        u3 = self.core_input(t, np.asarray(drive, dtype=float))
        return self.base.resolve_initial_state(u3, stress_MPa, initial_state, measured_um, t)

    def simulate(self, time_s, drive, stress_MPa=None, initial_drive: float | None = None,
                 initial_state: Any = None, measured_um: Any = None) -> np.ndarray:
        """Displacement for a drive history, at rest at `initial_drive` if given, else from the
        core's `initial_state` rule (default: the shared `gma_ffc.initial_state.DEFAULT`)."""
        t = np.asarray(time_s, dtype=float)
        u = np.asarray(drive, dtype=float)
        if t.shape != u.shape or t.ndim != 1 or t.size == 0:
            raise ModelError(f"time_s and drive must be 1-D of equal, non-zero length ({t.shape} vs {u.shape})")
        if not np.all(np.isfinite(u)):
            raise ModelError("drive contains NaN or infinite values")
        u3 = self.core_input(t, u, initial_drive)
        if initial_drive is None:
            yc = np.asarray(self.base.simulate(t, u3, stress_MPa, initial_state=initial_state,
                                               measured_um=measured_um), dtype=float)
        else:
            yc = np.asarray(self.base.simulate(t, u3, stress_MPa, initial_drive=float(initial_drive)), dtype=float)
        return self.output_from_core(t, u, u3, yc, stress_MPa, initial_drive)

    def output_from_core(self, t: np.ndarray, drive: np.ndarray, u3: np.ndarray, yc: np.ndarray,
                         stress_MPa: Any, initial_drive: float | None = None) -> np.ndarray:
        """Apply the output-side blocks to the core's displacement."""
        n = t.size
        dt, _ = _time_steps(t)
        s = _stress_array(stress_MPa, n)
        st = self.static
        ds = s - st["stress_ref_MPa"]
        y = (st["offset_um"] + (st["gain"] + st["stress_gain_per_MPa"] * ds) * yc
             + st["quadratic_per_um"] * (yc - st["center_um"]) ** 2)
        if self.play_thresholds.size:
            p0 = float(u3[0]) if initial_drive is None else float(initial_drive)
            plays = K.play_bank(u3, self.play_thresholds, p0) - u3[:, None]
            y = y + plays @ self.play_c0 + ds * (plays @ self.play_c1)
        if self._wide is not None:
            if initial_drive is None:
                yw = np.asarray(self._wide.simulate(t, u3, stress_MPa), dtype=float)
            else:
                yw = np.asarray(self._wide.simulate(t, u3, stress_MPa, initial_drive=float(initial_drive)), dtype=float)
            sw = self.stress_width
            y = y + sw["coef_per_MPa"] * ds * (yw - yc) / sw["eps"]
        if self.saturation:
            y = y + saturation_term(np.asarray(drive, dtype=float), self.saturation)
        if self.creep:
            acc = np.zeros_like(yc)
            for k in CREEP_SPREAD:
                acc += K.lag_filter(yc, dt, float(self.creep["tau_s"]) * k, float(yc[0])) - yc
            y = y + self.creep["gain"] * acc / len(CREEP_SPREAD)
        if self.dynamics:
            d = self.dynamics
            y = K.msd_filter(np.ascontiguousarray(y), dt, s, 2 * math.pi * d["f_ref_hz"], d["zeta"],
                             d.get("beta_per_MPa", 0.0), d.get("stress_ref_MPa", 0.0), float(y[0]))
        if self.thermal:
            theta = K.lag_filter(np.asarray(drive, dtype=float) ** 2, dt, float(self.thermal["tau_s"]), 0.0)
            y = y + self.thermal["gain_um_per_A2"] * theta
            if "fast_tau_s" in self.thermal:
                fast = K.lag_filter(np.asarray(drive, dtype=float) ** 2, dt, float(self.thermal["fast_tau_s"]), 0.0)
                y = y + self.thermal["fast_gain_um_per_A2"] * fast
        return np.asarray(y)

    # ----------------------------------------------------------------- batch inverse
    def invert(self, time_s, reference_um, stress_MPa=None) -> np.ndarray:
        """Open-loop drive; runs the inverse stepper over the reference previewed by the delay."""
        t = np.asarray(time_s, dtype=float)
        r = np.asarray(reference_um, dtype=float)
        if t.shape != r.shape or t.ndim != 1 or t.size < 2:
            raise ModelError("time_s and reference_um must be 1-D of equal length (at least 2 samples)")
        lo, hi = self.stress_range_MPa or (-math.inf, math.inf)
        s = _stress_array(stress_MPa, t.size) if stress_MPa is not None else None
        if s is not None and (s.min() < lo - 1e-9 or s.max() > hi + 1e-9):
            raise ModelError(f"stress {s.min():.3g}..{s.max():.3g} MPa is outside the model's range {lo:.3g}..{hi:.3g} MPa")
        if self.preview_s > 0:
            r = np.interp(t + self.preview_s, t, r)
        dt = float(np.median(np.diff(t)))
        # the actuator rests at the low end of the identified range, as the core's own inverse assumes
        x0 = self.drive_range[0] if math.isfinite(self.drive_range[0]) else 0.0
        inv = self.inverse_stepper(dt, initial_drive=x0)
        out = np.empty_like(r)
        for k in range(t.size):
            out[k] = inv.step(float(r[k]), None if s is None else float(s[k]))
        return out

    # ----------------------------------------------------------------- steppers
    def forward_stepper(self, dt_s: float, initial_drive: float = 0.0) -> "ForwardStepper":
        return ForwardStepper(self, dt_s, initial_drive)

    def inverse_stepper(self, dt_s: float, initial_drive: float = 0.0) -> "InverseStepper":
        return InverseStepper(self, dt_s, initial_drive)

    # ----------------------------------------------------------------- files
    def to_dict(self) -> dict[str, Any]:
        def clean(v: Any) -> Any:
            if isinstance(v, dict):
                return {k: clean(x) for k, x in v.items()}
            if isinstance(v, (list, tuple, np.ndarray)):
                return [clean(x) for x in v]
            if isinstance(v, (np.floating, np.integer)):
                return v.item()
            return v

        blocks = {k: clean(v) for k, v in self.blocks().items() if v is not None}
        return {"format": "gma-ffc-model", "version": 1, "kind": KIND, "effects": list(self.effects),
                "inverted": {k: INVERTED[k] for k in blocks},
                "blocks": blocks, "base": self.base.to_dict()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "ExtendedModel":
        if not isinstance(d, Mapping) or d.get("kind") != KIND:
            raise ModelError("extended model: 'kind' must be 'extended'")
        base_d = d.get("base")
        if not isinstance(base_d, Mapping):
            raise ModelError("extended model: missing 'base' (the SDPI/MPI core it extends)")
        if base_d.get("kind") == KIND:
            raise ModelError("extended model: 'base' must be an sdpi or mpi model, not another extended model")
        from ..modelio import model_from_dict

        base = model_from_dict(dict(base_d))
        blocks = d.get("blocks") or {}
        if not isinstance(blocks, Mapping):
            raise ModelError("extended model: 'blocks' must be a mapping")
        unknown = set(blocks) - set(INVERTED)
        if unknown:
            raise ModelError(f"extended model: unknown block(s) {sorted(unknown)}; known: {sorted(INVERTED)}")
        return cls(base, blocks, list(d.get("effects") or []))


class _BlockStepper:
    """What the forward and inverse steppers share: filter coefficients and buffers of the
    blocks, set up once per sample period, and the widened core's stepper."""

    def __init__(self, model: ExtendedModel, dt_s: float) -> None:
        if not (dt_s > 0 and math.isfinite(dt_s)):
            raise ModelError(f"dt_s must be a positive number, got {dt_s!r}")
        self.m = model
        self.dt = float(dt_s)
        self._a_eddy = K.lag_coeff(self.dt, model.eddy_lag["tau_s"]) if model.eddy_lag else 0.0
        self._a_creep = np.array([K.lag_coeff(self.dt, model.creep["tau_s"] * k) for k in CREEP_SPREAD]) \
            if model.creep else np.zeros(0)
        self._z = np.zeros(self._a_creep.size)
        self._a_heat = K.lag_coeff(self.dt, model.thermal["tau_s"]) if model.thermal else 0.0
        self._fast_heat = bool(model.thermal) and "fast_tau_s" in model.thermal
        self._a_heat_fast = K.lag_coeff(self.dt, model.thermal["fast_tau_s"]) if self._fast_heat else 0.0
        self._th = model.play_thresholds
        self._c0 = model.play_c0
        self._c1 = model.play_c1
        self._plays = np.zeros(self._th.size)
        self._core = None
        self._wide = None

    def _reset_wide(self, u1: float) -> None:
        if self.m._wide is not None:
            if self._wide is None:
                self._wide = self.m._wide.forward_stepper(self.dt, initial_drive=u1)
            else:
                self._wide.reset(u1)


class ForwardStepper(_BlockStepper):
    """Sample-by-sample forward model; equals `ExtendedModel.simulate` for uniform sampling."""

    def __init__(self, model: ExtendedModel, dt_s: float, initial_drive: float = 0.0) -> None:
        super().__init__(model, dt_s)
        dsamp = model.preview_s / self.dt
        self._whole = int(math.floor(dsamp))
        self._frac = dsamp - self._whole
        self._buf = np.zeros(self._whole + 2)
        self.reset(initial_drive)

    def reset(self, initial_drive: float = 0.0) -> None:
        u1 = float(initial_drive)
        self._reset_wide(u1)
        self._eddy = u1
        self._buf[:] = u1
        self._head = 0
        self._plays[:] = u1
        self._first = True
        self._theta = 0.0
        self._theta_fast = 0.0
        self._y1 = self._y2 = 0.0
        self._z[:] = 0.0
        if self._core is None:
            self._core = self.m.base.forward_stepper(self.dt, initial_drive=u1)
        else:
            self._core.reset(u1)

    def _delay(self, u2: float) -> float:
        n = self._buf.size
        self._head = (self._head + 1) % n
        self._buf[self._head] = u2
        v0 = self._buf[(self._head - self._whole) % n]
        v1 = self._buf[(self._head - self._whole - 1) % n]
        return (1.0 - self._frac) * v0 + self._frac * v1

    def step(self, drive: float, stress_MPa: float | None = None) -> float:
        m = self.m
        u1 = float(drive)
        if m.eddy_lag:
            self._eddy = self._a_eddy * self._eddy + (1.0 - self._a_eddy) * u1
            u2 = self._eddy
        else:
            u2 = u1
        u3 = self._delay(u2) if self._whole or self._frac else u2
        s = 0.0 if stress_MPa is None else _clamp(float(stress_MPa), m.stress_range_MPa)
        yc = float(self._core.step(u3, s))
        st = m.static
        ds = s - st["stress_ref_MPa"]
        y = (st["offset_um"] + (st["gain"] + st["stress_gain_per_MPa"] * ds) * yc
             + st["quadratic_per_um"] * (yc - st["center_um"]) ** 2)
        if self._th.size:
            acc = 0.0
            for j in range(self._th.size):
                p = min(max(self._plays[j], u3 - self._th[j]), u3 + self._th[j])
                self._plays[j] = p
                acc += (self._c0[j] + self._c1[j] * ds) * (p - u3)
            y += acc
        if self._wide is not None:
            sw = m.stress_width
            y += sw["coef_per_MPa"] * ds * (float(self._wide.step(u3, s)) - yc) / sw["eps"]
        if m.saturation:
            y += saturation_scalar(u1, m.saturation)
        if m.creep:
            acc = 0.0
            for k in range(self._z.size):
                z = yc if self._first else self._a_creep[k] * self._z[k] + (1.0 - self._a_creep[k]) * yc
                self._z[k] = z
                acc += z - yc
            y += m.creep["gain"] * acc / self._z.size
        if m.dynamics:
            if self._first:
                self._y1 = self._y2 = y
            d = m.dynamics
            w = K.msd_omega(2 * math.pi * d["f_ref_hz"], d.get("beta_per_MPa", 0.0), s, d.get("stress_ref_MPa", 0.0))
            a1, a2, kk = K.msd_coeffs(self.dt, w, d["zeta"])
            y = kk * y - a1 * self._y1 - a2 * self._y2
            self._y2 = self._y1
            self._y1 = y
        if m.thermal:
            self._theta = self._a_heat * self._theta + (1.0 - self._a_heat) * u1 * u1
            y += m.thermal["gain_um_per_A2"] * self._theta
            if self._fast_heat:
                self._theta_fast = self._a_heat_fast * self._theta_fast + (1.0 - self._a_heat_fast) * u1 * u1
                y += m.thermal["fast_gain_um_per_A2"] * self._theta_fast
        self._first = False
        return float(y)


class InverseStepper(_BlockStepper):
    """Sample-by-sample inverse (reference -> drive); see the module docstring for each block.

    With a delay in the model, feed ``reference(t + preview_s)``: a delay cannot be undone causally.
    """

    def __init__(self, model: ExtendedModel, dt_s: float, initial_drive: float = 0.0) -> None:
        super().__init__(model, dt_s)
        self.preview_s = model.preview_s
        self.reset(initial_drive)

    def reset(self, initial_drive: float = 0.0) -> None:
        u1 = float(initial_drive)
        self._reset_wide(u1)
        self._width_prev = 0.0      # (y_c,wide - y_c) / eps at the previous sample
        self._u3_prev = u1
        self._plays[:] = u1
        self._drive_prev = u1
        self._theta = 0.0
        self._theta_fast = 0.0
        self._first = True
        self._r1 = self._r2 = 0.0
        self._z[:] = 0.0
        if self._core is None:
            self._core = self.m.base.inverse_stepper(self.dt, initial_drive=u1)
        else:
            self._core.reset(u1)

    def step(self, reference_um: float, stress_MPa: float | None = None) -> float:
        m = self.m
        s = 0.0 if stress_MPa is None else _clamp(float(stress_MPa), m.stress_range_MPa)
        target = float(reference_um)
        if m.thermal:
            # heating follows the drive already commanded (one sample behind: tau_s >> dt)
            self._theta = self._a_heat * self._theta + (1.0 - self._a_heat) * self._drive_prev ** 2
            target -= m.thermal["gain_um_per_A2"] * self._theta
            if self._fast_heat:
                self._theta_fast = (self._a_heat_fast * self._theta_fast
                                    + (1.0 - self._a_heat_fast) * self._drive_prev ** 2)
                target -= m.thermal["fast_gain_um_per_A2"] * self._theta_fast
        if m.dynamics:
            if self._first:
                self._r1 = self._r2 = target
            d = m.dynamics
            w = K.msd_omega(2 * math.pi * d["f_ref_hz"], d.get("beta_per_MPa", 0.0), s, d.get("stress_ref_MPa", 0.0))
            a1, a2, kk = K.msd_coeffs(self.dt, w, d["zeta"])
            y_cr = (target + a1 * self._r1 + a2 * self._r2) / kk
            self._r2 = self._r1
            self._r1 = target
        else:
            y_cr = target
        st = m.static
        ds = s - st["stress_ref_MPa"]
        extra = 0.0
        if self._th.size:
            u = self._u3_prev
            for j in range(self._th.size):
                extra += (self._c0[j] + self._c1[j] * ds) * (min(max(self._plays[j], u - self._th[j]), u + self._th[j]) - u)
        if self._wide is not None:
            extra += m.stress_width["coef_per_MPa"] * ds * self._width_prev
        if m.saturation:
            extra += saturation_scalar(float(self._drive_prev), m.saturation)
        # creep: y = static(yc) + g mean_k a_k (z_k - yc), z_k the lags' previous states
        ga = 0.0
        zc = 0.0
        if m.creep and not self._first:
            n = self._z.size
            for k in range(n):
                ga += m.creep["gain"] * self._a_creep[k] / n
                zc += m.creep["gain"] * self._a_creep[k] * self._z[k] / n
        q = st["quadratic_per_um"]
        c0 = st["center_um"]
        lin = st["gain"] + st["stress_gain_per_MPa"] * ds - 2.0 * q * c0 - ga
        const = q * c0 * c0 + st["offset_um"] + extra + zc - y_cr
        yc = _quadratic_root(q, lin, const)
        for k in range(self._z.size):
            self._z[k] = yc if self._first else self._a_creep[k] * self._z[k] + (1.0 - self._a_creep[k]) * yc
        u3 = float(self._core.step(yc, s))
        if self._wide is not None:
            self._width_prev = (float(self._wide.step(u3, s)) - yc) / m.stress_width["eps"]
        for j in range(self._th.size):
            self._plays[j] = min(max(self._plays[j], u3 - self._th[j]), u3 + self._th[j])
        if m.eddy_lag:
            u = (u3 - self._a_eddy * self._u3_prev) / (1.0 - self._a_eddy)
        else:
            u = u3
        self._u3_prev = u3
        self._drive_prev = u
        self._first = False
        return float(u)


def _clamp(s: float, rng: tuple[float, float] | None) -> float:
    if rng is None:
        return s
    return min(max(s, rng[0]), rng[1])


def _quadratic_root(q: float, b: float, c: float) -> float:
    """Root of q x^2 + b x + c = 0 continuous with the linear solution -c/b as q -> 0."""
    if abs(q) < 1e-15:
        return -c / b
    disc = b * b - 4.0 * q * c
    if disc < 0.0:
        disc = 0.0
    root = math.sqrt(disc)
    den = b + root if b >= 0 else b - root
    if den == 0.0:
        return -b / (2.0 * q)
    return -2.0 * c / den
