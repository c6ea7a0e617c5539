"""The control law: ros2_control's *controller*, run once per tick by the manager.

Reference (the lead included) plus the learned correction, through the model's analytic inverse,
with the model's drive range applied by policy (`envelope.DriveRange`). No clock, no driver, no
I/O, no allocation in a tick: the runner (`manager.ControllerManager`) owns time, the hardware,
limits, faults and telemetry, and calls `update` once per tick. Tests run it alone against the
batch inverse.

Its lifecycle follows a ros2_control controller's:

* construct = configure: the reference, the inverse stepper, the learner and the drive range,
  all built from one model (`builder`);
* `activate(drive)`: the inverse starts from the shared default start at that drive (the safe
  current), at the start of each run;
* `resume(safe, coil_path)`: activation after a fault and a reconnect. The inverse's memory carries
  on through the currents the coil carried meanwhile (0 A while the output was off);
* `take_over(previous, drive)`: activation on a reload. The new inverse continues the old one's
  hysteresis memory at the command the amplifier holds, so the command and the tracking go on
  without a bump;
* `deactivate(t, why)`: the output is no longer the law's (a fault wrote the safe current, or
  the run ended); learning freezes on a fault;
* `update(t, stress) -> drive` each tick while active, then `observe(...)` with the tick's
  outcome: the one place the learner hears whether the command was the law's own.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ..model import InverseStepper as SDPIInverseStepper
from ..model import SDPIModel
from .envelope import DriveRange
from .learning import RAMPING
from .safety import MODEL_RANGE, RAMP

if TYPE_CHECKING:
    from ..protocols import InverseStepper, Model
    from .learning import RepetitiveLearner
    from .reference import Reference

# Why a tick teaches the learner nothing (constants: a tick allocates no message).
STOPPING = "stopping"
NO_STRESS = "no valid stress yet"


class FeedforwardController:
    """`update(t, stress) -> drive` for the inverse-model feedforward (learning optional).

    After each update: `beyond` says whether the inverse asked for a drive outside the model's
    identified range, `raw` is that request before the policy, `correction` what the learner
    added, `updated_t` the tick's time (so `observe` knows the tick's command was asked by the law). With policy "clamp" the returned drive is held inside the range; with "warn" and
    "fault" it is returned as asked and the runner decides (a fault stops the run).
    """

    __slots__ = ("model", "reference", "stepper", "learner", "drive", "lo", "hi", "clamp", "beyond", "raw",
                 "correction", "active", "initial_state", "updated_t")

    def __init__(self, model: Model, reference: Reference, stepper: InverseStepper,
                 learner: RepetitiveLearner | None = None, drive: DriveRange | None = None) -> None:
        self.model = model
        self.reference = reference
        self.stepper = stepper
        self.learner = learner
        self.drive = drive if drive is not None else DriveRange()
        self.lo, self.hi, self.clamp = self.drive.lo, self.drive.hi, self.drive.clamp   # read each tick
        self.beyond = False
        self.raw = 0.0
        self.correction = 0.0
        self.active = False
        self.initial_state = ""
        self.updated_t = math.nan

    # ---- lifecycle ---------------------------------------------------------------------------
    def activate(self, drive_A: float) -> str:
        """Start the inverse from the shared default start at `drive_A`; returns how (for the status)."""
        self.initial_state = start_stepper(self.stepper, self.model, drive_A)
        self.active = True
        return self.initial_state

    def take_over(self, previous: FeedforwardController, drive_A: float) -> None:
        """Activate in place of `previous` (a reload), continuing its hysteresis memory at the
        command `drive_A` the amplifier holds; a stepper without play state starts relaxed there.
        A `previous` that was not driving (between runs) has no memory worth keeping: the
        default start, as `activate`."""
        if not previous.active:
            self.activate(drive_A)
            return
        plays = carried_play_state(previous.model, previous.stepper, self.model)
        if plays is not None and isinstance(self.stepper, SDPIInverseStepper):
            self.stepper.reset(drive_A, plays)
            self.initial_state = f"continued from the previous model's state at {drive_A:.4g} (reload)"
        else:
            self.stepper.reset(drive_A)
            self.initial_state = f"relaxed at the command {drive_A:.4g} (reload)"
        self.active = True

    def resume(self, safe_A: float, coil_path_A: tuple[float, ...] | None) -> None:
        """Activate again at the safe current `safe_A` after a fault and a reconnect. The inverse's
        hysteresis memory carries on through `coil_path_A`, the currents the coil carried since the
        law's last command (the safe current, and 0 A while the output was off). None, when the
        safe write did not get through and the coil's path is not known: the default start, as
        `activate`. A stepper without play state starts relaxed at the safe current."""
        plays = None if coil_path_A is None else carried_play_state(self.model, self.stepper, self.model)
        if plays is None or coil_path_A is None or not isinstance(self.model, SDPIModel):
            self.activate(safe_A)
            return
        offset, r = self.model.input_offset, self.model.play_thresholds
        for x in coil_path_A + (safe_A,):          # each play follows the coil: p <- clip(p, x - r, x + r)
            np.clip(plays, x - offset - r, x - offset + r, out=plays)
        self.stepper.reset(safe_A, plays)          # type: ignore[call-arg]  # an SDPI stepper
        path = " -> ".join(f"{x:.4g}" for x in coil_path_A + (safe_A,))
        self.initial_state = f"continued through the coil's currents since the fault ({path} A; reconnect)"
        self.active = True

    def deactivate(self, t: float, why: str, freeze_learning: bool = True) -> None:
        """The output is no longer this law's: learning (if any) freezes for the period."""
        self.active = False
        if freeze_learning and self.learner is not None:
            self.learner.freeze(t, why)

    # ---- the tick ----------------------------------------------------------------------------
    def update(self, t: float, stress: float) -> float:
        ref = self.reference.value(t)
        if self.learner is not None:                   # learning feedforward: the inverse follows r + c
            self.correction = self.learner.correction(t + self.reference.lead_s)
            ref += self.correction
        u = self.stepper.step(ref, stress)
        self.raw = u
        self.updated_t = t
        self.beyond = u < self.lo or u > self.hi
        if self.beyond and self.clamp:
            u = self.lo if u < self.lo else self.hi
        return u

    def observe(self, t: float, reference_um: float, displacement_um: float, stress: float,
                limited_by: str, command_A: float) -> None:
        """The tick's outcome, after the write of `command_A`. The learner learns from every tick
        whose command the law asked for (`update` ran at `t`). Where a limit cut it, the learner
        hears which and in which direction, so that phase holds (anti-windup) while the rest of
        the period learns: `limited_by` names the runner's limit (`safety.CURRENT_MIN`,
        `CURRENT_MAX`, `SLEW`, `RAMP`); a cut it does not name is the law's own clamp to the
        model's range (`safety.MODEL_RANGE`). A RAMP (to or from the safe current) freezes the
        period, and a tick whose command the runner chose (stopping, no valid stress yet)
        teaches nothing."""
        learner = self.learner
        if learner is None:
            return
        if stress != stress:
            learner.observe(t, reference_um, displacement_um, stress, False, NO_STRESS)
        elif self.updated_t != t:                      # the runner's safe current, not the law's
            learner.observe(t, reference_um, displacement_um, stress, False, STOPPING)
        else:
            if command_A != self.raw:
                learner.limited(t, limited_by or MODEL_RANGE, command_A - self.raw)
            if limited_by == RAMP:                     # to or from the safe current: a transient
                learner.observe(t, reference_um, displacement_um, stress, False, RAMPING)
            else:
                learner.observe(t, reference_um, displacement_um, stress, True, "", command_A)


def start_stepper(stepper: InverseStepper, model: Model, safe_A: float) -> str:
    """Put the inverse stepper in the shared default start (`gma_ffc.initial_state`): the loop
    starts at the safe current and its drive first moves towards the middle of the identified
    range, so the plays start consistent with that first monotone stretch. Returns how."""
    if not isinstance(stepper, SDPIInverseStepper):       # only the SDPI/MPI stepper takes a play state
        stepper.reset(safe_A)
        return f"relaxed at the safe current ({safe_A:g}), the {model.kind} model's own start"
    lo, hi = model.drive_range
    target = 0.5 * (lo + hi) if math.isfinite(lo) and math.isfinite(hi) else safe_A + 1.0
    start = model.resolve_initial_state(np.array([safe_A, target if target != safe_A else safe_A + 1.0]))
    stepper.reset(safe_A, start.play_state)
    return f"{start.how.split(';')[0]}, from the safe current {safe_A:g}"


def carried_play_state(old_model: Model, old_stepper: InverseStepper, new_model: Model) -> np.ndarray | None:
    """The new model's forward play state that continues the old inverse's hysteresis memory, or
    None when either is not an SDPI/MPI (only those keep a play state).

    At any instant a play's output is a function of its threshold, p(r), piecewise linear and
    1-Lipschitz (the memory curve). The new thresholds read it by linear interpolation: exact
    where the thresholds agree, and flat beyond the old largest one, where the old model kept no
    older memory. |x - p(r)| <= r holds for every interpolated play, as a play's state must.
    """
    if not (isinstance(old_stepper, SDPIInverseStepper) and isinstance(old_model, SDPIModel)
            and isinstance(new_model, SDPIModel)):
        return None
    plays = old_stepper.play_state() + old_model.input_offset          # drive units
    return np.interp(new_model.play_thresholds, old_model.play_thresholds, plays) - new_model.input_offset
