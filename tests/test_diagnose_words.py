"""Words follow the recording (issue 31): a voltage-driven actuator without a stress column is
never told about a coil, Joule heating, a load cell or a static compressive stress, whichever
effect is named; the effect's words are checked one by one, and a resonance end to end."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.cases import FS, diagnosis_drive
from gma_ffc.diagnose.engine import diagnose
from gma_ffc.diagnose.explain import physics
from gma_ffc.effects import REGISTRY, candidates
from gma_ffc.identify import SDPIIdentifier
from gma_ffc.recordings import Recording
from hil_sim.plant import GMAPlant, PlantConfig

CURRENT_WORDS = ("coil", "Joule", "current", "A^2", "eddy")
STRESS_WORDS = ("load cell", "compressive stress", "most compressive")

# each effect's reported parameters, as the diagnosis fills them for a recording without stress
PARAMS = {"rate_dependence": {"tau_s": 0.002}, "time_delay": {"delay_s": 0.0015},
          "mechanical_dynamics": {"f_ref_hz": 180.0, "zeta": 0.1, "beta_per_MPa": 0.0, "stress_ref_MPa": 0.0},
          "thermal_drift": {"tau_s": 60.0, "gain_um_per_A2": 0.01},
          "creep": {"gain": 0.02, "tau_s": 3.0},
          "stress_dependent_play": {"loop_width_change_per_MPa": 0.01},
          "saturation": {"drive_lo": 0.0, "drive_hi": 150.0}}


@pytest.mark.parametrize("name", [c.name for c in candidates()])
def test_every_effect_speaks_of_a_voltage_drive_without_stress_in_its_own_words(name):
    text = physics(name, "V", has_stress=False).replace("no coil current", "") + " " + REGISTRY[name].describe(PARAMS[name], "V")
    for deciders in REGISTRY[name].deciders.values():
        text += " " + deciders
    found = [w for w in CURRENT_WORDS + STRESS_WORDS if w.lower() in text.lower()]
    assert not found, (name, found, text)


def test_a_current_driven_actuator_with_a_load_cell_keeps_its_words():
    assert "load cell" in physics("mechanical_dynamics", "A", has_stress=True)
    assert "eddy currents" in physics("rate_dependence", "A")
    assert "Joule" in physics("thermal_drift", "A")


def test_a_resonance_of_a_voltage_driven_actuator_without_a_load_cell_is_named_in_its_words():
    """hil_sim with its load resonance at one fixed load; the recordings carry a voltage and a
    displacement column only, and the model is an MPI identified from slow loops of the same rig."""
    cfg = PlantConfig().with_effects(["noise", "dynamics"])
    cfg.dynamics.damping_ratio = 0.08
    t_id = np.arange(int(3 * FS)) / FS
    i_id = 0.5 * 2.0 * (1 - np.cos(2 * np.pi * 3 * t_id))
    out = GMAPlant(cfg, seed=5).run(t_id, i_id, load_mass_kg=25.0)
    ident = Recording({"time_s": t_id, "voltage_V": out["current_A"], "displacement_um": out["displacement_um"]},
                      {}, "id.csv")
    model = SDPIIdentifier().fit([ident]).model_
    assert model.kind == "mpi" and model.drive_name == "voltage_V"
    t, i, _ = diagnosis_drive(np.random.default_rng(6), 1.9, 0.6)
    out = GMAPlant(cfg, seed=6).run(t, i, load_mass_kg=25.0)
    rec = Recording({"time_s": t, "voltage_V": out["current_A"], "displacement_um": out["displacement_um"]},
                    {}, "piezo_like.csv")
    dg = diagnose(model, [rec])
    assert dg.verdict == ["mechanical_dynamics"], dg.explanation
    text = dg.explanation + " " + " ".join(dg.cannot_conclude)
    found = [w for w in ("coil", "Joule", "load cell", "compressive stress", "most compressive") if w in text]
    assert not found, (found, text)
    assert "no stress" in text and "constant mass" in text


def test_a_delay_under_half_a_sample_beside_a_lag_or_a_resonance_is_kept_but_not_named():
    """Beside eddy currents and a resonance, a 0.09 ms delay at 0.5 ms sampling is the samples' own
    timing (a drive held over each interval or moving through it): not named, said why and what to
    record. A delay of a sample or more, or one named without a lag or a resonance, is named."""
    from types import SimpleNamespace

    from gma_ffc.diagnose.outcome import samples_timing
    from gma_ffc.diagnose.results import Candidate

    def cands(delay_s):
        return {"time_delay": Candidate("time_delay", True, params={"delay_s": delay_s})}

    data = [SimpleNamespace(dt_med=5e-4), SimpleNamespace(dt_med=2e-4)]
    pair = ["rate_dependence", "mechanical_dynamics", "time_delay"]
    verdict, note = samples_timing(pair, cands(9e-5), data, 0.5)
    assert verdict == ["rate_dependence", "mechanical_dynamics"]
    assert note.startswith("time_delay: the 0.09 ms delay found beside rate_dependence and mechanical_dynamics")
    assert "shorter than 0.25 ms (0.5 of the 0.5 ms sample period)" in note and "record at 1.11e+04 Hz" in note
    assert samples_timing(pair, cands(5e-4), data, 0.5) == (pair, "")
    assert samples_timing(["time_delay"], cands(9e-5), data, 0.5) == (["time_delay"], "")
    assert samples_timing(["mechanical_dynamics"], cands(9e-5), data, 0.5) == (["mechanical_dynamics"], "")
    assert "first-order lag" not in note                   # the lag is named: nothing to add
    # hil_sim's eddy currents beside a resonance were fitted as a 0.076 ms delay, and the lag was named nowhere
    unnamed = {**cands(7.6e-5), "rate_dependence": Candidate("rate_dependence", True)}
    verdict, note = samples_timing(["mechanical_dynamics", "time_delay"], unnamed, data, 0.5)
    assert verdict == ["mechanical_dynamics"] and "first-order lag as short" in note and "near 2.09e+03 Hz" in note


def test_terms_left_out_per_recording_are_not_called_stress_levels_without_a_stress_column():
    """Four current-driven recordings without a stress column were told 'fitted without each of the
    4 stress levels ... would not carry to other loads': each block was a recording."""
    from gma_ffc.diagnose.recalibration import left_out_words

    text = left_out_words(["quadratic"], 4, has_stress=False, by_level=True)
    assert "4 recordings" in text and "other recordings" in text
    assert not any(w in text for w in ("stress", "load"))
    assert "2 stress levels" in left_out_words(["stress_gain"], 2, has_stress=True, by_level=True)


def test_the_anchor_of_a_stress_independent_model_has_no_stress_and_one_error_is_one_figure():
    """'1.01 Hz full-range loops at 1 stress(es)' and 'its identification error there (0.219-0.219 um)'
    on an MPI model: such a model has no stress, and one error is one figure."""
    from types import SimpleNamespace

    from gma_ffc.diagnose.anchor import anchor_words

    mpi = SimpleNamespace(stress_range_MPa=None, provenance={"fit_rms_um": {"a.csv": 0.218582},
                                                            "drive_frequency_hz": 1.009})
    text = anchor_words(mpi, [0.5])
    assert "stress" not in text and "(0.219 um)" in text, text


def test_without_ident_an_mpi_voltage_model_is_not_told_of_eddy_lags_or_loop_widths_that_follow_stress():
    """The identification note spoke of 'an eddy lag' and 'a loop width that follows stress', and of
    stress_dependent_play's law being fitted, on an MPI model (which cannot test that effect)."""
    from types import SimpleNamespace

    from gma_ffc.diagnose.identification import check

    for drive, srange in (("voltage_V", None), ("current_A", None), ("voltage_V", (-20.0, -5.0))):
        model = SimpleNamespace(drive_name=drive, stress_range_MPa=srange, provenance={"recordings": ["id.csv"]})
        note = check(model, []).words()
        assert ("eddy" in note) == (drive == "current_A"), note
        assert ("stress" in note) == (srange is not None), note
    sdpi = SimpleNamespace(drive_name="current_A", stress_range_MPa=(-20.0, -5.0), provenance={})
    assert "stress_dependent_play's loop-width law" in check(sdpi, []).words()


def test_one_identification_recording_given_is_not_told_all_1_recordings():
    """A model identified on one recording (the measured piezo's first half) and diagnosed with it
    given to --ident: the report and the command said 'All 1 identification recordings given match'."""
    from types import SimpleNamespace

    from gma_ffc.diagnose.identification import check

    fp = {"name": "a.csv", "bytes": 10, "sha256": "aa"}
    model = SimpleNamespace(drive_name="voltage_V", stress_range_MPa=None,
                            provenance={"recordings": ["a.csv"], "identification_files": [fp]})
    one = check(model, ["a.csv"], [fp]).words()
    assert "All 1" not in one and "recordings given match" not in one
    assert one == "The identification recording given (a.csv) matches the model's record by name, size and content."
    fp2 = {"name": "b.csv", "bytes": 20, "sha256": "bb"}
    model.provenance = {"recordings": ["a.csv", "b.csv"], "identification_files": [fp, fp2]}
    assert check(model, ["a.csv", "b.csv"], [fp, fp2]).words().startswith("All 2 identification recordings given match")


def test_the_validation_of_a_voltage_driven_actuator_without_stress_does_not_speak_of_stress():
    """The measured piezo (voltage_V, no stress column, an MPI model): its report said 'Models are
    simulated over the whole recording from its drive and stress only'. There is no stress."""
    from types import SimpleNamespace

    from gma_ffc.diagnose.explain import validation_words

    for srange, words in ((None, "from its drive only,"), ((-24.0, -11.3), "from its drive and stress only,")):
        fitter = SimpleNamespace(model=SimpleNamespace(stress_range_MPa=srange), data=[object()], sensor_jumps=[],
                                 stress_varies=False, delta=0.1)
        text = validation_words(fitter, 0.04, 0.75, 6.0)       # type: ignore[arg-type]
        assert words in text, text
