"""The extended model: an SDPI/MPI core with an ordered list of physical effects around it.

Signal path (each effect optional but the static map; see `gma_ffc.effects` for each one)::

    drive -> input effects   (eddy_lag: first-order lag of the field; delay: transport delay)
          -> core SDPI/MPI   (rate-independent hysteresis; loop_width scales its play
                             thresholds with stress: an effect may reshape the core)     = y_c
          -> sum effects     static map offset + (gain + stress_gain ds) y_c + quadratic (y_c - center)^2
                             + play_correction, + stress_play (/ the older stress_width), + saturation, + creep
          -> filter effects  (dynamics, form rod_load: the load on the rod's stiffness driven by this
                             free stroke, its resonance moving with the load's static stress; files
                             without 'form' keep the older mass-spring-damper output filter)
          -> after effects   (thermal: Joule heating offset, cools at zero current)

Stress transform: an effect may supply the stress the model sees (`seen_stress`, called before
the core; the rod_load dynamics give the load's static stress, the load-cell stress with its
inertial force low-passed out), so the core, the static map and every later stage see it.

Inverse (``invert`` and ``inverse_stepper``), stage by stage backwards: the after effects are
subtracted from the reference, the filter undone by its exact inverse, the sum effects (each
linear in this sample's y_c) folded into the static map's quadratic and solved in closed form,
the core by its own inverse, the input effects by their inverse filters. Sum terms that also
depend on this sample's core input (the plays of play_correction and stress_play, saturation)
make that a scalar equation in the core input u: u = core_inverse(y_c(u)). It is solved each
sample by the secant method from the previous sample's input, kept inside a bracket once one is
found (Illinois): the terms are piecewise linear in u, so three or four tries are usually exact. (Evaluating
them at the previous sample's input instead, as before, is a fixed-point iteration run once per
sample: where a term's slope exceeds the core's, it oscillates at the sample rate.) A delay
cannot be undone causally: batch ``invert`` previews the known reference by ``preview_s``; the
inverse stepper expects the caller to feed ``reference(t + preview_s)``.

The file form (`to_dict`, version 1) keeps one mapping per block under ``blocks``; each effect
class reads and writes its own keys.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from .effects import by_block_key
from .effects.base import BatchSignals, Effect, EffectState, PlayStart, StepSignals, refuse_unknown_keys, time_steps
from .effects.static import StaticMap
from .errors import ModelError
from .model import refuse_stress_outside

KIND = "extended"
SOLVE_TOL = 1e-12          # the inverse's core-input solve: converged within this fraction of the drive range
SOLVE_MAX_TRIES = 60       # then the best input found is taken (a flat or non-invertible stretch); bounds the tick


def _stress_array(stress: Any, n: int) -> np.ndarray:
    if stress is None:
        return np.zeros(n)
    s = np.asarray(stress, dtype=float)
    if s.ndim == 0:
        return np.full(n, float(s))
    if s.shape != (n,):
        raise ModelError(f"stress_MPa has {s.size} values but the drive has {n}")
    return s


def effects_from_blocks(blocks: Mapping[str, Any], base: Any) -> list[Effect]:
    """The effect objects a model file's blocks describe (ModelError for unknown or damaged blocks)."""
    owners = by_block_key()
    unknown = set(blocks) - set(owners)
    if unknown:
        raise ModelError(f"extended model: unknown block(s) {sorted(unknown)}; known: {sorted(owners)}")
    for key, block in blocks.items():
        refuse_unknown_keys(key, block, owners[key].block_keys[key])
    out = []
    for cls in dict.fromkeys(owners[k] for k in blocks):
        eff = cls.from_blocks(blocks, base)
        if eff is not None:
            out.append(eff)
    return out


class ExtendedModel:
    """An SDPI/MPI core with physical effects around it (see module docstring).

    `chain` is either the effect objects (any order: they are placed by their position on the
    signal path) or a model file's ``blocks`` mapping. Without a static map, the identity one is used.
    `effects` are the names the diagnosis gave (kept in the file for the reader).
    """

    kind = KIND

    def __init__(self, base: Any, chain: Mapping[str, Any] | Sequence[Effect] | None = None,
                 effects: list[str] | None = None) -> None:
        self.base = base
        if chain is None or isinstance(chain, Mapping):
            items = effects_from_blocks(chain or {}, base)
        else:
            items = list(chain)
        statics = [e for e in items if isinstance(e, StaticMap)]
        self.static: StaticMap = statics[0] if statics else StaticMap()
        if not statics:
            items.append(self.static)
        self.chain: list[Effect] = sorted(items, key=lambda e: e.position)
        self.effects = list(effects or [])
        self.core: Any = base            # what runs between the input and sum stages
        for e in self.chain:
            self.core = e.wrap_core(self.core)

    # ----------------------------------------------------------------- contract properties
    @property
    def stress_range_MPa(self) -> Any:
        return self.base.stress_range_MPa

    @property
    def drive_range(self) -> Any:
        return self.base.drive_range

    @property
    def drive_name(self) -> str:
        return getattr(self.base, "drive_name", "current_A")

    @property
    def preview_s(self) -> float:
        """How far ahead the inverse stepper's reference must be (the transport delay)."""
        return float(sum(e.preview_s for e in self.chain))

    def blocks(self) -> dict[str, dict[str, Any]]:
        """The model file's blocks, in signal-path order (the static map always among them)."""
        out: dict[str, dict[str, Any]] = {}
        for e in self.chain:
            out.update(e.to_blocks())
        return out

    def stage(self, name: str) -> list[Effect]:
        return [e for e in self.chain if e.stage == name]

    # ----------------------------------------------------------------- batch forward
    def core_input(self, time_s: np.ndarray, drive: np.ndarray, initial_drive: float | None = None) -> np.ndarray:
        """The drive as the core sees it after the input-side effects (at rest at initial_drive before)."""
        u = np.asarray(drive, dtype=float)
        u0 = float(u[0]) if initial_drive is None else float(initial_drive)
        dt, dt_med = time_steps(time_s)
        for e in self.stage("input"):
            u = e.apply_input(u, dt, dt_med, u0)
        return np.ascontiguousarray(u)

    def resolve_initial_state(self, drive: Any, stress_MPa: Any = None, initial_state: Any = None,
                              measured_um: Any = None, time_s: Any = None) -> Any:
        """The core's initial state (`gma_ffc.initial_state`) for the drive and the stress as the core
        sees them: the same start `simulate` resolves for itself."""
        t = np.arange(len(drive), dtype=float) if time_s is None else np.asarray(time_s, dtype=float)
        u3 = self.core_input(t, np.asarray(drive, dtype=float))
        seen = None if stress_MPa is None else self.seen_stress(t, stress_MPa)
        return self.core.resolve_initial_state(u3, seen, initial_state, measured_um, t)

    def simulate(self, time_s: Any, drive: Any, stress_MPa: Any = None, initial_drive: float | None = None,
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
        stress_MPa = self.seen_stress(t, stress_MPa)
        if initial_drive is None:
            # resolved here, once, so the output side's plays can start from the same history
            plays = self.core.resolve_initial_state(u3, stress_MPa if self.stress_range_MPa else None, initial_state,
                                                    measured_um, t).play_state
            yc = np.asarray(self.core.simulate(t, u3, stress_MPa, initial_play_state=plays), dtype=float)
            start = PlayStart.of_core(self.core, float(u3[0]), plays)
        else:
            yc = np.asarray(self.core.simulate(t, u3, stress_MPa, initial_drive=float(initial_drive)), dtype=float)
            start = PlayStart.of_core_rule(self.core, float(initial_drive))
        return self.output_from_core(t, u, u3, yc, stress_MPa, initial_drive, start)

    @property
    def transforms_stress(self) -> bool:
        """True when an effect supplies the stress the core sees (the rod_load dynamics read the load
        cell, inertial force and all, and take the load's static stress from it)."""
        return any(getattr(e, "transforms_stress", False) for e in self.chain)

    def seen_stress(self, time_s: np.ndarray, stress_MPa: Any) -> Any:
        """The stress the core and the output stages see: as given, unless an effect transforms it
        (the rod_load dynamics: the load's static stress)."""
        if not self.transforms_stress:
            return stress_MPa
        t = np.asarray(time_s, dtype=float)
        dt, _ = time_steps(t)
        for e in self.chain:
            if getattr(e, "transforms_stress", False):
                stress_MPa = e.seen_stress(stress_MPa, t, dt)
        return stress_MPa

    def output_from_core(self, t: np.ndarray, drive: np.ndarray, u3: np.ndarray, yc: np.ndarray,
                         stress_MPa: Any, initial_drive: float | None = None,
                         play_start: PlayStart | None = None) -> np.ndarray:
        """Apply the output-side effects to the core's displacement (`stress_MPa` as the model sees
        it: `seen_stress` of the recorded one; `play_start`: where the core's plays started)."""
        dt, _ = time_steps(t)
        s = _stress_array(stress_MPa, t.size)
        sig = BatchSignals(t, dt, np.asarray(drive, dtype=float), u3, yc, s, s - self.static.stress_ref,
                           stress_MPa, initial_drive, play_start)
        y = self.static.apply(np.zeros_like(yc), sig)
        for e in self.chain:
            if e.stage != "input" and e is not self.static:
                y = e.apply(y, sig)
        return np.asarray(y)

    # ----------------------------------------------------------------- batch inverse
    def invert(self, time_s: Any, reference_um: Any, stress_MPa: Any = None) -> np.ndarray:
        """Open-loop drive; runs the inverse stepper over the reference previewed by the delay."""
        t = np.asarray(time_s, dtype=float)
        r = np.asarray(reference_um, dtype=float)
        if t.shape != r.shape or t.ndim != 1 or t.size < 2:
            raise ModelError("time_s and reference_um must be 1-D of equal length (at least 2 samples)")
        s = _stress_array(stress_MPa, t.size) if stress_MPa is not None else None
        if s is not None and self.stress_range_MPa is not None:
            refuse_stress_outside(s, self.stress_range_MPa)     # the plain model's words and advice
        if self.preview_s > 0:
            r = np.interp(t + self.preview_s, t, r)
        dt = float(np.median(np.diff(t)))
        inv = self.inverse_stepper(dt, initial_drive=self.inverse_start_drive)
        out = np.empty_like(r)
        for k in range(t.size):
            out[k] = inv.step(float(r[k]), None if s is None else float(s[k]))
        return out

    @property
    def inverse_start_drive(self) -> float:
        """Where `invert` starts: the actuator at rest at the low end of the identified range (the
        core's stepper rule from there); `simulate --initial-state drive:` this value matches it."""
        return self.drive_range[0] if math.isfinite(self.drive_range[0]) else 0.0

    # ----------------------------------------------------------------- steppers
    def forward_stepper(self, dt_s: float, initial_drive: float = 0.0) -> "ForwardStepper":
        return ForwardStepper(self, dt_s, initial_drive)

    def inverse_stepper(self, dt_s: float, initial_drive: float = 0.0) -> "InverseStepper":
        return InverseStepper(self, dt_s, initial_drive)

    # ----------------------------------------------------------------- files
    def to_dict(self) -> dict[str, Any]:
        blocks = {k: _plain(v) for k, v in self.blocks().items()}
        inverted = {k: e.inverted_text()[k] for e in self.chain for k in e.to_blocks()}
        return {"format": "gma-ffc-model", "version": 1, "kind": KIND, "effects": list(self.effects),
                "inverted": inverted, "blocks": blocks, "base": self.base.to_dict()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "ExtendedModel":
        if not isinstance(d, Mapping) or d.get("kind") != KIND:
            raise ModelError("extended model: 'kind' must be 'extended'")
        base_d = d.get("base")
        if not isinstance(base_d, Mapping):
            raise ModelError("extended model: missing 'base' (the SDPI/MPI core it extends)")
        if base_d.get("kind") == KIND:
            raise ModelError("extended model: 'base' must be an sdpi or mpi model, not another extended model")
        from .modelio import model_from_dict

        base = model_from_dict(dict(base_d), "base")     # a fault in it is named under its key
        blocks = d.get("blocks") or {}
        if not isinstance(blocks, Mapping):
            raise ModelError("extended model: 'blocks' must be a mapping")
        effects = d.get("effects") or []
        if not isinstance(effects, list) or not all(isinstance(e, str) for e in effects):
            raise ModelError(f"extended model: 'effects' must be a list of effect names (as diagnose wrote it, "
                             f"e.g. [thermal_drift]), got {effects!r}")
        return cls(base, blocks, list(effects))


def _plain(v: Any) -> Any:
    """Numbers and lists as YAML writes them (no numpy types)."""
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, np.ndarray)):
        return [_plain(x) for x in v]
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    return v


def _clamp(s: float, rng: tuple[float, float] | None) -> float:
    if rng is None:
        return s
    return min(max(s, rng[0]), rng[1])


class _Stepper:
    """What the forward and inverse steppers share: one state per effect, built once per sample
    period, and the signals they pass along (allocated once: a step allocates nothing)."""

    def __init__(self, model: ExtendedModel, dt_s: float, inverse: bool) -> None:
        if not (dt_s > 0 and math.isfinite(dt_s)):
            raise ModelError(f"dt_s must be a positive number, got {dt_s!r}")
        self.m = model
        self.dt = float(dt_s)
        self._x = StepSignals()
        self._sref = model.static.stress_ref
        self._range = model.stress_range_MPa
        states = {id(e): e.state(self.dt, self._sref, inverse) for e in model.chain}
        self._static = states[id(model.static)]
        self._input: list[EffectState] = [states[id(e)] for e in model.stage("input")]
        self._sum: list[EffectState] = [states[id(e)] for e in model.stage("sum")]
        self._filter: list[EffectState] = [states[id(e)] for e in model.stage("filter")]
        self._after: list[EffectState] = [states[id(e)] for e in model.stage("after")]
        self._all = list(states.values())
        # stress transforms (the rod_load dynamics' static stress), applied before the clamp
        self._seen: list[Any] = [states[id(e)] for e in model.chain if getattr(e, "transforms_stress", False)
                                 and hasattr(states[id(e)], "seen_stress")]

    def _reset_states(self, u1: float) -> None:
        for st in self._all:
            st.reset(u1)
        start = PlayStart.of_core_rule(self.m.core, u1)     # as the core's stepper starts
        for st in self._all:
            if hasattr(st, "start_plays"):
                st.start_plays(u1, start)

    def _stress(self, stress_MPa: float | None) -> None:
        x = self._x
        for st in self._seen:
            stress_MPa = st.seen_stress(stress_MPa)
        x.s = 0.0 if stress_MPa is None else _clamp(float(stress_MPa), self._range)
        x.ds = x.s - self._sref


class ForwardStepper(_Stepper):
    """Sample-by-sample forward model; equals `ExtendedModel.simulate` for uniform sampling."""

    def __init__(self, model: ExtendedModel, dt_s: float, initial_drive: float = 0.0) -> None:
        super().__init__(model, dt_s, inverse=False)
        self._outputs = [st for st in self._sum if st is not self._static] + self._filter + self._after
        self._core = model.core.forward_stepper(self.dt, initial_drive=float(initial_drive))
        self._reset_states(float(initial_drive))

    def reset(self, initial_drive: float = 0.0) -> None:
        self._reset_states(float(initial_drive))
        self._core.reset(float(initial_drive))

    def step(self, drive: float, stress_MPa: float | None = None) -> float:
        x = self._x
        x.u1 = float(drive)
        x.u3 = x.u1
        for st in self._input:
            st.step(x)
        self._stress(stress_MPa)
        x.yc = float(self._core.step(x.u3, x.s))
        self._static.step(x)
        for st in self._outputs:
            st.step(x)
        return float(x.y)


class InverseStepper(_Stepper):
    """Sample-by-sample inverse (reference -> drive); see the module docstring for each stage.

    With a delay in the model, feed ``reference(t + preview_s)``: a delay cannot be undone causally.
    """

    def __init__(self, model: ExtendedModel, dt_s: float, initial_drive: float = 0.0) -> None:
        super().__init__(model, dt_s, inverse=True)
        self.preview_s = model.preview_s
        self._before_sum = self._after[::-1] + self._filter[::-1]
        self._input_back = self._input[::-1]
        self._solve = getattr(self._static, "solve")
        self._core = model.core.inverse_stepper(self.dt, initial_drive=float(initial_drive))
        # the core input is solved for when a sum term reads it (see the module docstring)
        self._reading = [st for st in self._sum if getattr(st, "reads_input", False)]
        self._fixed = [st for st in self._sum if not getattr(st, "reads_input", False)]
        # a core without `peek` (a plugin's) keeps the older scheme: those terms at the previous input
        self._implicit = bool(self._reading) and hasattr(self._core, "peek")
        self._const_fixed = self._lin_fixed = 0.0
        lo, hi = model.drive_range
        self._tol = SOLVE_TOL * max(abs(hi - lo), 1e-12)
        self._yc_try = 0.0
        self._start(float(initial_drive))

    def _start(self, u1: float) -> None:
        self._reset_states(u1)
        self._x.u3_prev = u1
        self._x.drive_prev = u1

    def reset(self, initial_drive: float = 0.0) -> None:
        self._start(float(initial_drive))
        self._core.reset(float(initial_drive))

    def step(self, reference_um: float, stress_MPa: float | None = None) -> float:
        x = self._x
        self._stress(stress_MPa)
        x.target = float(reference_um)
        for st in self._before_sum:
            st.inverse_step(x)
        if self._implicit:
            self._solve_input(x)
        else:
            x.u3_at = x.u3_prev
            x.drive_at = x.drive_prev
            x.yc = self._core_output(x)
        u3 = float(self._core.step(x.yc, x.s))
        x.u3 = u3
        for st in self._sum:
            st.commit(x)
        for st in self._input_back:
            st.inverse_step(x)
        x.u3_prev = u3
        x.drive_prev = x.u3
        return float(x.u3)

    def _core_output(self, x: StepSignals) -> float:
        """The core output y_c the sum stage needs for x.target, its terms taken at x.u3_at / x.drive_at."""
        x.const = 0.0
        x.lin = 0.0
        for st in self._sum:
            st.inverse_step(x)
        return float(self._solve(x))

    def _miss(self, x: StepSignals, u: float) -> float:
        """core_inverse(y_c(u)) - u: zero at this sample's core input (y_c(u) kept in _yc_try)."""
        x.u3_at = u
        x.drive_at = u if not self._input else x.drive_prev    # the drive is the core input without input effects
        x.const = self._const_fixed
        x.lin = self._lin_fixed
        for st in self._reading:
            st.inverse_step(x)
        yc = float(self._solve(x))
        self._yc_try = yc
        return float(self._core.peek(yc, x.s)) - u

    def _solve_input(self, x: StepSignals) -> None:
        """Root of _miss (strictly decreasing when the model is strictly increasing in its drive):
        secant steps from the previous sample's input until the root is bracketed, then the Illinois
        variant of regula falsi, which keeps the bracket and converges superlinearly even where the
        core's inverse is steep. Sets x.yc to the y_c of the best input found; allocates nothing."""
        tol = self._tol
        x.const = 0.0
        x.lin = 0.0
        for st in self._fixed:            # the terms that do not depend on the input: once per sample
            st.inverse_step(x)
        self._const_fixed, self._lin_fixed = x.const, x.lin
        u0 = x.u3_prev
        h0 = self._miss(x, u0)
        best_h, best_yc = abs(h0), self._yc_try
        u1 = u0 + h0                      # the core inverse's own answer at the previous input
        tries = 0
        bracketed = False
        while best_h > tol and tries < SOLVE_MAX_TRIES:
            tries += 1
            h1 = self._miss(x, u1)
            if abs(h1) < best_h:
                best_h, best_yc = abs(h1), self._yc_try
            if best_h <= tol:
                break
            if h0 * h1 < 0.0:
                bracketed = True
                break
            u2 = u1 + h1 if h1 == h0 else u1 - h1 * (u1 - u0) / (h1 - h0)
            if u2 != u2:                  # NaN: nothing better to be found
                break
            u0, h0, u1 = u1, h1, u2
        if bracketed:                     # between u0 and u1 (h0, h1 of opposite signs)
            a, fa, b, fb = u0, h0, u1, h1
            p, fp = a, fa                 # the iterate before b (for the secant through the last two)
            while tries < SOLVE_MAX_TRIES and abs(b - a) > tol:
                tries += 1
                c = b - fb * (b - p) / (fb - fp) if fb != fp else math.nan
                if not (min(a, b) < c < max(a, b)):      # NaN-safe: regula falsi on the bracket instead
                    c = b - fb * (b - a) / (fb - fa)
                p, fp = b, fb
                fc = self._miss(x, c)
                if abs(fc) < best_h:
                    best_h, best_yc = abs(fc), self._yc_try
                    if best_h <= tol:
                        break
                if fc * fb < 0.0:         # the root lies between b and c: b becomes the far end
                    a, fa = b, fb
                else:                     # the far end kept twice in a row: halve its weight (Illinois)
                    fa *= 0.5
                b, fb = c, fc
        x.yc = best_yc
