"""A step test (drive levels held 12 s each, hil_sim's `steps` kind), the classic creep and heating
experiment, has few drive reversals (three here). diagnose asked for 32 and concluded nothing, even with 2 um
of drift against a 0.02 um noise floor. Its holds now let it test the slow effects (heating,
creep) while the loop effects stay untested, and it says so. On a rig with neither, nothing is
named."""

from __future__ import annotations

import pytest

from gma_ffc.diagnose.engine import diagnose
from gma_ffc.diagnose.report import render_html
from gma_ffc.identify import SDPIIdentifier
from hil_sim.record import make_recording, make_recordings


def step_test_diagnosed(effects: list[str]):
    ident = make_recordings("identification", effects=effects, seed=5)
    model = SDPIIdentifier().fit(ident).model_
    return diagnose(model, [make_recording("steps", effects=effects, seed=3)], identification=ident)


@pytest.mark.slow
def test_a_step_test_names_heating_and_creep_and_says_the_loop_effects_were_not_tested():
    dg = step_test_diagnosed(["noise", "thermal", "creep"])
    assert dg.outcome == "effects_named" and sorted(dg.verdict) == ["creep", "thermal_drift"]
    assert dg.rms_after_um < 0.05 * dg.rms_before_um
    note = next(c for c in dg.cannot_conclude if c.startswith("too few drive reversals"))
    assert "heating and creep are tested on the drive's" in note and "at two or more drive frequencies" in note
    untested = {c.effect for c in dg.candidates if c.reason and "too few drive reversals" in c.reason}
    assert untested == {"rate_dependence", "mechanical_dynamics", "time_delay", "stress_dependent_play", "saturation"}
    # the report draws no loop chart: where the drive sweeps no loop it was a scribble of holds
    page = render_html(dg, dg.to_json())
    assert "Residual over time" in page and "Candidates: held-out RMS" in page and "Loops where" not in page


@pytest.mark.slow
def test_a_step_test_of_a_rig_without_slow_effects_names_none():
    dg = step_test_diagnosed(["noise"])
    assert dg.verdict == [] and dg.outcome != "effects_named"
