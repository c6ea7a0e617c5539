"""The `evidence` each candidate carries in diagnosis.json and the report: the Akaike weight of the
model with the effect against the model without it, from its held-out log-likelihood gain. A
researcher's report showed 0.000 for both named effects and 1.000 for a look-alike the
leave-one-out refused: the weights were shared among a round's candidates, set-aside ones too,
and an effect named in an earlier round kept its share of a later round's."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gma_ffc.diagnose.outcome import candidates
from gma_ffc.diagnose.scoring import evidence_weight
from gma_ffc.diagnose.search import SearchResult
from gma_ffc.diagnose.specs import Spec
from gma_ffc.diagnose.state import Trial


@given(st.floats(-700.0, 700.0), st.floats(0.0, 50.0))
def test_the_weight_is_a_probability_that_grows_with_the_gain(gain, more):
    w = evidence_weight(gain)
    assert 0.0 <= w <= 1.0
    assert evidence_weight(gain + more) >= w
    assert w + evidence_weight(-gain) == pytest.approx(1.0)


def test_no_gain_measured_is_no_evidence_and_the_acceptance_margin_is_near_certainty():
    assert evidence_weight(math.nan) == 0.0 and evidence_weight(0.0) == 0.5
    assert evidence_weight(6.0) > 0.997        # the gain an effect needs to be named (min_loglik_gain)


def _trial(name: str, gain: float, rnd: int) -> Trial:
    spec = Spec({name: 1.0})
    res = SearchResult((spec, spec, spec), 1.0, 1.0, 1.0, 10, np.zeros(1), ["gain"], 1)
    return Trial(name, res, {}, rnd, gain)


def test_named_effects_keep_their_evidence_beside_a_later_rounds_refused_winner():
    """The researcher's run: creep (15,115 nats) named in round 2, the resonance (1,625 nats) in
    round 1, and heating (4,707 nats) the best of round 3 but refused by the leave-one-out."""
    trials = {"creep": _trial("creep", 15114.94, 2), "mechanical_dynamics": _trial("mechanical_dynamics", 1624.91, 1),
              "thermal_drift": _trial("thermal_drift", 4706.94, 3), "rate_dependence": _trial("rate_dependence", -6.21, 3)}
    sel = SimpleNamespace(testable=set(trials), reasons={}, trials=trials, accepted=("mechanical_dynamics", "creep"),
                          swapped=())
    got = candidates(sel)
    assert got["creep"].evidence > 0.99 and got["mechanical_dynamics"].evidence > 0.99
    assert got["rate_dependence"].evidence < 0.01
    assert got["saturation"].evidence == 0.0          # never fitted: no gain, no evidence
