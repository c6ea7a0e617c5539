"""Identification of SDPI and MPI models from recordings (seed paper sections 2.4 and 3.3).

`SDPIIdentifier` follows scikit-learn's conventions: the constructor takes settings, `fit` learns,
learned attributes end in an underscore (`model_`, `report_`).

The steps, as in the paper, with what the paper leaves open made explicit:

1. MPI at the reference stress (the least compressive one: preload only). Thresholds are equal
   intervals over the data: play thresholds over the drive's half-range, inverse dead-zone
   thresholds over the displacement's half-range (the paper's grid, `threshold_grid="output"`;
   by default the dead-zones are then placed again, at equal intervals of the play
   superposition's output, and their slopes refitted). The weights come from the linear
   least-squares fit of (15), w_s'^T S'[y] = w_h^T H[x], with the inverse dead-zone's centre slope
   fixed to 1 (the equation is homogeneous) and Proposition 3.1 as bounds: weights are
   parametrised by the slopes of the linear pieces, so "cumulative weights >= eps" becomes
   "slopes >= eps". The forward dead-zone thresholds follow analytically (11)-(14). The fit is
   then refined in output error (displacement residual) with the thresholds held.
2.+3. With play weights and all thresholds held, the dead-zone weights are fitted as quadratic
   functions of stress directly on all recordings at once (a linear least-squares problem in the
   coefficients), with Proposition 3.1 imposed at every stress of the range: a quadratic program
   whose constraints are enforced on a grid and then verified exactly (ends and vertex), adding
   any violating stress and re-solving until none is left. Fitting the quadratics directly, not
   per-stress weights then curves, uses recordings whose stress changes during the run too.

Initial states are explicit: the fit starts each recording's plays in the state a drive history
that came down to the first sample leaves ("descending"), and ignores the recording until the
drive has swept from one extreme to the other (after that the play states no longer depend on
where they began). A recording that would lose more than a fifth of its samples that way has its
initial state estimated from the measurement (`gma_ffc.initial_state`) and all its samples fitted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
from scipy import optimize

from . import operators as ops
from .constrained_weights import (PlayWeights, bounded_least_squares, deadzones_determined, determined,
                                  intermediate_grid, powers_to_sigma, slope_basis, slopes_and_offset, slopes_in_stress,
                                  slopes_to_weights, weights_to_slopes)
from .errors import FaultError, InputError
from .identification_checks import (BUTTERFLY_SHARE, CLOCKWISE_WIDTH, FAST_LOOP_HZ, burn_in_end, butterfly_words,
                                    column_notes, fewer_operators, has_full_sweep, late_sweep_note, loop_rates_hz,
                                    scale_mismatch, travel_against_drive)
from .initial_state import first_direction, monotone_play_state, resolve
from .inverse import deadzone_inverse
from .model import SDPIModel, rms
from .recordings import Recording


@dataclass
class RecordingFit:
    """How well the model fits one recording."""

    name: str
    stress_MPa: float | None
    rms_um: float
    stroke_um: float
    max_abs_um: float
    offset_um: float = 0.0         # the error's mean: a constant the model's offset could not take up
    max_at_s: float | None = None  # when the largest error falls (the recording's time), to look it up
    fitted_from: int = 0           # the first sample scored (after the burn-in sweep; 0 when every one was fitted)

    @property
    def shape_rms_um(self) -> float:
        """The error with its mean taken out: how well the loop's shape fits, whatever its level."""
        return math.sqrt(max(self.rms_um ** 2 - self.offset_um ** 2, 0.0))

    @property
    def rms_pct_stroke(self) -> float:
        return 100.0 * self.rms_um / self.stroke_um if self.stroke_um > 0 else float("nan")


@dataclass
class _Data:
    """One recording prepared for fitting: play outputs, burn-in mask, decimated rows."""

    name: str
    x: np.ndarray
    y: np.ndarray
    sigma: np.ndarray | None
    plays: np.ndarray = field(default_factory=lambda: np.empty((0, 0)))
    rows: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=int))
    start: int | None = None      # first fitted sample; None: after the burn-in sweep
    pred: np.ndarray = field(default_factory=lambda: np.empty(0))   # the fitted model's output, as scored
    zero_shift: float = 0.0       # added to y (fitting orientation) when each recording's zero is its own
    t: np.ndarray | None = None   # the recording's time, to say where the largest error falls

    def shift_zero(self, by: float) -> None:
        self.y = self.y + by
        self.zero_shift += by

    @property
    def stress(self) -> np.ndarray:
        """`sigma` where a stress-dependent step needs it (`_prepare` gives all recordings a stress or none)."""
        if self.sigma is None:
            raise InputError(f"{self.name}: no stress_MPa column")
        return self.sigma


TRUST_REGION_SOLVER = "exact"
"""The output-error refinements' trust-region steps: an SVD of the Jacobian. They have 10 to 18
unknowns over thousands of rows, so one SVD per step costs less than lsmr's many products through
scipy's operator wrappers, and it takes fewer steps (29 identifications of a resonance pair's
diagnosis: 1943 -> 1276 evaluations, 10.3 -> 7.4 s of CPU)."""


def _within(level: float | None, span: tuple[float, float] | None) -> float | None:
    """A stress level (binned to the identifier's tolerance) moved into the model's stress range: the
    most compressive bin of -24.33 MPa data is -24.5 MPa, outside the range the file states."""
    if level is None or span is None:
        return level
    return min(max(level, span[0]), span[1])


@dataclass
class SDPIIdentifier:
    """Fit an SDPI (several stresses) or an MPI (one stress, or no stress column) to recordings.

    Settings:
        n_play                number of play operators (paper: 10)
        n_deadzone            number of dead-zone operators, odd (paper: 7)
        reference_stress_MPa  stress of step 1; default the least compressive one in the data
        stress_tolerance_MPa  stresses closer than this count as one level
        max_rows              samples per recording used by the least-squares fits (evenly
                              spaced after burn-in); play outputs are always computed at full rate
        refine                output-error refinement of step 1 (off = the paper's (15) alone)
        joint_passes          alternations of (play weights on all stresses) and (stress QP) after
                              step 3; the play weights stay stress-independent, as the SDPI
                              assumes, but are fitted to every stress rather than the reference
                              alone (0 = the paper's procedure)
        threshold_grid        "output": the paper's equal intervals in displacement for the
                              inverse dead-zones (forward ones follow from (11)-(14));
                              "intermediate": equal intervals over the range of the play
                              superposition's output, so no dead-zone piece is left without data
        zero                  "shared": every recording measures displacement from one zero, so the
                              model's offset may follow stress (the rod's compression under load);
                              "per_recording": each recording's zero is its own (the sensor zeroed
                              before each run): a constant per recording is fitted away and the
                              model's offset is one constant
        initial_state         the fit's start of each recording's plays, and the model file's
                              stepper rule: "descending" (as if the drive came down to its first
                              value) or "relaxed"
        loop_width            None (the paper's SDPI), or (kappa per MPa, reference stress MPa): every
                              play threshold scaled by g(sigma) = max(1 + kappa (sigma_ref - sigma), 0.05)
                              at each sample's stress, a loop width (coercive current) that follows
                              stress; the fitted core then runs as `core_` (the widened core of
                              `gma_ffc.effects.stress_play`, with its exact inverse), `model_` being its
                              plain SDPI part
        progress              optional callback(stage: str) for long fits
    Learned:
        model_, report_ (list of RecordingFit), stress_levels_MPa_, notes_ (what was assumed),
        zero_shifts_um_ (per recording, what was added to its displacement; zeros when shared)
    """

    n_play: int = 10
    n_deadzone: int = 7
    reference_stress_MPa: float | None = None
    stress_tolerance_MPa: float = 0.5
    max_rows: int = 6000
    refine: bool = True
    joint_passes: int = 2
    threshold_grid: str = "intermediate"
    initial_state: str = "descending"
    zero: str = "shared"
    loop_width: tuple[float, float] | None = None
    progress: Callable[[str], None] | None = None

    def _say(self, stage: str) -> None:
        if self.progress is not None:
            self.progress(self._pass + stage)

    # -- public ------------------------------------------------------------------------------
    def fit(self, recordings: Sequence[Recording]) -> "SDPIIdentifier":
        self._check_settings()
        self._pass = ""          # which fit the progress's steps belong to: the first, or one again (and why)
        self.notes_: list[str] = []
        mismatch = scale_mismatch(recordings)
        if mismatch:
            raise InputError(mismatch)
        data = self._prepare(recordings)
        self.output_sign_ = self._orientation(data)
        self._check_loop_direction(data)
        self.notes_ += column_notes(recordings)
        fast = max(loop_rates_hz(recordings), default=math.nan)
        if fast > FAST_LOOP_HZ:
            self.notes_.append(f"the drive loops at up to {fast:.3g} Hz: eddy currents, a delay or the load's dynamics "
                               "widen a loop that fast, and a rate-independent model takes that lag into its "
                               "hysteresis, so it will not carry to slower or faster drives; identify from a slow "
                               f"drive (below about {FAST_LOOP_HZ:g} Hz) and let `diagnose` model the lag")
        levels, per_rec_stress = self._stress_levels(data)
        self.stress_levels_MPa_ = levels
        x_all = np.concatenate([d.x for d in data])
        x_lo, x_hi = float(x_all.min()), float(x_all.max())
        x_c = 0.5 * (x_lo + x_hi)
        half = 0.5 * (x_hi - x_lo)
        if half <= 0:
            raise InputError("the drive is constant in every recording; a hysteresis model needs a swept drive")
        y_all = np.concatenate([d.y for d in data])
        self._gain = float(np.ptp(y_all)) / (x_hi - x_lo)     # the data's mean gain: the play weights' scale
        r_h = np.arange(self.n_play) * half / self.n_play
        # A recording whose burn-in sweep is a large share of it (one cycle, a cut-out window)
        # would lose much of its data to the unknown initial state: that state is estimated from
        # the measurement with a first model, and the fit repeated on every sample. Where what
        # follows the burn-in is no full cycle, the first fit too uses every sample, started
        # from the state consistent with the drive's first monotone stretch.
        short = [d for d in data if burn_in_end(d.x) > 0.2 * len(d.x)]
        no_cycle_after_burn_in = [d for d in short if not has_full_sweep(d.x[burn_in_end(d.x):])]
        for d in data:
            y0 = d.x[0] - x_c + (r_h if self.initial_state == "descending" else np.zeros_like(r_h))
            if any(d is s for s in no_cycle_after_burn_in):
                y0 = monotone_play_state(r_h, d.x[0] - x_c, first_direction(d.x), x_lo - x_c, x_hi - x_c)
                d.start = 0
            d.plays = np.empty((len(d.x), self.n_play))
            self._play_outputs(d, r_h, x_c, y0)
        self._fit_all(recordings, data, levels, per_rec_stress, r_h, x_c, (x_lo, x_hi))
        if short:
            self._pass = "fit again, start states estimated: "      # progress says why the steps come again
            for d in short:
                start = resolve(self.model_, d.x, d.sigma, "estimate", self.output_sign_ * d.y)
                d.start = 0
                self._play_outputs(d, r_h, x_c, start.play_state)
            self.notes_.append(late_sweep_note([burn_in_end(d.x) / len(d.x) for d in short]))
            self._fit_all(recordings, data, levels, per_rec_stress, r_h, x_c, (x_lo, x_hi))
        self.zero_shifts_um_ = {d.name: 0.0 for d in data}
        if self.zero == "per_recording" and len(data) > 1:
            self._align_zeros(lambda: self._fit_all(recordings, data, levels, per_rec_stress, r_h, x_c,
                                                    (x_lo, x_hi)), data)
        self._check_degenerate(data, fast)
        return self

    def _play_outputs(self, d: _Data, r_h: np.ndarray, x_c: float, y0: np.ndarray) -> None:
        """The recording's play outputs (the regressors) into d.plays, from play states y0; with a
        loop width, each sample's thresholds scaled by its stress's width factor."""
        x = np.ascontiguousarray(d.x - x_c)
        y0 = np.ascontiguousarray(y0, dtype=float)
        if self.loop_width is None:
            ops.play_outputs(x, r_h, y0, d.plays)
            return
        kappa, s_ref = self.loop_width
        g = np.maximum(1.0 + kappa * (s_ref - d.stress), ops.WIDTH_MIN)
        ops.play_outputs_scaled(x, r_h, np.ascontiguousarray(g), y0, d.plays)

    @property
    def core_(self) -> Any:
        """The identified core as it runs: `model_`, or with `loop_width` its widened core."""
        if self.loop_width is None:
            return self.model_
        from .effects.stress_play import WidenedCore

        return WidenedCore(self.model_, *self.loop_width)

    def _align_zeros(self, refit: Callable[[], None], data: list[_Data]) -> None:
        """Each recording's zero its own. The stress step fits each recording's zero with its terms
        (and moves the recording onto the first one's); what is left (step 1 fitted the reference
        loops before they were moved) is taken up by shifting each recording by its mean error
        relative to the first's and fitting again, until the shifts are a small part of the
        loops' own error."""
        for k in range(ZERO_PASSES):
            self._pass = f"fit again, zeros aligned ({k + 1}): "
            off = np.array([f.offset_um for f in self.report_])
            shape = float(np.median([f.shape_rms_um for f in self.report_]))
            shift = off - off[0]
            if float(np.max(np.abs(shift))) <= ZERO_SETTLED * shape:
                break
            for d, sh in zip(data, shift):
                d.shift_zero(self.output_sign_ * float(sh))
            refit()
        self.zero_shifts_um_ = {d.name: self.output_sign_ * d.zero_shift for d in data}
        each = ", ".join(f"{name} {v:+.3g} um" for name, v in self.zero_shifts_um_.items())
        self.notes_.append(f"each recording's displacement zero was fitted on its own (--zero per-recording): {each}; "
                           "the model's offset is one constant, so its absolute displacement across loads is not known")
        self.model_.provenance["notes"] = list(self.notes_)
        self.model_.provenance["zero_shifts_um"] = {k: round(v, 6) for k, v in self.zero_shifts_um_.items()}

    def _fit_all(self, recordings: Sequence[Recording], data: list[_Data], levels: list[float],
                 per_rec_stress: list[float], r_h: np.ndarray, x_c: float,
                 drive_range: tuple[float, float]) -> None:
        """Steps 1-3 (and the joint passes) on prepared data; sets model_ and report_."""
        ref_level, ref_data = self._reference(data, levels, per_rec_stress)
        w_h, r_s, slopes, y_c = self._step_1(ref_data)
        w_h, coeffs, out_coeffs, stress_range = self._stress_steps(data, len(levels), w_h, r_s, slopes, y_c)
        self.model_ = SDPIModel(
            play_thresholds=r_h, play_weights=w_h, deadzone_thresholds=r_s, deadzone_coeffs=coeffs,
            output_coeffs=out_coeffs, input_offset=x_c, stress_range_MPa=stress_range,
            reference_stress_MPa=_within(ref_level, stress_range), drive_range=drive_range, output_sign=self.output_sign_,
            drive_name=recordings[0].drive_name, initial_state=self.initial_state,
            provenance={"tool": "gma-ffc identify", "recordings": [d.name for d in data],
                        "settings": {"n_play": self.n_play, "n_deadzone": self.n_deadzone,
                                     "refine": self.refine, "zero": self.zero,
                                     **({} if self.loop_width is None else
                                        {"loop_width": [float(v) for v in self.loop_width]})},
                        "notes": list(self.notes_)},
        )
        violations = self.model_.invertibility_violations()
        if violations:  # the fits' bounds make this impossible: a defect, never a bad inverse handed out
            raise FaultError("the identified model violates Proposition 3.1 although every fit is constrained "
                             "to it (a defect in gma-ffc identify; please report it with the recordings): "
                             + "; ".join(map(str, violations)))
        self._report(recordings, data)

    def _reference(self, data: list[_Data], levels: list[float],
                   per_rec_stress: list[float]) -> tuple[float | None, list[_Data]]:
        """Step 1's stress level and recordings: the reference level's with several levels, else all
        (noting why the model will be a stress-independent MPI)."""
        self._check_reference_stress(data)
        if len(levels) > 1:
            ref = self.reference_stress_MPa if self.reference_stress_MPa is not None else max(levels)
            ref_level = min(levels, key=lambda s: abs(s - ref))
            nearest = min(abs(s - ref_level) for s in per_rec_stress)
            return ref_level, [d for d, s in zip(data, per_rec_stress)
                               if abs(s - ref_level) <= max(self.stress_tolerance_MPa, nearest + 1e-9)]
        if not levels:
            note = "recordings have no stress_MPa column: fitted a stress-independent MPI"
        else:   # the range the stress really covers (a few glitch rows do not count)
            lo_s, hi_s = np.percentile(np.concatenate([d.stress for d in data]), [0.5, 99.5])
            note = (f"the stress varies ({lo_s:.3g}..{hi_s:.3g} MPa) but dwells at only "
                    f"one level ({levels[0]:.3g} MPa, to the nearest {self.stress_tolerance_MPa:g} MPa): fitted a "
                    "stress-independent MPI; record at least three levels, each held for a few drive cycles, for an SDPI"
                    if hi_s - lo_s > 2 * self.stress_tolerance_MPa else
                    f"all recordings are at one stress (median {np.median([np.median(d.stress) for d in data]):.4g} MPa): "
                    "fitted a stress-independent MPI; give recordings at several stresses for an SDPI")
        if note not in self.notes_:
            self.notes_.append(note)
        return (levels[0] if levels else None), data

    def _check_reference_stress(self, data: list[_Data]) -> None:
        """The reference stress asked for must be one the recordings were at (between their least and
        most compressive samples, the model's stress range): step 1 is fitted on the recordings there."""
        ref = self.reference_stress_MPa
        if ref is None:
            return
        if data[0].sigma is None:
            raise InputError(f"a reference stress ({ref:g} MPa) needs recordings with a stress_MPa column; "
                             "these have none: leave it out")
        lo = min(float(d.stress.min()) for d in data)
        hi = max(float(d.stress.max()) for d in data)
        if not (math.isfinite(ref) and lo <= ref <= hi):
            # the range shown to 0.01 MPa, rounded inwards: every value the message invites is inside
            lo_in, hi_in = math.ceil(lo * 100) / 100, math.floor(hi * 100) / 100
            raise InputError(f"reference stress {ref:g} MPa is outside the recordings' stresses "
                             f"({lo_in:.2f}..{hi_in:.2f} MPa); give one inside that range, or leave it out "
                             "for the least compressive")

    def _step_1(self, ref_data: list[_Data]) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """Step 1, the MPI at the reference stress: play weights, dead-zone thresholds, slopes, offset."""
        self._say("step 1: MPI at the reference stress")
        w_h, r_s, slopes, y_c = self._fit_mpi(ref_data)
        if self.threshold_grid == "intermediate":
            r_s, slopes, y_c = self._regrid(ref_data, w_h)
        if self.refine:
            self._say("step 1: output-error refinement")
            w_h, slopes, y_c = self._refine_mpi(ref_data, w_h, r_s, slopes, y_c)
        return w_h, r_s, slopes, y_c

    def _stress_steps(self, data: list[_Data], n_levels: int, w_h: np.ndarray, r_s: np.ndarray,
                      slopes: np.ndarray, y_c: float
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[float, float] | None]:
        """Steps 2-3 and the joint passes with several stress levels (play weights, dead-zone and
        output coefficients over stress, the stress range); with one, step 1's MPI as they are."""
        if n_levels <= 1:
            coeffs = np.zeros((3, len(r_s)))
            coeffs[0] = slopes_to_weights(slopes)
            return w_h, coeffs, np.array([y_c, 0.0, 0.0]), None
        self._say("steps 2-3: quadratic dead-zone weights over stress")
        stress_range = (min(float(d.stress.min()) for d in data), max(float(d.stress.max()) for d in data))
        coeffs, out_coeffs = self._fit_stress(data, w_h, r_s, stress_range, n_levels)
        if self.joint_passes:
            self._say("joint refinement of play weights over all stresses")
            w_h, coeffs, out_coeffs = self._refine_joint(data, w_h, r_s, coeffs, out_coeffs, stress_range, n_levels)
        return w_h, coeffs, out_coeffs, stress_range

    def _report(self, recordings: Sequence[Recording], data: list[_Data]) -> None:
        """Score the fit on each recording (report_), and record in the model's provenance where it
        is known to be right: each recording's error, the loop rate and the stresses it was fitted at
        (diagnose keeps an extended model close to the base there, `gma_ffc.diagnose.anchor`)."""
        self.report_ = [self._score(d) for d in data]
        zero_note = zero_mismatch(self.report_) if self.zero == "shared" else ""
        if zero_note and zero_note not in self.notes_:
            self.notes_.append(zero_note)
            self.model_.provenance["notes"] = list(self.notes_)
        self.model_.provenance["fit_rms_um"] = {f.name: round(f.rms_um, 6) for f in self.report_}
        rates = loop_rates_hz(recordings)
        if rates:
            self.model_.provenance["drive_frequency_hz"] = float(f"{float(np.median(rates)):.4g}")
        if self.model_.stress_range_MPa is not None:
            self.model_.provenance["fit_stress_MPa"] = {f.name: round(float(f.stress_MPa), 4)
                                                        for f in self.report_ if f.stress_MPa is not None}

    def _orientation(self, data: list[_Data]) -> float:
        """+1 if the displacement rises with the drive, -1 if it falls (the data are then fitted
        negated, and the model carries output_sign -1): the slope of y on x over all data."""
        x = np.concatenate([d.x for d in data])
        y = np.concatenate([d.y for d in data])
        slope = float(np.polyfit(x, y, 1)[0]) if np.ptp(x) > 0 else 0.0
        if slope < 0:
            for d in data:
                d.y = -d.y
            self.notes_.append("the displacement falls as the drive rises: identified as a falling actuator "
                               "(output_sign -1 in the model)")
            return -1.0
        return 1.0

    def _check_loop_direction(self, data: list[_Data]) -> None:
        """Note recordings whose loop runs clockwise: the displacement leads the drive.

        Every play operator's output lags its input, so a PI/SDPI loop always runs anticlockwise
        (rising branch below the falling one) and a clockwise loop is outside the model class:
        the fit then draws a curve through the middle. A drive column that lags the displacement
        (a filtered or late-sampled current) is the usual cause, so the user is told, not refused.
        The loop's signed area, -(integral of y dx), is compared with the area of the loop of
        the same travel one twentieth of the stroke wide; noise and fast settling add little."""
        for d in data:
            swept = burn_in_end(d.x)
            x, y = d.x[swept:], d.y[swept:]
            low = np.flatnonzero(x <= x.min() + 0.02 * np.ptp(x)) if x.size else x
            if low.size < 2 or low[-1] - low[0] < 3:
                continue
            # from the first to the last visit of the drive's minimum: closed in the drive, so the
            # integral holds whole loops, not a half sweep's large one-sided area
            x, y = x[low[0]: low[-1] + 1], y[low[0]: low[-1] + 1]
            dx = np.diff(x)
            area = -float(np.sum(0.5 * (y[1:] + y[:-1]) * dx))        # > 0 for an anticlockwise loop
            thin = CLOCKWISE_WIDTH * float(np.ptp(y)) * 0.5 * float(np.sum(np.abs(dx)))
            if area < -thin:
                self.notes_.append(
                    f"{d.name}: the loop runs clockwise (the displacement leads the drive), which no play "
                    "operator can do, so expect a poor fit: check that the drive column is not delayed against "
                    "the displacement (a filtered or late-sampled current) and that neither column is inverted")

    def _check_degenerate(self, data: list[_Data], fastest_hz: float) -> None:
        """Refuse a model that explains almost none of the displacement: flat, or noise. Judged on
        the samples `_score` scored, from the initial state estimated from each recording where it
        matters there (a default start can put a model with wide plays far outside its loop for the
        first sweep)."""
        y = np.concatenate([d.y[d.y.size - d.pred.size:] for d in data])     # the samples `_score` scored
        pred = np.concatenate([self.output_sign_ * d.pred for d in data])
        total = float(np.var(y))
        explained = 1.0 - float(np.var(y - pred)) / total if total > 0 else 0.0
        stroke = float(np.ptp(pred))
        if explained < 0.5 or stroke <= 0:
            names = ", ".join(d.name for d in data)
            against = max(travel_against_drive(d.x, d.y) for d in data)
            if against >= BUTTERFLY_SHARE:
                physics, advice = butterfly_words(self.model_.drive_name)
                raise InputError(
                    f"{names}: the displacement moves against the drive over {100 * against:.0f} % of its travel, "
                    f"falling on part of each rising sweep and rising on part of each falling one: a butterfly, "
                    f"{physics}. A play model's displacement follows its drive, so none fits this (it explains "
                    f"{100 * max(explained, 0):.0f} % of the variance); {advice}, where the displacement follows "
                    "the drive")
            raise InputError(f"{names}: the displacement hardly follows the drive (the model explains "
                             f"{100 * max(explained, 0):.0f} % of its variance, stroke {stroke:.3g} um): check that "
                             "the columns are the drive and the displacement of one actuator, and record with a "
                             f"drive that moves it over most of its stroke{self._fast_hint(fastest_hz)}")

    @staticmethod
    def _fast_hint(fast: float) -> str:
        """The other cause of an unexplained displacement: a drive so fast that lags and resonance
        (which no rate-independent model has) dominate the loop."""
        if not fast > FAST_LOOP_HZ:
            return ""
        return (f"; or, as the drive loops at {fast:.3g} Hz, eddy currents, a delay or a resonance (which a "
                "rate-independent model does not have) may dominate the loop: identify from a slow drive "
                f"(below about {FAST_LOOP_HZ:g} Hz)")

    # -- preparation -------------------------------------------------------------------------
    def _check_settings(self) -> None:
        if self.loop_width is not None and not all(math.isfinite(float(v)) for v in self.loop_width):
            raise InputError(f"loop_width must be two finite numbers (kappa per MPa, reference MPa), got {self.loop_width}")
        if self.n_play < 1:
            raise InputError(f"n_play must be at least 1, got {self.n_play}")
        if self.zero not in ZERO_MODES:
            raise InputError(f"zero must be one of {', '.join(ZERO_MODES)}, got {self.zero!r}")
        if self.n_deadzone < 1 or self.n_deadzone % 2 == 0:
            raise InputError(f"n_deadzone must be odd (2l+1: l negative, one centre, l positive), got {self.n_deadzone}")

    def _prepare(self, recordings: Sequence[Recording]) -> list[_Data]:
        if not recordings:
            raise InputError("no recordings given")
        drives = {r.drive_name for r in recordings}     # first: a mix of drives is the graver fault
        if len(drives) > 1:
            raise InputError(f"recordings mix drives {sorted(drives)}; identify one kind at a time")
        has_stress = [r.stress_MPa is not None for r in recordings]
        if any(has_stress) and not all(has_stress):
            missing = [r.name for r, h in zip(recordings, has_stress) if not h]
            raise InputError(f"some recordings have stress_MPa and some do not ({', '.join(missing)}); "
                             "give all or none a stress column")
        data = []
        for r in recordings:
            self._refuse_unusable(r)
            data.append(_Data(r.name, r.drive.copy(), r.column("displacement_um").copy(),
                              None if r.stress_MPa is None else r.stress_MPa.copy(), t=r.time_s))
        return data

    def _refuse_unusable(self, r: Recording) -> None:
        """InputError for a recording no fit can use: no displacement, a drive that never sweeps its range
        and back (named first, and fewer operators not suggested: they would not mend it), fewer samples
        than the operators need, or a constant drive."""
        if r.displacement_um is None:
            raise InputError(f"{r.source}: identification needs a displacement_um column")
        swept = has_full_sweep(r.drive)
        min_samples = 8 * (self.n_play + self.n_deadzone)
        need = (f"identifying {self.n_play} plays and {self.n_deadzone} dead-zones needs at least {min_samples}: "
                f"record at least {min_samples} samples over at least one full drive cycle (min to max and back)")
        if len(r) < min_samples and not swept:       # the real fault first: fewer operators would not mend it
            raise InputError(f"{r.source}: the drive never sweeps from one end of its range to the other and back, "
                             f"and there are only {len(r)} samples; {need}")
        if len(r) < min_samples:
            raise InputError(f"{r.source}: only {len(r)} samples; {need}{fewer_operators(len(r), self.n_play)}")
        if np.ptp(r.drive) <= 0:
            raise InputError(f"{r.source}: the drive is constant; a hysteresis model needs a swept drive")
        if not swept:
            raise InputError(f"{r.source}: the drive never sweeps from one end of its range to the other and "
                             "back, so the hysteresis loop is not in the data: record at least one full "
                             "drive cycle (min to max and back)")

    def _stress_levels(self, data: list[_Data]) -> tuple[list[float], list[float]]:
        """The stress levels held, and each recording's median stress; both empty without stress."""
        if data[0].sigma is None:
            return [], []
        per_rec = [float(np.median(d.stress)) for d in data]
        samples = np.concatenate([d.stress for d in data])
        # A level is a stress held for a real share of the data; a few outlier rows (a load-cell
        # glitch) must neither create a level nor decide the reference recordings.
        bins, counts = np.unique(np.round(samples / self.stress_tolerance_MPa), return_counts=True)
        held = bins[counts >= max(10, 0.01 * samples.size)] * self.stress_tolerance_MPa
        levels: list[float] = []
        for s in np.sort(held):
            if not levels or abs(s - levels[-1]) > self.stress_tolerance_MPa:
                levels.append(float(s))
        return levels, per_rec

    def _rows(self, d: _Data) -> np.ndarray:
        start = burn_in_end(d.x) if d.start is None else d.start
        n = len(d.x) - start
        step = max(1, n // self.max_rows)
        return np.arange(start, len(d.x), step)

    # -- step 1 ------------------------------------------------------------------------------
    def _fit_mpi(self, data: list[_Data]) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """Equation-error fit of (15) in the inverse domain, Proposition 3.1 as slope bounds."""
        y_all = np.concatenate([d.y for d in data])
        y_c = 0.5 * (float(y_all.min()) + float(y_all.max()))
        y_half = 0.5 * (float(y_all.max()) - float(y_all.min()))
        if y_half <= 0:
            names = ", ".join(d.name for d in data)
            raise InputError(f"the displacement is constant ({float(y_all[0]):.6g} um) in every recording ({names}): "
                             "the sensor's reading never changes, so there is nothing to identify; check that the "
                             "sensor is connected and that displacement_um is its channel")
        l = (self.n_deadzone - 1) // 2
        r_inv = np.arange(-l, l + 1) * y_half / (l + 1)
        H_parts, Phi_parts = [], []
        for d in data:
            rows = self._rows(d)
            H_parts.append(d.plays[rows])
            Phi_parts.append(slope_basis(d.y[rows] - y_c, r_inv))
        H, Phi = np.vstack(H_parts), np.vstack(Phi_parts)
        c = l
        others = [k for k in range(self.n_deadzone) if k != c]
        A = np.hstack([H, -Phi[:, others]])
        b = Phi[:, c]
        plays = PlayWeights(self.n_play, self._gain)
        A[:, : self.n_play] = A[:, : self.n_play] @ plays.T           # in the play weights' bounded variables
        scale = np.linalg.norm(A, axis=0)
        scale[scale == 0] = 1.0
        lower = np.r_[plays.lower, np.full(len(others), 1e-3)] * scale
        theta = bounded_least_squares(A / scale, b, lower, max_iter=2000) / scale
        w_h = plays.weights(theta[: self.n_play])
        s_inv = np.ones(self.n_deadzone)
        s_inv[others] = theta[self.n_play:]
        # Forward dead-zones from the inverse ones, analytically: the inverse of the inverse.
        r_s, w_s = deadzone_inverse(r_inv, slopes_to_weights(s_inv))
        r_s[c] = 0.0
        return w_h, r_s, weights_to_slopes(w_s), y_c

    def _regrid(self, data: list[_Data], w_h: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """Dead-zone thresholds at equal intervals over the intermediate signal z = P[x] on each
        side of 0, and the slopes for them by bounded linear least squares."""
        z = np.concatenate([d.plays[self._rows(d)] @ w_h for d in data])
        y = np.concatenate([d.y[self._rows(d)] for d in data])
        l = (self.n_deadzone - 1) // 2
        z_hi, z_lo = max(float(z.max()), 1e-12), min(float(z.min()), -1e-12)
        r_s = intermediate_grid(z_lo, z_hi, l)
        A = slopes_and_offset(z, r_s)
        if not determined(A):
            raise InputError(f"the plays' output takes too few distinct values ({np.unique(z).size}) to fix "
                             f"{self.n_deadzone} dead-zone slopes (the drive holds a few levels): record a swept "
                             "drive (a sine or triangle from min to max and back), or fit fewer dead-zones "
                             f"(--deadzones {deadzones_determined(z, z_lo, z_hi, l)})")
        scale = np.linalg.norm(A, axis=0)
        scale[scale == 0] = 1.0
        floor = 1e-3 * np.ptp(y) / max(np.ptp(z), 1e-12)
        lower = np.r_[np.full(self.n_deadzone, floor), -np.inf] * scale
        theta = bounded_least_squares(A / scale, y, lower) / scale
        return r_s, theta[:-1], float(theta[-1])

    def _refine_mpi(self, data: list[_Data], w_h: np.ndarray, r_s: np.ndarray, slopes: np.ndarray,
                    y_c: float) -> tuple[np.ndarray, np.ndarray, float]:
        """Output-error refinement with thresholds held: minimise the displacement residual."""
        H = np.vstack([d.plays[self._rows(d)] for d in data])
        y = np.concatenate([d.y[self._rows(d)] for d in data])
        n_h, n_s = self.n_play, self.n_deadzone
        edges = np.r_[-np.inf, r_s[: (n_s - 1) // 2], r_s[(n_s + 1) // 2:], np.inf]

        plays = PlayWeights(n_h, self._gain)
        Hq = H @ plays.T                                   # the plays in the weights' bounded variables

        def unpack(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
            return plays.weights(theta[:n_h]), theta[n_h: n_h + n_s], theta[-1]

        def resid(theta: np.ndarray) -> np.ndarray:
            _, s, yc = unpack(theta)
            return yc + slope_basis(Hq @ theta[:n_h], r_s) @ s - y

        def jac(theta: np.ndarray) -> np.ndarray:
            _, s, _ = unpack(theta)
            z = Hq @ theta[:n_h]
            seg = np.searchsorted(edges, z, side="right") - 1
            local_slope = s[np.clip(seg, 0, n_s - 1)]
            return np.hstack([Hq * local_slope[:, None], slope_basis(z, r_s), np.ones((len(z), 1))])

        s_floor = 1e-3 * float(np.max(slopes))
        lower = np.r_[plays.lower, np.full(n_s, s_floor), -np.inf]
        theta0 = np.r_[plays.variables(w_h), np.maximum(slopes, s_floor), y_c]
        res = optimize.least_squares(resid, theta0, jac=jac, bounds=(lower, np.inf), method="trf",
                                     x_scale="jac", max_nfev=200, tr_solver=TRUST_REGION_SOLVER)
        if rms(res.fun) < rms(resid(theta0)):
            return unpack(res.x)
        return w_h, slopes, y_c

    # -- steps 2 and 3 -----------------------------------------------------------------------
    def _fit_stress(self, data: list[_Data], w_h: np.ndarray, r_s: np.ndarray,
                    stress_range: tuple[float, float], n_levels: int) -> tuple[np.ndarray, np.ndarray]:
        """Slopes and output offset as polynomials (degree <= 2) in stress, Proposition 3.1 imposed."""
        lo, hi = stress_range
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        degree = min(2, n_levels - 1)
        off_degree = 0 if self.zero == "per_recording" else degree   # zeros apart: the offset is one constant
        n_zero = len(data) - 1 if self.zero == "per_recording" else 0
        n_s = len(r_s)
        A, y = self._stress_design(data, w_h, r_s, (mid, half), degree, off_degree, n_zero)
        n_coef = (degree + 1) * n_s
        col_scale = np.linalg.norm(A, axis=0)
        col_scale[col_scale == 0] = 1.0
        theta = slopes_in_stress(A, y, col_scale, degree, n_s) / col_scale
        slope_poly = theta[:n_coef].reshape(degree + 1, n_s)
        offset_poly = np.r_[theta[n_coef: n_coef + off_degree + 1], np.zeros(degree - off_degree)]
        for d, z in zip(data[1:], theta[n_coef + off_degree + 1:]):   # each recording onto the first's zero
            d.shift_zero(-float(z))
        # Back from normalised u = (sigma - mid)/half to plain sigma, coefficients (c0, c1, c2).
        to_sigma = powers_to_sigma(mid, half, degree)
        slope_coeffs = to_sigma @ slope_poly  # (3, n_s)
        out_coeffs = to_sigma @ offset_poly
        return slopes_to_weights(slope_coeffs), out_coeffs

    def _stress_design(self, data: list[_Data], w_h: np.ndarray, r_s: np.ndarray, centre: tuple[float, float],
                       degree: int, off_degree: int, n_zero: int) -> tuple[np.ndarray, np.ndarray]:
        """The stress step's least squares (A, y): per row, each dead-zone's slope basis times the
        powers of the normalised stress u = (sigma - mid)/half ([p, k] order), the offset's powers, and
        for the recordings after the first their own zero."""
        mid, half = centre
        blocks, targets = [], []
        for i, d in enumerate(data):
            rows = self._rows(d)
            u = (d.stress[rows] - mid) / half
            powers = np.vstack([u ** p for p in range(degree + 1)]).T  # (rows, degree+1)
            phi = slope_basis(d.plays[rows] @ w_h, r_s)
            feats = (phi[:, None, :] * powers[:, :, None]).reshape(len(rows), -1)  # [p, k] order
            own_zero = np.zeros((len(rows), n_zero))           # recordings after the first: their zero
            if 0 < i <= n_zero:
                own_zero[:, i - 1] = 1.0
            blocks.append(np.hstack([feats, powers[:, : off_degree + 1], own_zero]))
            targets.append(d.y[rows])
        return np.vstack(blocks), np.concatenate(targets)

    def _refine_joint(self, data: list[_Data], w_h: np.ndarray, r_s: np.ndarray, coeffs: np.ndarray,
                      out_coeffs: np.ndarray, stress_range: tuple[float, float],
                      n_levels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Alternate: play weights by output error on all recordings (stress terms held), then the
        stress QP (play weights held). Keeps the best pass; each step cannot break Prop. 3.1."""
        rows = [self._rows(d) for d in data]
        H = np.vstack([d.plays[r] for d, r in zip(data, rows)])
        sig = np.concatenate([d.stress[r] for d, r in zip(data, rows)])
        y = np.concatenate([d.y[r] for d, r in zip(data, rows)])
        n_s = len(r_s)
        edges = np.r_[-np.inf, r_s[: (n_s - 1) // 2], r_s[(n_s + 1) // 2:], np.inf]

        def predict(wh: np.ndarray, cf: np.ndarray, oc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            slopes = weights_to_slopes(cf[0] + sig[:, None] * (cf[1] + sig[:, None] * cf[2]))
            z = H @ wh
            offset = oc[0] + sig * (oc[1] + sig * oc[2])
            return offset + np.einsum("ij,ij->i", slope_basis(z, r_s), slopes), slopes, z

        best = (rms(predict(w_h, coeffs, out_coeffs)[0] - y), w_h, coeffs, out_coeffs)
        plays = PlayWeights(len(w_h), self._gain)
        Hq = H @ plays.T                                   # the plays in the weights' bounded variables
        for _ in range(self.joint_passes):
            _, slopes, _ = predict(w_h, coeffs, out_coeffs)
            offset = out_coeffs[0] + sig * (out_coeffs[1] + sig * out_coeffs[2])

            def resid(q: np.ndarray) -> np.ndarray:
                return offset + np.einsum("ij,ij->i", slope_basis(Hq @ q, r_s), slopes) - y

            def jac(q: np.ndarray) -> np.ndarray:
                seg = np.clip(np.searchsorted(edges, Hq @ q, side="right") - 1, 0, n_s - 1)
                return Hq * slopes[np.arange(len(seg)), seg][:, None]

            res = optimize.least_squares(resid, plays.variables(w_h), jac=jac, bounds=(plays.lower, np.inf),
                                         method="trf", x_scale="jac", max_nfev=50, tr_solver=TRUST_REGION_SOLVER)
            w_h = plays.weights(res.x)
            coeffs, out_coeffs = self._fit_stress(data, w_h, r_s, stress_range, n_levels)
            err = rms(predict(w_h, coeffs, out_coeffs)[0] - y)
            if err < best[0]:
                best = (err, w_h, coeffs, out_coeffs)
        return best[1], best[2], best[3]

    # -- scoring -----------------------------------------------------------------------------
    def _score(self, d: _Data) -> RecordingFit:
        """RMS over the fitted samples (after the burn-in sweep, or all of a short recording), the
        model started from its estimated initial state where the start can change them; those
        samples' output kept in `d.pred` for the degeneracy check."""
        measured = self.output_sign_ * d.y                 # the recording's own orientation
        start = burn_in_end(d.x) if d.start is None else d.start
        pred = self._output_whatever_the_start(d, start)
        if pred is None:
            pred = self.core_.simulate(None, d.x, d.sigma, measured_um=measured)
        d.pred = pred[start:]
        err = d.pred - measured[start:]
        stroke = float(d.y.max() - d.y.min())
        stress = None if d.sigma is None else float(np.median(d.sigma))
        worst = int(np.argmax(np.abs(err)))
        at = None if d.t is None else float(d.t[start + worst])
        return RecordingFit(d.name, stress, rms(err), stroke, float(abs(err[worst])), float(np.mean(err)), at,
                            int(start))

    def _output_whatever_the_start(self, d: _Data, start: int) -> np.ndarray | None:
        """The output when no initial state changes it from `start` on, else None. The runs from every
        play at the bottom and at the top of its box (the kernel's first step clamps a state beyond
        it) bound the run from any other state: the model rises with each play (Proposition 3.1). When
        they agree from `start` on, the burn-in sweep has wiped the start, and the state fit (about
        0.2 s a recording, and diagnose re-identifies cores by the dozen) would change nothing."""
        if start <= 0:
            return None
        beyond = np.full(self.n_play, BEYOND_THE_BOX)
        low = self.core_.simulate(None, d.x, d.sigma, initial_play_state=-beyond)
        high = self.core_.simulate(None, d.x, d.sigma, initial_play_state=beyond)
        return low if np.array_equal(low[start:], high[start:]) else None


BEYOND_THE_BOX = 1e30
"""A play state beyond any play's admissible box (the drive's first value plus or minus its
threshold): the kernel's first step clamps it to the box's edge."""


ZERO_RATIO = 3.0   # a recording's mean error 3x the loops' own (shape) error: the level, not the loop, is off
ZERO_MODES = ("shared", "per_recording")
ZERO_PASSES = 4    # per-recording zeros: whole refits at most (the stress step fits the zeros jointly;
                   # a refit lets step 1 see the aligned data)
ZERO_SETTLED = 0.05  # ... and none once the shifts left are 5 % of the loops' own error


def zero_mismatch(fits: Sequence[RecordingFit]) -> str:
    """A note when some recordings sit off the model by a constant far beyond the error of their
    loops' shape: their displacement zero is not the others' (a sensor zeroed again between runs),
    which no model of the actuator can fit ('' otherwise)."""
    if len(fits) < 2:
        return ""
    shape = float(np.median([f.shape_rms_um for f in fits]))
    off = [f for f in fits if abs(f.offset_um) > ZERO_RATIO * max(shape, 1e-12)]
    if not off:
        return ""
    each = ", ".join(f"{f.name} {f.offset_um:+.3g} um" for f in off)
    return (f"recordings sit off the model by constants ({each}) while the loops' shape fits to {shape:.3g} um: "
            "their displacement zero is not the others' (the sensor zeroed again between runs?). The model's "
            "offset follows stress, not a recording, so it takes up only what is smooth in stress: its absolute "
            "displacement is off by about as much at those stresses. Zero the sensor the same way for every run "
            "(e.g. at zero drive and one load), or identify with --zero per-recording")


def identify(recordings: Sequence[Recording], **settings: Any) -> SDPIModel:
    """Convenience: `SDPIIdentifier(**settings).fit(recordings).model_`."""
    return SDPIIdentifier(**settings).fit(recordings).model_
