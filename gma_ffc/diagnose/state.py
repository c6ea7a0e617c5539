"""The selection's state, explicit and frozen: what each step of `EffectSelector.fit` hands the next.

    Problem      what the recordings are (prepared data, the fitter over them, noise floor, what
                 cannot be concluded from them) and the null model every effect must beat
    Trial        one effect fitted and scored on top of the model so far (a round, or the swap pass)
    Selection    the forward selection after a step: which effects are accepted, the current fit,
                 the last trial of every effect, why some cannot be tested, the rounds' record
    Final        the guarded result: the extended model and its predictions

Each step takes these and returns new ones (`dataclasses.replace`); nothing is changed in place,
so a round's result can be read, logged or tested on its own. Pure data: no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Mapping

import numpy as np

from ..extended import ExtendedModel
from .data import RecData
from .fitting import Fitter
from .specs import LeaveOneOut
from .identification import IdentificationCheck
from .locate import Located
from .search import SearchResult


@dataclass(frozen=True)
class NullFit:
    """The base model as given and the null model (the base with a static recalibration)."""

    base_pred: tuple[np.ndarray, ...]     # the base model's displacement per recording
    rms_before: float                     # its RMS on the scored samples: "before"
    fit: SearchResult                     # the recalibrated base, scored on held-out blocks
    null_pred: tuple[np.ndarray, ...]     # its all-data prediction per recording
    located: tuple[Located, ...]          # where the residual sits, per recording


@dataclass(frozen=True)
class Problem:
    """The recordings as the selection sees them: prepared data, the fitter (its caches are its
    own business), the core the extended model is built on, the noise floor, and the null model."""

    model: Any                            # the base model as the user gave it
    core: Any                             # the core the extended model is built on (`rebase` may replace it)
    data: tuple[RecData, ...]
    fitter: Fitter
    noise: float                          # the data's noise floor (um)
    n_samples: int                        # scored samples in all
    too_little: bool                      # too little data for blocked cross-validation
    cannot: tuple[str, ...]               # what cannot be concluded, found before any fit
    null: NullFit
    identification: IdentificationCheck   # the identification recordings given, against the model's record
    slow_only: bool = False               # too few drive reversals for loop effects: only slow ones are tested

    def leave_one_out(self, spec: Any) -> LeaveOneOut | None:
        """The spec, each recording predicted by its gains fitted on the others; None with one
        recording (nothing to leave out) or too little data."""
        if len(self.data) < 2 or self.too_little:
            return None
        return LeaveOneOut.of(self.fitter.left_out(spec))

    def sole_setter(self, tau_s: float) -> int | None:
        """The one recording long enough to set a slow effect's time constant `tau_s`, when every
        other is shorter (None otherwise). A run sets a time constant when it lasts two of them: the
        grid rule of creep and heating, a constant beyond half a run being a drift it cannot tell
        from another. Left out, that recording's fold fits the law on runs that cannot set it, then
        extrapolates: hil_sim's realistic actuator, heating at 80 s, missed its one 240 s run by
        5.96 um so. That fold tests nothing, and the law is judged on the others."""
        long_enough = [k for k, d in enumerate(self.data) if d.duration_s >= 2.0 * tau_s]
        return long_enough[0] if len(long_enough) == 1 and len(self.data) > 1 else None


@dataclass(frozen=True)
class Trial:
    """One effect fitted on top of the model so far and scored on held-out blocks."""

    effect: str
    result: SearchResult
    params: Mapping[str, float]
    round: int
    loglik_gain: float = math.nan
    leave_one_out: LeaveOneOut | None = None     # its law judged on each recording it was not fitted on

    @property
    def cv_mse(self) -> float:
        return self.result.cv_mse

    @property
    def cv_loss(self) -> float:
        return self.result.cv_loss


LOO_REFUSED = "refused by the leave-one-recording-out"
"""How the decision on a round's winner the leave-one-recording-out refused begins (the note on it reads it)."""


@dataclass(frozen=True)
class RoundRecord:
    """What a round tried and decided (the report's table).

    `table` holds the candidates the round kept in the running, best first: the ones the notes on
    its best read. `scored` holds every candidate it scored, best first, each with what became of
    it: accepted, or why it was set aside (a failed signature check, refused by the leave-one-out,
    short of the rule, behind the round's best). A reader of the report sees them all."""

    round: int
    n_eff: float
    current_rms_um: float
    table: tuple[tuple[str, float, float], ...]      # (effect, held-out RMS, log-likelihood gain)
    accepted: str | None
    scored: tuple[tuple[str, float, float, str], ...] = ()   # (effect, held-out RMS, gain, its decision)

    def accepting(self, effect: str, decisions: Mapping[str, str]) -> "RoundRecord":
        """The record with `effect` accepted after all (a look-ahead's pair in the place of the effect
        accepted before), and the effects in `decisions` with the decision given there."""
        rows = tuple((name, rms, gain, decisions.get(name, decision)) for name, rms, gain, decision in self.scored)
        return replace(self, accepted=effect, scored=rows)

    def as_dict(self) -> dict[str, Any]:
        return {"round": self.round, "n_eff": self.n_eff, "current_rms_um": self.current_rms_um,
                "table": list(self.table), "accepted": self.accepted, "scored": list(self.scored)}


@dataclass(frozen=True)
class Selection:
    """The forward selection after a step."""

    fit: SearchResult                               # the current model (specs, held-out loss and MSE)
    testable: frozenset[str]                        # effects the data can test (a failed signature removes one)
    reasons: Mapping[str, str]                      # per effect: why it cannot be tested, or a caveat
    accepted: tuple[str, ...] = ()                  # in the order named (most important first after the swap pass)
    trials: Mapping[str, Trial] = field(default_factory=dict)   # the last trial of each effect
    rounds: tuple[RoundRecord, ...] = ()
    ambiguous: tuple[tuple[str, str], ...] = ()     # look-alikes the data do not tell apart
    swapped: tuple[tuple[str, str, float, float], ...] = ()     # (first choice, its replacement, their RMS)
    outside_class: str = ""                         # a drive the model's class cannot follow (named nothing)
    rebase_note: str = ""
    cannot: tuple[str, ...] = ()                    # what cannot be concluded, found by the selection's steps
    leave_one_out: LeaveOneOut | None = None        # the current model, each recording fitted without it
    null_leave_one_out: LeaveOneOut | None = None   # the null model's (None: one recording, or too little data)
    set_aside: Mapping[str, str] = field(default_factory=dict)  # failed a check this round: its reason before
    # (named, a look-alike of it that fitted the held-out blocks better in its round but whose law did
    # not carry to a recording left out, why the recordings cannot tell them apart): see `_undecided`
    undecided: tuple[tuple[str, str, str], ...] = ()

    @property
    def cur_cv(self) -> float:
        return self.fit.cv_mse

    @property
    def cur_loss(self) -> float:
        return self.fit.cv_loss

    def with_reason(self, effect: str, reason: str, testable: bool | None = None) -> "Selection":
        """The same selection with a new reason for `effect` (and, if given, its testability)."""
        tested = self.testable if testable is None else (
            self.testable | {effect} if testable else self.testable - {effect})
        return replace(self, reasons={**self.reasons, effect: reason}, testable=tested)

    def aside(self, effect: str, reason: str) -> "Selection":
        """`effect` failed a check on top of the current model: not tried again until another effect is
        accepted (a resonance's fit that ran to a lag's damping may peak once the lag is in the model)."""
        return replace(self.with_reason(effect, reason, testable=False),
                       set_aside={**self.set_aside, effect: self.reasons.get(effect, "")})

    def readmitted(self) -> "Selection":
        """The effects set aside, testable again with the reasons they had (the model has changed)."""
        return replace(self, testable=self.testable | frozenset(self.set_aside),
                       reasons={**self.reasons, **self.set_aside}, set_aside={})


@dataclass(frozen=True)
class Final:
    """The guarded result of the selection."""

    selection: Selection
    extended: ExtendedModel
    final_pred: tuple[np.ndarray, ...]
    cv_mse: float                         # the extended model's held-out MSE (the base's as given when kept)
    base_kept: bool
    cannot: tuple[str, ...]               # what cannot be concluded, in the order found
    leave_one_out: LeaveOneOut | None = None    # the final model, each recording fitted without it
