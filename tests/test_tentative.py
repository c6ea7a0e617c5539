"""Which named effects are tentative (docs/cli.md): those a look-alike fits as well, not every
effect beside them; all of them when a column's fault may be what they compensate."""

from __future__ import annotations

from types import SimpleNamespace

from hypothesis import given, strategies as st

from gma_ffc.diagnose.outcome import tentative_effects
from gma_ffc.diagnose.results import OUTCOMES, verdict_words

EFFECTS = ("creep", "thermal_drift", "time_delay", "rate_dependence", "mechanical_dynamics")


def _selection(*pairs: tuple[str, str]) -> SimpleNamespace:
    return SimpleNamespace(ambiguous=tuple(pairs))      # all `tentative_effects` reads of a Selection


def test_an_effect_beside_an_ambiguous_lag_is_vouched_for_the_lag_is_not():
    sel = _selection(("time_delay", "rate_dependence"), ("time_delay", "mechanical_dynamics"))
    assert tentative_effects(["creep", "time_delay"], "inconclusive", sel, False) == ["time_delay"]
    assert verdict_words(["creep", "time_delay"], ["time_delay"]) == \
        "creep, time_delay (tentative: time_delay; see 'cannot conclude')"


def test_a_column_fault_makes_every_named_effect_tentative():
    assert tentative_effects(["creep", "time_delay"], "inconclusive", _selection(), True) == ["creep", "time_delay"]


def test_a_confident_verdict_has_nothing_tentative_and_prints_as_before():
    sel = _selection(("time_delay", "rate_dependence"))
    assert tentative_effects(["creep"], "effects_named", sel, False) == []
    assert verdict_words(["creep"], []) == "creep" and verdict_words([], []) == "none"


@given(verdict=st.lists(st.sampled_from(EFFECTS), unique=True, max_size=3),
       pairs=st.lists(st.tuples(st.sampled_from(EFFECTS), st.sampled_from(EFFECTS)), max_size=3),
       outcome=st.sampled_from(OUTCOMES), fault=st.booleans())
def test_tentative_effects_are_named_ones_and_only_under_an_inconclusive_outcome(verdict, pairs, outcome, fault):
    tentative = tentative_effects(verdict, outcome, _selection(*pairs), fault)
    assert set(tentative) <= set(verdict)
    assert [v for v in verdict if v in tentative] == tentative         # in the verdict's order
    # an inconclusive verdict is never presented as vouched for: at least one of its effects is marked
    assert bool(tentative) == (outcome == "inconclusive" and bool(verdict))


def test_the_runner_up_is_put_in_words_once_from_the_first_rounds_table():
    """It was a sentence rewritten by prefix in two other places (a look-alike at one frequency
    'came second'; a winner no longer named made it 'the first round's'); now the round's table is
    kept and put in words once."""
    from gma_ffc.diagnose.explain import runner_up_words
    from gma_ffc.diagnose.state import RoundRecord

    rounds = (RoundRecord(1, 40.0, 0.5, (("time_delay", 0.2, 30.0), ("rate_dependence", 0.25, 21.0)), "time_delay"),)
    assert runner_up_words(rounds, ["time_delay"], []) == (
        "The runner-up, rate_dependence, lost: held-out RMS 0.25 um against 0.2 um for time_delay "
        "(9 nats less penalised held-out likelihood).")
    assert runner_up_words(rounds, ["time_delay"], [("rate_dependence", "time_delay")]).endswith(
        "came second (held-out RMS 0.25 um against 0.2 um for time_delay): the data do not rule it out.")
    assert runner_up_words(rounds, ["mechanical_dynamics"], []).startswith("In the first round, the runner-up")
    nothing = (RoundRecord(1, 40.0, 0.5, rounds[0].table, None),)
    assert runner_up_words(nothing, [], []) == "" and runner_up_words((), [], []) == ""
