"""Inputs every command refuses in one line, exit 2 (docs/cli.md): non-finite cells and option values,
model files with non-finite offsets, a recording given twice."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gma_ffc.cli import main
from gma_ffc.recordings import Recording, read_recording, write_recording
from cli_workdir import STRESSES, make_cli_workdir


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("cells")
    return make_cli_workdir(d)


def _one_line_exit_2(argv: list[str], capsys, *words: str) -> str:
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:       # argparse's own refusals
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and "internal error" not in err and "Warning" not in err, err
    for word in words:
        assert word in err, err
    return err


def _with_cell(src: Path, dst: Path, column: str, row: int, text: str) -> int:
    """`src` with the cell (row `row` of the data, `column`) replaced by `text`; the cell's line number."""
    lines = src.read_text().splitlines(keepends=True)
    header = next(k for k, ln in enumerate(lines) if not ln.startswith("#"))
    col = lines[header].strip().split(",").index(column)
    cells = lines[header + 1 + row].rstrip("\n").split(",")
    cells[col] = text
    lines[header + 1 + row] = ",".join(cells) + "\n"
    dst.write_text("".join(lines))
    return header + 2 + row


@pytest.mark.parametrize("cell", ["nan", "inf", "-inf"])
def test_a_non_finite_stress_cell_is_refused_by_every_command_naming_file_and_line(workdir: Path, capsys, cell) -> None:
    bad = workdir / f"stress_{cell}.csv"
    line = _with_cell(workdir / "id_15.2.csv", bad, "stress_MPa", 99, cell)
    badref = workdir / f"ref_{cell}.csv"
    refline = _with_cell(workdir / "ref.csv", badref, "stress_MPa", 5, cell)
    others = [str(workdir / "id_11.3.csv"), str(workdir / "id_24.0.csv")]
    model, out = str(workdir / "model.yaml"), str(workdir / f"never_{cell}.csv")
    where = (f"{bad}, line {line}", "stress_MPa")
    _one_line_exit_2(["identify", str(bad), *others, "-o", str(workdir / "never.yaml")], capsys, *where)
    _one_line_exit_2(["identify", str(bad), "-o", str(workdir / "never.yaml")], capsys, *where)
    _one_line_exit_2(["simulate", "--model", model, str(bad), "-o", out], capsys, *where)
    _one_line_exit_2(["diagnose", "--model", model, str(bad), "--out", str(workdir / "never")], capsys, *where)
    _one_line_exit_2(["invert", "--model", model, str(badref), "-o", out], capsys, f"{badref}, line {refline}")
    assert not Path(out).exists() and not (workdir / "never.yaml").exists()
    # the advice: put the stress at that time in the cell
    _with_cell(bad, bad, "stress_MPa", 99, "-15.2")
    assert main(["simulate", "--model", model, str(bad), "-o", out]) == 0


@pytest.mark.parametrize("cell", ["nan", "inf"])
def test_simulate_refuses_a_non_finite_measured_displacement_and_writes_no_nan(workdir: Path, capsys, cell) -> None:
    bad = workdir / f"disp_{cell}.csv"
    line = _with_cell(workdir / "id_15.2.csv", bad, "displacement_um", 40, cell)
    out = workdir / f"sim_{cell}.csv"
    _one_line_exit_2(["simulate", "--model", str(workdir / "model.yaml"), str(bad), "-o", str(out)], capsys,
                     f"{bad}, line {line}", "displacement_um", "leave the column out")
    assert not out.exists()
    # the advice: leave the column out to predict without a comparison
    rec = read_recording(bad, require=("time_s", "drive"))
    dropped = workdir / f"nodisp_{cell}.csv"
    write_recording(dropped, Recording({k: v for k, v in rec.columns.items() if k != "displacement_um"}))
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(dropped), "-o", str(out)]) == 0
    assert np.isfinite(read_recording(out).displacement_um).all()


@pytest.mark.parametrize("shift, scale, warned", [(0.0, 1.0, False), (0.0, 4.7 / 3.0, True), (-1.5, 1.0, True)])
def test_simulate_warns_when_the_drive_leaves_the_identified_range(workdir: Path, capsys, shift, scale, warned) -> None:
    rec = read_recording(workdir / "id_15.2.csv")
    cols = dict(rec.columns)
    cols["current_A"] = cols["current_A"] * scale + shift
    path = workdir / f"drive_{shift}_{scale:.3f}.csv"
    write_recording(path, Recording(cols))
    capsys.readouterr()
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(path), "-o", str(path.with_suffix(".out.csv"))]) == 0
    err = capsys.readouterr().err
    assert ("leaves the range the model was identified on" in err) == warned, err
    if warned:
        assert err.startswith(f"warning: {path}: the drive") and "extrapolation" in err


@pytest.mark.parametrize("limit", [["nan", "3"], ["0", "nan"], ["0", "inf"], ["-1", "inf"]])
def test_invert_refuses_a_non_finite_limit_at_parsing(workdir: Path, capsys, limit) -> None:
    out = workdir / "drive_limit.csv"
    _one_line_exit_2(["invert", "--model", str(workdir / "model.yaml"), str(workdir / "ref.csv"), "-o", str(out),
                      "--limit", *limit], capsys, "--limit", "is not a finite number")
    assert not out.exists()


@pytest.mark.parametrize("key", ["input_offset", "reference_stress_MPa"])
@pytest.mark.parametrize("value", [".nan", ".inf", "-.inf"])
def test_a_model_with_a_non_finite_offset_or_reference_stress_is_refused_on_load(workdir: Path, capsys, key,
                                                                                   value) -> None:
    text = (workdir / "model.yaml").read_text()
    lines = [f"{key}: {value}" if ln.startswith(f"{key}:") else ln for ln in text.splitlines()]
    bad = workdir / f"bad_{key}{value}.yaml"
    bad.write_text("\n".join(lines) + "\n")
    out = workdir / f"bad_{key}{value}.csv"
    for argv in (["invert", "--model", str(bad), str(workdir / "ref.csv")],
                 ["simulate", "--model", str(bad), str(workdir / "id_15.2.csv")]):
        _one_line_exit_2([*argv, "-o", str(out)], capsys, str(bad), f"{key} must be a finite number")
    assert not out.exists()


@pytest.mark.parametrize("value, message", [("nan", "is not a finite number"), ("inf", "is not a finite number"),
                                            ("-50", "outside the recordings' stresses"),
                                            ("5", "outside the recordings' stresses")])
def test_identify_refuses_a_reference_stress_the_recordings_were_not_at(workdir: Path, capsys, value, message) -> None:
    ids = [str(workdir / f"id_{-s}.csv") for s in STRESSES]
    out = workdir / f"ref_stress_{value}.yaml"
    err = _one_line_exit_2(["identify", *ids, "-o", str(out), f"--reference-stress={value}"], capsys, message)
    assert not out.exists()
    if "outside" in err:    # the advice: a value inside the range named (its ends, as shown)
        lo, hi = (float(v) for v in err.split("stresses (")[1].split(" MPa")[0].split(".."))
        for ref in (lo, hi):
            assert main(["identify", *ids, "-o", str(out), f"--reference-stress={ref}"]) == 0
            out.unlink()


def test_identify_writes_a_reference_stress_inside_the_models_stress_range(workdir: Path) -> None:
    """Stress levels are binned to 0.5 MPa: the most compressive level of data reaching -24.3 MPa is
    -24.5, which was written as the reference stress, outside the file's own stress range."""
    ids = []
    for s in STRESSES:
        rec = read_recording(workdir / f"id_{-s}.csv")
        path = workdir / f"id_deep_{-s}.csv"
        write_recording(path, Recording({**rec.columns, "stress_MPa": rec.stress_MPa - 0.3}))
        ids.append(str(path))
    out = workdir / "deep_ref.yaml"
    assert main(["identify", *ids, "-o", str(out), "--reference-stress=-24.3"]) == 0
    from gma_ffc.modelio import load_model

    model = load_model(out)
    lo, hi = model.stress_range_MPa
    assert lo <= model.reference_stress_MPa <= hi and abs(model.reference_stress_MPa + 24.3) < 0.26


def test_identify_at_one_stress_names_the_datas_stress_not_its_bin(workdir: Path, capsys) -> None:
    rec = read_recording(workdir / "id_15.2.csv")
    path = workdir / "at_15.32.csv"
    write_recording(path, Recording({**rec.columns, "stress_MPa": np.full(len(rec), -15.32)}))
    capsys.readouterr()
    assert main(["identify", str(path), "-o", str(workdir / "at_15.32.yaml")]) == 0
    assert "at one stress (median -15.32 MPa)" in capsys.readouterr().err


def test_a_recording_given_twice_is_refused_naming_both(workdir: Path, capsys) -> None:
    """By path, through another path to the same file, or as a copy: in diagnose a copy kept each
    'left-out' recording in the fit, and changed the verdict."""
    a, b, c = (str(workdir / f"id_{-s}.csv") for s in STRESSES[1:])
    copy = workdir / "copy_of_15.2.csv"
    copy.write_bytes(Path(a).read_bytes())
    dotted = f"{workdir}/./{Path(a).name}"
    model, out = str(workdir / "model.yaml"), workdir / "twice.yaml"
    for argv, both in ((["identify", a, b, a], (f"{a} is given twice",)),
                       (["identify", a, b, str(copy)], (a, str(copy), "same content")),
                       (["identify", a, dotted, b], (a, dotted, "same file"))):
        _one_line_exit_2([*argv, "-o", str(out)], capsys, *both, "give each recording once")
    for argv in ([a, b, a], [a, b, "--ident", str(copy), c], [a, b, "--ident", c, c]):
        _one_line_exit_2(["diagnose", "--model", model, *argv, "--out", str(workdir / "twice")], capsys,
                         "give each recording once")
    assert not out.exists() and not (workdir / "twice").exists()
    assert main(["identify", a, b, c, "-o", str(out)]) == 0        # the advice: each once


def test_an_overload_value_in_a_reference_is_refused_by_invert_and_removing_its_row_works(workdir: Path,
                                                                                          capsys) -> None:
    """One reference_um row at a sensor's overload value (9.9e37) was inverted into a drive sample of
    5.8e36 A, exit 0; a reference times 1e100 never finished."""
    bad = workdir / "ref_overload.csv"
    line = _with_cell(workdir / "ref.csv", bad, "reference_um", 300, "9.9e37")
    out = workdir / "drive_overload.csv"
    model = str(workdir / "model.yaml")
    _one_line_exit_2(["invert", "--model", model, str(bad), "-o", str(out)], capsys,
                     f"{bad}, line {line}", "'reference_um' is 9.9e+37", "remove that row")
    scaled = workdir / "ref_e100.csv"
    rec = read_recording(workdir / "ref.csv", require=("time_s", "reference_um"))
    write_recording(scaled, Recording({**rec.columns, "reference_um": rec.columns["reference_um"] * 1e100}))
    _one_line_exit_2(["invert", "--model", model, str(scaled), "-o", str(out)], capsys, str(scaled), "reference_um",
                     "convert the column")
    assert not out.exists()
    # the advice: remove that row
    lines = bad.read_text().splitlines(keepends=True)
    bad.write_text("".join(lines[:line - 1] + lines[line:]))
    assert main(["invert", "--model", model, str(bad), "-o", str(out)]) == 0
    assert np.abs(read_recording(out, require=("time_s", "drive")).drive).max() < 10


@pytest.mark.parametrize("column", ["displacement_um", "current_A"])
def test_a_column_of_absurd_magnitude_is_refused_by_every_command_and_converting_it_works(workdir: Path, capsys,
                                                                                         column) -> None:
    """A column times 1e300 got through reading: simulate printed 'RMS vs measured inf um' and dozens
    of numpy warnings, identify and diagnose stopped on internal errors."""
    rec = read_recording(workdir / "id_15.2.csv")
    bad = workdir / f"huge_{column}.csv"
    logged = rec.columns[column] * 1e300
    write_recording(bad, Recording({**rec.columns, column: logged}, dict(rec.metadata)))
    model, out = str(workdir / "model.yaml"), workdir / f"huge_{column}.out.csv"
    words = (str(bad), f"'{column}'", "beyond any physical", "convert the column")
    _one_line_exit_2(["identify", str(bad), "-o", str(workdir / "never.yaml")], capsys, *words)
    _one_line_exit_2(["simulate", "--model", model, str(bad), "-o", str(out)], capsys, *words)
    _one_line_exit_2(["diagnose", "--model", model, str(bad), "--out", str(workdir / "never")], capsys, *words)
    assert not out.exists() and not (workdir / "never.yaml").exists()
    # the advice: convert the column (here, undo the logger's scaling)
    write_recording(bad, Recording({**rec.columns, column: logged / 1e300}))
    assert main(["simulate", "--model", model, str(bad), "-o", str(out)]) == 0


@pytest.mark.parametrize("samples", [2, 3, 4])
def test_diagnose_refuses_a_recording_of_a_few_samples_in_one_line(workdir: Path, capsys, samples) -> None:
    """A recording of 2-4 samples stopped diagnose on an internal IndexError (locate's smoothing
    window is 5 samples); identify already refused it ('only 3 samples; ... needs at least N')."""
    rec = read_recording(workdir / "id_15.2.csv")
    short = workdir / f"short{samples}.csv"
    write_recording(short, rec.rows(np.arange(len(rec)) < samples))
    _one_line_exit_2(["diagnose", "--model", str(workdir / "model.yaml"), str(short), str(workdir / "id_19.1.csv"),
                      "--out", str(workdir / "never")], capsys, str(short), f"only {samples} samples", "needs at least 5",
                     "record at least")
    assert not (workdir / "never").exists()


def test_diagnose_refuses_a_constant_displacement_as_identify_does(workdir: Path, capsys) -> None:
    """A flat displacement column was diagnosed (exit 0, 'held-out RMS 30.11 -> 30.11 um (noise floor
    0 um)', advice to record more cycles) where identify refuses it."""
    rec = read_recording(workdir / "id_15.2.csv")
    flat = workdir / "flat_displacement.csv"
    write_recording(flat, Recording({**rec.columns, "displacement_um": np.full(len(rec), 5.0)}))
    words = ("the displacement is constant",)
    _one_line_exit_2(["identify", str(flat), "-o", str(workdir / "never.yaml")], capsys, *words, flat.name,
                     "never changes", "sensor is connected")
    _one_line_exit_2(["diagnose", "--model", str(workdir / "model.yaml"), str(flat), "--out", str(workdir / "never")],
                     capsys, str(flat), *words, "never changes", "sensor is connected")
    assert not (workdir / "never").exists()


def test_a_recording_saved_again_differently_is_refused_as_given_twice(workdir: Path, capsys) -> None:
    """The same rows with CRLF line endings, or with the columns in another order, were accepted twice
    by identify and diagnose, where a byte copy is refused (docs/cli.md: a copy counts twice)."""
    a, b = (str(workdir / f"id_{-s}.csv") for s in STRESSES[1:3])
    crlf = workdir / "crlf_of_15.2.csv"
    crlf.write_bytes(Path(a).read_bytes().replace(b"\n", b"\r\n"))
    rec = read_recording(a)
    reordered = workdir / "reordered_of_15.2.csv"
    write_recording(reordered, Recording({k: rec.columns[k] for k in reversed(list(rec.columns))}, {"note": "resaved"}))
    model, out = str(workdir / "model.yaml"), workdir / "resaved.yaml"
    for copy in (crlf, reordered):
        words = (a, str(copy), "same rows", "give each recording once")
        _one_line_exit_2(["identify", a, b, str(copy), "-o", str(out)], capsys, *words)
        _one_line_exit_2(["diagnose", "--model", model, a, str(copy), "--out", str(workdir / "resaved")], capsys, *words)
    assert not out.exists() and not (workdir / "resaved").exists()
    assert main(["identify", str(crlf), b, "-o", str(out)]) == 0        # the advice: each once


def test_a_recording_with_both_drive_columns_is_refused_and_dropping_one_works(workdir: Path, capsys) -> None:
    """A recording with current_A and voltage_V was read with current_A, silently."""
    rec = read_recording(workdir / "id_15.2.csv")
    both = workdir / "both_drives.csv"
    write_recording(both, Recording({**rec.columns, "voltage_V": 4.0 * rec.drive}))
    model, out = str(workdir / "model.yaml"), workdir / "both_drives.out.csv"
    words = (str(both), "current_A", "voltage_V", "drop the column")
    _one_line_exit_2(["simulate", "--model", model, str(both), "-o", str(out)], capsys, *words)
    _one_line_exit_2(["identify", str(both), "-o", str(workdir / "never.yaml")], capsys, *words)
    assert not out.exists()
    write_recording(both, Recording({k: v for k, v in rec.columns.items()}))    # the advice: voltage_V dropped
    assert main(["simulate", "--model", model, str(both), "-o", str(out)]) == 0


@pytest.mark.parametrize("command", ["simulate", "invert", "diagnose"])
def test_an_initial_drive_far_outside_the_models_range_is_refused_naming_the_range(workdir: Path, capsys,
                                                                                   command) -> None:
    """--initial-state drive:1e300 was accepted."""
    model = str(workdir / "model.yaml")
    given = str(workdir / ("ref.csv" if command == "invert" else "id_15.2.csv"))
    out = ["--out", str(workdir / "never")] if command == "diagnose" else ["-o", str(workdir / "never.csv")]
    err = _one_line_exit_2([command, "--model", model, given, *out, "--initial-state", "drive:1e300"], capsys,
                           "--initial-state drive:1e+300", "outside the drive range", "give a drive from")
    lo, hi = (float(v) for v in err.split("give a drive from ")[1].split(" A")[0].split(" to "))
    assert lo < 0.0 < 3.0 < hi
    if command == "simulate":           # the advice: a drive in the range named
        for drive in (lo, hi):
            assert main([command, "--model", model, given, *out, f"--initial-state=drive:{drive!r}"]) == 0


def test_a_stress_option_of_the_wrong_sign_is_answered_with_the_option_and_following_it_works(workdir: Path,
                                                                                              capsys) -> None:
    """--stress 15 on a recording without stress_MPa was answered 'negate the stress_MPa column'."""
    rec = read_recording(workdir / "id_15.2.csv")
    nostress = workdir / "no_stress_column.csv"
    write_recording(nostress, Recording({k: v for k, v in rec.columns.items() if k != "stress_MPa"}))
    model, out = str(workdir / "model.yaml"), workdir / "no_stress_column.out.csv"
    for command, given in (("simulate", nostress), ("invert", workdir / "ref.csv")):
        err = _one_line_exit_2([command, "--model", model, str(given), "-o", str(out), "--stress", "15"], capsys,
                               "--stress 15 MPa is outside", "pass --stress -15")
        assert "stress_MPa column" not in err
    _one_line_exit_2(["simulate", "--model", model, str(nostress), "-o", str(out), "--stress", "-40"], capsys,
                     "--stress -40 MPa is outside", "pass a --stress from")
    assert not out.exists()
    assert main(["simulate", "--model", model, str(nostress), "-o", str(out), "--stress", "-15"]) == 0   # as advised


def test_identify_names_a_mix_of_drives_before_a_mix_of_stress_columns(workdir: Path, capsys) -> None:
    """A voltage recording without stress beside a current one with stress was told 'give all or none
    a stress column'; given one, it was then told 'recordings mix drives'."""
    rec = read_recording(workdir / "id_15.2.csv")
    volts = workdir / "volts_no_stress.csv"
    write_recording(volts, Recording({"time_s": rec.time_s, "voltage_V": 50.0 * rec.drive,
                                      "displacement_um": rec.displacement_um}))
    out = workdir / "mixed.yaml"
    _one_line_exit_2(["identify", str(workdir / "id_15.2.csv"), str(volts), "-o", str(out)], capsys,
                     "recordings mix drives", "identify one kind at a time")
    assert not out.exists()
    assert main(["identify", str(volts), "-o", str(out)]) == 0      # the advice: one kind at a time
