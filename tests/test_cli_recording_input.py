"""A new user's recordings through the CLI (identify, simulate, invert): a stress column named
slightly wrong, a .mat stress of one value, and the columns simulate carries along. Each refusal
is one line, exit 2, and doing what it says gives the result asked for."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from gma_ffc.cli import main
from gma_ffc.modelio import load_model
from gma_ffc.recordings import Recording, read_recording, write_recording
from cli_workdir import make_cli_workdir


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_cli_workdir(tmp_path_factory.mktemp("cli_input"))


def _one_line_refusal(argv: list[str], capsys) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


def test_identify_refuses_a_stress_named_slightly_wrong_and_renamed_as_advised_fits_an_sdpi(workdir, capsys):
    """It fitted a stress-independent MPI (fit RMS 0.306 um against 0.092 um) with only a note."""
    misnamed = []
    for s in ("11.3", "15.2"):
        p = workdir / f"misnamed_{s}.csv"
        p.write_text((workdir / f"id_{s}.csv").read_text().replace(",stress_MPa,", ",Stress_MPa,"))
        misnamed.append(p)
    model = workdir / "misnamed.yaml"
    err = _one_line_refusal(["identify", *map(str, misnamed), "-o", str(model)], capsys)
    m = re.search(r"Stress_MPa: rename it (\w+) \(names are case-sensitive\)", err)
    assert m is not None and not model.exists(), err
    for p in misnamed:                                                        # done as advised
        p.write_text(p.read_text().replace(",Stress_MPa,", f",{m.group(1)},"))
    assert main(["identify", *map(str, misnamed), "-o", str(model)]) == 0
    assert "stress-independent" not in capsys.readouterr().err
    assert load_model(model).stress_range_MPa == pytest.approx((-15.2, -11.3))


def test_simulate_names_a_stress_in_kpa_with_its_factor_not_only_add_the_column(workdir, capsys):
    rec = read_recording(workdir / "id_15.2.csv")
    cols = {k: v for k, v in rec.columns.items() if k != "stress_MPa"}
    write_recording(workdir / "kpa.csv", Recording({**cols, "stress_kPa": rec.stress_MPa * 1000}, {}))
    out = workdir / "kpa_predicted.csv"
    argv = ["simulate", "--model", str(workdir / "model.yaml"), str(workdir / "kpa.csv"), "-o", str(out)]
    err = _one_line_refusal(argv, capsys)
    assert "stress_kPa is in kPa, gma-ffc reads MPa: divide it by 1000 into a column named stress_MPa" in err
    assert "pass --stress" not in err and not out.exists()
    write_recording(workdir / "kpa.csv", Recording({**cols, "stress_MPa": rec.stress_MPa}, {}))   # as advised
    assert main(argv) == 0
    np.testing.assert_array_equal(read_recording(out).stress_MPa, rec.stress_MPa)


def test_simulate_on_a_mat_stress_of_one_value_is_told_of_stress_and_passing_it_runs(workdir, capsys):
    import scipy.io

    rec = read_recording(workdir / "id_15.2.csv")
    cols = {k: v for k, v in rec.columns.items() if k != "stress_MPa"}
    scipy.io.savemat(workdir / "one.mat", {**cols, "stress_MPa": -15.2})
    out = workdir / "one_predicted.csv"
    argv = ["simulate", "--model", str(workdir / "model.yaml"), str(workdir / "one.mat"), "-o", str(out)]
    err = _one_line_refusal(argv, capsys)
    assert "variable 'stress_MPa' is a single value (-15.2)" in err and "no stress_MPa column" not in err
    option = re.search(r"leave it out and pass (--stress \S+)$", err.strip())
    assert option is not None, err
    scipy.io.savemat(workdir / "one.mat", cols)                              # left out, and the option passed
    assert main(argv + option.group(1).split()) == 0
    np.testing.assert_array_equal(read_recording(out).stress_MPa, -15.2)


def test_simulate_carries_the_inputs_other_columns_and_never_over_its_own(workdir):
    """The recording format: unknown columns are carried along. simulate dropped reference_um,
    force_N and temperature_C."""
    rec = read_recording(workdir / "id_19.1.csv")
    n = len(rec)
    extra = {"reference_um": np.linspace(0.0, 30.0, n), "force_N": np.full(n, 548.0),
             "temperature_C": np.linspace(21.0, 23.0, n), "measured_displacement_um": np.full(n, -1.0)}
    write_recording(workdir / "logged.csv", Recording({**rec.columns, **extra}, {}))
    out = workdir / "logged_predicted.csv"
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(workdir / "logged.csv"), "-o", str(out)]) == 0
    back = read_recording(out)
    for name in ("reference_um", "force_N", "temperature_C"):
        np.testing.assert_array_equal(back.columns[name], extra[name])
    np.testing.assert_array_equal(back.columns["measured_displacement_um"], rec.displacement_um)  # simulate's own
    assert not np.array_equal(back.displacement_um, rec.displacement_um)                          # the prediction
    assert list(back.columns)[:5] == ["time_s", "current_A", "stress_MPa", "displacement_um",
                                      "measured_displacement_um"]


def test_simulate_of_an_inverted_drive_keeps_the_reference_it_was_inverted_from(workdir):
    drive = workdir / "drive.csv"
    assert main(["invert", "--model", str(workdir / "model.yaml"), str(workdir / "ref.csv"), "-o", str(drive)]) == 0
    out = workdir / "drive_predicted.csv"
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(drive), "-o", str(out)]) == 0
    back = read_recording(out, require=("time_s", "drive", "reference_um"))
    np.testing.assert_array_equal(back.columns["reference_um"], read_recording(
        workdir / "ref.csv", require=("time_s", "reference_um")).columns["reference_um"])


def test_identify_on_a_hil_sim_folder_glob_names_the_manifest_and_the_advised_glob_fits(tmp_path, capsys):
    """`gma-ffc identify rec/* -o model.yaml` on a `hil_sim record` folder took in its manifest.yaml and
    said "column 'generator: python -m hil_sim record' has no unit". It now says the file is YAML, not
    a recording, and gives the glob that leaves it out; that glob fits a model."""
    from hil_sim.record import write_recordings

    rec = tmp_path / "rec"
    write_recordings("identification", rec, effects=["noise"], stresses=[-11.3, -19.1])
    everything = sorted(str(p) for p in rec.iterdir())
    assert any(p.endswith("manifest.yaml") for p in everything)
    words = _one_line_refusal(["identify", *everything, "-o", str(tmp_path / "model.yaml")], capsys)
    assert "manifest.yaml is a YAML file, not a recording" in words, words
    advised = re.search(r"give (\S+)$", words).group(1)
    assert advised == str(rec / "*.csv")
    assert main(["identify", *map(str, sorted(Path(advised).parent.glob(Path(advised).name))),
                 "-o", str(tmp_path / "model.yaml")]) == 0
    assert load_model(tmp_path / "model.yaml").kind == "sdpi"


def test_identify_on_a_telemetry_folder_glob_names_the_lock_file_and_the_folder(workdir, tmp_path, capsys):
    """A controller leaves NAME.csv.lock (its pid) beside its telemetry, and now its background
    diagnoses' folder: `gma-ffc identify telemetry/*` said "column '8096' has no unit" of the lock
    and "cannot read ([Errno 21] Is a directory ...)" of the folder. Each is named for what it is,
    with the glob that leaves it out; that glob reads."""
    tel = tmp_path / "telemetry"
    (tel / "diagnoses").mkdir(parents=True)
    for name in ("id_15.2.csv", "id_19.1.csv"):
        (tel / name).write_bytes((workdir / name).read_bytes())
    (tel / "id_15.2.csv.lock").write_text("8096\n")
    out = str(tmp_path / "model.yaml")
    words = _one_line_refusal(["identify", str(tel / "id_15.2.csv.lock"), str(tel / "id_19.1.csv"), "-o", out], capsys)
    assert "is a controller's telemetry lock file" in words and words.rstrip().endswith(f"give {tel / '*.csv'}"), words
    words = _one_line_refusal(["identify", str(tel / "diagnoses"), str(tel / "id_19.1.csv"), "-o", out], capsys)
    assert f"{tel / 'diagnoses'} is a folder, not a recording" in words, words
    assert main(["identify", *map(str, sorted(tel.glob("*.csv"))), "-o", out]) == 0
