"""The control law of one tick, alone: ros2_control's controller `update`, without the loop.

Reference (the lead included) plus the learned correction, through the model's analytic inverse,
with the model's drive range applied by policy. No clock, no driver, no I/O, no allocation: the
loop runner (`controller.Controller`) owns time, the hardware, limits, faults and telemetry, and
calls `update` once per tick. Tests run it alone against the batch inverse.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..protocols import InverseStepper
    from .learning import RepetitiveLearner
    from .reference import Reference

BEYOND_POLICIES = ("warn", "clamp", "fault")


class FeedforwardController:
    """`update(t, stress) -> drive` for the inverse-model feedforward (learning optional).

    After each update: `beyond` says whether the inverse asked for a drive outside the model's
    identified range, `raw` is that request before the policy, `correction` what the learner
    added. With policy "clamp" the returned drive is held inside the range; with "warn" and
    "fault" it is returned as asked and the runner decides (a fault stops the run).
    """

    __slots__ = ("reference", "stepper", "learner", "lo", "hi", "policy", "beyond", "raw", "correction")

    def __init__(self, reference: Reference, stepper: InverseStepper, learner: RepetitiveLearner | None = None,
                 drive_range: tuple[float, float] = (-math.inf, math.inf), policy: str = "warn") -> None:
        if policy not in BEYOND_POLICIES:
            raise ValueError(f"policy must be one of {BEYOND_POLICIES}, got {policy!r}")
        self.reference = reference
        self.stepper = stepper
        self.learner = learner
        self.lo, self.hi = float(drive_range[0]), float(drive_range[1])
        self.policy = policy
        self.beyond = False
        self.raw = 0.0
        self.correction = 0.0

    def update(self, t: float, stress: float) -> float:
        ref = self.reference.value(t)
        if self.learner is not None:                   # learning feedforward: the inverse follows r + c
            self.correction = self.learner.correction(t + self.reference.lead_s)
            ref += self.correction
        u = self.stepper.step(ref, stress)
        self.raw = u
        self.beyond = u < self.lo or u > self.hi
        if self.beyond and self.policy == "clamp":
            u = self.lo if u < self.lo else self.hi
        return u
