"""Model files: versioned YAML with units and provenance; damaged or inconsistent files refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from gma_ffc.errors import ModelError
from gma_ffc.constrained_weights import slopes_to_weights
from gma_ffc.model import SDPIModel
from gma_ffc.modelio import load_model, save_model


@pytest.fixture()
def model() -> SDPIModel:
    slopes = np.vstack([[0.8, 1.0, 1.2, 1.1, 0.9], [0.01, 0.0, -0.01, 0.005, 0.0], [0.0, 0.0, 0.0, 0.0, 0.0]])
    return SDPIModel(np.array([0.0, 0.3, 0.6]), np.array([2.0, 1.0, 0.5]), np.array([-4.0, -2.0, 0.0, 2.0, 4.0]),
                     slopes_to_weights(slopes), output_coeffs=[10.0, 0.2, 0.0], input_offset=1.5,
                     stress_range_MPa=(-24.0, -11.3), reference_stress_MPa=-11.3, drive_range=(0.0, 3.0),
                     provenance={"recordings": ["a.csv"]})


def test_save_load_round_trip_is_exact(tmp_path: Path, model: SDPIModel) -> None:
    path = tmp_path / "m.yaml"
    save_model(model, path)
    back = load_model(path)
    x = 1.5 + 1.4 * np.sin(np.linspace(0, 20, 500))
    np.testing.assert_array_equal(back.simulate(None, x, -17.0), model.simulate(None, x, -17.0))
    d = yaml.safe_load(path.read_text())
    assert d["format"] == "gma-ffc-model" and d["version"] == 2 and d["kind"] == "sdpi" and d["output_sign"] == 1
    assert d["units"] == {"drive": "A", "displacement": "um", "stress": "MPa"}
    assert d["stress_range_MPa"] == [-24.0, -11.3] and d["provenance"]["recordings"] == ["a.csv"]


def _mutate(tmp_path: Path, model: SDPIModel, change) -> Path:
    d = model.to_dict()
    change(d)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


@pytest.mark.parametrize("change, message", [
    (lambda d: d.update(format="something"), "not a gma-ffc model file"),
    (lambda d: d.update(version=99), "version 99 is not supported"),
    (lambda d: d.update(kind="fancy"), "unknown model kind 'fancy'"),
    (lambda d: d.update(kind="mpi"), "kind says 'mpi'"),
    (lambda d: d["play"].pop("weights"), "missing key 'play.weights'"),
    (lambda d: d["play"].update(weights=[1.0, 2.0]), "equally long"),
    (lambda d: d["play"].update(thresholds=[0.0, 0.6, 0.3]), "strictly increase"),
    (lambda d: d["deadzone"].update(thresholds=[-4.0, -2.0, 0.5, 2.0, 4.0]), "centre one at 0"),
    (lambda d: d["deadzone"]["weight_coeffs"].__setitem__(2, [-1.0, 0.0, 0.0]), "Proposition 3.1"),
    (lambda d: d["play"]["weights"].__setitem__(0, float("nan")), "finite"),
    (lambda d: d.update(stress_range_MPa=[-10.0, -20.0]), "low < high"),
    (lambda d: d.update(drive_range=[0.0, 1.5, 3.0]), "drive range must be two values"),
    (lambda d: d.update(drive_range=[3.0, 0.0]), r"low < high, got \[3, 0\]"),
    (lambda d: d.update(drive_range=[float("nan"), 3.0]), r"low < high, got \[nan, 3\]"),
    (lambda d: d["units"].update(drive="mA"), "units.drive is 'mA' but gma-ffc models are in 'A'"),
    (lambda d: d["units"].update(displacement="mm"), "units.displacement is 'mm'"),
    (lambda d: d.update(units="A"), "units must be a mapping"),
    (lambda d: d["deadzone"].update(index_of_r0=30), "index_of_r0 is 30 but the centre"),
])
def test_inconsistent_files_are_refused_with_the_reason(tmp_path: Path, model: SDPIModel, change, message) -> None:
    path = _mutate(tmp_path, model, change)
    with pytest.raises(ModelError, match=message) as err:
        load_model(path)
    assert str(path) in str(err.value)



def test_a_fault_in_an_extended_models_base_is_named_under_base(tmp_path: Path, model: SDPIModel) -> None:
    """The base of an extended model was read with no name of its own: the refusal said
    "m.yaml: <dict>: deadzone.index_of_r0 ...", as if the user knew what <dict> was."""
    from gma_ffc.extended import ExtendedModel

    save_model(ExtendedModel(model), tmp_path / "ext.yaml")
    d = yaml.safe_load((tmp_path / "ext.yaml").read_text())
    d["base"]["deadzone"]["index_of_r0"] = -1
    (tmp_path / "ext.yaml").write_text(yaml.safe_dump(d))
    with pytest.raises(ModelError) as err:
        load_model(tmp_path / "ext.yaml")
    assert f"{tmp_path / 'ext.yaml'}: base: deadzone.index_of_r0 is -1" in str(err.value)
    assert "<dict>" not in str(err.value)


def test_a_model_violating_proposition_3_1_is_refused_without_numpy_warnings(tmp_path: Path, model: SDPIModel,
                                                                            recwarn) -> None:
    """A zero or overflowing first play weight made numpy print warnings before the one-line refusal.
    One past any model's number (`PARAMETER_BOUND`) is refused as such, before the proposition."""
    for w0, message in ((0.0, "Proposition 3.1"), (1e300, r"play weights holds 1e\+300, past the 1e\+30")):
        path = _mutate(tmp_path, model, lambda d: d["play"]["weights"].__setitem__(0, w0))
        with pytest.raises(ModelError, match=message):
            load_model(path)
    assert [str(w.message) for w in recwarn] == []


def test_damaged_yaml_and_missing_files_are_refused(tmp_path: Path) -> None:
    bad = tmp_path / "d.yaml"
    bad.write_text("format: gma-ffc-model\nplay: [1, 2\n")
    with pytest.raises(ModelError, match=r"d.yaml, line \d+: not valid YAML .*; is it a model file\?"):
        load_model(bad)
    with pytest.raises(ModelError, match="no such model file"):
        load_model(tmp_path / "missing.yaml")


def test_stress_outside_the_identified_range_is_refused(model: SDPIModel) -> None:
    with pytest.raises(ModelError, match="outside the model's identified range"):
        model.simulate(None, np.ones(10), -30.0)
    with pytest.raises(ModelError, match="needs a stress"):
        model.simulate(None, np.ones(10))


def _rename(d: dict, section: str | None, old: str, new: str) -> None:
    where = d if section is None else d[section]
    where[new] = where.pop(old)


@pytest.mark.parametrize("section, key, typo", [(None, "output_sign", "ouput_sign"), ("play", "weights", "wieghts"),
                                                (None, "drive_range", "drive_rnage")])
def test_a_misspelt_key_is_named_with_the_known_one_and_renaming_it_loads(tmp_path: Path, model: SDPIModel,
                                                                         section, key, typo) -> None:
    """'ouput_sign' was reported as "missing key 'output_sign': the file is incomplete (cut short?)"."""
    path = _mutate(tmp_path, model, lambda d: _rename(d, section, key, typo))
    with pytest.raises(ModelError) as err:
        load_model(path)
    msg = str(err.value)
    where = "" if section is None else f"{section}."
    assert f"unknown key '{where}{typo}' (did you mean '{where}{key}'?)" in msg and "cut short" not in msg, msg
    assert str(path) in msg and "\n" not in msg
    path.write_text(path.read_text().replace(f"{typo}:", f"{key}:"))        # the advice: rename it
    loaded, expected = load_model(path).to_dict(), model.to_dict()
    assert (loaded if section is None else loaded[section])[key] == (expected if section is None else expected[section])[key]


@pytest.mark.parametrize("stress_range, kind", [((-24.0, -11.3), "sdpi"), (None, "mpi")])
def test_a_missing_kind_is_named_with_the_kinds_and_adding_the_line_loads(tmp_path: Path, model: SDPIModel,
                                                                         stress_range, kind) -> None:
    """A file without `kind` was reported as "unknown model kind 'None'"."""
    model.stress_range_MPa = stress_range
    if stress_range is None:
        model.reference_stress_MPa = None
    path = _mutate(tmp_path, model, lambda d: d.pop("kind"))
    with pytest.raises(ModelError) as err:
        load_model(path)
    msg = str(err.value)
    assert "missing key 'kind'" in msg and "extended, mpi, sdpi" in msg and "None" not in msg, msg
    line = msg.split("add the line '")[1].rstrip("'")
    path.write_text(path.read_text() + line + "\n")                      # the advice: add that line
    assert load_model(path).kind == kind


@pytest.mark.parametrize("text", ["yes", "no", "true", "up", "'-1'"])
def test_an_output_sign_that_is_not_a_number_is_refused(tmp_path: Path, model: SDPIModel, text: str) -> None:
    """'output_sign: yes' was read as +1 (a YAML boolean is True, which Python takes for 1)."""
    path = _mutate(tmp_path, model, lambda d: None)
    path.write_text(path.read_text().replace("output_sign: 1", f"output_sign: {text}"))
    with pytest.raises(ModelError, match=r"output_sign must be \+1 .* or -1 .*, got") as err:
        load_model(path)
    assert str(path) in str(err.value)
    path.write_text(path.read_text().replace(f"output_sign: {text}", "output_sign: -1"))     # the advice: -1
    assert load_model(path).output_sign == -1


# ---- model files edited into what no command can run (mutated files, 2026-11-30) ---------------

def _extended_doc() -> dict:
    import gzip
    import json

    with gzip.open(Path(__file__).parent / "fixtures" / "extended_v1_all_blocks.json.gz", "rt") as fh:
        return json.load(fh)["model"]


@pytest.mark.parametrize("change, message", [
    (lambda d: d.update(effects=-1e30), "'effects' must be a list of effect names"),      # was a TypeError
    (lambda d: d["blocks"]["creep"].update(gain=-1e308), r"creep.gain must be a finite number within \+-1e\+30"),
    (lambda d: d["blocks"]["creep"].update(tau_s=True), "creep.tau_s must be a positive number"),  # read as 1 s
    (lambda d: d["blocks"]["delay"].update(delay_s=1e30), "delay.delay_s must be a number of seconds from 0 to 60"),
    (lambda d: d["base"].update(drive_range=[0.0, 1e308]), r"base: drive range holds 1e\+308"),
    (lambda d: d["base"].update(drive_name=0.0), "drive_name must be current_A or voltage_V"),  # was a KeyError
])
def test_an_extended_model_edited_past_what_runs_is_refused_in_one_line(tmp_path: Path, change, message,
                                                                       recwarn) -> None:
    """Each ran into a traceback, or into overflow warnings and inf before a refusal, or was read
    as something it is not."""
    d = _extended_doc()
    change(d)
    path = tmp_path / "ext.yaml"
    path.write_text(yaml.safe_dump(d))
    with pytest.raises(ModelError, match=message):
        load_model(path)
    assert [str(w.message) for w in recwarn] == []


def test_a_provenance_edited_into_other_types_is_no_record_and_no_overflow(model: SDPIModel, recwarn) -> None:
    """diagnose reads the provenance as a record, not as the model: a list edited into a number
    raised a TypeError, and a fit RMS of 1e308 overflowed when squared. Both are now not recorded."""
    from gma_ffc.diagnose.anchor import identification_loops
    from gma_ffc.diagnose.identification import recorded_files

    model.provenance = {"identification_files": 1e308, "recordings": "a.csv", "fit_rms_um": {"a.csv": 1e308}}
    assert recorded_files(model) == ([], [])
    assert all(np.isnan(err) for _, err in identification_loops(model))
    assert [str(w.message) for w in recwarn] == []
