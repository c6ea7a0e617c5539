"""The drive beyond the identified range, where the material's curve bends and the model goes straight on.

Two parts. A hinge: a straight and a quadratic term in how far the drive is beyond each end (zero
inside the range). Wide plays: a loop wider than the identified range can be wider than the
model's, whose plays a loop of that range sweeps. A play whose threshold is beyond half the
identified span is never swept by a loop inside it, so the identification could not set its
weight; where the recordings' loops go beyond, it is fitted. Its term is c (H_r[u] - m), the part a
PI model's play adds once swept, its output starting at the range's middle m: a drive inside the
range never sweeps it, so the term is zero there, and recordings inside the range cannot set it.
"""

from __future__ import annotations

from typing import Any, ClassVar, Mapping

import numpy as np

from ..drive import drive_unit
from ..errors import ModelError
from . import kernels as K
from .base import (BatchSignals, EffectBase, FitData, OwnPlays, PlayBankState, PlayStart, Regressors, SignatureCheck,
                   SignatureFailure, StepSignals, finite, play_weights)

KEYS = ("lo", "hi", "lin_lo", "quad_lo", "lin_hi", "quad_hi")
# how many wide plays a fit may take: none (the hinge alone) or three; held-out blocks choose
WIDE_PLAYS = (0, 3)


def wide_thresholds(fitter: FitData, n: int) -> np.ndarray:
    """Thresholds of n plays that only loops wider than the identified range sweep: half the
    identified span plus k / (n + 1) of half what the recordings reach beyond it (at 0 a loop of the
    range sweeps the play, at 1 only a loop over the whole span, once). None unless they stand a range
    margin apart (a drive within a margin counts as inside the range: closer plays cannot be told apart)."""
    u_min = min(float(d.u.min()) for d in fitter.data)
    u_max = max(float(d.u.max()) for d in fitter.data)
    extra = (u_max - u_min) - fitter.drive_span
    if n == 0 or 0.5 * extra / (n + 1) < fitter.drive_margin:
        return np.zeros(0)
    return 0.5 * fitter.drive_span + 0.5 * extra * np.arange(1, n + 1) / (n + 1)


def swept_plays(u: np.ndarray, thresholds: np.ndarray, middle: float) -> np.ndarray:
    """H_rj[u] - middle over a batch, one column per play, each output starting at `middle`."""
    p0 = np.full(thresholds.size, float(middle))
    return np.asarray(K.play_bank_from(np.ascontiguousarray(u, dtype=float), thresholds, p0) - middle)


def swept_play_sum(u: np.ndarray, thresholds: np.ndarray, coefficients: np.ndarray, middle: float) -> np.ndarray:
    """sum_j c_j (H_rj[u] - middle) over a batch, each play's output starting at `middle`."""
    return np.asarray(swept_plays(u, thresholds, middle) @ coefficients)


class SweptPlays(PlayBankState):
    """Plays stepped in plain floats (a step allocates nothing): sum_j c_j (p_j - middle), each
    output starting at `middle` whatever the drive's start."""

    def __init__(self, thresholds: np.ndarray, coefficients: np.ndarray, middle: float) -> None:
        super().__init__(thresholds, coefficients)
        self.middle = float(middle)

    def reset(self, u: float, start: "PlayStart | None" = None) -> None:
        for j in range(len(self.p)):
            self.p[j] = self.middle

    def advance(self, u: float) -> float:
        acc = 0.0
        for j in range(len(self.p)):
            p = min(max(self.p[j], u - self.th[j]), u + self.th[j])
            self.p[j] = p
            acc += self.c[j] * (p - self.middle)
        return acc

    def peek(self, u: float) -> float:
        acc = 0.0
        for j in range(len(self.p)):
            acc += self.c[j] * (min(max(self.p[j], u - self.th[j]), u + self.th[j]) - self.middle)
        return acc


def untestable_inside(fitter: FitData) -> str:
    """Why saturation cannot be tested on a drive inside the identified range, and the drive that
    would test it: beyond the range, but never beyond the controller's `drive_limits` (docs/cli.md).
    A limit within the range margin of the range's end leaves no room beyond it on that side."""
    lo, hi, margin = fitter.drive_lo, fitter.drive_hi, fitter.drive_margin
    unit = drive_unit(getattr(fitter.model, "drive_name", "current_A"))
    inside = f"the drive stays inside the range the model was identified on ({lo:.3g}..{hi:.3g} {unit})"
    tested = ", so saturation beyond it cannot be tested"
    if fitter.drive_limits is None:
        return inside + tested + "; record with a drive beyond that range to test it"
    low, high = (float(v) for v in fitter.drive_limits)
    room = []
    if low < lo - margin:
        room.append(f"down to {low:.3g} {unit}")
    if high > hi + margin:
        room.append(f"up to {high:.3g} {unit}")
    limits = f"the drive limits ({low:.3g}..{high:.3g} {unit})"
    if not room:
        return (f"{inside}, which already reaches {limits}: saturation beyond them cannot be tested, and does "
                "not matter on a rig held to those limits")
    return (f"{inside}{tested}; record with a drive {' or '.join(room)}, to the end of {limits} and no further, "
            "to test it within them")


class Saturation(EffectBase):
    name: ClassVar[str] = "saturation"
    keys: ClassVar[tuple[str, ...]] = ("saturation",)
    block_keys: ClassVar[Mapping[str, tuple[str, ...]]] = {"saturation": KEYS + ("play_thresholds", "play_coefficients")}
    stage: ClassVar[str] = "sum"
    follows_drive: ClassVar[bool] = True
    position: ClassVar[int] = 50
    inverted: ClassVar[Mapping[str, str]] = {"saturation": "exactly, solved with the core's inverse (from the previous "
                                                           "sample's drive when an eddy lag or delay is inverted after it)"}
    physics: ClassVar[str] = (
        "the drive goes beyond the range the model was identified on, where the material's curve bends "
        "(towards saturation, or steeper first) and its loops widen while the model extrapolates straight on")
    n_params: ClassVar[int] = 2          # the hinge's; each wide play adds one

    def __init__(self, block: Mapping[str, Any]) -> None:
        super().__init__(block)
        self.lo, self.hi, self.lin_lo, self.quad_lo, self.lin_hi, self.quad_hi = \
            (finite(block, k, "saturation") for k in KEYS)
        if self.lo > self.hi:
            raise ModelError(f"extended model: saturation.lo ({self.lo:g}) must not be above saturation.hi "
                             f"({self.hi:g}): they are the ends of the drive range the model was identified on")
        self.thresholds: np.ndarray
        self.coefficients: np.ndarray
        self.thresholds, self.coefficients = play_weights(
            {"thresholds": block.get("play_thresholds", []), "coefficients": block.get("play_coefficients", [])},
            "coefficients", "saturation play")
        self.middle = 0.5 * (self.lo + self.hi)       # where the wide plays start: no drive inside sweeps them

    def term(self, u: float) -> float:
        """Hinge correction beyond the identified drive range, in plain floats (a step allocates nothing)."""
        hi = u - self.hi if u > self.hi else 0.0
        lo = self.lo - u if u < self.lo else 0.0
        return self.lin_hi * hi + self.quad_hi * hi * hi + self.lin_lo * lo + self.quad_lo * lo * lo

    def apply(self, y: np.ndarray, sig: BatchSignals) -> np.ndarray:
        u = np.asarray(sig.drive, dtype=float)
        hi = np.maximum(u - self.hi, 0.0)
        lo = np.maximum(self.lo - u, 0.0)
        y = y + (self.lin_hi * hi + self.quad_hi * hi * hi + self.lin_lo * lo + self.quad_lo * lo * lo)
        if self.thresholds.size:
            y = y + swept_play_sum(sig.u3, self.thresholds, self.coefficients, self.middle)
        return y

    def state(self, dt: float, stress_ref: float, inverse: bool) -> "_SaturationState":
        return _SaturationState(self)

    # ---- diagnosis
    @classmethod
    def testable(cls, fitter: FitData) -> tuple[bool, str]:
        margin = fitter.drive_margin
        n = sum(d.u.size for d in fitter.data)
        above = sum(int(np.sum(d.u > fitter.drive_hi + margin)) for d in fitter.data) / n
        below = sum(int(np.sum(d.u < fitter.drive_lo - margin)) for d in fitter.data) / n
        if below + above < 0.005:
            return False, untestable_inside(fitter)
        return True, ""

    @classmethod
    def grid(cls, fitter: FitData) -> list[int]:
        """How many wide plays: those the recordings' span allows (`wide_thresholds`)."""
        return [n for n in WIDE_PLAYS if n == 0 or wide_thresholds(fitter, n).size]

    @classmethod
    def count_params(cls, fitter: FitData) -> int:
        return cls.n_params + max(cls.grid(fitter))      # the most plays tried: the likelihood's penalty

    @classmethod
    def columns(cls, fitter: FitData, r: Regressors, p: Any) -> None:
        """A side's terms where some recording goes beyond the range there (the same columns for
        every recording, so their rows stack)."""
        u = r.d.u
        margin = fitter.drive_margin
        for side, h, beyond in (("hi", np.maximum(u - fitter.drive_hi, 0.0),
                                 any(float(d.u.max()) > fitter.drive_hi + margin for d in fitter.data)),
                                ("lo", np.maximum(fitter.drive_lo - u, 0.0),
                                 any(float(d.u.min()) < fitter.drive_lo - margin for d in fitter.data))):
            if beyond:
                r.cols += [h, h * h]
                r.names += [f"sat_lin_{side}", f"sat_quad_{side}"]
        wide = wide_thresholds(fitter, p)
        if wide.size:       # one pass of the play bank: each play a column
            plays = swept_plays(r.u3, wide, 0.5 * (fitter.drive_lo + fitter.drive_hi))
            for j in range(wide.size):
                r.cols.append(plays[:, j])
                r.names.append(f"sat_play_{j}")

    @classmethod
    def fitted_params(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, float]:
        out = {"drive_lo": fitter.drive_lo, "drive_hi": fitter.drive_hi}
        out.update({k: v for k, v in coef.items() if k.startswith("sat_")})
        return out

    @classmethod
    def fitted_blocks(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, dict[str, Any]]:
        block: dict[str, Any] = {"lo": fitter.drive_lo, "hi": fitter.drive_hi,
                                 "lin_lo": coef.get("sat_lin_lo", 0.0), "quad_lo": coef.get("sat_quad_lo", 0.0),
                                 "lin_hi": coef.get("sat_lin_hi", 0.0), "quad_hi": coef.get("sat_quad_hi", 0.0)}
        wide = wide_thresholds(fitter, p)
        if wide.size:
            block["play_thresholds"] = [float(v) for v in wide]
            block["play_coefficients"] = [coef[f"sat_play_{j}"] for j in range(wide.size)]
        return {"saturation": block}

    @classmethod
    def signature(cls, check: SignatureCheck) -> SignatureFailure | None:
        """Saturation flattens the material's curve beyond the identified range; it never turns it round.

        Beyond each end of the range, the recalibrated model's own slope at that end plus the fitted
        hinge is integrated out to the farthest drive in the data: if the curve comes back by more than
        ordinary identification error (model_error_factor x the noise floor), it reversed: the model is
        used outside its class there.
        """
        fitter, params, res = check.fitter, check.params, check.result
        lo, hi = fitter.drive_lo, fitter.drive_hi
        u_min = min(float(d.u.min()) for d in fitter.data)
        u_max = max(float(d.u.max()) for d in fitter.data)
        c = dict(zip(res.names, (float(v) for v in res.coef_all)))
        ramp = np.linspace(lo, hi, 401)
        du = float(ramp[1] - ramp[0])
        there_and_back = np.concatenate([ramp, ramp[::-1]])
        y = check.model.simulate(there_and_back, there_and_back, np.full(there_and_back.size, fitter.stress_ref),
                                 initial_state="relaxed")
        n = ramp.size

        def static_slope(y_end: float, dy: float) -> float:      # the recalibration's map applied to the core
            return dy / du * (c.get("gain", 1.0) + 2.0 * c.get("quadratic", 0.0) * (y_end - fitter.yc_center))

        tolerance = check.model_error_factor * check.noise
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
            return None
        return SignatureFailure(
            "; ".join(out) + ". Saturation flattens a magnetostrictive or piezoelectric curve, it never reverses "
            "it: the drive takes the model outside its class there (a bipolar drive on a model identified on one "
            "polarity, or domain switching). Re-identify on data that cover that drive range", outside_class=True)

    @staticmethod
    def describe(params: Mapping[str, float], unit: str) -> str:
        wider = ", and loops wider than the model's where the drive sweeps beyond it" \
            if any(k.startswith("sat_play_") for k in params) else ""
        return (f"a bend of the material's curve beyond the identified drive range "
                f"{params['drive_lo']:.3g}..{params['drive_hi']:.3g} that the model extrapolates straight through"
                f"{wider}")


class _SaturationState(OwnPlays):
    reads_input = True

    def __init__(self, m: Saturation) -> None:
        self.m = m
        self.plays = SweptPlays(m.thresholds, m.coefficients, m.middle) if m.thresholds.size else None

    def reset(self, initial_drive: float) -> None:
        if self.plays is not None:
            self.plays.reset(float(initial_drive))

    def step(self, x: StepSignals) -> None:
        x.y += self.m.term(x.u1)
        if self.plays is not None:
            x.y += self.plays.advance(x.u3)

    def inverse_step(self, x: StepSignals) -> None:
        x.const += self.m.term(x.drive_at)
        if self.plays is not None:
            x.const += self.plays.peek(x.u3_at)

    def commit(self, x: StepSignals) -> None:
        if self.plays is not None:
            self.plays.advance(x.u3)
