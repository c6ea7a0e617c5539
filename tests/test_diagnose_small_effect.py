"""A second effect that is significant but short of the margin is said, not left in a table:
thermal_drift named, creep beside it 0.1111 -> 0.0974 um with +72 nats, and no word of it."""

from __future__ import annotations

from types import SimpleNamespace

from gma_ffc.diagnose.outcome import short_of_the_margin
from gma_ffc.diagnose.selection import EffectSelector
from gma_ffc.diagnose.state import RoundRecord

SELECTOR = EffectSelector()


def _sel(accepted, *rounds):
    return SimpleNamespace(accepted=tuple(accepted), rounds=tuple(rounds))


NAMED = RoundRecord(1, 900.0, 2.591, (("thermal_drift", 0.1111, 4000.0), ("creep", 0.1196, 3500.0)), "thermal_drift")


def test_a_significant_runner_short_of_the_margin_is_named_with_its_figures():
    last = RoundRecord(2, 900.0, 0.1111, (("creep", 0.0974, 72.0), ("rate_dependence", 0.1088, 9.0)), None)
    note = short_of_the_margin(SELECTOR, _sel(["thermal_drift"], NAMED, last))
    assert note.startswith("creep: a smaller effect may be there beside thermal_drift")
    assert "0.1111 to 0.0974 um" in note and "72 nats" in note and "neither named nor in the extended model" in note
    assert f"{1 - SELECTOR.min_mse_ratio:.0%}" in note


def test_nothing_is_said_of_an_insignificant_or_worse_runner_or_without_a_named_effect():
    weak = RoundRecord(2, 900.0, 0.1111, (("creep", 0.1100, SELECTOR.min_loglik_gain - 1),), None)
    worse = RoundRecord(2, 900.0, 0.1111, (("creep", 0.1120, 50.0),), None)
    assert short_of_the_margin(SELECTOR, _sel(["thermal_drift"], NAMED, weak)) == ""
    assert short_of_the_margin(SELECTOR, _sel(["thermal_drift"], NAMED, worse)) == ""
    accepted_last = RoundRecord(2, 900.0, 0.1111, (("creep", 0.05, 500.0),), "creep")
    assert short_of_the_margin(SELECTOR, _sel(["thermal_drift", "creep"], NAMED, accepted_last)) == ""
    null_round = RoundRecord(1, 900.0, 0.12, (("creep", 0.11, 20.0),), None)
    assert short_of_the_margin(SELECTOR, _sel([], null_round)) == ""
