"""A second effect that is significant but short of the margin is said, not left in a table:
thermal_drift named, creep beside it 0.1111 -> 0.0974 um with +72 nats, and no word of it.
So is an effect that did all an effect must to the held-out loss but fell short of the evidence
alone, with the run that would decide (`outcome.short_of_the_evidence`)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from gma_ffc.diagnose.outcome import short_of_the_evidence, short_of_the_margin
from gma_ffc.diagnose.selection import EffectSelector
from gma_ffc.diagnose.state import RoundRecord

SELECTOR = EffectSelector()


def _sel(accepted, *rounds):
    trials = {effect: SimpleNamespace(effect=effect) for r in rounds for effect, _, _ in r.table}
    return SimpleNamespace(accepted=tuple(accepted), rounds=tuple(rounds), trials=trials, fit=SimpleNamespace(specs=None))


def _margin(selector, sel):
    return short_of_the_margin(selector, SimpleNamespace(noise=0.03, fitter=None), sel)


class _Signatures(EffectSelector):
    """The selector with its signature checks answered: `fails` names the effects whose check fails."""

    def __init__(self, fails=()):
        super().__init__()
        self.fails = set(fails)

    def signature_failure(self, problem, base, trial):
        return SimpleNamespace(reason="no signature") if trial.effect in self.fails else None


NAMED = RoundRecord(1, 900.0, 2.591, (("thermal_drift", 0.1111, 4000.0), ("creep", 0.1196, 3500.0)), "thermal_drift")


def test_a_significant_runner_short_of_the_margin_is_named_with_its_figures():
    last = RoundRecord(2, 900.0, 0.1111, (("creep", 0.0974, 72.0), ("rate_dependence", 0.1088, 9.0)), None)
    note = _margin(_Signatures(), _sel(["thermal_drift"], NAMED, last))
    assert note.startswith("creep: a smaller effect may be there beside thermal_drift")
    assert "0.1111 to 0.0974 um" in note and "72 nats" in note and "neither named nor in the extended model" in note
    assert f"{1 - SELECTOR.min_mse_ratio:.0%}" in note


def test_a_runner_that_fails_its_own_signature_is_not_said_to_be_there():
    """A 7.8 s heating recording: heating named, then creep beside it at -1.9 % of each step (it relaxes
    against the drive's changes, which creep does not) lowered the held-out RMS 0.0904 -> 0.0854 um
    with 7 nats. That fit is not creep, so it says nothing of whether creep is there."""
    last = RoundRecord(2, 900.0, 0.0904, (("creep", 0.0854, 7.0),), None)
    assert _margin(_Signatures(fails={"creep"}), _sel(["thermal_drift"], NAMED, last)) == ""
    assert _margin(_Signatures(), _sel(["thermal_drift"], NAMED, last)).startswith("creep: a smaller effect")


def test_nothing_is_said_of_an_insignificant_or_worse_runner_or_without_a_named_effect():
    weak = RoundRecord(2, 900.0, 0.1111, (("creep", 0.1100, SELECTOR.min_loglik_gain - 1),), None)
    worse = RoundRecord(2, 900.0, 0.1111, (("creep", 0.1120, 50.0),), None)
    assert _margin(_Signatures(), _sel(["thermal_drift"], NAMED, weak)) == ""
    assert _margin(_Signatures(), _sel(["thermal_drift"], NAMED, worse)) == ""
    accepted_last = RoundRecord(2, 900.0, 0.1111, (("creep", 0.05, 500.0),), "creep")
    assert _margin(_Signatures(), _sel(["thermal_drift", "creep"], NAMED, accepted_last)) == ""
    null_round = RoundRecord(1, 900.0, 0.12, (("creep", 0.11, 20.0),), None)
    assert _margin(_Signatures(), _sel([], null_round)) == ""


def _short(selector, last, noise=0.03):
    trials = {effect: SimpleNamespace(effect=effect) for effect, _, _ in last.table}
    sel = SimpleNamespace(accepted=(), rounds=(last,), trials=trials, fit=SimpleNamespace(specs=None))
    return short_of_the_evidence(selector, SimpleNamespace(noise=noise, fitter=None), sel)


def test_an_effect_short_only_of_the_evidence_is_said_with_the_run_that_would_decide():
    """The nineteenth draw's play: 0.4354 -> 0.362 um held out (an MSE share of 0.69, under 0.75),
    5.98 nats where 6 are needed, over 39 effective samples. No effect named, and before this note
    nothing said how close it came or what to record."""
    last = RoundRecord(1, 38.7, 0.4354, (("stress_dependent_play", 0.362, 5.98), ("creep", 0.409, -0.7)), None)
    note = _short(_Signatures(), last)
    assert note.startswith("stress_dependent_play: may be what is missing")
    assert "0.4354 to 0.362 um" in note and "5.98 nats where 6 are needed" in note and "about 39 independent" in note
    assert "Record another run like these" in note


def test_nothing_is_said_where_the_loss_share_the_signature_or_any_evidence_is_missing():
    selector = _Signatures()
    too_little = RoundRecord(1, 38.7, 0.4354, (("creep", 0.40, 5.0),), None)          # MSE share 0.84
    none_at_all = RoundRecord(1, 38.7, 0.4354, (("creep", 0.362, -0.5),), None)
    enough = RoundRecord(1, 900.0, 0.4354, (("creep", 0.362, 50.0),), None)           # named, or another note's
    accepted = RoundRecord(1, 38.7, 0.4354, (("creep", 0.362, 5.98),), "creep")
    for last in (too_little, none_at_all, enough, accepted):
        assert _short(selector, last) == ""
    near = RoundRecord(1, 38.7, 0.4354, (("creep", 0.362, 5.98),), None)
    assert _short(_Signatures(fails={"creep"}), near) == ""
    assert _short(selector, near, noise=0.2) == ""      # removes less than half the noise floor off the RMS
    assert _short(selector, near) != ""


@pytest.mark.nightly
def test_the_nineteenth_draws_play_is_named_or_said_to_be_short_of_the_evidence():
    """End to end, on the case that showed it: the nineteenth general draw's stress-dependent play on
    the default actuator, with its loops. Here its evidence is 5.98 nats of the 6 (a hair from being
    named, so either is accepted); it must never end with neither named nor said."""
    from benchmarks.cases import case_recordings
    from benchmarks.general import GENERAL_NINETEENTH_SEED, general_cases
    from gma_ffc.diagnose.engine import diagnose

    name = "nineteenth:stress_dependent_play@default"
    case = {c.name: c for c in general_cases(GENERAL_NINETEENTH_SEED, prefix="nineteenth")}[name]
    model, ident, rec = case_recordings(case)
    dg = diagnose(model, [rec], identification=ident)
    said = [n for n in dg.cannot_conclude if n.startswith("stress_dependent_play: may be what is missing")]
    assert dg.verdict == ["stress_dependent_play"] or said, (dg.verdict, dg.cannot_conclude)
    if said:
        assert "Record another run like these" in said[0]
        assert "the best, stress_dependent_play, reaches" in dg.explanation and "nats of evidence" in dg.explanation
