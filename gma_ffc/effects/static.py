"""The static recalibration of the core: gain, offset, curvature, stress gain and loop-width plays.

Always present (it is the null model every effect must beat, and the identity when nothing was
fitted), never a candidate. In the inverse it is the hinge of the output side: the sum-stage
terms of the other effects, linear in the core output, are folded into its quadratic and solved
in closed form.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Mapping

import numpy as np

from ..errors import ModelError
from ..model import PARAMETER_BOUND
from . import kernels as K
from .base import (BatchSignals, EffectBase, FitData, OwnPlays, PlayBankState, PlayStart, Regressors, StepSignals,
                   block_of, first_play_outputs, is_number, play_sum, play_weights)

STATIC_DEFAULTS = {"offset_um": 0.0, "gain": 1.0, "stress_gain_per_MPa": 0.0,
                   "quadratic_per_um": 0.0, "center_um": 0.0, "stress_ref_MPa": 0.0}


class StaticMap(EffectBase):
    name: ClassVar[str] = "static_recalibration"
    keys: ClassVar[tuple[str, ...]] = ("static", "play_correction")
    block_keys: ClassVar[Mapping[str, tuple[str, ...]]] = {
        "static": ("offset_um", "gain", "stress_gain_per_MPa", "quadratic_per_um", "center_um", "stress_ref_MPa"),
        "play_correction": ("thresholds", "coefficients")}
    stage: ClassVar[str] = "sum"
    position: ClassVar[int] = 30
    inverted: ClassVar[Mapping[str, str]] = {"static": "closed form (quadratic root)",
                                             "play_correction": "exactly: solved together with the core's inverse for "
                                                                "each sample's core input"}
    physics: ClassVar[str] = "gain, offset, curvature, stress gain and loop width of the core, recalibrated"
    candidate: ClassVar[bool] = False
    n_params: ClassVar[int] = 0

    def __init__(self, static: Mapping[str, float] | None = None,
                 play_correction: Mapping[str, Any] | None = None) -> None:
        self.static = dict(STATIC_DEFAULTS)
        self.static.update(static or {})
        for key, v in self.static.items():
            if not is_number(v):
                raise ModelError(f"extended model: static.{key} must be a finite number within "
                                 f"+-{PARAMETER_BOUND:g}, got {v!r}")
        if abs(self.static["gain"]) < 1e-9:
            raise ModelError("extended model: static.gain must not be zero")
        self.play_correction = None if play_correction is None else dict(play_correction)
        self.thresholds: np.ndarray
        self.coefficients: np.ndarray
        self.thresholds, self.coefficients = (np.zeros(0), np.zeros(0)) if play_correction is None else \
            play_weights(play_correction, "coefficients", "play_correction")

    @property
    def stress_ref(self) -> float:
        return float(self.static["stress_ref_MPa"])

    @classmethod
    def from_blocks(cls, blocks: Mapping[str, Any], base: Any) -> "StaticMap":
        return cls(block_of(blocks, "static"), block_of(blocks, "play_correction"))

    def to_blocks(self) -> dict[str, dict[str, Any]]:
        out: dict[str, dict[str, Any]] = {"static": dict(self.static)}
        if self.play_correction is not None:
            out["play_correction"] = dict(self.play_correction)
        return out

    def apply(self, y: np.ndarray, sig: BatchSignals) -> np.ndarray:
        st = self.static
        yc = sig.yc
        out = (st["offset_um"] + (st["gain"] + st["stress_gain_per_MPa"] * sig.ds) * yc
               + st["quadratic_per_um"] * (yc - st["center_um"]) ** 2)
        if self.thresholds.size:
            out = out + play_sum(sig, self.thresholds, self.coefficients)
        return np.asarray(out)

    def state(self, dt: float, stress_ref: float, inverse: bool) -> "_StaticState":
        return _StaticState(self)

    # ---- diagnosis: the null model's columns, always first
    @classmethod
    def grid(cls, fitter: FitData) -> list[Any]:
        return []

    @classmethod
    def columns(cls, fitter: FitData, r: Regressors, p: Any) -> None:
        yc, u3 = r.yc, r.u3
        off: frozenset[str] = getattr(fitter, "static_off", frozenset())   # terms left out where they do not carry
        r.cols += [yc]
        r.names += ["gain"]
        if "quadratic" not in off:
            r.cols.append((yc - fitter.yc_center) ** 2)
            r.names.append("quadratic")
        r.cols.append(np.ones_like(yc))
        r.names.append("offset")
        if fitter.stress_varies and "stress_gain" not in off:
            r.cols.append((fitter.stress(r.d, r.spec) - fitter.stress_ref) * yc)   # the stress the model sees
            r.names.append("stress_gain")
        # the plays start from the history the core's run starts from (as every run of the model does)
        start = PlayStart.of_core(fitter.model, float(u3[0]), getattr(r.d.start, "play_state", None))
        p0 = first_play_outputs(start, fitter.play_thresholds, float(u3[0]))
        plays = r.shared["plays"] = K.play_bank_from(u3, fitter.play_thresholds, p0)
        for j in range(fitter.play_thresholds.size):
            r.cols.append(plays[:, j] - u3)
            r.names.append(f"play_{j}")

    @classmethod
    def fitted_params(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, float]:
        return {}

    @classmethod
    def fitted_blocks(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, dict[str, Any]]:
        c = coef
        return {"static": {"offset_um": c["offset"], "gain": c["gain"],
                           "stress_gain_per_MPa": c.get("stress_gain", 0.0),
                           "quadratic_per_um": c.get("quadratic", 0.0), "center_um": fitter.yc_center,
                           "stress_ref_MPa": fitter.stress_ref},
                "play_correction": {"thresholds": [float(v) for v in fitter.play_thresholds],
                                    "coefficients": [c[f"play_{j}"] for j in range(fitter.play_thresholds.size)]}}

    @staticmethod
    def describe(params: Mapping[str, float], unit: str) -> str:
        return "a static recalibration"


class _StaticState(OwnPlays):
    def __init__(self, m: StaticMap) -> None:
        st = m.static
        self.offset, self.gain, self.sgain = st["offset_um"], st["gain"], st["stress_gain_per_MPa"]
        self.q, self.c0 = st["quadratic_per_um"], st["center_um"]
        self.plays = PlayBankState(m.thresholds, m.coefficients) if m.thresholds.size else None
        self.reads_input = self.plays is not None

    def reset(self, initial_drive: float) -> None:
        if self.plays is not None:
            self.plays.reset(float(initial_drive))

    def step(self, x: StepSignals) -> None:
        yc = x.yc
        d = yc - self.c0
        x.y = self.offset + (self.gain + self.sgain * x.ds) * yc + self.q * d * d
        if self.plays is not None:
            x.y += self.plays.advance(x.u3)

    def inverse_step(self, x: StepSignals) -> None:
        if self.plays is not None:
            x.const += self.plays.peek(x.u3_at)

    def solve(self, x: StepSignals) -> float:
        """The core output for which static map + the other sum terms (x.const + x.lin yc) = x.target."""
        q, c0 = self.q, self.c0
        lin = self.gain + self.sgain * x.ds - 2.0 * q * c0 + x.lin
        const = q * c0 * c0 + self.offset + x.const - x.target
        return quadratic_root(q, lin, const)

    def commit(self, x: StepSignals) -> None:
        if self.plays is not None:
            self.plays.advance(x.u3)


def quadratic_root(q: float, b: float, c: float) -> float:
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
