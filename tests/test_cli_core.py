"""`gma-ffc identify | simulate | invert` end to end, and the CLI contract for bad input."""

from __future__ import annotations

import os
import re
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gma_ffc.cli import main
from gma_ffc.model import rms
from gma_ffc.model_reach import model_reach_um
from gma_ffc.modelio import load_model
from gma_ffc.recordings import Recording, read_recording, write_recording
from cli_workdir import STRESSES, make_cli_workdir
from preisach import PreisachActuator


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("cli")
    return make_cli_workdir(d, "--plot", str(d / "loops.png"))


def test_identify_writes_a_model_and_a_plot_and_reports_the_fit(workdir: Path, capsys) -> None:
    model = load_model(workdir / "model.yaml")
    assert model.kind == "sdpi" and model.stress_range_MPa == (-24.0, -11.3)
    assert (workdir / "loops.png").read_bytes()[:4] == b"\x89PNG"
    assert main(["identify", str(workdir / "id_15.2.csv"), "-o", str(workdir / "mpi.yaml"), "--plays", "6"]) == 0
    out = capsys.readouterr()
    assert "MPI model, 6 plays" in out.out and "% stroke" in out.out and "one stress" in out.err


def test_identify_names_runs_zeroed_apart_and_fits_them_with_zero_per_recording(workdir: Path, capsys) -> None:
    moved = []
    for k, s in enumerate(STRESSES):
        rec = read_recording(workdir / f"id_{-s}.csv")
        cols = dict(rec.columns)
        cols["displacement_um"] = cols["displacement_um"] + (2.0 if k % 2 else 0.0)
        path = workdir / f"zeroed_{-s}.csv"
        write_recording(path, Recording(cols, dict(rec.metadata)))
        moved.append(str(path))
    capsys.readouterr()
    assert main(["identify", *moved, "-o", str(workdir / "zeroed_shared.yaml")]) == 0
    assert "--zero per-recording" in capsys.readouterr().err
    assert main(["identify", *moved, "-o", str(workdir / "zeroed_own.yaml"), "--zero", "per-recording"]) == 0
    err = capsys.readouterr().err
    assert "fitted on its own" in err and "sit off the model" not in err
    assert load_model(workdir / "zeroed_own.yaml").provenance["zero_shifts_um"]


def test_simulate_output_is_a_recording_that_matches_the_measurement(workdir: Path) -> None:
    out = workdir / "sim.csv"
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(workdir / "id_19.1.csv"), "-o", str(out)]) == 0
    sim, rec = read_recording(out), read_recording(workdir / "id_19.1.csv")
    np.testing.assert_allclose(sim.time_s, rec.time_s)
    np.testing.assert_allclose(sim.stress_MPa, rec.stress_MPa)
    assert rms(sim.displacement_um[200:] - rec.displacement_um[200:]) < 0.01 * np.ptp(rec.displacement_um)


def test_invert_then_simulate_follows_the_reference(workdir: Path) -> None:
    drive = workdir / "drive.csv"
    assert main(["invert", "--model", str(workdir / "model.yaml"), str(workdir / "ref.csv"), "-o", str(drive),
                 "--limit", "0", "3"]) == 0
    d = read_recording(drive, require=("time_s", "drive"))
    assert d.drive.min() >= 0 and d.drive.max() <= 3
    model = load_model(workdir / "model.yaml")
    y = model.simulate(d.time_s, d.drive, -17.0)          # the shared default start, from sample 0
    assert rms(y - d.columns["reference_um"]) < 1e-6
    # and on the independent rig (not the model) it tracks within a few percent of the stroke
    rig_y = PreisachActuator().run(d.drive, -17.0)
    assert rms(rig_y[200:] - d.columns["reference_um"][200:]) < 0.02 * 24.0


def test_invert_beyond_reach_names_the_limit_to_add_and_that_limit_keeps_the_drive_inside(workdir: Path, capsys) -> None:
    """A reference beyond the identified stroke: the warning said 'consider --limit', which alone is
    refused (the option takes two numbers). It names the two, and with them the drive stays inside."""
    ref = read_recording(workdir / "ref.csv", require=("time_s",))
    far = workdir / "ref_far.csv"
    write_recording(far, Recording({**ref.columns, "reference_um": 2.0 * ref.columns["reference_um"]}, {}))
    out = workdir / "drive_far.csv"
    assert main(["invert", "--model", str(workdir / "model.yaml"), str(far), "-o", str(out)]) == 0
    m = re.search(r"add --limit (\S+) (\S+) to clip the drive", capsys.readouterr().err)
    assert m is not None
    assert main(["invert", "--model", str(workdir / "model.yaml"), str(far), "-o", str(out),
                 "--limit", m.group(1), m.group(2)]) == 0
    assert "leaves the identified range" not in capsys.readouterr().err
    d = read_recording(out, require=("time_s", "drive")).drive
    assert d.min() >= float(m.group(1)) - 1e-9 and d.max() <= float(m.group(2)) + 1e-9


def test_invert_initial_drive_starts_relaxed_at_that_drive_as_its_help_says(workdir: Path, capsys) -> None:
    """--initial-drive A is --initial-state drive:A; it started from the model file's stepper rule
    (descending: every play A + r), while saying 'relaxed'."""
    outs = {}
    for flags in (["--initial-drive", "1.2"], ["--initial-state", "drive:1.2"]):
        out = workdir / f"drive_{flags[0].strip('-')}.csv"
        assert main(["invert", "--model", str(workdir / "model.yaml"), str(workdir / "ref.csv"), "-o", str(out),
                     *flags]) == 0
        assert "initial state: relaxed at drive 1.2\n" in capsys.readouterr().out
        outs[flags[0]] = read_recording(out, require=("time_s", "drive")).drive
    np.testing.assert_array_equal(outs["--initial-drive"], outs["--initial-state"])
    model = load_model(workdir / "model.yaml")
    descending = model.invert(None, read_recording(workdir / "ref.csv", require=("time_s",)).columns["reference_um"],
                              -17.0, initial_drive=1.2)
    assert np.max(np.abs(descending - outs["--initial-drive"])) > 1e-3      # the two rules differ here


def test_invert_refuses_start_options_an_extended_model_does_not_take(workdir: Path, capsys) -> None:
    import gzip
    import json

    from gma_ffc.modelio import model_from_dict, save_model

    fixture = Path(__file__).parent / "fixtures" / "extended_v1_all_blocks.json.gz"
    with gzip.open(fixture, "rt") as fh:
        save_model(model_from_dict(json.load(fh)["model"]), workdir / "extended.yaml")
    for flags in (["--initial-drive", "0.5"], ["--initial-state", "relaxed"]):
        assert main(["invert", "--model", str(workdir / "extended.yaml"), str(workdir / "ref.csv"), "-o",
                     str(workdir / "x.csv"), *flags]) == 2
        err = capsys.readouterr().err
        assert "apply to sdpi and mpi models" in err and err.count("\n") == 1
    assert not (workdir / "x.csv").exists()


@pytest.mark.parametrize("model_name, flags", [("extended.yaml", []), ("model.yaml", ["--initial-state", "drive:1.2"]),
                                                ("model.yaml", ["--initial-state", "relaxed"])])
def test_simulate_starts_an_inverted_drive_where_invert_did(workdir: Path, capsys, model_name, flags) -> None:
    """An extended model's inverse starts at rest at the low end of its range; simulate's default
    rule started the same drive elsewhere, 5.5 um off the reference at t = 0. The drive file now
    names its start, and simulate follows it: invert then simulate gives the reference back."""
    import gzip
    import json

    from gma_ffc.modelio import model_from_dict, save_model

    if model_name == "extended.yaml":
        fixture = Path(__file__).parent / "fixtures" / "extended_v1_all_blocks.json.gz"
        with gzip.open(fixture, "rt") as fh:
            save_model(model_from_dict(json.load(fh)["model"]), workdir / model_name)
    ref_file = workdir / "ref.csv"
    if model_name == "extended.yaml":    # beyond its reach the fixture's inverse runs away (the test below)
        ref_file = _followed_advice(workdir, capsys, workdir / model_name)
    drive, back = workdir / "round_drive.csv", workdir / "round_back.csv"
    assert main(["invert", "--model", str(workdir / model_name), str(ref_file), "-o", str(drive), *flags]) == 0
    assert main(["simulate", "--model", str(workdir / model_name), str(drive), "-o", str(back)]) == 0
    assert "(the start `gma-ffc invert` gave this drive, from the file's metadata)" in capsys.readouterr().out
    ref = read_recording(ref_file, require=("time_s",)).columns["reference_um"]
    y = read_recording(back, require=("time_s",)).displacement_um
    # the fixture's 2.5 ms delay puts its first and last samples out of reach, and its heating and
    # dynamics blocks invert to within 0.01 um of 18 (0.06 %); the base's inverse is exact
    edge, tol = (4, 0.02) if model_name == "extended.yaml" else (0, 1e-6)
    assert np.max(np.abs(y - ref)[edge:len(y) - edge]) < tol


def _followed_advice(workdir: Path, capsys, model_file: Path) -> Path:
    """invert on a reference its extended model cannot follow: one line, exit 2, no file, and advice
    with figures; the reference the advice describes (a 3 Hz sine from the rest output to 80 % of
    the stroke) is followed."""
    assert main(["invert", "--model", str(model_file), str(workdir / "ref.csv"), "-o", str(workdir / "run.csv")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "the inverse runs away from t = " in err and not (workdir / "run.csv").exists()
    rest = float(err.split("output at rest (")[1].split(" um")[0])
    top = float(err.split("drive range (about ")[1].split(" um")[0].split("..")[1])
    t = np.arange(0, 1.2, 1e-3)
    y = rest + 0.4 * (top - rest) * (1 - np.cos(2 * np.pi * 3 * t))
    path = workdir / "ref_within_reach.csv"
    write_recording(path, Recording({"time_s": t, "reference_um": y, "stress_MPa": np.full_like(t, -17.0)}))
    return path



def test_invert_refuses_a_drive_no_recording_may_hold_and_its_limit_advice_works(workdir: Path, capsys) -> None:
    """A reference a million times the model's stroke (a sensor's unit mixed up, as the fuzz drew it):
    the inverse asked for 1e7 A, finite, and was written, a file every command then refused to read
    (|current_A| up to 1e6 A). Now refused, one line, no file; the --limit it advises is then written."""
    t = np.arange(0, 0.5, 1e-3)
    ref = workdir / "ref_far.csv"
    write_recording(ref, Recording({"time_s": t, "reference_um": 1e8 * (1 - np.cos(2 * np.pi * 4 * t)),
                                    "stress_MPa": np.full_like(t, -17.0)}))
    out = workdir / "far_drive.csv"
    assert main(["invert", "--model", str(workdir / "model.yaml"), str(ref), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "x the most the model gives" in err and not out.exists()
    # a --limit too wide to clip anything lets the inverse through: its drive no file may hold is refused
    assert main(["invert", "--model", str(workdir / "model.yaml"), str(ref), "-o", str(out), "--limit", "-1e9", "1e9"]) == 2
    wide = capsys.readouterr().err
    assert wide.count("\n") == 1 and "past the 1e+06 A a recording may hold" in wide and not out.exists()
    limit = re.search(r"add --limit (\S+) (\S+)", err).groups()
    assert main(["invert", "--model", str(workdir / "model.yaml"), str(ref), "-o", str(out), "--limit", *limit]) == 0
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(out), "-o", str(workdir / "far_back.csv")]) == 0



def test_invert_refuses_a_reference_far_beyond_the_models_reach_as_the_controller_does(workdir: Path, capsys) -> None:
    """A reference 500x the model's stroke (nanometres typed as micrometres) was inverted to a drive
    of hundreds of amperes and written with exit 0 and a warning. Refused now, one line, no file,
    as the controller refuses it; twice the stroke is still extrapolation, warned of and written."""
    ref = read_recording(workdir / "ref.csv", require=("time_s",))
    model = load_model(workdir / "model.yaml")
    reach = model_reach_um(model)
    out = workdir / "drive_slip.csv"
    for factor, code in ((500.0, 2), (2.0, 0)):
        slip = workdir / f"ref_x{factor:g}.csv"
        peak = float(np.max(np.abs(ref.columns["reference_um"])))
        write_recording(slip, Recording({**ref.columns, "reference_um": factor * reach / peak * ref.columns["reference_um"]}, {}))
        assert main(["invert", "--model", str(workdir / "model.yaml"), str(slip), "-o", str(out)]) == code
        err = capsys.readouterr().err
        if code == 2:
            assert err.count("\n") == 1 and "500x the most the model gives" in err and not out.exists()
        else:
            assert "leaves the identified range" in err and out.exists()


def test_simulate_refuses_a_prediction_no_recording_may_hold(tmp_path: Path, capsys) -> None:
    """A model identified on a 1 mA drive (a stroke of 35 m in um, within the reader's bounds),
    simulated on a drive of 500 kA: the extrapolation reached 6e12 um and was written, a file every
    command then refused (|displacement_um| up to 1e9 um). Now refused, one line, no file."""
    t = np.arange(2000) / 1000.0
    drive = 1e-3 * 0.5 * (1 - np.cos(2 * np.pi * 5 * t))
    rig = PreisachActuator(drive_range=(0, 1e-3), n_grid=24, width_A=1e-4, width_spread=1e-4, noise_um=0.01, seed=1)
    write_recording(tmp_path / "ident.csv", Recording({"time_s": t, "current_A": drive,
                                                       "displacement_um": 1e6 * rig.run(drive, -15.0)}))
    write_recording(tmp_path / "far.csv", Recording({"time_s": t, "current_A": 5e8 * drive}))
    assert main(["identify", str(tmp_path / "ident.csv"), "-o", str(tmp_path / "m.yaml")]) == 0
    capsys.readouterr()
    out = tmp_path / "sim.csv"
    assert main(["simulate", "--model", str(tmp_path / "m.yaml"), str(tmp_path / "far.csv"), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "past the 1e+09 um a recording may hold" in err and not out.exists()
    assert "identify the model from recordings over the whole drive range used" in err


def _bad(workdir: Path, name: str, text: str) -> Path:
    p = workdir / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("argv_tail, message", [
    (["simulate", "--model", "{d}/model.yaml", "{d}/nocol.csv"], "missing drive column"),
    (["simulate", "--model", "{d}/model.yaml", "{d}/nan.csv"], "'current_A' is nan"),
    (["simulate", "--model", "{d}/model.yaml", "{d}/back.csv"], "time does not increase"),
    (["simulate", "--model", "{d}/garbage.yaml", "{d}/id_15.2.csv"], "not valid YAML"),
    (["simulate", "--model", "{d}/model.yaml", "{d}/id_15.2.csv", "--stress", "-40"], "outside the model's identified range"),
    (["simulate", "--model", "{d}/model.yaml", "{d}/nostress.csv"], "no stress_MPa column"),
    (["invert", "--model", "{d}/model.yaml", "{d}/id_15.2.csv"], "missing required column 'reference_um'"),
    (["identify", "{d}/nocol.csv"], "missing drive column"),
])
def test_bad_input_is_one_line_exit_2_and_no_output(workdir: Path, capsys, argv_tail, message) -> None:
    _bad(workdir, "nocol.csv", "time_s,displacement_um,stress_MPa\n0,0,-15\n1,1,-15\n")
    _bad(workdir, "nan.csv", "time_s,current_A,stress_MPa\n0,0,-15\n1,nan,-15\n")
    _bad(workdir, "back.csv", "time_s,current_A,stress_MPa\n0,0,-15\n1,1,-15\n0.5,1,-15\n")
    _bad(workdir, "nostress.csv", "time_s,current_A\n0,0\n1,1\n")
    _bad(workdir, "garbage.yaml", "format: [\n")
    out = workdir / "should_not_exist.csv"
    out_model = workdir / "should_not_exist.yaml"
    argv = [a.format(d=workdir) for a in argv_tail] + ["-o", str(out_model if argv_tail[0] == "identify" else out)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists() and not out_model.exists()
    assert not list(workdir.glob(".*.tmp"))


def test_console_script_usage_errors_exit_2_and_help_teaches() -> None:
    exe = [sys.executable, "-m", "gma_ffc.cli"]
    bad = subprocess.run(exe + ["identify"], capture_output=True, text=True)
    assert bad.returncode == 2 and "error:" in bad.stderr and "Traceback" not in bad.stderr
    helptext = subprocess.run(exe + ["identify", "--help"], capture_output=True, text=True)
    assert helptext.returncode == 0 and "example:" in helptext.stdout and "--plays" in helptext.stdout


def test_a_reader_that_closes_the_pipe_stops_the_command_quietly_with_its_files_written(workdir: Path) -> None:
    """`gma-ffc identify ... | head -1`: the reader closes stdout before the table is printed. That
    printed 'gma-ffc identify: error: : Broken pipe'; a Unix tool stops quietly, with the shell's
    141, and the model it had already written stays."""
    out = workdir / "piped.yaml"
    proc = subprocess.Popen([sys.executable, "-m", "gma_ffc.cli", "identify", *map(str, sorted(workdir.glob("id_*.csv"))),
                             "-o", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()                                   # the reader is gone before anything is printed
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141, err
    assert "error" not in err and "Traceback" not in err and "Exception ignored" not in err
    assert load_model(out).kind == "sdpi"


def test_an_output_path_that_cannot_be_written_is_one_line_exit_2(workdir: Path, capsys) -> None:
    out = "/proc/no-such-dir/out.csv"  # cannot be created, even as root
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(workdir / "id_15.2.csv"), "-o", out]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gma-ffc simulate: error: /proc/no-such-dir") and err.count("\n") == 1
    assert "Traceback" not in err


@pytest.mark.parametrize("command", ["simulate", "identify"])
def test_an_output_that_is_a_fifo_is_refused_before_the_work_and_left_alone(workdir: Path, capsys, command) -> None:
    """`-o /dev/null` as root replaced the device with a regular file and exited 0; a FIFO the same."""
    fifo = workdir / f"pipe_{command}"             # no extension, as /dev/null: what it is comes first
    os.mkfifo(fifo)
    rec = str(workdir / "id_15.2.csv")
    argv = ["simulate", "--model", str(workdir / "model.yaml"), rec] if command == "simulate" else ["identify", rec]
    assert main([*argv, "-o", str(fifo)]) == 2
    err = capsys.readouterr().err
    assert "is a FIFO (named pipe), not a regular file" in err and err.count("\n") == 1
    assert stat.S_ISFIFO(fifo.lstat().st_mode)


def test_simulate_through_a_symlink_writes_the_file_it_points_to(workdir: Path) -> None:
    (workdir / "through.csv").symlink_to("pointed_at.csv")
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(workdir / "id_15.2.csv"),
                 "-o", str(workdir / "through.csv")]) == 0
    assert (workdir / "through.csv").is_symlink() and len(read_recording(workdir / "pointed_at.csv")) == 1200


def test_a_full_disk_is_one_line_naming_the_output(workdir: Path, capsys, monkeypatch) -> None:
    """It said 'gma-ffc simulate: error: : No space left on device', naming no file."""
    import errno

    def no_space(fd: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    out = workdir / "full.csv"
    monkeypatch.setattr(os, "fsync", no_space)
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(workdir / "id_15.2.csv"), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"gma-ffc simulate: error: {out}: cannot write it: No space left on device")
    assert "free some space" in err and err.count("\n") == 1 and not out.exists()


@pytest.mark.parametrize("command, output, words", [
    ("simulate", "out.h5", "output recordings are written as .csv or .mat (what gma-ffc reads back), got '.h5'"),
    ("invert", "out.tdms", "got '.tdms'"),
    ("simulate", "-", "output -: recordings are written to a file, not to standard output"),
])
def test_an_output_it_cannot_read_back_is_refused(workdir: Path, capsys, monkeypatch, command, output, words) -> None:
    """`-o x.h5` wrote CSV text the HDF5 reader refused; `-o -` made a file named '-'."""
    monkeypatch.chdir(workdir)
    inp = "ref.csv" if command == "invert" else "id_15.2.csv"
    assert main([command, "--model", "model.yaml", inp, "-o", output]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1 and not (workdir / output).exists()


def test_a_plot_format_matplotlib_cannot_write_is_refused_before_the_fit(workdir: Path, capsys, monkeypatch) -> None:
    """`--plot loops.txt` fitted the whole model, then 'internal error: ValueError' and no model."""
    import gma_ffc.identify

    def no_fit(*args, **kwargs):
        raise AssertionError("the fit started")

    monkeypatch.setattr(gma_ffc.identify.SDPIIdentifier, "fit", no_fit)
    assert main(["identify", str(workdir / "id_15.2.csv"), "-o", str(workdir / "p.yaml"),
                 "--plot", str(workdir / "loops.txt")]) == 2
    err = capsys.readouterr().err
    assert f"--plot {workdir / 'loops.txt'}: cannot save a plot as .txt; name it {workdir / 'loops.png'}" in err
    assert ".pdf" in err and err.count("\n") == 1 and not (workdir / "p.yaml").exists()
    monkeypatch.chdir(workdir)                    # `--plot -` made a file named '-'
    assert main(["identify", "id_15.2.csv", "-o", "p.yaml", "--plot", "-"]) == 2
    assert "--plot -: plots are saved to a file, not to standard output" in capsys.readouterr().err
    assert not (workdir / "-").exists()


@pytest.mark.parametrize("content", [b"", b"MATLAB 5.0 MAT-file", "cut"])
def test_an_empty_or_cut_off_mat_file_is_one_line_naming_it(workdir: Path, capsys, tmp_path, content) -> None:
    """An empty .mat was 'internal error: MatReadError', a cut one 'internal error: IndexError'."""
    if content == "cut":
        write_recording(tmp_path / "whole.mat", read_recording(workdir / "id_15.2.csv"))
        content = (tmp_path / "whole.mat").read_bytes()[:100]
    bad = tmp_path / "bad.mat"
    bad.write_bytes(content)
    for argv in (["identify", str(bad), "-o", str(tmp_path / "m.yaml")],
                 ["simulate", "--model", str(workdir / "model.yaml"), str(bad), "-o", str(tmp_path / "o.csv")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"error: {bad}: " in err and "save it again from MATLAB" in err and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "whole.mat") == ["bad.mat"]


def test_a_dropout_in_time_is_noted_and_bridged_while_jitter_is_not(workdir: Path, capsys) -> None:
    """A logger that lost 50 ms: simulate still runs (per-sample steps), and says where the gap is,
    so a residual there is not read as physics. Timestamp jitter of a tenth of a step says nothing."""
    rec = read_recording(workdir / "id_19.1.csv")
    keep = (rec.time_s < 0.5) | (rec.time_s >= 0.55)
    gapped = Recording({k: v[keep] for k, v in rec.columns.items()}, dict(rec.metadata))
    write_recording(workdir / "gapped.csv", gapped)
    jitter = np.random.default_rng(1).uniform(-1e-4, 1e-4, len(rec))
    write_recording(workdir / "jitter.csv", Recording({**rec.columns, "time_s": rec.time_s + jitter}, {}))
    capsys.readouterr()
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(workdir / "gapped.csv"),
                 "-o", str(workdir / "gapped_sim.csv")]) == 0
    err = capsys.readouterr().err
    assert "1 gap(s) in time_s" in err and "t = 0.499 s" in err and "0.051 s" in err
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(workdir / "jitter.csv"),
                 "-o", str(workdir / "jitter_sim.csv")]) == 0
    assert "gap" not in capsys.readouterr().err


@pytest.mark.parametrize("option, bad", [("--plays", "0"), ("--deadzones", "0"), ("--deadzones", "4"),
                                         ("--deadzones", "-3")])
def test_an_operator_count_refused_names_the_option_and_its_advice_works(workdir: Path, capsys, option, bad) -> None:
    """The refusal names the option typed (not the identifier's `n_play`), and the number it
    suggests identifies a model."""
    out = workdir / f"counts_{option[2:]}_{bad}.yaml"
    argv = ["identify", str(workdir / "id_15.2.csv"), "-o", str(out)]
    with pytest.raises(SystemExit) as refused:         # argparse's own exit, as for every option it refuses
        main(argv + [option, bad])
    assert refused.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}:" in err and err.count("\n") == 1 and not out.exists()
    advice = re.search(r"try (\d+)", err)
    assert advice is not None
    assert main(argv + [option, advice.group(1)]) == 0
    counts = {"--plays": "n_play", "--deadzones": "n_deadzone"}
    assert getattr(load_model(out), counts[option]) == int(advice.group(1))


def test_stress_readings_beyond_the_range_by_noise_are_clamped_and_a_load_beyond_it_refused(workdir: Path, capsys):
    """A recording at the lightest identified load reads a little beyond that load's own extremes,
    by the load cell's noise: simulate runs it (clamped, and says so) and writes the readings as
    they were; a reading a whole load away is refused, saying by how much."""
    rec = read_recording(workdir / "id_11.3.csv")
    noise = np.random.default_rng(5).normal(0.0, 0.01, len(rec))          # a load cell's noise, 0.01 MPa
    cols = dict(rec.columns)
    cols["stress_MPa"] = -11.3 + noise - noise.max() + 0.02               # at most 0.02 MPa (2 sigma) above -11.3
    write_recording(workdir / "noisy_11.3.csv", Recording(cols, dict(rec.metadata)))
    out = workdir / "noisy_predicted.csv"
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(workdir / "noisy_11.3.csv"), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "outside the model's identified range" in err and "clamped into it" in err
    assert np.array_equal(read_recording(out).stress_MPa, read_recording(workdir / "noisy_11.3.csv").stress_MPa)
    cols["stress_MPa"] = cols["stress_MPa"] + 1.0                         # another load: 1 MPa lighter
    write_recording(workdir / "lighter.csv", Recording(cols, dict(rec.metadata)))
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(workdir / "lighter.csv"),
                 "-o", str(workdir / "lighter_predicted.csv")]) == 2
    err = capsys.readouterr().err
    assert "reaches 1 MPa outside the model's identified range" in err and err.count("\n") == 1
    assert not (workdir / "lighter_predicted.csv").exists()


def test_stress_readings_rung_beyond_the_range_by_the_loads_inertia_are_clamped(workdir: Path, capsys):
    """hil_sim's resonant rig, unloaded, on current steps: the load cell rings 0.11 MPa past the
    lightest identified load at each step, far beyond its noise. The plain model refused the run,
    advising recordings covering that stress, which no identification can give. The load's static
    stress stays at -11.3 MPa: the readings are its inertial force, clamped with a note."""
    rec = read_recording(workdir / "id_11.3.csv")
    t = rec.time_s
    noise = np.random.default_rng(6).normal(0.0, 0.002, len(rec))
    ring = np.zeros(len(rec))
    for t0 in t[::max(len(rec) // 4, 1)][1:]:                     # a step's ringing: 0.3 MPa, 150 Hz, 20 ms
        after = t >= t0
        ring[after] += 0.3 * np.exp(-(t[after] - t0) / 0.02) * np.sin(2 * np.pi * 150 * (t[after] - t0))
    cols = dict(rec.columns)
    cols["stress_MPa"] = -11.32 + noise + ring
    write_recording(workdir / "rung_11.3.csv", Recording(cols, dict(rec.metadata)))
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(workdir / "rung_11.3.csv"),
                 "-o", str(workdir / "rung_predicted.csv")]) == 0
    err = capsys.readouterr().err
    assert "inertial force" in err and "clamped into it" in err
    cols["stress_MPa"] = cols["stress_MPa"] + 1.0                 # the same ringing 1 MPa lighter: another load
    write_recording(workdir / "rung_lighter.csv", Recording(cols, dict(rec.metadata)))
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(workdir / "rung_lighter.csv"),
                 "-o", str(workdir / "rung_lighter_predicted.csv")]) == 2
    assert "outside the model's identified range" in capsys.readouterr().err


def test_python_dash_m_gma_ffc_is_the_command():
    """A user whose venv's bin is not on PATH runs `python -m gma_ffc`: the same parser, version and
    exit code as `gma-ffc` (it was 'No module named gma_ffc.__main__')."""
    from gma_ffc import __version__

    done = subprocess.run([sys.executable, "-m", "gma_ffc", "--version"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert __version__ in done.stdout
    bad = subprocess.run([sys.executable, "-m", "gma_ffc", "no-such-command"], capture_output=True, text=True,
                         timeout=120)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr


def test_an_extended_model_with_load_dynamics_runs_readings_beyond_the_range_by_noise(workdir: Path, capsys):
    """The plain model clamps stress readings beyond its range by the load cell's noise; the extended
    model diagnose writes (its load dynamics read the load cell) refused the same recording in
    simulate and invert ('stress ... outside the model's identified range'). It low-passes the
    readings to the load's static stress, so readings clamped by noise leave it within the range."""
    from gma_ffc.extended import ExtendedModel
    from gma_ffc.modelio import save_model

    dyn = {"form": "rod_load", "f_ref_hz": 500.0, "zeta": 0.05, "beta_per_MPa": 0.0, "stress_ref_MPa": -11.3,
           "stress_lowpass_hz": 1.0}
    save_model(ExtendedModel(load_model(workdir / "model.yaml"), {"dynamics": dyn}, ["mechanical_dynamics"]),
               workdir / "extended_dyn.yaml")
    rec = read_recording(workdir / "id_11.3.csv")
    noise = np.random.default_rng(6).normal(0.0, 0.01, len(rec))
    cols = dict(rec.columns)
    cols["stress_MPa"] = -11.3 + noise - noise.max() + 0.02               # at most 0.02 MPa above -11.3
    write_recording(workdir / "noisy_dyn.csv", Recording(cols, dict(rec.metadata)))
    ref = read_recording(workdir / "ref.csv", require=("time_s",))
    write_recording(workdir / "ref_noisy.csv", Recording({**ref.columns, "stress_MPa": cols["stress_MPa"]}, {}))
    for model in ("model.yaml", "extended_dyn.yaml"):
        capsys.readouterr()
        assert main(["simulate", "--model", str(workdir / model), str(workdir / "noisy_dyn.csv"),
                     "-o", str(workdir / f"noisy_dyn_{model}.csv")]) == 0, capsys.readouterr().err
        assert "clamped into it" in capsys.readouterr().err
        assert main(["invert", "--model", str(workdir / model), str(workdir / "ref_noisy.csv"),
                     "-o", str(workdir / f"drive_noisy_{model}.csv"), "--limit", "0", "3"]) == 0, \
            capsys.readouterr().err


@pytest.mark.parametrize("stress, says", [(-11.0, "reaches 0.3 MPa outside the model's identified range -24..-11.3 MPa"),
                                          (17.0, "negate the stress_MPa column")])
def test_invert_with_an_extended_model_refuses_a_stress_as_the_plain_model_does(workdir: Path, capsys, stress, says):
    """An extended model's invert said 'stress -11..-11 MPa is outside the model's range -24..-11.3 MPa'
    (three digits: it read as inside) with no advice, and for a load cell logging compression as
    positive did not say to negate it, as the plain model's invert does."""
    from gma_ffc.extended import ExtendedModel
    from gma_ffc.modelio import save_model

    save_model(ExtendedModel(load_model(workdir / "model.yaml"), {"creep": {"gain": 0.01, "tau_s": 3.0}}, ["creep"]),
               workdir / "extended_creep.yaml")
    ref = read_recording(workdir / "ref.csv", require=("time_s",))
    write_recording(workdir / "ref_off.csv", Recording({**ref.columns, "stress_MPa": np.full(len(ref), stress)}, {}))
    for model in ("model.yaml", "extended_creep.yaml"):
        capsys.readouterr()
        assert main(["invert", "--model", str(workdir / model), str(workdir / "ref_off.csv"),
                     "-o", str(workdir / "drive_off.csv")]) == 2
        err = capsys.readouterr().err
        assert says in err and err.count("\n") == 1, (model, err)


def test_a_drive_in_milliamperes_under_current_a_is_told_the_factor(workdir: Path, capsys, tmp_path):
    """Milliamperes logged under current_A (1000x the identified 0-3 A): simulate warned 'identify the
    model from recordings over the whole drive range used', advice no rig can follow (3000 A), and
    diagnose said to record inside the range or identify over these drives. Both now name the factor;
    divided by it, the recording runs without a warning."""
    rec = read_recording(workdir / "id_15.2.csv")
    write_recording(tmp_path / "mA.csv", Recording({**rec.columns, "current_A": rec.drive * 1000.0}, {}))
    capsys.readouterr()
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(tmp_path / "mA.csv"),
                 "-o", str(tmp_path / "mA_sim.csv")]) == 0
    err = capsys.readouterr().err
    assert "divide current_A by 1000" in err and "whole drive range used" not in err, err
    assert main(["diagnose", "--model", str(workdir / "model.yaml"), str(tmp_path / "mA.csv"),
                 "--out", str(tmp_path / "diag")]) == 2
    err = capsys.readouterr().err
    assert "divide current_A by 1000" in err and err.count("\n") == 1, err
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(workdir / "id_15.2.csv"),
                 "-o", str(tmp_path / "A_sim.csv")]) == 0
    assert "warning" not in capsys.readouterr().err


def test_a_model_and_a_recording_given_in_each_others_place_are_named_as_such(workdir: Path, capsys):
    """A model file given as the recording was refused as "column 'format: gma-ffc-model' has no
    unit", and a recording given to --model as "not a model file (expected a YAML mapping)": true,
    but neither said the two were swapped. Both now do; given in their places, simulate runs."""
    model, rec = str(workdir / "model.yaml"), str(workdir / "id_15.2.csv")
    out = str(workdir / "swapped.csv")
    assert main(["simulate", "--model", model, model, "-o", out]) == 2
    err = capsys.readouterr().err
    assert "is a gma-ffc model file, not a recording" in err and err.count("\n") == 1, err
    assert main(["simulate", "--model", rec, rec, "-o", out]) == 2
    err = capsys.readouterr().err
    assert "is a recording, not a model file" in err and "--model" in err and err.count("\n") == 1, err
    assert main(["simulate", "--model", model, rec, "-o", out]) == 0


def test_a_wrong_model_for_the_controller_is_named_without_advice_that_does_not_apply(workdir: Path, tmp_path, capsys):
    """`reload --model` on a background diagnosis' folder said "no such file" of a folder that is there,
    and a recording given as the controller's model was told to "give it in the recording's place",
    which reload and a config's 'model' key do not have. The folder's message names its
    extended_model.yaml, a file; the recording's names the config key."""
    from gma_ffc.errors import ModelError
    from gma_ffc.modelio import load_model

    diagnosis = tmp_path / "diagnoses" / "20261201-040000"
    diagnosis.mkdir(parents=True)
    (diagnosis / "extended_model.yaml").write_text((workdir / "model.yaml").read_text())
    runtime = str(tmp_path / "rt")
    assert main(["reload", "--model", str(diagnosis), "--runtime-dir", runtime]) == 2
    err = capsys.readouterr().err
    assert f"is a folder, not a model file: give {diagnosis / 'extended_model.yaml'}\n" in err, err
    advised = err.rsplit("give ", 1)[1].strip()
    assert load_model(advised).kind == load_model(workdir / "model.yaml").kind
    assert main(["reload", "--model", advised, "--runtime-dir", runtime]) == 1     # now only: nothing runs
    assert "no controller running" in capsys.readouterr().err
    with pytest.raises(ModelError) as exc:
        load_model(workdir / "id_15.2.csv")
    assert "recording's place" not in str(exc.value) and "a config's 'model' key" in str(exc.value)


def test_identify_names_a_recording_whose_displacement_is_in_another_unit(workdir: Path, capsys, tmp_path):
    """One identification recording's displacement logged in mm under displacement_um, beside others
    in um: identify said 'the displacement hardly follows the drive ... check that the columns are the
    drive and the displacement of one actuator', naming every file. It names the one, and the factor;
    multiplied by it, the recordings identify."""
    rec = read_recording(workdir / "id_19.1.csv")
    write_recording(tmp_path / "in_mm.csv", Recording({**rec.columns, "displacement_um": rec.displacement_um / 1000},
                                                      {}))
    argv = ["identify", str(workdir / "id_11.3.csv"), str(workdir / "id_15.2.csv"), str(tmp_path / "in_mm.csv"),
            "-o", str(tmp_path / "m.yaml")]
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "in_mm.csv" in err and "id_11.3.csv" not in err.split(":")[1] and "multiply displacement_um by 1000" in err
    assert err.count("\n") == 1 and not (tmp_path / "m.yaml").exists()
    write_recording(tmp_path / "in_mm.csv", Recording(dict(rec.columns), {}))
    assert main(argv) == 0


def test_simulate_warns_of_a_measured_displacement_in_another_unit(workdir: Path, capsys, tmp_path):
    """simulate of a recording whose displacement is in mm under displacement_um printed 'RMS vs
    measured 32.97 um' and nothing else: the comparison is meaningless, and the factor is named."""
    rec = read_recording(workdir / "id_15.2.csv")
    write_recording(tmp_path / "in_mm.csv", Recording({**rec.columns, "displacement_um": rec.displacement_um / 1000},
                                                      {}))
    capsys.readouterr()
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(tmp_path / "in_mm.csv"),
                 "-o", str(tmp_path / "p.csv")]) == 0
    err = capsys.readouterr().err
    assert "warning:" in err and "multiply displacement_um by 1000" in err, err
    assert main(["simulate", "--model", str(workdir / "model.yaml"), str(workdir / "id_15.2.csv"),
                 "-o", str(tmp_path / "p.csv")]) == 0
    assert "warning" not in capsys.readouterr().err


@pytest.mark.parametrize("text", ["-1e9", "-2.5E-3", "-3", "-.5", "-2."])
def test_a_negative_number_in_any_notation_is_a_value_not_an_option(text: str) -> None:
    """`--limit -1e9 1e9` was read as an option `-1e9`: "expected 2 arguments", and nothing said why."""
    from gma_ffc.cli import build_parser

    args = build_parser().parse_args(["invert", "--model", "m.yaml", "ref.csv", "-o", "out.csv", "--limit", text, "1e9"])
    assert args.limit[0] == float(text)
