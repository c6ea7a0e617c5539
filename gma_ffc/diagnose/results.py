"""What a diagnosis returns: the candidates it tried and the `Diagnosis` (verdict, outcome, models)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..extended import ExtendedModel
from .data import RecData
from .locate import Located
from .search import SearchResult


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
    leave_one_out_mse: float = math.nan   # its law fitted on the other recordings, each left out in turn

    def to_json(self) -> dict:
        d: dict[str, Any] = {"effect": self.effect, "evidence": round(float(self.evidence), 4),
                             "params": {k: _round(v) for k, v in self.params.items()}}
        d["validation_rms_um"] = None if not math.isfinite(self.cv_mse) else _round(math.sqrt(self.cv_mse))
        d["heldout_loglik_gain"] = None if not math.isfinite(self.loglik_gain) else round(self.loglik_gain, 2)
        if math.isfinite(self.leave_one_out_mse):
            d["leave_one_out_rms_um"] = _round(math.sqrt(self.leave_one_out_mse))
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
    initial_state: str = "estimate"   # the rule asked for; each recording's resolved state is in data[k].start
    located_after: list[Located] = field(default_factory=list)   # the residual the named effects leave
    identification: dict = field(default_factory=dict)   # the identification recordings given (`--ident`), checked
    leave_one_out: dict = field(default_factory=dict)    # leave-one-recording-out figures (two or more recordings)
    tentative: list[str] = field(default_factory=list)   # the verdict's effects a look-alike fits as well (docs/cli.md)
    rms_written_um: float = math.nan   # extended_model.yaml run as `simulate` runs it (`written.py`); NaN: it is the base

    def initial_states(self) -> list[dict]:
        """Per recording: the rule, how its state was chosen, and how long it is not scored."""
        return [{"recording": d.name, "rule": self.initial_state, "how": d.start.how,
                 "not_scored_s": _round(d.unscored_s), "scored_share": round(d.n_scored / max(d.t.size, 1), 4)}
                for d in self.data]

    def to_json(self, model_file: str = "extended_model.yaml") -> dict:
        return {
            "outcome": self.outcome,
            "verdict": list(self.verdict),
            "tentative": list(self.tentative),
            "explanation": self.explanation,
            "located": [loc.to_json() for loc in self.located],
            "located_after": [loc.to_json() for loc in self.located_after],
            "candidates": [c.to_json() for c in self.candidates],
            "rms_before_um": _round(self.rms_before_um),
            "rms_after_um": _round(self.rms_after_um),
            "rms_recalibrated_um": _round(self.rms_recalibrated_um),
            "rms_written_um": _finite_or_none(self.rms_written_um),
            "noise_floor_um": _round(self.noise_um),
            "validation": self.validation,
            "conclusive": self.conclusive,
            "cannot_conclude": list(self.cannot_conclude),
            "initial_state": self.initial_states(),
            "identification": dict(self.identification),
            "leave_one_out": dict(self.leave_one_out),
            "rounds": [round_json(r) for r in self.rounds],
            "extended_model": model_file,
        }


def round_json(r: dict) -> dict:
    """A selection round as diagnosis.json gives it: the held-out RMS it started from, what it
    accepted, and every candidate it scored with its figures and its decision (accepted, or why it
    was set aside: `state.RoundRecord`). A figure that was not measured is null."""
    return {"round": r["round"], "rms_at_start_um": _finite_or_none(r["current_rms_um"]),
            "n_eff": _finite_or_none(r["n_eff"]), "accepted": r["accepted"],
            "scored": [{"effect": name, "validation_rms_um": _finite_or_none(rms),
                        "heldout_loglik_gain": None if not math.isfinite(gain) else round(gain, 2),
                        "decision": decision} for name, rms, gain, decision in r["scored"]]}


def verdict_words(verdict: list[str], tentative: list[str]) -> str:
    """The verdict as the command prints it: "none", or the effects, with those a look-alike fits as
    well named again as tentative (docs/cli.md)."""
    if not verdict:
        return "none"
    marked = f" (tentative: {', '.join(tentative)}; see 'cannot conclude')" if tentative else ""
    return ", ".join(verdict) + marked


def rms_summary(doc: dict) -> str:
    """Before -> after on the held-out blocks; with no sample scored, nothing was held out, and the
    one figure is the base's miss over every sample."""
    floor = f"(noise floor {doc['noise_floor_um']:.3g} um)"
    if doc["initial_state"] and all(s["scored_share"] == 0 for s in doc["initial_state"]):
        return f"RMS {doc['rms_before_um']:.4g} um over every sample: none could be scored, so nothing was held out {floor}"
    return f"held-out RMS {doc['rms_before_um']:.4g} um -> {doc['rms_after_um']:.4g} um {floor}"


def written_summary(doc: dict) -> str | None:
    """How extended_model.yaml does as `gma-ffc simulate` runs it, or None when it is the base."""
    if doc.get("rms_written_um") is None:
        return None
    return ("the written model (extended_model.yaml), run as `gma-ffc simulate` runs it (from a start estimated on "
            "each recording, without the fit's per-recording terms): "
            f"RMS {doc['rms_before_um']:.4g} um -> {doc['rms_written_um']:.4g} um over the scored samples, not held out")


def _finite_or_none(v: float) -> float | None:
    return _round(v) if math.isfinite(v) else None


def _round(v: float) -> float | None:
    """Six significant digits; a non-finite value is passed on as it is, for the check on write
    (`report.finite_document`) to refuse: every number the document must hold is a real one."""
    if v is None:
        return None
    if not math.isfinite(v):
        return float(v)
    return float(f"{v:.6g}")
