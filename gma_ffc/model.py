"""The SDPI model (seed paper (16)) and its stress-independent special case, the MPI (6).

A model is plain data: thresholds, weights, stress-quadratic coefficients, the ranges it was
identified on and where it came from. Behaviour (simulate, invert, steppers) runs the numba
kernels of `operators`. Proposition 3.1 (unique invertibility) is checked exactly over the whole
stress range, not on a grid: each cumulative dead-zone weight is a quadratic in stress, so its
minimum on an interval is at an end or at the vertex.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from . import operators as ops
from .drive import drive_unit
from .errors import ModelError
from .inverse import deadzone_inverse, play_forward_state, play_inverse, play_inverse_initial_state

if TYPE_CHECKING:
    from .initial_state import ResolvedInitialState

INITIAL_STATES = ("descending", "relaxed")


@dataclass(frozen=True)
class Violation:
    """One failed invertibility constraint of Proposition 3.1."""

    constraint: str
    stress_MPa: float | None
    value: float
    required: float
    upper: bool = False        # the required value is a bound from above (an overflow), not from below

    def __str__(self) -> str:
        where = "" if self.stress_MPa is None else f" at {self.stress_MPa:.3g} MPa"
        if self.upper:
            return f"{self.constraint} = {self.value:.6g}{where}, needs <= {self.required:.3g} (its inverse overflows)"
        return f"{self.constraint} = {self.value:.6g}{where}, needs >= {self.required:.3g} " \
               f"(short by {self.required - self.value:.3g})"


PARAMETER_BOUND = 1e30
"""The largest magnitude a model file's number may hold. No actuator's parameter in um, A, V, MPa
and s comes near it, and products of a few such numbers with the largest values a recording may
hold (1e9 um, 1e6 A) stay far inside float range (1e308): a number past it is an edit gone wrong,
and simulating with it overflows (warnings, then inf) instead of being refused on load."""

MAX_PLAY_WEIGHT_SUM = float(np.sqrt(np.finfo(float).max)) * 1e-3
"""The inverse's play weights (9) divide by the square of partial sums of the play weights: a sum
beyond this (1.3e151) would overflow there, with a thousandfold margin for the products after it."""



SIGN_FLIP_SHARE = 0.5   # the share of readings that, negated, fall in the model's range: most of them, so a
                        # recording merely at other loads is not told to flip its sign


def stress_sign_advice(stress: np.ndarray, stress_range: tuple[float, float]) -> str:
    """'' or, when the readings negated would mostly lie in `stress_range`, that compression is
    negative here and how to read a load cell that logs it as positive."""
    lo, hi = stress_range
    s = np.asarray(stress, dtype=float)
    tol = 0.02 * max(hi - lo, 1.0)          # the overlap checks' margin (diagnose.checks)
    flipped = np.mean((-s >= lo - tol) & (-s <= hi + tol)) if s.size else 0.0
    if flipped < SIGN_FLIP_SHARE or np.mean((s >= lo - tol) & (s <= hi + tol)) >= SIGN_FLIP_SHARE:
        return ""
    return ("the readings negated lie in it: compression is negative in gma-ffc's recordings (docs/recordings.md); "
            "if the load cell logs compression as positive, negate the stress_MPa column")


def stress_beyond(stress: np.ndarray, lo: float, hi: float) -> float:
    """How far stresses reach outside lo..hi, in MPa (0 when all are inside)."""
    s = np.asarray(stress, dtype=float)
    return max(lo - float(s.min()), float(s.max()) - hi, 0.0)


def refuse_stress_outside(stress: np.ndarray, stress_range: tuple[float, float]) -> None:
    """ModelError when `stress` leaves `stress_range` (beyond a rounding's tolerance): how far, in
    four digits (three made -11.3 look inside -24.3..-11.3), and what to do (every model kind's words)."""
    lo, hi = stress_range
    s = np.asarray(stress, dtype=float)
    tol = 1e-6 * max(1.0, abs(lo), abs(hi))
    if s.size == 0 or (s.min() >= lo - tol and s.max() <= hi + tol):
        return
    beyond = stress_beyond(s, lo, hi)
    raise ModelError(
        f"stress {s.min():.4g}..{s.max():.4g} MPa reaches {beyond:.2g} MPa outside the model's identified "
        f"range {lo:.4g}..{hi:.4g} MPa; {stress_sign_advice(s, (lo, hi)) or 'identify with recordings covering it'}")


@dataclass(eq=False)
class SDPIModel:
    """y = c(sigma) + sum_j w_sj(sigma) S_{r_sj}[ sum_i w_hi H_{r_hi}[x - x_c] ].

    play_thresholds   r_h, ascending, r_h[0] = 0 (drive units)
    play_weights      w_h (um per drive unit after the dead-zones' unit centre slope)
    deadzone_thresholds r_s, ascending, odd count, centre one = 0 (intermediate units)
    deadzone_coeffs   (3, n_s): w_sj(sigma) = C0 + C1 sigma + C2 sigma^2, sigma in MPa
    output_coeffs     (3,): output offset c(sigma) = o0 + o1 sigma + o2 sigma^2 (um)
    input_offset      x_c: the drive value the operators are centred on
    stress_range_MPa  (lo, hi) identified on, None for a stress-independent MPI
    output_sign       +1 for an actuator whose displacement rises with the drive, -1 for one whose
                      displacement falls (a poled ceramic driven the other way): y = sign * (...)
    initial_state     the state a stepper without an explicit one starts from (file format 1's
                      field, kept): "descending" as if the drive came down to its first value,
                      "relaxed" centred on it. Batch runs take `gma_ffc.initial_state` rules.
    """

    play_thresholds: np.ndarray
    play_weights: np.ndarray
    deadzone_thresholds: np.ndarray
    deadzone_coeffs: np.ndarray
    output_coeffs: np.ndarray = field(default_factory=lambda: np.zeros(3))
    input_offset: float = 0.0
    stress_range_MPa: tuple[float, float] | None = None
    reference_stress_MPa: float | None = None
    drive_range: tuple[float, float] = (-np.inf, np.inf)
    drive_name: str = "current_A"
    initial_state: str = "descending"
    provenance: dict[str, Any] = field(default_factory=dict)
    output_sign: float = 1.0

    def __post_init__(self) -> None:
        self.play_thresholds = np.ascontiguousarray(self.play_thresholds, dtype=float)
        self.play_weights = np.ascontiguousarray(self.play_weights, dtype=float)
        self.deadzone_thresholds = np.ascontiguousarray(self.deadzone_thresholds, dtype=float)
        coeffs = np.asarray(self.deadzone_coeffs, dtype=float)
        if coeffs.ndim == 1:
            coeffs = np.vstack([coeffs, np.zeros_like(coeffs), np.zeros_like(coeffs)])
        self.deadzone_coeffs = np.ascontiguousarray(coeffs)
        self.output_coeffs = np.ascontiguousarray(np.resize(np.asarray(self.output_coeffs, float), 3)
                                                  if np.size(self.output_coeffs) else np.zeros(3))
        if self.stress_range_MPa is not None:
            lo, hi = (float(v) for v in self.stress_range_MPa)
            self.stress_range_MPa = (lo, hi)
        try:
            drive_lo, drive_hi = (float(v) for v in self.drive_range)
        except (TypeError, ValueError):
            raise ModelError(f"drive range must be two values (low, high), got {self.drive_range!r}") from None
        self.drive_range = (drive_lo, drive_hi)
        self._validate_structure()
        r_inv, w_inv = play_inverse(self.play_thresholds, self.play_weights)
        lo, hi = self.stress_range_MPa if self.stress_range_MPa else (-np.inf, np.inf)
        if self.stress_range_MPa is None:
            # An MPI ignores stress: collapse the quadratic so any stress value gives the same weights.
            self.deadzone_coeffs[1:] = 0.0
            self.output_coeffs[1:] = 0.0
            lo, hi = 0.0, 0.0
        self._packed = ops.pack(self.input_offset, (lo, hi), self.output_coeffs, self.play_thresholds,
                                self.play_weights, r_inv, w_inv, self.deadzone_thresholds,
                                self.deadzone_coeffs)

    # -- structure ---------------------------------------------------------------------------
    @property
    def kind(self) -> str:
        return "mpi" if self.stress_range_MPa is None else "sdpi"

    @property
    def preview_s(self) -> float:
        """The model contract's transport delay: none in a rate-independent SDPI/MPI."""
        return 0.0

    @property
    def n_play(self) -> int:
        return len(self.play_thresholds)

    @property
    def n_deadzone(self) -> int:
        return len(self.deadzone_thresholds)

    def _validate_structure(self) -> None:
        r_h, w_h, r_s = self.play_thresholds, self.play_weights, self.deadzone_thresholds
        arrays = {"play thresholds": r_h, "play weights": w_h, "dead-zone thresholds": r_s,
                  "dead-zone weight coefficients": self.deadzone_coeffs, "output offset": self.output_coeffs}
        for name, arr in arrays.items():
            if arr.size == 0 or not np.all(np.isfinite(arr)):
                raise ModelError(f"{name} must be non-empty and finite")
        _refuse_past_the_bound({**arrays, "drive range": np.asarray(self.drive_range, dtype=float),
                                "stress range": np.asarray(self.stress_range_MPa or (0.0, 0.0), dtype=float),
                                "input_offset": np.asarray(self.input_offset, dtype=float),
                                "reference_stress_MPa": np.asarray(self.reference_stress_MPa or 0.0, dtype=float)})
        if r_h.ndim != 1 or w_h.shape != r_h.shape:
            raise ModelError(f"play thresholds ({r_h.size}) and weights ({w_h.size}) must be 1-D and equally long")
        if r_h[0] != 0.0 or np.any(np.diff(r_h) <= 0):
            raise ModelError("play thresholds must start at 0 and strictly increase (paper eq. 3)")
        n_s = r_s.size
        if r_s.ndim != 1 or n_s % 2 == 0:
            raise ModelError(f"dead-zone thresholds must be an odd number (2l+1), got {n_s}")
        if r_s[(n_s - 1) // 2] != 0.0 or np.any(np.diff(r_s) <= 0):
            raise ModelError("dead-zone thresholds must strictly increase with the centre one at 0 (paper eq. 5)")
        if self.deadzone_coeffs.shape != (3, n_s):
            raise ModelError(f"dead-zone weight coefficients must be {n_s} triples (c0, c1, c2)")
        drive_lo, drive_hi = self.drive_range
        if not drive_lo < drive_hi:            # NaN compares false: refused too
            raise ModelError(f"drive range must be (low, high) with low < high, got [{drive_lo:g}, {drive_hi:g}]; "
                             "the clamp and fault policies rely on it: write the model again with gma-ffc identify")
        if self.stress_range_MPa is not None:
            lo, hi = self.stress_range_MPa
            if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
                raise ModelError(f"stress range must be two finite values, low < high, got {self.stress_range_MPa}")
        scalars = {"input_offset": self.input_offset, "reference_stress_MPa": self.reference_stress_MPa}
        for name, value in scalars.items():     # NaN or inf would reach every output as all-NaN (inf) drives
            if value is not None and not np.isfinite(value):
                raise ModelError(f"{name} must be a finite number, got {value!r}; write the model again with "
                                 "gma-ffc identify")
        if self.drive_name not in ("current_A", "voltage_V"):     # recordings.DRIVE_COLUMNS: what a drive is read as
            raise ModelError(f"drive_name must be current_A or voltage_V (the recordings' drive column), got "
                             f"{self.drive_name!r}")
        if self.output_sign not in (1.0, -1.0):
            raise ModelError(f"output_sign must be +1 (displacement rises with the drive) or -1 (falls), "
                             f"got {self.output_sign!r}")
        if self.initial_state not in INITIAL_STATES:
            raise ModelError(f"initial_state must be one of {INITIAL_STATES}, got {self.initial_state!r}")

    # -- stress dependence -------------------------------------------------------------------
    def deadzone_weights(self, stress_MPa: float | None = None) -> np.ndarray:
        """w_s(sigma) (paper eq. 16); stress is ignored by an MPI."""
        s = 0.0 if self.stress_range_MPa is None or stress_MPa is None else float(stress_MPa)
        c = self.deadzone_coeffs
        return c[0] + s * (c[1] + s * c[2])

    def output_offset(self, stress_MPa: float | None = None) -> float:
        s = 0.0 if self.stress_range_MPa is None or stress_MPa is None else float(stress_MPa)
        o = self.output_coeffs
        return float(o[0] + s * (o[1] + s * o[2]))

    def invertibility_violations(self, eps: float | None = None) -> list[Violation]:
        """Proposition 3.1 over the whole stress range; [] when the inverse exists uniquely.

        Play weights: w_h0 >= eps, w_hi >= 0. Dead-zones: every cumulative weight from the centre
        outwards (the slope of each linear piece) >= eps at every stress in the range.

        By default each eps is a billionth of its own weights' scale, in their units: the play
        weights' sum for w_h0, the largest dead-zone weight for the slopes. Data fix only the
        product of play and dead-zone weights, so a fit may move scale between them; measured
        against each other (as before), a model whose w_h0 held its share of the plays was refused
        (a butterfly loop: w_h0 1.7e-9 of 4.5e-8, dead-zone weights up to 8.7e4).
        """
        w_h = self.play_weights
        c = self.deadzone_coeffs
        centre = (self.n_deadzone - 1) // 2
        eps_w = 1e-9 * max(float(np.sum(np.abs(w_h))), 1e-300) if eps is None else eps
        if eps is None:
            eps = 1e-9 * max(float(np.max(np.abs(c[0]))), 1e-300)
        out = []
        if w_h[0] < eps_w:
            out.append(Violation("w_h0", None, float(w_h[0]), eps_w))
        total = float(np.sum(np.abs(w_h)))
        if not total <= MAX_PLAY_WEIGHT_SUM:
            out.append(Violation("sum w_h", None, total, MAX_PLAY_WEIGHT_SUM, upper=True))
        for i in np.flatnonzero(w_h[1:] < 0) + 1:
            out.append(Violation(f"w_h{i}", None, float(w_h[i]), 0.0))
        cum_pos = np.cumsum(c[:, centre:], axis=1)
        cum_neg = np.cumsum(c[:, centre::-1], axis=1)
        labels = [f"sum w_s0..w_s{k}" for k in range(cum_pos.shape[1])] + \
                 [f"sum w_s{-k}..w_s0" for k in range(1, cum_neg.shape[1])]
        quads = np.hstack([cum_pos, cum_neg[:, 1:]])
        for label, (a, b, q) in zip(labels, quads.T):
            s_min, v_min = self._quadratic_min(a, b, q)
            if v_min < eps:
                out.append(Violation(label, s_min, v_min, eps))
        return out

    def _quadratic_min(self, a: float, b: float, q: float) -> tuple[float | None, float]:
        if self.stress_range_MPa is None:
            return None, float(a)
        lo, hi = self.stress_range_MPa
        cands = [lo, hi]
        if q > 0:
            v = -b / (2 * q)
            if lo < v < hi:
                cands.append(v)
        vals = [a + s * (b + s * q) for s in cands]
        k = int(np.argmin(vals))
        return float(cands[k]), float(vals[k])

    # -- batch -------------------------------------------------------------------------------
    def _stress_array(self, stress_MPa: Any, n: int) -> np.ndarray:
        if self.stress_range_MPa is None:
            return np.zeros(n)
        if stress_MPa is None:
            raise ModelError("this SDPI model needs a stress (stress_MPa column or value)")
        s = np.broadcast_to(np.asarray(stress_MPa, dtype=float), (n,))
        if not np.all(np.isfinite(s)):
            raise ModelError("stress contains NaN or infinite values")
        lo, hi = self.stress_range_MPa
        refuse_stress_outside(s, (lo, hi))
        return np.ascontiguousarray(np.clip(s, lo, hi))

    def forward_state(self, initial_drive: float, play_state: Any = None) -> np.ndarray:
        """Kernel state at the start of a run.

        `play_state` gives the forward plays' outputs explicitly (e.g. left by an earlier run);
        otherwise they follow `initial_state` at `initial_drive`. Either way the state is made
        consistent with the first input by the kernel's first step, as eq. (2) requires.
        """
        state = np.zeros(ops.state_size(self.n_play, self.n_deadzone))
        if play_state is not None:
            ps = np.asarray(play_state, dtype=float)
            if ps.shape != (self.n_play,) or not np.all(np.isfinite(ps)):
                raise ModelError(f"initial play state must be {self.n_play} finite values")
            state[: self.n_play] = ps
            return state
        v = initial_drive - self.input_offset
        state[: self.n_play] = v + (self.play_thresholds if self.initial_state == "descending" else 0.0)
        return state

    def inverse_state(self, initial_drive: float, play_state: Any = None) -> np.ndarray:
        """Inverse-play states (10) consistent with the forward plays' states."""
        state = self.forward_state(initial_drive, play_state)
        state[: self.n_play] = play_inverse_initial_state(self.play_weights, state[: self.n_play])
        return state

    def resolve_initial_state(self, drive: Any, stress_MPa: Any = None, initial_state: Any = None,
                              measured_um: Any = None, time_s: Any = None) -> ResolvedInitialState:
        """The `gma_ffc.initial_state` rule for a run on `drive` (default: the shared DEFAULT)."""
        from .initial_state import DEFAULT, ResolvedInitialState, resolve

        if isinstance(initial_state, ResolvedInitialState):
            return initial_state
        x = np.ascontiguousarray(drive, dtype=float)
        s = None if stress_MPa is None else self._stress_array(stress_MPa, x.size)
        return resolve(self, x, s, DEFAULT if initial_state is None else initial_state, measured_um, time_s)

    def simulate(self, time_s: Any, drive: Any, stress_MPa: Any = None,
                 initial_drive: float | None = None, initial_play_state: Any = None,
                 initial_state: Any = None, measured_um: Any = None) -> np.ndarray:
        """Displacement (um) for a drive history; time is unused (rate-independent).

        The play states at the first sample: `initial_play_state` if given, else the model's
        stepper convention at `initial_drive` if given (its `initial_state` field: "descending"
        or "relaxed"), else the `initial_state` rule (`gma_ffc.initial_state`; default
        "estimate", which uses `measured_um` if given).
        """
        x, s, state = self.batch_start(time_s, drive, stress_MPa, initial_drive, initial_play_state,
                                       initial_state, measured_um)
        out = np.empty_like(x)
        ops.forward_batch(x, s, self._packed, state, out)
        if self.output_sign < 0:
            np.negative(out, out=out)
        return out

    def batch_start(self, time_s: Any, drive: Any, stress_MPa: Any = None, initial_drive: float | None = None,
                    initial_play_state: Any = None, initial_state: Any = None,
                    measured_um: Any = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A batch run's checked drive, clamped stress and starting kernel state (see `simulate`);
        also what a core built on this one (the widened core of loop_width) starts from."""
        x = np.ascontiguousarray(drive, dtype=float)
        if x.ndim != 1 or x.size == 0 or not np.all(np.isfinite(x)):
            raise ModelError("drive must be a non-empty 1-D array of finite values")
        s = self._stress_array(stress_MPa, x.size)
        if initial_play_state is None and initial_drive is None:
            initial_play_state = self.resolve_initial_state(x, s if self.stress_range_MPa else None,
                                                            initial_state, measured_um, time_s).play_state
        return x, s, self.forward_state(x[0] if initial_drive is None else initial_drive, initial_play_state)

    def _core_output_inverse(self, y: float, stress: float) -> float:
        """z with D_sigma(z) + c(sigma) = y: the dead-zone superposition's inverse at one stress."""
        r_inv, w_inv = deadzone_inverse(self.deadzone_thresholds, self.deadzone_weights(stress))
        v = y - self.output_offset(stress)
        z = 0.0
        for r, w in zip(r_inv, w_inv):
            z += w * (max(v - r, 0.0) if r > 0 else min(v - r, 0.0) if r < 0 else v)
        return float(z)

    def invert_initial_state(self, reference_um: np.ndarray, stress0: float | None,
                             direction: int | None = None) -> tuple[np.ndarray, str]:
        """Forward play states for `invert` such that the model's output at the first sample IS
        the reference, and that the shared default rule, applied to invert's own output drive,
        gives back: plays at the boundary the drive's first monotone stretch implies
        (`direction`, by default the reference's: the model rises with the drive on every branch)."""
        from .initial_state import centred_range, first_direction, monotone_play_state, monotone_start_drive

        y = self.output_sign * np.asarray(reference_um, dtype=float)
        d = first_direction(y) if direction is None else direction
        z0 = self._core_output_inverse(float(y[0]), 0.0 if stress0 is None else stress0)
        r, w = self.play_thresholds, self.play_weights
        lo, hi = centred_range(self)
        v0 = monotone_start_drive(w, r, z0, d, lo, hi)
        how = {1: "the drive first rises", -1: "the drive first falls", 0: "the reference never moves"}[d]
        return (monotone_play_state(r, v0, d, lo, hi),
                f"consistent with the first monotone stretch ({how}), output = reference at t0")

    def invert(self, time_s: Any, reference_um: Any, stress_MPa: Any = None,
               initial_drive: float | None = None, initial_play_state: Any = None,
               initial_state: Any = None) -> np.ndarray:
        """The drive that makes the model follow `reference_um` (analytic inverse, eq. 17).

        Start: `initial_play_state` (forward plays, mapped to the inverse by (10)) or the stepper
        convention at `initial_drive` if given (see `simulate`); by default the state whose output
        is the reference's first value, consistent with the first monotone stretch (see
        `invert_initial_state`), so that simulating the result with the default rule returns the
        reference from the first sample.
        `initial_state` "relaxed" / "drive:V" take those rules at the drive they imply.
        """
        y = np.ascontiguousarray(reference_um, dtype=float)
        if y.ndim != 1 or y.size == 0 or not np.all(np.isfinite(y)):
            raise ModelError("reference must be a non-empty 1-D array of finite values")
        s = self._stress_array(stress_MPa, y.size)
        x0 = self.drive_range[0] if initial_drive is None else initial_drive
        if not np.isfinite(x0):
            x0 = 0.0
        yy = y if self.output_sign > 0 else -y
        out = np.empty_like(y)
        if initial_play_state is None and initial_drive is None:
            from .initial_state import InitialStateSpec, first_direction

            spec = InitialStateSpec.parse("estimate" if initial_state is None else initial_state)
            s0 = float(s[0]) if self.stress_range_MPa else None
            if spec.kind in ("relaxed", "drive"):
                p, _ = self.invert_initial_state(y, s0, 0)
                if spec.kind == "relaxed" or spec.drive is None:     # parse() gives "drive" a value
                    v = float(p[0])
                else:
                    v = float(spec.drive) - self.input_offset
                initial_play_state = np.full(self.n_play, v)
            else:
                # The drive's first move can differ from the reference's when stress moves the
                # output too: keep the start whose own output drive confirms its direction.
                d_ref = first_direction(self.output_sign * y)
                for d in dict.fromkeys((d_ref, -d_ref, 0)):
                    p, _ = self.invert_initial_state(y, s0, d)
                    ops.inverse_batch(yy, s, self._packed, self.inverse_state(x0, p), out)
                    if first_direction(out) == d:
                        return out
                initial_play_state = p
        state = self.inverse_state(x0, initial_play_state)
        ops.inverse_batch(yy, s, self._packed, state, out)
        return out

    # -- steppers ----------------------------------------------------------------------------
    def forward_stepper(self, dt_s: float = 0.0, initial_drive: float = 0.0) -> "ForwardStepper":
        return ForwardStepper(self, initial_drive)

    def inverse_stepper(self, dt_s: float = 0.0, initial_drive: float = 0.0) -> "InverseStepper":
        return InverseStepper(self, initial_drive)

    # -- data --------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        n_s = self.n_deadzone
        centre = (n_s - 1) // 2
        return {
            "format": "gma-ffc-model",
            "version": 2,
            "kind": self.kind,
            "units": {"drive": drive_unit(self.drive_name), "displacement": "um", "stress": "MPa"},
            "drive_name": self.drive_name,
            "output_sign": int(self.output_sign),
            "input_offset": float(self.input_offset),
            "initial_state": self.initial_state,
            "play": {
                "thresholds": [float(v) for v in self.play_thresholds],
                "weights": [float(v) for v in self.play_weights],
            },
            "deadzone": {
                "thresholds": [float(v) for v in self.deadzone_thresholds],
                "weight_coeffs": [[float(v) for v in self.deadzone_coeffs[:, j]] for j in range(n_s)],
                "index_of_r0": centre,
            },
            "output_offset_coeffs": [float(v) for v in self.output_coeffs],
            "stress_dependence": "w_s(sigma) = c0 + c1*sigma + c2*sigma^2, sigma in MPa (compression < 0)",
            "stress_range_MPa": None if self.stress_range_MPa is None else list(self.stress_range_MPa),
            "reference_stress_MPa": self.reference_stress_MPa,
            "drive_range": list(self.drive_range),
            "provenance": self.provenance,
        }

    REQUIRED_KEYS = ("kind", "drive_name", "input_offset", "play", "deadzone", "output_offset_coeffs",
                     "stress_range_MPa", "drive_range", "provenance")

    KNOWN_KEYS = REQUIRED_KEYS + ("format", "version", "units", "output_sign", "initial_state", "stress_dependence",
                                  "reference_stress_MPa")
    SECTION_KEYS = {"play": ("thresholds", "weights"), "deadzone": ("thresholds", "weight_coeffs")}   # required
    SECTION_OPTIONAL = ("index_of_r0",)     # deadzone's: written by identify, checked when present

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "SDPIModel":
        required = cls.REQUIRED_KEYS + (("output_sign",) if d.get("version", 1) >= 2 else ())
        refuse_missing_keys(d, required, cls.KNOWN_KEYS)
        for section, keys in cls.SECTION_KEYS.items():
            if isinstance(d[section], dict):
                refuse_missing_keys(d[section], keys, keys + cls.SECTION_OPTIONAL, f"{section}.")
        _check_output_sign(d.get("output_sign", 1))
        try:
            play, dz = d["play"], d["deadzone"]
            coeffs = np.asarray(dz["weight_coeffs"], dtype=float)
            if coeffs.ndim != 2 or coeffs.shape[1] != 3:
                raise ModelError("deadzone.weight_coeffs must be a list of [c0, c1, c2] triples")
            sr = d.get("stress_range_MPa")
            model = cls(
                play_thresholds=np.asarray(play["thresholds"], dtype=float),
                play_weights=np.asarray(play["weights"], dtype=float),
                deadzone_thresholds=np.asarray(dz["thresholds"], dtype=float),
                deadzone_coeffs=coeffs.T,
                output_coeffs=np.asarray(d.get("output_offset_coeffs", [0.0, 0.0, 0.0]), dtype=float),
                input_offset=float(d.get("input_offset", 0.0)),
                stress_range_MPa=None if sr is None else (float(sr[0]), float(sr[1])),
                reference_stress_MPa=None if d.get("reference_stress_MPa") is None else float(d["reference_stress_MPa"]),
                drive_range=d.get("drive_range", (-np.inf, np.inf)),      # two floats, checked on construction
                drive_name=str(d.get("drive_name", "current_A")),
                initial_state=str(d.get("initial_state", "descending")),
                provenance=dict(d.get("provenance") or {}),
                output_sign=float(d.get("output_sign", 1)),
            )
        except ModelError:
            raise
        except KeyError as exc:
            raise ModelError(f"missing key {exc.args[0]!r}") from None
        except (TypeError, ValueError, IndexError) as exc:
            raise ModelError(f"malformed values ({exc})") from None
        _check_declared_units(d, model)
        declared = d.get("kind")
        if declared not in (None, model.kind):
            raise ModelError(f"kind says {declared!r} but the stress range makes it {model.kind!r}")
        bad = model.invertibility_violations()
        if bad:
            raise ModelError("violates Proposition 3.1 (no unique inverse): " + "; ".join(map(str, bad[:3]))
                             + ". The inverse controller cannot use it: identify the model again (gma-ffc "
                             "identify) from recordings that sweep the full drive range at every stress")
        return model


def refuse_missing_keys(d: Mapping[str, Any], required: Sequence[str], known: Sequence[str], prefix: str = "") -> None:
    """ModelError for the first of `required` missing from `d`: as a misspelt key when a key of `d`
    that is none of `known` is close to it ('ouput_sign'), else as a file cut short."""
    missing = [k for k in required if k not in d]
    if not missing:
        return
    unknown = [str(k) for k in d if k not in known]
    for key in missing:
        close = difflib.get_close_matches(key, unknown, n=1, cutoff=0.6)
        if close:
            raise ModelError(f"unknown key '{prefix}{close[0]}' (did you mean '{prefix}{key}'?): rename it "
                             f"'{key}'")
    raise ModelError(f"missing key{'s' if len(missing) > 1 else ''} {', '.join(repr(prefix + k) for k in missing)}: "
                     f"the file is incomplete (cut short?); write it again with gma-ffc identify")


def _check_output_sign(value: Any) -> None:
    """ModelError unless `value` is a number (the constructor then holds it to +1 or -1): YAML reads
    yes/no/true/false as a boolean, which Python would take for 1 or 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ModelError(f"output_sign must be +1 (displacement rises with the drive) or -1 (falls), got {value!r}"
                         f"{' (a YAML boolean, not a sign)' if isinstance(value, bool) else ''}")


def _check_declared_units(d: dict[str, Any], model: SDPIModel) -> None:
    """A file's `units` and `deadzone.index_of_r0` are what identify wrote, not settings: a hand-edited
    value the code would ignore (mA for A, mm for um) is refused, not silently read as the default."""
    units = d.get("units")
    if units is not None:
        expected = {"drive": drive_unit(model.drive_name), "displacement": "um", "stress": "MPa"}
        if not isinstance(units, dict):
            raise ModelError(f"units must be a mapping like {expected}, got {units!r}")
        wrong = {k: v for k, v in units.items() if k in expected and str(v) != expected[k]}
        if wrong:
            k, v = next(iter(wrong.items()))
            raise ModelError(f"units.{k} is {v!r} but gma-ffc models are in {expected[k]!r} (drive_name "
                             f"{model.drive_name!r}); convert the recordings and identify again, or restore "
                             f"units.{k}: {expected[k]}")
    centre = d.get("deadzone", {}).get("index_of_r0")
    if centre is not None and centre != (model.n_deadzone - 1) // 2:
        raise ModelError(f"deadzone.index_of_r0 is {centre!r} but the centre of {model.n_deadzone} dead-zone "
                         f"thresholds is {(model.n_deadzone - 1) // 2}: the file was edited; write it again "
                         "with gma-ffc identify")


class ForwardStepper:
    """One sample in, one displacement out; state kept between calls; nothing allocated per step."""

    __slots__ = ("_p", "_state", "_model", "_sign")

    def __init__(self, model: SDPIModel, initial_drive: float = 0.0) -> None:
        self._model = model
        self._p = model._packed
        self._sign = float(model.output_sign)
        self._state = model.forward_state(initial_drive)

    def reset(self, initial_drive: float = 0.0, play_state: Any = None) -> None:
        self._state[:] = self._model.forward_state(initial_drive, play_state)

    def step(self, drive: float, stress_MPa: float = 0.0) -> float:
        return self._sign * ops.forward_step(drive, stress_MPa, self._p, self._state)

    def peek(self, drive: float, stress_MPa: float = 0.0) -> float:
        """What `step` would return, without moving the state."""
        return self._sign * ops.forward_peek(drive, stress_MPa, self._p, self._state)


class InverseStepper:
    """One reference sample in, one drive out (analytic inverse); state kept, no allocation."""

    __slots__ = ("_p", "_state", "_model", "_sign")

    def __init__(self, model: SDPIModel, initial_drive: float = 0.0) -> None:
        self._model = model
        self._p = model._packed
        self._sign = float(model.output_sign)
        self._state = model.inverse_state(initial_drive)

    def reset(self, initial_drive: float = 0.0, play_state: Any = None) -> None:
        """Back to the model's stepper convention at `initial_drive` (its `initial_state` field),
        or to the forward play state given."""
        self._state[:] = self._model.inverse_state(initial_drive, play_state)

    def step(self, reference_um: float, stress_MPa: float = 0.0) -> float:
        return ops.inverse_step(self._sign * reference_um, stress_MPa, self._p, self._state)

    def play_state(self) -> np.ndarray:
        """The forward plays' outputs (the model's play units: drive - input_offset) that this
        inverse's state stands for: what `reset` takes to continue the same hysteresis memory."""
        return play_forward_state(self._model.play_weights, self._state[: self._model.n_play])

    def peek(self, reference_um: float, stress_MPa: float = 0.0) -> float:
        """What `step` would return, without moving the state (an extended model's inverse solves
        for each sample's drive by trying several)."""
        return ops.inverse_peek(self._sign * reference_um, stress_MPa, self._p, self._state)


def rms(a: Sequence[float] | np.ndarray) -> float:
    a = np.asarray(a, dtype=float)
    return float(np.sqrt(np.mean(a * a))) if a.size else float("nan")


def _refuse_past_the_bound(arrays: Mapping[str, np.ndarray]) -> None:
    """ModelError naming the first number past PARAMETER_BOUND (NaN and inf are refused apart)."""
    for name, arr in arrays.items():
        big = np.abs(arr[np.isfinite(arr)])
        if big.size and float(big.max()) > PARAMETER_BOUND:
            raise ModelError(f"{name} holds {float(big.max()):.3g}, past the {PARAMETER_BOUND:g} a model's number may "
                             "hold: the file was edited; write it again with gma-ffc identify")
