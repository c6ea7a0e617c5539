"""The diagnosis in words: each effect as its class describes it, the residual left, the validation."""

from __future__ import annotations

import math
from typing import Any, Sequence

from ..effects import REGISTRY
from .data import N_BLOCKS
from .fitting import Fitter
from .locate import Located, condition_words
from .results import Candidate


def drive_unit(model: Any) -> str:
    """"A" for a current-driven actuator, "V" for a voltage-driven one (no coil to heat)."""
    return "V" if str(getattr(model, "drive_name", "current_A")).endswith("_V") else "A"


def decider(a: str, b: str) -> str:
    """The experiment that tells look-alikes a and b apart (each effect class names its own)."""
    for x, y in ((a, b), (b, a)):
        cls = REGISTRY.get(x)
        if cls is not None and y in cls.deciders:
            return cls.deciders[y]
    return "an experiment that changes one of them and not the other would decide"


def runner_up_words(rounds: Sequence[Any], accepted: Sequence[str], ambiguous: Sequence[tuple[str, str]]) -> str:
    """The first round's runner-up, from its table (effect, held-out RMS, log-likelihood gain; best
    first): it lost, or, where the data fit it and the winner alike (`ambiguous`), it came second
    and is not ruled out. Said of "the first round" once its winner is no longer named. '' when the
    first round accepted nothing or tried one effect."""
    if not rounds or rounds[0].accepted is None or len(rounds[0].table) < 2:
        return ""
    (winner, w_rms, w_gain), (runner, r_rms, r_gain) = rounds[0].table[:2]
    lead = "The runner-up" if winner in accepted else "In the first round, the runner-up"
    if any({winner, runner} == set(pair) for pair in ambiguous):
        return (f"{lead}, {runner}, came second (held-out RMS {r_rms:.4g} um against {w_rms:.4g} um for {winner}): "
                "the data do not rule it out.")
    nats = f" ({w_gain - r_gain:.0f} nats less penalised held-out likelihood)" if math.isfinite(r_gain) else ""
    return f"{lead}, {runner}, lost: held-out RMS {r_rms:.4g} um against {w_rms:.4g} um for {winner}{nats}."


def describe(c: Candidate, unit: str = "A") -> str:
    cls = REGISTRY.get(c.effect)
    return c.effect if cls is None else cls.describe(c.params, unit)


def physics(effect: str, unit: str, has_stress: bool = True) -> str:
    """An effect's physics in the recording's words: for its drive (a voltage drive has no coil) and,
    without a stress column, without a load cell or a stress to speak of."""
    cls = REGISTRY[effect]
    unloaded = None if has_stress else getattr(cls, "physics_without_stress", None)
    return unloaded or ((cls.physics_voltage or cls.physics) if unit == "V" else cls.physics)


def residual_words(worst: Located, unit: str = "A") -> str:
    """What an unexplained residual looks like: where, at which frequencies, what it follows."""
    follows = condition_words(worst.conditions, "V" if unit == "V" else "I", 3)
    follows_txt = (", ".join(follows) if follows
                   else "follows none of drive rate, amplitude, stress or elapsed time (|r| < 0.3)")
    return (f"The residual left is {worst.residual_rms_recalibrated_um:.3g} um RMS in {worst.recording} "
            f"({worst.where}); it {follows_txt}.")


def identification_rms(model: Any) -> tuple[float, float] | None:
    """The least and largest RMS the model left on its own identification recordings (from the
    model file's provenance), or None: the scale of the core's own error on the data it was fitted to."""
    fit = (getattr(model, "provenance", None) or {}).get("fit_rms_um")
    if not isinstance(fit, dict):
        return None
    vals = [float(v) for v in fit.values() if isinstance(v, (int, float)) and math.isfinite(v) and v > 0]
    return (min(vals), max(vals)) if vals else None


def fit_rms_words(fit_rms_um: tuple[float, float]) -> str:
    """The range of what the model missed on its own identification recordings, e.g. "0.149-0.656 um RMS"."""
    lo, hi = fit_rms_um
    return f"{lo:.3g}{'' if hi <= 1.005 * lo else f'-{hi:.3g}'} um RMS"


def explain(verdict: list[str], candidates: dict[str, Candidate], located: list[Located], rms_before: float,
            rms_null: float, rms_after: float, noise: float, too_little: bool, runner_note: str,
            outcome: str, unit: str, noise_factor: float, fit_rms_um: tuple[float, float] | None = None,
            located_after: list[Located] | None = None, model_error_factor: float = 3.0,
            has_stress: bool = True, held_out: bool = True) -> str:
    worst = max(located, key=lambda loc: loc.residual_rms_recalibrated_um)
    where = ("on held-out data" if held_out else
             "over every sample (none could be scored, so nothing was held out)")
    parts = [f"The base model misses the recordings by {rms_before:.4g} um RMS; a static recalibration "
             f"(gain/offset/curvature/loop width) leaves {rms_null:.4g} um {where}, against a noise floor of "
             f"{noise:.3g} um estimated from the data. The largest residual is in {worst.recording}: {worst.where}."]
    if too_little:
        parts.append("There is too little data to tell the effects apart, so no effect is named; see "
                     "cannot_conclude for the experiment that would decide.")
        return " ".join(parts)
    if not verdict:
        if outcome == "within_noise":
            ratio = rms_after / max(noise, 1e-12)
            parts.append("That is within the noise: the model explains the recordings, no effect is named."
                         if ratio <= noise_factor else
                         f"That is {ratio:.1f}x the noise floor, the size of ordinary identification error: no "
                         "structured residual is left for an effect to explain, so no effect is named.")
        elif outcome == "inconclusive":
            parts.append("The residual is above the noise but the data cannot decide what it is: see "
                         "cannot_conclude for what could not be tested and the recording that would decide.")
            parts.append(residual_words(worst, unit))
        else:
            parts += unexplained_words(candidates, rms_after, fit_rms_um)
            parts.append(residual_words(worst, unit))
        return " ".join(parts)
    named = [candidates[v] for v in verdict]
    effects = "; then ".join(f"{describe(c, unit)} ({c.effect})" for c in named)
    if outcome == "inconclusive":     # look-alikes the recordings cannot tell apart (cannot_conclude says which)
        parts.append(f"The recordings are fitted best with {effects}, but cannot tell it from a look-alike: see "
                     "cannot_conclude for the recording that would decide.")
    else:
        parts.append(f"The recordings show {effects}.")
    parts.append(f"With {'it' if len(named) == 1 else 'them'} the held-out RMS falls to {rms_after:.4g} um "
                 f"({rms_after / max(rms_before, 1e-12):.0%} of before).")
    for c in named:
        parts.append(f"{c.effect}: {physics(c.effect, unit, has_stress)}.")
    if located_after and rms_after > model_error_factor * noise:
        parts.append(left_words(located_after, rms_after, noise, fit_rms_um))
    if runner_note:
        parts.append(runner_note)
    return " ".join(parts)


def unexplained_words(candidates: dict[str, Candidate], rms_after: float,
                      fit_rms_um: tuple[float, float] | None) -> list[str]:
    """Nothing named above the noise: the best candidate's figure, the model's own identification
    error for scale, and what the rest can be."""
    parts = []
    tried = sorted((c for c in candidates.values() if c.testable and math.isfinite(c.cv_mse)), key=lambda c: c.cv_mse)
    if tried:
        best = tried[0]
        evidence = f" with {best.loglik_gain:.3g} nats of evidence" if math.isfinite(best.loglik_gain) else ""
        parts.append(f"No effect in the vocabulary explains the rest: the best, {best.effect}, reaches "
                     f"{math.sqrt(best.cv_mse):.4g} um held-out{evidence}, short of the margin required.")
    if fit_rms_um is not None:
        parts.append(f"For scale, the model missed its own identification recordings by "
                     f"{fit_rms_words(fit_rms_um)}; the held-out residual here is "
                     f"{rms_after / fit_rms_um[1]:.1f}x the largest of those.")
    parts.append("What is left is the core's error on a drive unlike its identification data (steps, minor "
                 "loops, other frequencies), the limit of its class (behaviour its operators cannot represent, "
                 "such as these minor loops or a drive range it was not made for), or physics not in the "
                 "vocabulary. Identifying the core again with a second recording like these among its data "
                 "(gma-ffc identify) and diagnosing these with it removes the first; what stays is one of "
                 "the other two, which these recordings cannot tell apart.")
    return parts


def left_words(located_after: list[Located], rms_after: float, noise: float,
               fit_rms_um: tuple[float, float] | None) -> str:
    """What the named effects leave when it is well above the noise, and where it sits, so a named
    effect is not read as the whole story; set against what the model missed on its own
    identification recordings when its file records it (below that, it may be the core's error)."""
    worst = max(located_after, key=lambda loc: loc.residual_rms_um)
    left = f"{rms_after:.3g} um held-out, {rms_after / max(noise, 1e-12):.1f}x the noise floor"
    where = f"It is largest in {worst.recording}, {worst.where}."
    if fit_rms_um is not None:
        fit = fit_rms_words(fit_rms_um)
        if rms_after <= fit_rms_um[1]:
            return (f"What is left, {left}, is within what the model missed on its own identification recordings "
                    f"({fit}), so it may be the core's own error rather than missing physics. {where}")
        return (f"Not all of it is explained: what is left, {left}, is more than the model missed on its own "
                f"identification recordings ({fit}). {where} That is more of the named effect than its law "
                "captures, or physics not in the vocabulary, or the core's error on a drive unlike its "
                "identification data: these recordings do not tell them apart.")
    return (f"Not all of it may be explained: what is left is {left}. {where} That is the core's own error, more "
            "of the named effect than its law captures, or physics not in the vocabulary: these recordings do "
            "not tell them apart.")


def _zero_words(fitter: Fitter) -> str:
    """What the fits allow the displacement sensor's zero (nothing to say for one recording without jumps)."""
    parts = []
    if len(fitter.data) > 1:
        parts.append("each recording has its own displacement zero (a sensor is often zeroed again between runs), "
                     "so only what changes within a recording can show an effect")
    if fitter.sensor_jumps:
        parts.append(f"the zero may also step where the sensor's did ({len(fitter.sensor_jumps)} step(s), "
                     "see located)")
    return (" In every fit, the null's included, " + "; ".join(parts) + ".") if parts else ""


def _reads_stress(fitter: Fitter) -> bool:
    """Does the model read a stress (an SDPI)? A stress-independent one, as for a voltage-driven piezo
    without a stress column, runs from the drive alone, and the words say so."""
    return getattr(fitter.model, "stress_range_MPa", None) is not None


def validation_words(fitter: Fitter, null_cv: float, min_mse_ratio: float, min_loglik_gain: float,
                     held_out: bool = True) -> str:
    """How every figure of the diagnosis was validated."""
    if not held_out:
        return ("nothing was validated: no sample of any recording could be scored, since everywhere the "
                "model's output still depends, by more than the noise floor, on the hysteresis state the "
                "recording starts in. rms_before, rms_recalibrated and rms_after are the models' miss over "
                f"every sample (the recalibrated base {math.sqrt(null_cv):.4g} um), not held-out figures, and "
                "no effect could be accepted.")
    return (
        f"each recording was cut into {N_BLOCKS} contiguous time blocks; every model was fitted on the even blocks "
        "and scored on the odd ones, and the other way round (2-fold blocked cross-validation). Models are "
        f"simulated over the whole recording from its drive{' and stress' if _reads_stress(fitter) else ''} "
        "only, so no held-out displacement "
        "enters a fit. Nonlinear parameters (time constants, delay, resonance) are chosen per fold from that "
        "fold's training blocks. rms_before is the base model as given; rms_after is the held-out RMS of the "
        "selected model; the null every effect had to beat is the base with a static recalibration "
        f"(gain, offset, curvature, loop width{', stress gain' if fitter.stress_varies else ''}), held-out RMS "
        f"{math.sqrt(null_cv):.4g} um.{_zero_words(fitter)} Fits and the selection use a Huber loss (squared "
        f"error up to {fitter.delta:.3g} um, linear beyond) so that a few bursts no model in the catalog can "
        "follow do not decide it. An effect is accepted if it cuts the held-out loss by >= "
        f"{1 - min_mse_ratio:.0%}, gains >= {min_loglik_gain:g} nats of penalised held-out likelihood "
        "(effective sample count from the residual's correlation time, one nat per parameter) and removes "
        "more than half the noise floor. rms_after is scored on the same held-out blocks that chose the effects, "
        "so it is slightly optimistic: no third set of blocks is kept back for a final, untouched score.")
