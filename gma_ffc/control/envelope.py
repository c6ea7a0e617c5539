"""The model's envelope: the drive and stress ranges it was identified on, and the policy beyond each.

This is the one home of three policies:

* the drive range (`DriveRange`): the law flags a drive outside it, and clamps it under
  `limits.beyond_model: clamp`;
* the stress range (`StressRange`): the model's kernel clamps the stress into it; the loop
  flags a stress outside it once per tick, and `stress.out_of_range` says whether that is a fault;
* the reference stress (`REFERENCE_STRESS_MPA`): the stress used where a model states none.

What the runner does on each flag (go on, or ramp to the safe current and stop) is a row of the
fault table (`safety.FAULT_ACTIONS`, chosen by the same config keys), not code here.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..protocols import Model

# The paper's rod under its preload alone (seed paper, section 4). Used only where a model states
# no stress: an MPI ignores the value, so any stress serves, and this one is physical.
REFERENCE_STRESS_MPA = -11.3

BEYOND_POLICIES = ("warn", "clamp", "fault")      # limits.beyond_model
STRESS_POLICIES = ("clamp", "fault")              # stress.out_of_range

# The identified extremes are where the fit's data ended: a command that rounds a hair past them
# is not a drive the model never saw. 1 % of the range is well above rounding, well below a step.
DRIVE_PAD = 0.01

_BEYOND_VERB = {"warn": "commanded anyway", "clamp": "clamped to the range's edge", "fault": "fault"}
_STRESS_VERB = {"clamp": "clamped to the model's range", "fault": "fault (stress.out_of_range: fault)"}


class DriveRange:
    """[lo, hi] of the drive, and whether the law clamps a drive beyond it."""

    __slots__ = ("lo", "hi", "policy", "clamp", "identified")

    def __init__(self, lo: float = -math.inf, hi: float = math.inf, policy: str = "warn",
                 identified: tuple[float, float] | None = None) -> None:
        if policy not in BEYOND_POLICIES:
            raise ValueError(f"policy must be one of {BEYOND_POLICIES}, got {policy!r}")
        self.lo, self.hi = float(lo), float(hi)
        self.policy = policy
        self.clamp = policy == "clamp"
        self.identified = identified      # the model file's drive_range, when [lo, hi] is it widened

    @classmethod
    def of_model(cls, model: Model, policy: str) -> DriveRange:
        """The model's identified drive range, widened by `DRIVE_PAD` of its span at each end."""
        lo, hi = model.drive_range
        pad = DRIVE_PAD * (hi - lo) if math.isfinite(hi - lo) else 0.0
        return cls(float(lo) - pad, float(hi) + pad, policy, (float(lo), float(hi)) if pad else None)

    def message(self, drive: float, current_lo: float = -math.inf, current_hi: float = math.inf) -> str:
        """The fault message for a drive beyond the range (the fault path only: it allocates): the
        range checked, by its name, and what was written once the current limits
        [`current_lo`, `current_hi`] (limits.current_min_A, current_max_A) had their say."""
        checked = f"[{self.lo:.5g}, {self.hi:.5g}]"
        if self.identified is not None:
            checked += (f" (the model's identified drive_range [{self.identified[0]:.5g}, {self.identified[1]:.5g}] "
                        f"widened by {100 * DRIVE_PAD:g} % of its span at each end)")
        else:
            checked += " (the drive range the model was identified on)"
        return (f"the inverse asks for {drive:.4g}, outside {checked}: "
                f"{self._written(drive, current_lo, current_hi)} (limits.beyond_model: {self.policy})")

    def _written(self, drive: float, current_lo: float, current_hi: float) -> str:
        """What became of the drive: the policy's word, then the current limit that clipped it, if one did."""
        if self.policy == "fault":
            return "fault"
        sent = min(max(drive, self.lo), self.hi) if self.clamp else drive
        verb = _BEYOND_VERB[self.policy] + (f" {sent:.4g}" if self.clamp else "")
        if sent < current_lo:
            return f"clipped to {current_lo:g} A by limits.current_min_A" + (f" ({verb} first)" if self.clamp else "")
        if sent > current_hi:
            return f"clipped to {current_hi:g} A by limits.current_max_A" + (f" ({verb} first)" if self.clamp else "")
        return verb


class StressRange:
    """[lo, hi] of the stress the model was identified on; unbounded for a stress-free MPI."""

    __slots__ = ("lo", "hi", "policy")

    def __init__(self, lo: float = -math.inf, hi: float = math.inf, policy: str = "clamp") -> None:
        if policy not in STRESS_POLICIES:
            raise ValueError(f"policy must be one of {STRESS_POLICIES}, got {policy!r}")
        self.lo, self.hi = float(lo), float(hi)
        self.policy = policy

    @classmethod
    def of_model(cls, model: Model, policy: str) -> StressRange:
        rng = model.stress_range_MPa
        return cls(*(rng if rng is not None else (-math.inf, math.inf)), policy=policy)

    def operating_point(self) -> float:
        """A stress inside the range: its middle, or the reference stress where it is unbounded."""
        if math.isfinite(self.lo) and math.isfinite(self.hi):
            return 0.5 * (self.lo + self.hi)
        return REFERENCE_STRESS_MPA

    def message(self, stress: float) -> str:
        return (f"stress {stress:.2f} MPa outside the model's range [{self.lo:.2f}, {self.hi:.2f}] MPa: "
                f"{_STRESS_VERB[self.policy]}{self._sign_advice(stress)}")

    def _sign_advice(self, stress: float) -> str:
        """The model identified with compression positive (its range on the other side of zero, the
        stress negated inside it): every tick ran clamped to the wrong end, and the message said only
        "outside the range". identify notes a positive stress_MPa; a model made despite it lands here."""
        if self.lo > 0.0 and self.lo <= -stress <= self.hi:      # a range of tension, the compression inside it
            return (f"; the stress negated ({-stress:.2f} MPa) is inside it: the model's recordings had "
                    "compression positive, where gma-ffc's are negative; negate their stress_MPa and identify again")
        return ""
