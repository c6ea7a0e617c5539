"""The report's rounds table lists every candidate a round scored, with its decision: the ones set
aside too (a failed signature check, refused by the leave-one-recording-out, a look-alike left
undecided beside the effect named), not only those the round kept in the running. A researcher
reading a round could not see which candidates were tried and set aside, and why."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np

from gma_ffc.diagnose import selection
from gma_ffc.diagnose.report import render_html, rounds_table
from gma_ffc.diagnose.results import round_json
from gma_ffc.diagnose.search import SearchResult
from gma_ffc.diagnose.specs import Spec
from gma_ffc.diagnose.state import Selection, Trial
from gma_ffc.effects.base import SignatureFailure

NOISE_UM = 0.02
START_RMS_UM = 1.0
NO_RESONANCE = "its fit runs to the heaviest damping of a resonance that peaks"
NOT_CARRIED = "fitted on the other recordings, it does not improve the one left out"


def _result(rms_um: float) -> SearchResult:
    spec = Spec()
    return SearchResult((spec, spec, spec), rms_um ** 2, rms_um ** 2, rms_um ** 2, 10, np.zeros(1), [], 1)


def _trial(name: str, rms_um: float, gain: float) -> Trial:
    return Trial(name, _result(rms_um), {}, 1, gain)


def one_round(monkeypatch) -> Selection:
    """A round with four candidates scored: the resonance, best, fails its signature check; heating,
    next, is refused by the leave-one-out (a look-alike of creep that fitted better); creep is
    accepted; the eddy lag is behind it. Searches and checks stubbed: the decisions are the round's."""
    trials = [_trial("mechanical_dynamics", 0.10, 900.0), _trial("thermal_drift", 0.121, 800.0),
              _trial("creep", 0.205, 700.0), _trial("rate_dependence", 0.6, 80.0)]
    monkeypatch.setattr(selection, "score_round", lambda *_args: (trials, 400.0))
    selector = selection.EffectSelector()
    selector.threads_ = 1
    monkeypatch.setattr(selector, "signature_failure", lambda _p, _b, t: SignatureFailure(NO_RESONANCE)
                        if t.effect == "mechanical_dynamics" else None)
    monkeypatch.setattr(selector, "_carries_over", lambda _p, _s, t: (t, NOT_CARRIED if t.effect == "thermal_drift"
                                                                      else ""))
    monkeypatch.setattr(selector, "_start_earned", lambda _p, _s, t, _n: t)     # creep as fitted, its start kept
    problem = SimpleNamespace(fitter=None, noise=NOISE_UM, leave_one_out=lambda _spec: None)
    names = frozenset(t.effect for t in trials)
    sel, more = selector._round(problem, Selection(_result(START_RMS_UM), names, {}), 1, lambda _msg: None)
    assert more and sel.accepted == ("creep",)
    return sel


def test_the_round_records_every_candidate_it_scored_with_its_decision(monkeypatch):
    record = one_round(monkeypatch).rounds[-1]
    assert [row[0] for row in record.table] == ["creep", "rate_dependence"]      # the kept ones, as before
    decisions = {name: decision for name, _, _, decision in record.scored}
    assert list(decisions) == ["mechanical_dynamics", "thermal_drift", "creep", "rate_dependence"]
    assert decisions["mechanical_dynamics"] == f"set aside, not its effect's signature: {NO_RESONANCE}"
    assert decisions["thermal_drift"].startswith(f"refused by the leave-one-recording-out: {NOT_CARRIED}")
    assert "left undecided beside creep" in decisions["thermal_drift"]
    assert decisions["creep"] == "accepted"
    assert decisions["rate_dependence"].startswith("behind creep")


def test_a_round_that_accepts_nothing_says_which_term_of_the_rule_its_best_missed():
    selector = selection.EffectSelector()
    words = selector.shortfall(0.9 ** 2, 4.2, 1.0, NOISE_UM)
    assert "below the evidence: 4.2 nats, where more than 6 are needed" in words
    assert "takes 19% of the held-out loss, where an effect must take more than 25%" in words
    assert selector.shortfall(0.5 ** 2, 50.0, 1.0, NOISE_UM) == ""
    assert selector.earns_place(0.5 ** 2, 50.0, 1.0, NOISE_UM) and not selector.earns_place(0.81, 4.2, 1.0, NOISE_UM)


def test_the_report_shows_a_set_aside_candidate_and_why(monkeypatch):
    record = one_round(monkeypatch).rounds[-1]
    doc = {"rounds": [round_json(record.as_dict())]}
    page = rounds_table(doc)
    for name in ("mechanical_dynamics", "thermal_drift", "creep", "rate_dependence"):
        assert f"<td>{name}</td>" in page or f"<td><b>{name}</b></td>" in page, name
    row = page.split("<td>mechanical_dynamics</td>", 1)[1].split("</tr>", 1)[0]
    assert "0.1</td>" in row and "900.0</td>" in row and NO_RESONANCE in row
    row = page.split("<td>thermal_drift</td>", 1)[1].split("</tr>", 1)[0]
    assert "refused by the leave-one-recording-out" in row and "0.121</td>" in row
    assert "<td><b>creep</b></td>" in page                 # the one accepted, marked
    assert doc["rounds"][0]["scored"][0] == {"effect": "mechanical_dynamics", "validation_rms_um": 0.1,
                                             "heldout_loglik_gain": 900.0,
                                             "decision": f"set aside, not its effect's signature: {NO_RESONANCE}"}


def test_a_whole_report_with_a_set_aside_candidate_lists_it_with_its_reason(monkeypatch, diagnosed):
    """A diagnosis rendered whole (a benchmark case), its rounds those of the round above."""
    record = one_round(monkeypatch).rounds[-1]
    _model, _rec, dg = diagnosed("time_delay#2", 0.5)
    dg = dataclasses.replace(dg, rounds=[record.as_dict()])
    doc = dg.to_json()
    page = render_html(dg, doc)
    table = page.split("<h2>Selection rounds</h2>", 1)[1].split("</table>", 1)[0]
    assert "<td>mechanical_dynamics</td>" in table and NO_RESONANCE in table
    assert "<td>thermal_drift</td>" in table and "refused by the leave-one-recording-out" in table
    assert doc["rounds"][0]["accepted"] == "creep"
