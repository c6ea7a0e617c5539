"""The drive beyond the identified range, where the material's curve bends and the model goes straight on."""

from __future__ import annotations

from typing import Any, ClassVar, Mapping

import numpy as np

from .base import (BatchSignals, EffectBase, FitData, Regressors, SignatureCheck, SignatureFailure, StepSignals,
                   finite)

KEYS = ("lo", "hi", "lin_lo", "quad_lo", "lin_hi", "quad_hi")


class Saturation(EffectBase):
    name: ClassVar[str] = "saturation"
    keys: ClassVar[tuple[str, ...]] = ("saturation",)
    stage: ClassVar[str] = "sum"
    follows_drive: ClassVar[bool] = True
    position: ClassVar[int] = 50
    inverted: ClassVar[Mapping[str, str]] = {"saturation": "exactly, solved with the core's inverse (from the previous "
                                                           "sample's drive when an eddy lag or delay is inverted after it)"}
    physics: ClassVar[str] = (
        "the drive goes beyond the range the model was identified on, where the material's curve bends "
        "(towards saturation, or steeper first) while the model extrapolates straight on")
    n_params: ClassVar[int] = 2

    def __init__(self, block: Mapping[str, Any]) -> None:
        super().__init__(block)
        self.lo, self.hi, self.lin_lo, self.quad_lo, self.lin_hi, self.quad_hi = \
            (finite(block, k, "saturation") for k in KEYS)

    def term(self, u: float) -> float:
        """Hinge correction beyond the identified drive range, in plain floats (a step allocates nothing)."""
        hi = u - self.hi if u > self.hi else 0.0
        lo = self.lo - u if u < self.lo else 0.0
        return self.lin_hi * hi + self.quad_hi * hi * hi + self.lin_lo * lo + self.quad_lo * lo * lo

    def apply(self, y: np.ndarray, sig: BatchSignals) -> np.ndarray:
        u = np.asarray(sig.drive, dtype=float)
        hi = np.maximum(u - self.hi, 0.0)
        lo = np.maximum(self.lo - u, 0.0)
        return y + (self.lin_hi * hi + self.quad_hi * hi * hi + self.lin_lo * lo + self.quad_lo * lo * lo)

    def state(self, dt: float, stress_ref: float, inverse: bool) -> "_SaturationState":
        return _SaturationState(self)

    # ---- diagnosis
    @classmethod
    def testable(cls, fitter: FitData) -> tuple[bool, str]:
        margin = 0.02 * fitter.drive_span
        n = sum(d.u.size for d in fitter.data)
        above = sum(int(np.sum(d.u > fitter.drive_hi + margin)) for d in fitter.data) / n
        below = sum(int(np.sum(d.u < fitter.drive_lo - margin)) for d in fitter.data) / n
        if below + above < 0.005:
            return False, ("the drive stays inside the range the model was identified on "
                           f"({fitter.drive_lo:.3g}..{fitter.drive_hi:.3g}), so saturation beyond it cannot be "
                           "tested; record with a drive beyond that range to test it")
        return True, ""

    @classmethod
    def grid(cls, fitter: FitData) -> list[bool]:
        return [True]

    @classmethod
    def columns(cls, fitter: FitData, r: Regressors, p: Any) -> None:
        """A side's terms where some recording goes beyond the range there (the same columns for
        every recording, so their rows stack)."""
        u = r.d.u
        margin = 0.02 * fitter.drive_span
        for side, h, beyond in (("hi", np.maximum(u - fitter.drive_hi, 0.0),
                                 any(float(d.u.max()) > fitter.drive_hi + margin for d in fitter.data)),
                                ("lo", np.maximum(fitter.drive_lo - u, 0.0),
                                 any(float(d.u.min()) < fitter.drive_lo - margin for d in fitter.data))):
            if beyond:
                r.cols += [h, h * h]
                r.names += [f"sat_lin_{side}", f"sat_quad_{side}"]

    @classmethod
    def fitted_params(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, float]:
        out = {"drive_lo": fitter.drive_lo, "drive_hi": fitter.drive_hi}
        out.update({k: v for k, v in coef.items() if k.startswith("sat_")})
        return out

    @classmethod
    def fitted_blocks(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, dict[str, Any]]:
        return {"saturation": {"lo": fitter.drive_lo, "hi": fitter.drive_hi,
                               "lin_lo": coef.get("sat_lin_lo", 0.0), "quad_lo": coef.get("sat_quad_lo", 0.0),
                               "lin_hi": coef.get("sat_lin_hi", 0.0), "quad_hi": coef.get("sat_quad_hi", 0.0)}}

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
        return (f"a bend of the material's curve beyond the identified drive range "
                f"{params['drive_lo']:.3g}..{params['drive_hi']:.3g} that the model extrapolates straight through")


class _SaturationState:
    reads_input = True

    def __init__(self, m: Saturation) -> None:
        self.m = m

    def reset(self, initial_drive: float) -> None:
        pass

    def step(self, x: StepSignals) -> None:
        x.y += self.m.term(x.u1)

    def inverse_step(self, x: StepSignals) -> None:
        x.const += self.m.term(x.drive_at)

    def commit(self, x: StepSignals) -> None:
        pass
