"""The diagnosis: locate the mismatch, select the missing physics, build the extended model.

Selection is greedy and forward: each round fits every untried effect of the catalog on top of
what is already accepted and scores it on held-out time blocks. The best is accepted only if it
(1) lowers the held-out mean-square error by a clear margin, (2) wins a penalised held-out
likelihood test with the residual's effective sample count, and (3) the residual it removes
is above the noise floor measured from the data. The null model every effect must beat is the
base model with a static recalibration (gain, offset, curvature, stress gain): ordinary model
error of that kind is never called an effect.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from ..errors import InputError
from ..recordings import Recording
from .catalog import CATALOG, ORDER
from .data import N_BLOCKS, RecData, noise_floor, prepare
from .extended import THERMAL_FAST_RATIO, ExtendedModel
from .fitting import Fitter, SearchResult, Spec, geom_refine, search
from .locate import Located, locate

MIN_MSE_RATIO = 0.75       # accepted effects cut the held-out MSE by at least 25 % (RMS by ~13 %)
MIN_LOGLIK_GAIN = 6.0      # penalised held-out log-likelihood gain (nats) an effect must win by
NOISE_FACTOR = 1.5         # a residual within 1.5x the noise floor is "within noise"
MODEL_ERROR_FACTOR = 3.0   # below 3x the noise floor, what a recalibrated core leaves is ordinary identification
                           # error (a core fitted to similar data reaches 2-3x its sensor noise): nothing to explain
SLOW_RATIO_MAX = 0.8       # stress_dependent_play must also cut the error on slow samples by 20 %
AMBIGUOUS_NATS = 3.0       # runner-up this close to the winner: look-alikes not told apart
HUBER_K = 3.0             # Huber scale in robust standard deviations of the recalibrated residual
MIN_SAMPLES = 400
JOINT = {"rate_dependence": "delay_s", "time_delay": "eddy_tau"}   # look-alikes searched jointly
WORKERS = 2                # candidate searches in parallel threads (numba kernels and BLAS release the GIL)
MIN_REVERSALS = 2 * N_BLOCKS   # drive turning points in all: on average a full drive cycle per time block, or a
                               # held-out block is a piece of one branch that the neighbouring training blocks
                               # interpolate, and blocked cross-validation tests interpolation, not prediction


@dataclass
class Candidate:
    effect: str
    testable: bool
    reason: str = ""
    cv_mse: float = math.nan
    cv_loss: float = math.nan
    loglik_gain: float = math.nan
    evidence: float = 0.0
    params: dict[str, float] = field(default_factory=dict)
    round: int = 0
    accepted: bool = False
    result: SearchResult | None = None

    def to_json(self) -> dict:
        d: dict[str, Any] = {"effect": self.effect, "evidence": round(float(self.evidence), 4),
                             "params": {k: _round(v) for k, v in self.params.items()}}
        d["validation_rms_um"] = None if not math.isfinite(self.cv_mse) else _round(math.sqrt(self.cv_mse))
        d["heldout_loglik_gain"] = None if not math.isfinite(self.loglik_gain) else round(self.loglik_gain, 2)
        d["accepted"] = self.accepted
        d["testable"] = self.testable
        if self.reason:
            d["note"] = self.reason
        d["round"] = self.round
        return d


OUTCOMES = ("within_noise", "effects_named", "unexplained", "inconclusive")


@dataclass
class Diagnosis:
    outcome: str               # one of OUTCOMES (docs/cli.md): what `verdict == []` means is never ambiguous
    verdict: list[str]
    explanation: str
    located: list[Located]
    candidates: list[Candidate]
    rms_before_um: float
    rms_recalibrated_um: float
    rms_after_um: float
    noise_um: float
    validation: str
    conclusive: bool
    cannot_conclude: list[str]
    extended: ExtendedModel
    data: list[RecData]
    base_predictions: list[np.ndarray]
    null_predictions: list[np.ndarray]
    final_predictions: list[np.ndarray]
    rounds: list[dict]
    n_eff: float

    def to_json(self, model_file: str = "extended_model.yaml") -> dict:
        return {
            "outcome": self.outcome,
            "verdict": list(self.verdict),
            "explanation": self.explanation,
            "located": [loc.to_json() for loc in self.located],
            "candidates": [c.to_json() for c in self.candidates],
            "rms_before_um": _round(self.rms_before_um),
            "rms_after_um": _round(self.rms_after_um),
            "rms_recalibrated_um": _round(self.rms_recalibrated_um),
            "noise_floor_um": _round(self.noise_um),
            "validation": self.validation,
            "conclusive": self.conclusive,
            "cannot_conclude": list(self.cannot_conclude),
            "extended_model": model_file,
        }


def _round(v: float) -> float | None:
    if v is None or not math.isfinite(v):
        return None
    return float(f"{v:.6g}")


# --------------------------------------------------------------------------------- helpers

def _reversals(u: np.ndarray) -> int:
    """Turning points of the drive by more than 10 % of its span (hysteresis-style counting)."""
    span = float(np.ptp(u))
    if span <= 0:
        return 0
    thr = 0.1 * span
    count, direction = 0, 0
    hi = lo = extreme = float(u[0])
    for v in u[:: max(1, u.size // 20000)]:
        if direction == 0:
            # no direction yet: track both extremes until the drive has moved away from one of them
            hi, lo = max(hi, v), min(lo, v)
            if hi - v > thr:
                direction, extreme = -1, v
            elif v - lo > thr:
                direction, extreme = 1, v
        elif direction > 0:
            if v > extreme:
                extreme = v
            elif extreme - v > thr:
                count += 1
                direction, extreme = -1, v
        else:
            if v < extreme:
                extreme = v
            elif v - extreme > thr:
                count += 1
                direction, extreme = 1, v
    return count


def effective_samples(resid: np.ndarray, lengths: Sequence[int]) -> float:
    """Independent samples in a residual (per recording: length / integrated correlation time)."""
    total = 0.0
    start = 0
    for n in lengths:
        r = resid[start:start + n]
        start += n
        if r.size < 8:
            total += r.size
            continue
        r = r - r.mean()
        var = float(r @ r) / r.size
        if var <= 0:
            total += r.size
            continue
        tau = 1.0
        for lag in range(1, min(r.size // 4, 2000)):
            rho = float(r[:-lag] @ r[lag:]) / (r.size * var)
            if rho < 0.05:
                break
            tau += 2 * rho
        total += r.size / tau
    return max(total, 1.0)


def _params_of(effect: str, spec: Spec, coef: np.ndarray, names: list[str], fitter: Fitter) -> dict[str, float]:
    c = dict(zip(names, coef))
    if effect == "rate_dependence":
        return {"tau_s": spec.eddy_tau}
    if effect == "time_delay":
        return {"delay_s": spec.delay_s}
    if effect == "thermal_drift":
        out = {"tau_s": spec.thermal_tau, "gain_um_per_A2": c.get("thermal_gain", math.nan)}
        if "thermal_fast_gain" in c:
            out.update(fast_tau_s=spec.thermal_tau * THERMAL_FAST_RATIO, fast_gain_um_per_A2=c["thermal_fast_gain"])
        return out
    if effect == "creep":
        return {"tau_s": spec.creep_tau, "gain": c.get("creep_gain", math.nan)}
    if effect == "mechanical_dynamics":
        f, z, b = spec.dynamics
        out = {"f_ref_hz": f, "zeta": z, "beta_per_MPa": b, "stress_ref_MPa": fitter.stress_top}
        if b > 0:
            s_lo = min(float(d.s.min()) for d in fitter.data)
            out["f_at_most_compressive_hz"] = f / math.sqrt(1 + b * (fitter.stress_top - s_lo))
        return out
    if effect == "stress_dependent_play":
        out = {f"coef_{j}_um_per_A_MPa": c.get(f"stress_play_{j}", math.nan) for j in range(fitter.play_thresholds.size)}
        out["loop_width_change_per_MPa"] = c.get("stress_width", math.nan)
        out["width_chord_step"] = float(spec.stress_play)
        return out
    if effect == "saturation":
        out = {"drive_lo": fitter.drive_lo, "drive_hi": fitter.drive_hi}
        out.update({k: v for k, v in c.items() if k.startswith("sat_")})
        return out
    return {}


def build_extended(model: Any, fitter: Fitter, spec: Spec, coef: np.ndarray, names: list[str],
                   effects: list[str]) -> ExtendedModel:
    """The extended model file's content for a spec and its all-data coefficients."""
    c = dict(zip(names, (float(v) for v in coef)))
    blocks: dict[str, Any] = {
        "static": {"offset_um": c["offset"], "gain": c["gain"],
                   "stress_gain_per_MPa": c.get("stress_gain", 0.0),
                   "quadratic_per_um": c["quadratic"], "center_um": fitter.yc_center,
                   "stress_ref_MPa": fitter.stress_ref}}
    if spec.saturation:
        blocks["saturation"] = {"lo": fitter.drive_lo, "hi": fitter.drive_hi,
                                "lin_lo": c.get("sat_lin_lo", 0.0), "quad_lo": c.get("sat_quad_lo", 0.0),
                                "lin_hi": c.get("sat_lin_hi", 0.0), "quad_hi": c.get("sat_quad_hi", 0.0)}
    if spec.eddy_tau:
        blocks["eddy_lag"] = {"tau_s": spec.eddy_tau}
    if spec.delay_s:
        blocks["delay"] = {"delay_s": spec.delay_s}
    blocks["play_correction"] = {"thresholds": [float(v) for v in fitter.play_thresholds],
                                 "coefficients": [c[f"play_{j}"] for j in range(fitter.play_thresholds.size)]}
    if spec.stress_play:
        blocks["stress_play"] = {"thresholds": [float(v) for v in fitter.play_thresholds],
                                 "coefficients_per_MPa": [c[f"stress_play_{j}"] for j in range(fitter.play_thresholds.size)]}
        if "stress_width" in c:
            blocks["stress_width"] = {"coef_per_MPa": c["stress_width"], "eps": float(spec.stress_play)}
    if spec.creep_tau:
        blocks["creep"] = {"gain": c["creep_gain"], "tau_s": spec.creep_tau}
    if spec.dynamics is not None:
        f, z, b = spec.dynamics
        blocks["dynamics"] = {"f_ref_hz": f, "zeta": z, "beta_per_MPa": b, "stress_ref_MPa": fitter.stress_top}
    if spec.thermal_tau:
        blocks["thermal"] = {"gain_um_per_A2": c["thermal_gain"], "tau_s": spec.thermal_tau}
        if "thermal_fast_gain" in c:
            blocks["thermal"].update(fast_gain_um_per_A2=c["thermal_fast_gain"],
                                     fast_tau_s=spec.thermal_tau * THERMAL_FAST_RATIO)
    return ExtendedModel(model, blocks, effects)


# --------------------------------------------------------------------------------- checks

def _check_overlap(model: Any, recordings: Sequence[Recording]) -> None:
    lo, hi = model.drive_range
    srange = model.stress_range_MPa
    drive_overlap = []
    stress_overlap = []
    for rec in recordings:
        u = rec.drive
        inside = (u >= lo - 0.02 * (hi - lo)) & (u <= hi + 0.02 * (hi - lo)) if math.isfinite(hi - lo) else np.ones(u.size, bool)
        drive_overlap.append(float(np.mean(inside)))
        if srange is not None and rec.stress_MPa is not None:
            s = rec.stress_MPa
            tol = 0.02 * max(srange[1] - srange[0], 1.0)
            stress_overlap.append(float(np.mean((s >= srange[0] - tol) & (s <= srange[1] + tol))))
    if max(drive_overlap) < 0.05:
        raise InputError(
            f"cannot conclude anything: the recordings' drive never enters the range the model was identified on "
            f"({lo:.3g}..{hi:.3g}); record inside that range, or identify a model from recordings covering these drives")
    if stress_overlap and max(stress_overlap) < 0.05:
        raise InputError(
            f"cannot conclude anything: every recording's stress lies outside the model's range "
            f"({srange[0]:.3g}..{srange[1]:.3g} MPa); record at loads inside that range, or identify an SDPI that covers these stresses")


# --------------------------------------------------------------------------------- main

def diagnose(model: Any, recordings: Sequence[Recording], max_effects: int = 3,
             progress: Callable[[str], None] | None = None) -> Diagnosis:
    """Run the whole diagnosis (no I/O); see the module docstring for the selection rule."""
    say = progress or (lambda _msg: None)
    if not recordings:
        raise InputError("give at least one recording to compare with the model")
    _check_overlap(model, recordings)
    data = prepare(recordings, model)
    fitter = Fitter(model, data)
    cannot: list[str] = []

    n_samples = sum(d.t.size - d.settled for d in data)      # samples scored: after the initial state settles
    reversals = sum(_reversals(d.u[d.settled:]) for d in data if d.settled < d.t.size)
    for d in data:
        if d.settled >= d.t.size:
            cannot.append(f"{d.name}: the drive never sweeps far enough for the model to forget its unknown "
                          "initial state, so none of it is scored; record at least one full drive cycle")
        elif d.settled > 0:
            d.extra["settled_note"] = (f"{d.name}: the first {d.t[d.settled] - d.t[0]:.3g} s are not scored: "
                                       "until the drive has swept the model's full loop, the output still "
                                       "depends on the unknown hysteresis state at the start")
    too_little = n_samples < MIN_SAMPLES or reversals < MIN_REVERSALS
    if too_little:
        cannot.append(
            f"too little data to tell effects apart ({n_samples} samples, {reversals} drive reversals in all): "
            "any effect would be fitted to the same few loops it is judged on; record at least a few cycles "
            f"(>= {MIN_REVERSALS // 2} full loops, >= {MIN_SAMPLES} samples) at two or more drive frequencies")
    clamped = [d for d in data if d.clamped_fraction > 0.01]
    for d in clamped:
        cannot.append(f"{d.name}: {d.clamped_fraction:.0%} of the samples are at stresses outside the model's range; "
                      "they were compared at the nearest stress of the range")
    noise = float(np.median([noise_floor(d.y) for d in data]))

    say("simulating the base model")
    base_core = fitter.core(Spec())
    _ = fitter.yc_center          # computed once, before any threads share the fitter
    base_pred = [yc for _, yc in base_core]
    rms_before = float(np.sqrt(sum(float(np.sum((d.y - yc)[d.settled:] ** 2)) for d, yc in zip(data, base_pred))
                               / max(n_samples, 1)))

    null_specs = (Spec(), Spec(), Spec())
    # Huber scale from the recalibrated base's held-out residual: bursts the core cannot follow at all
    # (e.g. a load change) then weigh in linearly, not quadratically, in fits and in the selection
    r0 = fitter.test_residuals(null_specs)
    robust_sigma = 1.4826 * float(np.median(np.abs(r0 - np.median(r0))))
    fitter.delta = max(HUBER_K * robust_sigma, 2.0 * noise, 1e-12)
    null = fitter.score(null_specs, want_coef=True)
    n_null = max(null.n_test[0] + null.n_test[1], 1)
    null_loss = (null.sse_test[0] + null.sse_test[1]) / n_null
    null_cv = (null.sq_test[0] + null.sq_test[1]) / n_null
    null_pred = fitter.predict_full(Spec(), null.coef_all)
    located = [locate(d, _scored(d, d.y - yb), _scored(d, d.y - yn)) for d, yb, yn in zip(data, base_pred, null_pred)]
    lengths = fitter.segment_lengths

    candidates = {name: Candidate(name, *CATALOG[name].testable(fitter)) for name in ORDER}
    if too_little:
        for c in candidates.values():
            c.testable, c.reason = False, c.reason or "too little data"
    short = fitter.duration_max < 20.0
    for name in ("thermal_drift", "creep"):
        if short and candidates[name].testable:
            candidates[name].reason = (f"the longest recording lasts {fitter.duration_max:.3g} s: slow effects "
                                       "(heating, creep) with time constants beyond it are hard to separate; "
                                       "a run of several minutes with current on/off phases would decide")
    for c in candidates.values():
        if not c.testable and c.reason and c.reason not in cannot and not too_little:
            cannot.append(f"{c.effect}: {c.reason}")

    current = null_specs
    cur_cv = null_cv
    cur_loss = null_loss
    accepted: list[str] = []
    rounds: list[dict] = []
    final = SearchResult(null_specs, null_loss, null_cv, null.all_mse, null.n_test[0] + null.n_test[1], null.coef_all,
                         null.names, 1)
    within_noise = math.sqrt(null_cv) <= NOISE_FACTOR * noise
    runner_note = ""
    ambiguous_pairs: list[tuple[str, str]] = []
    swapped: list[tuple[str, str, float, float]] = []
    outside_class = ""
    for rnd in range(1, max_effects + 1):
        if math.sqrt(cur_cv) <= NOISE_FACTOR * noise:
            break
        tried: list[Candidate] = []
        todo = [c for c in candidates.values() if c.testable and not c.accepted]
        say(f"round {rnd}: fitting {', '.join(c.effect for c in todo)}")
        results = _search_all(fitter, current, [c.effect for c in todo])
        for c in todo:
            res = results[c.effect]
            c.result = res
            c.cv_mse = res.cv_mse
            c.cv_loss = res.cv_loss
            c.params = _params_of(c.effect, res.specs[2], res.coef_all, res.names, fitter)
            c.round = rnd
            tried.append(c)
        if not tried:
            break
        # effective sample count of the noise, from the best candidate's held-out residual
        leader = min(tried, key=lambda c: c.cv_loss)
        n_eff = effective_samples(fitter.test_residuals(leader.result.specs), lengths)
        for c in tried:
            c.loglik_gain = 0.5 * n_eff * math.log(cur_loss / max(c.cv_loss, 1e-300)) - CATALOG[c.effect].n_params
        gains = np.array([c.loglik_gain for c in tried])
        top = max(0.0, float(gains.max()))
        weights = np.exp(np.clip(gains - top, -700, 0))
        norm = math.exp(-top) + float(weights.sum())
        for c, w in zip(tried, weights):
            c.evidence = float(w / norm)
        tried.sort(key=lambda c: c.cv_loss)
        best = tried[0]
        ok = (best.cv_loss < MIN_MSE_RATIO * cur_loss and best.loglik_gain > MIN_LOGLIK_GAIN
              and math.sqrt(cur_loss) - math.sqrt(best.cv_loss) > 0.5 * noise)
        if ok and best.effect == "stress_dependent_play":
            # signature: play weights are rate-independent, so the gain must hold where the drive is slow
            slow_ratio = _slow_gain_ratio(fitter, current, best.result.specs)
            if slow_ratio > SLOW_RATIO_MAX:
                best.testable = False
                best.reason = (f"its held-out gain comes from the fast parts of the drive (on the slowest 40 % of "
                               f"samples the error only falls to {slow_ratio:.0%} of before), where rate-independent "
                               "play weights cannot be the cause: a leftover of another effect that changes with the load")
                tried = tried[1:]
                if not tried:
                    break
                best = tried[0]
                ok = (best.cv_loss < MIN_MSE_RATIO * cur_loss and best.loglik_gain > MIN_LOGLIK_GAIN
                      and math.sqrt(cur_loss) - math.sqrt(best.cv_loss) > 0.5 * noise)
        if ok and best.effect == "saturation":
            # signature: saturation flattens the material's curve beyond the identified range, it never
            # turns it round; a correction that reverses the slope is the model used outside its class
            reverses = _saturation_reverses(model, fitter, best.params, best.result, noise)
            if reverses:
                best.testable, best.reason = False, reverses
                outside_class = reverses
                tried = tried[1:]
                if not tried:
                    break
                best = tried[0]
                ok = (best.cv_loss < MIN_MSE_RATIO * cur_loss and best.loglik_gain > MIN_LOGLIK_GAIN
                      and math.sqrt(cur_loss) - math.sqrt(best.cv_loss) > 0.5 * noise)
        rounds.append({"round": rnd, "n_eff": n_eff, "current_rms_um": math.sqrt(cur_cv),
                       "table": [(c.effect, math.sqrt(c.cv_mse), c.loglik_gain) for c in tried],
                       "accepted": best.effect if ok else None})
        if not ok:
            break
        if len(tried) > 1 and tried[1].loglik_gain > MIN_LOGLIK_GAIN and \
                best.loglik_gain - tried[1].loglik_gain < AMBIGUOUS_NATS:
            ambiguous_pairs.append((best.effect, tried[1].effect))
        if rnd == 1 and len(tried) > 1:
            runner_note = _runner_up_note(best, tried[1])
        best.accepted = True
        accepted.append(best.effect)
        current = best.result.specs
        cur_cv = best.cv_mse
        cur_loss = best.cv_loss
        final = best.result

    # swap pass: with the other accepted effects in place, is each one still the best choice for its slot?
    # (the first rounds judge look-alikes against a residual dominated by the biggest effect)
    importance: dict[str, float] = {}
    if len(accepted) >= 2:
        ambiguous_pairs = []
        n_eff_last = rounds[-1]["n_eff"] if rounds else 1.0
        for name in list(accepted):
            if name not in accepted:
                continue
            others = tuple(CATALOG[name].remove(s) for s in current)
            o = fitter.score(others)
            o_cv = (o.sse_test[0] + o.sse_test[1]) / max(o.n_test[0] + o.n_test[1], 1)   # loss
            best_name, best_res = name, None
            slot: list[tuple[float, str]] = []
            rivals = [c.effect for c in candidates.values()
                      if c.testable and not (c.accepted and c.effect != name)]
            say(f"checking {name} against the others with the other effects in place")
            found = _search_all(fitter, others, rivals)
            for cand_name in rivals:
                res = found[cand_name]
                cand = candidates[cand_name]
                slot.append((res.cv_loss, cand.effect))
                if best_res is None or res.cv_loss < best_res.cv_loss:
                    best_name, best_res = cand.effect, res
            if best_res is None:
                continue
            slot.sort()
            if len(slot) > 1 and 0.5 * n_eff_last * math.log(slot[1][0] / max(slot[0][0], 1e-300)) < AMBIGUOUS_NATS:
                ambiguous_pairs.append((slot[0][1], slot[1][1]))
            if best_name != name and best_res.cv_loss < cur_loss:
                swap = candidates[best_name]
                candidates[name].accepted = False
                swap.accepted = True
                swap.result = best_res
                swap.cv_mse = best_res.cv_mse
                swap.cv_loss = best_res.cv_loss
                swap.params = _params_of(best_name, best_res.specs[2], best_res.coef_all, best_res.names, fitter)
                swapped.append((name, best_name, math.sqrt(candidates[name].cv_mse), math.sqrt(best_res.cv_mse)))
                accepted[accepted.index(name)] = best_name
                current, cur_cv, cur_loss, final = best_res.specs, best_res.cv_mse, best_res.cv_loss, best_res
                name = best_name
            importance[name] = o_cv - cur_loss
        accepted.sort(key=lambda n: -importance.get(n, 0.0))

    # parameters of the accepted effects as they stand in the final model (later rounds may retune them)
    for name in accepted:
        candidates[name].params = _params_of(name, final.specs[2], final.coef_all, final.names, fitter)
    ext = build_extended(model, fitter, final.specs[2], final.coef_all, final.names, list(accepted))
    final_pred = fitter.predict_full(final.specs[2], final.coef_all)
    if cur_cv > rms_before ** 2:
        # Worse than the base model as given, on held-out data: never the verdict. The extended
        # model is the base as it was, and nothing is named.
        if accepted:
            cannot.append(f"{', '.join(accepted)} improved on the recalibrated model but not on the base model "
                          f"itself on held-out data ({math.sqrt(cur_cv):.4g} um against {rms_before:.4g} um), "
                          "so nothing is named: longer recordings, or several at different drive frequencies, "
                          "would let the fit be judged on more than the blocks it was chosen on")
            for name in accepted:
                candidates[name].accepted = False
            accepted = []
            ambiguous_pairs = []
        ext = ExtendedModel(model, {}, [])
        final_pred = list(base_pred)
        cur_cv = rms_before ** 2
    for a, b in ambiguous_pairs:
        cannot.append(f"{a} and {b} explain the held-out data almost equally well; " + _decider(a, b))

    if not accepted and cur_cv < rms_before ** 2:
        # nothing named: the static recalibration alone is kept only where it generalises, i.e. it
        # beats the base model on the held-out blocks of every recording (on data with nothing
        # missing, a recalibration fitted to one recording's quirks makes the next one worse)
        worse = _recalibration_hurts(fitter, final.specs, base_pred)
        if worse:
            cannot.append(f"the static recalibration was left out of the extended model: on held-out blocks it "
                          f"is worse than the base model on {', '.join(worse)}")
            ext = ExtendedModel(model, {}, [])
            final_pred = list(base_pred)
            cur_cv = rms_before ** 2
    if outside_class and accepted and not too_little:
        # the residual is dominated by drive the model's class cannot follow: whatever else fits it is
        # fitted to that, so nothing is named until the core is identified over the drive range used
        cannot.append(f"{', '.join(accepted)} would be fitted to the part of the residual the model's class cannot "
                      "follow, so nothing is named")
        for name in accepted:
            candidates[name].accepted = False
        accepted, ambiguous_pairs = [], []
        ext = ExtendedModel(model, {}, [])
        final_pred = list(base_pred)
        cur_cv = rms_before ** 2
    if outside_class:
        cannot.insert(0, f"outside the model's class: {outside_class}")
    verdict = [] if too_little else list(accepted)
    conclusive = not too_little and not ambiguous_pairs
    well_above = math.sqrt(cur_cv) > MODEL_ERROR_FACTOR * noise
    if too_little or ambiguous_pairs:
        outcome = "inconclusive"     # too little data, or look-alikes the data cannot tell apart
    elif verdict:
        outcome = "effects_named"
    elif not well_above and not outside_class:
        outcome = "within_noise"
    else:
        outcome = "unexplained"
    cannot.extend(d.extra["settled_note"] for d in data if "settled_note" in d.extra)
    for old_name, new_name, old_rms, new_rms in swapped:
        runner_note += (f" {old_name} was first chosen while a larger effect dominated the residual; with the other "
                        f"effects in place {new_name} explains the held-out data better ({new_rms:.4g} um against "
                        f"{old_rms:.4g} um), so it replaced {old_name}.")
    explanation = _explain(verdict, candidates, located, rms_before, math.sqrt(null_cv), math.sqrt(cur_cv),
                           noise, within_noise, too_little, runner_note.strip(), fitter, outcome,
                           _drive_unit(model))
    validation = (
        f"each recording was cut into {N_BLOCKS} contiguous time blocks; every model was fitted on the even blocks "
        "and scored on the odd ones, and the other way round (2-fold blocked cross-validation). Models are "
        "simulated over the whole recording from its drive and stress only, so no held-out displacement "
        "enters a fit. Nonlinear parameters (time constants, delay, resonance) are chosen per fold from that "
        "fold's training blocks. rms_before is the base model as given; rms_after is the held-out RMS of the "
        "selected model; the null every effect had to beat is the base with a static recalibration "
        f"(gain, offset, curvature, loop width{', stress gain' if fitter.stress_varies else ''}), held-out RMS "
        f"{math.sqrt(null_cv):.4g} um. Fits and the selection use a Huber loss (squared error up to "
        f"{fitter.delta:.3g} um, linear beyond) so that a few bursts no model in the catalog can follow do not "
        "decide it. An effect is accepted if it cuts the held-out loss by >= "
        f"{1 - MIN_MSE_RATIO:.0%}, gains >= {MIN_LOGLIK_GAIN:g} nats of penalised held-out likelihood "
        "(effective sample count from the residual's correlation time, one nat per parameter) and removes "
        "more than half the noise floor. rms_after is scored on the same held-out blocks that chose the effects, "
        "so it is slightly optimistic: no third set of blocks is kept back for a final, untouched score.")
    ordered = sorted(candidates.values(), key=lambda c: (not c.accepted, not c.testable,
                                                        c.cv_mse if math.isfinite(c.cv_mse) else math.inf))
    return Diagnosis(outcome, verdict, explanation, located, ordered, rms_before, math.sqrt(null_cv),
                     math.sqrt(cur_cv), noise, validation, conclusive, cannot, ext, data, base_pred, null_pred,
                     final_pred, rounds, rounds[0]["n_eff"] if rounds else float("nan"))


def _scored(d: RecData, r: np.ndarray) -> np.ndarray:
    """The residual with the samples before the initial state settles set to zero (not scored)."""
    if d.settled <= 0:
        return r
    out = r.copy()
    out[: d.settled] = 0.0
    return out


def _drive_unit(model: Any) -> str:
    """"A" for a current-driven actuator, "V" for a voltage-driven one (no coil to heat)."""
    return "V" if str(getattr(model, "drive_name", "current_A")).endswith("_V") else "A"


def _slow_gain_ratio(fitter: Fitter, before: tuple[Spec, Spec, Spec], after: tuple[Spec, Spec, Spec]) -> float:
    """Held-out MSE after/before on the slowest 40 % of samples (by drive rate)."""
    slow = fitter.rate_rows <= np.percentile(fitter.rate_rows, 40)
    r0 = fitter.test_residuals(before)[slow]
    r1 = fitter.test_residuals(after)[slow]
    return float(np.mean(r1 * r1) / max(float(np.mean(r0 * r0)), 1e-300))


def _recalibration_hurts(fitter: Fitter, specs: tuple[Spec, Spec, Spec], base_pred: list[np.ndarray]) -> list[str]:
    """Recordings on whose held-out blocks the selected (recalibrated) model does worse than the base."""
    held_out = fitter.test_residuals(specs)
    rows = fitter.row_blocks()                      # per recording: (fold A rows, fold B rows) in held_out
    worse = []
    for d, yb, idx, (ra, rb) in zip(fitter.data, base_pred, rows, fitter.rows_ab):
        base_r = np.concatenate([(d.y - yb)[ra], (d.y - yb)[rb]])
        if float(held_out[idx] @ held_out[idx]) > float(base_r @ base_r):
            worse.append(d.name)
    return worse


def _saturation_reverses(model: Any, fitter: Fitter, params: dict[str, float], res: SearchResult,
                         noise: float) -> str:
    """Why a fitted saturation bend is not saturation ('' when it is one).

    Saturation flattens the material's curve beyond the identified range; it never turns it round.
    Beyond each end of the range, the recalibrated model's own slope at that end plus the fitted
    hinge is integrated out to the farthest drive in the data: if the curve comes back by more than
    ordinary identification error (MODEL_ERROR_FACTOR x the noise floor), it reversed.
    """
    lo, hi = fitter.drive_lo, fitter.drive_hi
    u_min = min(float(d.u.min()) for d in fitter.data)
    u_max = max(float(d.u.max()) for d in fitter.data)
    c = dict(zip(res.names, (float(v) for v in res.coef_all)))
    ramp = np.linspace(lo, hi, 401)
    du = float(ramp[1] - ramp[0])
    there_and_back = np.concatenate([ramp, ramp[::-1]])
    y = model.simulate(there_and_back, there_and_back, np.full(there_and_back.size, fitter.stress_ref),
                       initial_state="relaxed")
    n = ramp.size

    def static_slope(y_end: float, dy: float) -> float:      # the recalibration's map applied to the core
        return dy / du * (c.get("gain", 1.0) + 2.0 * c.get("quadratic", 0.0) * (y_end - fitter.yc_center))

    tolerance = MODEL_ERROR_FACTOR * noise
    out = []
    for side, end, far, slope in (("above", hi, u_max, static_slope(float(y[n - 1]), float(y[n - 1] - y[n - 2]))),
                                  ("below", lo, u_min, static_slope(float(y[-1]), float(y[-2] - y[-1])))):
        if (far - end) * (1 if side == "above" else -1) <= 0:
            continue
        x = np.linspace(0.0, abs(far - end), 200)          # distance beyond the end of the range
        lin = params.get("sat_lin_hi" if side == "above" else "sat_lin_lo", 0.0)
        quad = params.get("sat_quad_hi" if side == "above" else "sat_quad_lo", 0.0)
        along = slope * x if side == "above" else -slope * x      # the model's straight extrapolation
        curve = along + lin * x + quad * x * x
        rising = slope > 0 if side == "above" else slope < 0      # the curve's direction moving away from the range
        turn = float(np.max(curve) - curve[-1]) if rising else float(curve[-1] - np.min(curve))
        if turn > tolerance:
            out.append(f"{side} {end:.3g} the fitted bend turns the curve round: it comes back {turn:.3g} um by "
                       f"the drive of {far:.3g}")
    if not out:
        return ""
    return ("; ".join(out) + ". Saturation flattens a magnetostrictive or piezoelectric curve, it never reverses "
            "it: the drive takes the model outside its class there (a bipolar drive on a model identified on one "
            "polarity, or domain switching). Re-identify on data that cover that drive range")


def _search_all(fitter: Fitter, base: tuple[Spec, Spec, Spec], names: list[str]) -> dict[str, SearchResult]:
    """Search several effects on top of `base`, two at a time (the kernels release the GIL)."""
    from concurrent.futures import ThreadPoolExecutor

    def one(name: str) -> SearchResult:
        eff = CATALOG[name]
        partner = JOINT.get(name)
        if partner is None or getattr(base[2], partner) is None:
            return search(fitter, base, eff.make, eff.grid(fitter), eff.refine)
        # delay and eddy lag trade off against each other: re-search the accepted one's value with the new one
        def make(s: Spec, p: Any) -> Spec:
            old = getattr(s, partner)
            return eff.make(s, p[0]).with_(**{partner: old * p[1]})

        def refine(f: Fitter, p: Any, level: int) -> list:
            out = [(q, p[1]) for q in eff.refine(f, p[0], level)] if eff.refine else []
            return out + [(p[0], min(p[1] * m, 1.5)) for m in geom_refine(1.0, 1.6, level)]

        grid = [(p, k) for p in eff.grid(fitter) for k in (0.3, 0.55, 0.8, 1.0)]
        return search(fitter, base, make, grid, refine)

    workers = min(WORKERS, max(len(names), 1))
    if workers <= 1:
        return {n: one(n) for n in names}
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return dict(zip(names, pool.map(one, names)))


_DECIDERS = {
    frozenset({"time_delay", "rate_dependence"}):
        "a delay's phase lag grows in proportion to frequency while an eddy-current lag's saturates at 90 "
        "degrees: record sine sweeps at several frequencies spanning 1/(2 pi tau) to decide",
    frozenset({"mechanical_dynamics", "rate_dependence"}):
        "a resonance peaks and moves with load mass, a lag does not: drive near the fitted resonance at two loads",
    frozenset({"mechanical_dynamics", "time_delay"}):
        "a resonance peaks and moves with load mass, a delay does not: drive near the fitted resonance at two loads",
    frozenset({"thermal_drift", "creep"}):
        "heating follows the integral of I^2 and recovers at zero current, creep follows the direction of the "
        "last step: record steps up and down with long holds and a zero-current pause",
}


def _decider(a: str, b: str) -> str:
    return _DECIDERS.get(frozenset({a, b}), "an experiment that changes one of them and not the other would decide")


def _runner_up_note(best: Candidate, runner: Candidate) -> str:
    return (f"The runner-up, {runner.effect}, lost: held-out RMS {math.sqrt(runner.cv_mse):.4g} um against "
            f"{math.sqrt(best.cv_mse):.4g} um for {best.effect}"
            + (f" ({best.loglik_gain - runner.loglik_gain:.0f} nats less penalised held-out likelihood)"
               if math.isfinite(runner.loglik_gain) else "") + ".")


def _describe(c: Candidate, unit: str = "A") -> str:
    p = c.params
    if c.effect == "rate_dependence":
        return f"an eddy-current lag of tau = {p['tau_s'] * 1e3:.3g} ms"
    if c.effect == "time_delay":
        return f"a transport delay of {p['delay_s'] * 1e3:.3g} ms"
    if c.effect == "thermal_drift":
        what = "heating" if unit == "A" else "a thermal drift (self-heating or ambient)"
        txt = (f"{what} with a thermal time constant of {p['tau_s']:.3g} s ({p['gain_um_per_A2']:+.3g} um per "
               f"{unit}^2 at equilibrium)")
        if math.isfinite(p.get("fast_gain_um_per_A2", math.nan)):
            txt += f" and a faster part at {p['fast_tau_s']:.3g} s ({p['fast_gain_um_per_A2']:+.3g} um per {unit}^2)"
        return txt
    if c.effect == "creep":
        return (f"creep of {p['gain'] * 100:+.3g} % of each step relaxing over time constants around "
                f"{p['tau_s']:.3g} s (0.1x to 10x)")
    if c.effect == "mechanical_dynamics":
        txt = f"a resonance at {p['f_ref_hz']:.4g} Hz (damping ratio {p['zeta']:.2g})"
        if "f_at_most_compressive_hz" in p:
            txt += f" that moves down to {p['f_at_most_compressive_hz']:.4g} Hz at the most compressive load"
        return txt
    if c.effect == "stress_dependent_play":
        k = p.get("loop_width_change_per_MPa", math.nan)
        if not math.isfinite(k):
            return "play weights (loop width) that change with stress"
        return (f"play weights and a loop width (coercive current) that change with stress: the width grows by "
                f"{-k * 100:.2g} % per MPa of extra compression")
    if c.effect == "saturation":
        return (f"a bend of the material's curve beyond the identified drive range "
                f"{p['drive_lo']:.3g}..{p['drive_hi']:.3g} that the model extrapolates straight through")
    return c.effect


VOLTAGE_PHYSICS = {
    "thermal_drift": "a voltage-driven actuator has no coil current to heat it: a drift that follows the drive "
                     "squared through a thermal time constant is self-heating of the stack (dielectric loss) or "
                     "the ambient temperature; a temperature_C column would tell which",
}


def _residual_words(worst: Located) -> str:
    """What an unexplained residual looks like: where, at which frequencies, what it follows."""
    strong = sorted(((abs(v), k, v) for k, v in worst.conditions.items() if abs(v) >= 0.3), reverse=True)
    names = {"drive_rate": "the drive rate", "drive_amplitude": "the drive amplitude",
             "cumulative_heating": "the cumulative drive squared (time)", "stress": "stress",
             "after_steps": "the time since drive steps"}
    follows = (", ".join(f"{names[k]} (r = {v:+.2f})" for _, k, v in strong[:3]) if strong
               else "none of drive rate, amplitude, stress or elapsed time (|r| < 0.3)")
    return (f"The residual left is {worst.residual_rms_recalibrated_um:.3g} um RMS in {worst.recording} "
            f"({worst.where}); it correlates with {follows}.")


def _explain(verdict: list[str], candidates: dict[str, Candidate], located: list[Located], rms_before: float,
             rms_null: float, rms_after: float, noise: float, within_noise: bool, too_little: bool,
             runner_note: str, fitter: Fitter, outcome: str = "", unit: str = "A") -> str:
    worst = max(located, key=lambda loc: loc.residual_rms_recalibrated_um)
    parts = [f"The base model misses the recordings by {rms_before:.4g} um RMS; a static recalibration "
             f"(gain/offset/curvature/loop width) leaves {rms_null:.4g} um on held-out data, against a noise floor of "
             f"{noise:.3g} um estimated from the data. The largest residual is in {worst.recording}: {worst.where}."]
    if too_little:
        parts.append("There is too little data to tell the effects apart, so no effect is named; see "
                     "cannot_conclude for the experiment that would decide.")
        return " ".join(parts)
    if not verdict:
        if outcome == "within_noise":
            ratio = rms_after / max(noise, 1e-12)
            parts.append("That is within the noise: the model explains the recordings, no effect is named."
                         if ratio <= NOISE_FACTOR else
                         f"That is {ratio:.1f}x the noise floor, the size of ordinary identification error: no "
                         "structured residual is left for an effect to explain, so no effect is named.")
        elif outcome == "inconclusive":
            parts.append("The residual is above the noise but the data cannot decide what it is: see "
                         "cannot_conclude for what could not be tested and the recording that would decide.")
            parts.append(_residual_words(worst))
        else:
            tried = [c for c in candidates.values() if c.testable and math.isfinite(c.cv_mse)]
            tried.sort(key=lambda c: c.cv_mse)
            if tried:
                b = tried[0]
                parts.append(f"No effect in the vocabulary explains the rest: the best, {b.effect}, "
                             f"reaches {math.sqrt(b.cv_mse):.4g} um held-out, short of the margin required. The "
                             "model is outside its class here or the physics is not in the vocabulary "
                             "(re-identify the core on data like these, or model it yourself).")
            parts.append(_residual_words(worst))
        return " ".join(parts)
    named = [candidates[v] for v in verdict]
    parts.append("The recordings show " + "; then ".join(f"{_describe(c, unit)} ({c.effect})" for c in named) + ".")
    parts.append(f"With {'it' if len(named) == 1 else 'them'} the held-out RMS falls to {rms_after:.4g} um "
                 f"({rms_after / max(rms_before, 1e-12):.0%} of before).")
    for c in named:
        physics = VOLTAGE_PHYSICS.get(c.effect, CATALOG[c.effect].physics) if unit == "V" else CATALOG[c.effect].physics
        parts.append(f"{c.effect}: {physics}.")
    if runner_note:
        parts.append(runner_note)
    return " ".join(parts)
