"""`gma-ffc diagnose` end to end: the spec's outputs, the extended model in `simulate`, bad input."""

from __future__ import annotations

import html
import json
from pathlib import Path

import numpy as np
import pytest

from gma_ffc.cli import main
from benchmarks import cases as bench
from gma_ffc.modelio import load_model, save_model
from gma_ffc.recordings import Recording, read_recording, write_recording



@pytest.fixture(scope="module")
def case_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("diag")
    case = {c.name: c for c in bench.cases()}["thermal_drift#3"]
    model, rec = bench.make_case(case, scale=0.4)
    save_model(model, d / "model.yaml")
    write_recording(d / "long_run.csv", rec)
    return d


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_outputs_follow_the_spec(case_files, capsys, tmp_path, memoised_rounds):
    out_dir = tmp_path / "diagnosis"
    code, out, err = _run(capsys, "diagnose", "--model", str(case_files / "model.yaml"),
                          str(case_files / "long_run.csv"), "--out", str(out_dir))
    assert code == 0, err
    assert "verdict: thermal_drift" in out
    out_first = out
    doc = json.loads((out_dir / "diagnosis.json").read_text())
    _says_its_initial_state(doc, err, None, "estimated from the measured")
    for key, kind in (("verdict", list), ("explanation", str), ("located", list), ("located_after", list),
                      ("candidates", list),
                      ("rms_before_um", float), ("rms_after_um", float), ("validation", str),
                      ("extended_model", str)):
        assert isinstance(doc[key], kind), key
    assert doc["verdict"] == ["thermal_drift"] and doc["tentative"] == []
    assert doc["extended_model"] == "extended_model.yaml"
    assert doc["rms_after_um"] < 0.5 * doc["rms_before_um"]
    loc = doc["located"][0]
    assert loc["recording"] == "long_run.csv" and "t = " in loc["where"] and loc["residual_rms_um"] > 0
    assert loc["sensor_jumps"] == [] and "line" in loc      # the keys docs/cli.md promises, empty here
    left = doc["located_after"][0]                 # what the extended model leaves, located the same way
    assert left["recording"] == "long_run.csv" and 0 < left["residual_rms_um"] < loc["residual_rms_um"]
    names = [c["effect"] for c in doc["candidates"]]
    assert names[0] == "thermal_drift" and len(set(names)) == 7
    top = doc["candidates"][0]
    assert top["evidence"] > 0.9 and top["params"]["tau_s"] > 0 and top["validation_rms_um"] > 0
    assert "held" in doc["validation"] and "thermal_drift" in doc["explanation"]
    assert not any("moves against the model" in s for s in doc["cannot_conclude"])
    page = (out_dir / "report.html").read_text()
    assert page.count("data:image/png;base64,") >= 4
    assert page.index("<img") < page.index("Explanation")          # plots before prose
    # what the command says of the identification recordings, the report says too, above the plots
    note = html.escape(doc["identification"]["note"], quote=True)
    assert doc["identification"]["note"] and note in page[:page.index("<img")]
    # the extended model is a model like any other: simulate accepts it and it beats the base
    ext = load_model(out_dir / "extended_model.yaml")
    assert ext.kind == "extended" and ext.effects == ["thermal_drift"]
    for model_file, target in ((out_dir / "extended_model.yaml", "ext.csv"), (case_files / "model.yaml", "base.csv")):
        code, out, err = _run(capsys, "simulate", "--model", str(model_file), str(case_files / "long_run.csv"),
                              "-o", str(tmp_path / target))
        assert code == 0, err
    measured = read_recording(case_files / "long_run.csv").displacement_um
    rms = {n: float(np.sqrt(np.mean((read_recording(tmp_path / n).displacement_um - measured) ** 2)))
           for n in ("ext.csv", "base.csv")}
    assert rms["ext.csv"] < 0.5 * rms["base.csv"]
    # the figure the command gives for the written model is what simulate gives over the scored samples
    t = read_recording(case_files / "long_run.csv").time_s
    scored = t >= t[0] + (doc["initial_state"][0]["not_scored_s"] or 0.0)
    miss = read_recording(tmp_path / "ext.csv").displacement_um[scored] - measured[scored]
    assert doc["rms_written_um"] == pytest.approx(float(np.sqrt(np.mean(miss ** 2))), rel=1e-4)
    assert f"-> {doc['rms_written_um']:.4g} um over the scored samples" in out_first
    # and invert accepts it too
    t = np.arange(2000) / 1000.0
    ref = Recording({"time_s": t, "reference_um": 10 + 5 * np.sin(2 * np.pi * t), "stress_MPa": np.full(t.size, -15.0)},
                    {}, "ref.csv")
    write_recording(tmp_path / "ref.csv", ref)
    code, out, err = _run(capsys, "invert", "--model", str(out_dir / "extended_model.yaml"), str(tmp_path / "ref.csv"),
                          "-o", str(tmp_path / "drive.csv"))
    assert code == 0, err


def _short(tmp_path: Path, name: str, drive_scale: float = 1.0, n: int = 3000, cols: tuple = ()) -> Path:
    t = np.arange(n) / 1000.0
    u = drive_scale * (1 - np.cos(2 * np.pi * 2 * t))
    data = {"time_s": t, "current_A": u, "stress_MPa": np.full(n, -15.0), "displacement_um": 10 * u}
    for c in cols:
        data.pop(c)
    write_recording(tmp_path / name, Recording(data, {}, name))
    return tmp_path / name


@pytest.mark.parametrize("setup, words", [
    (lambda d, tmp: (str(d / "model.yaml"), str(tmp / "absent.csv")), "no such file"),
    (lambda d, tmp: (str(tmp / "absent.yaml"), str(d / "long_run.csv")), "no such model file"),
    (lambda d, tmp: (str(d / "model.yaml"), str(_short(tmp, "nodisp.csv", cols=("displacement_um",)))),
     "displacement_um"),
    (lambda d, tmp: (str(d / "model.yaml"), str(_short(tmp, "far.csv", drive_scale=10.0) )), "cannot conclude"),
])
def test_bad_input_is_one_line_and_exit_2(case_files, capsys, tmp_path, setup, words):
    model, rec = setup(case_files, tmp_path)
    if "far.csv" in rec:   # drive 10..20 A, far beyond the identified range
        r = read_recording(rec)
        r.columns["current_A"] = r.columns["current_A"] + 10.0
        write_recording(rec, r)
    out_dir = tmp_path / "out"
    code, out, err = _run(capsys, "diagnose", "--model", model, rec, "--out", str(out_dir))
    assert code == 2
    assert words in err and "Traceback" not in err and err.count("\n") == 1
    assert not out_dir.exists()                 # nothing half-written


def test_a_bad_cpu_count_in_the_environment_is_one_line_and_exit_2(case_files, capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("GMA_FFC_CPUS", "all")
    out_dir = tmp_path / "out"
    code, out, err = _run(capsys, "diagnose", "--model", str(case_files / "model.yaml"),
                          str(case_files / "long_run.csv"), "--out", str(out_dir))
    assert code == 2
    assert "GMA_FFC_CPUS='all'" in err and "Traceback" not in err and err.count("\n") == 1
    assert not out_dir.exists()


def test_single_short_recording_says_what_cannot_be_concluded(case_files, capsys, tmp_path):
    rec = _short(tmp_path, "short.csv", n=600)    # 0.6 s: about one loop
    code, out, err = _run(capsys, "diagnose", "--model", str(case_files / "model.yaml"), str(rec),
                          "--out", str(tmp_path / "o"))
    assert code == 0, err
    doc = json.loads((tmp_path / "o" / "diagnosis.json").read_text())
    assert doc["verdict"] == [] and doc["conclusive"] is False
    assert any("too little data" in s and "record" in s for s in doc["cannot_conclude"])
    assert doc["rms_written_um"] is None and "run as `gma-ffc simulate`" not in out   # the base, as given
    assert (tmp_path / "o" / "extended_model.yaml").exists()


def test_a_recording_none_of_which_is_scored_reports_no_held_out_figure(case_files, capsys, tmp_path):
    """A short small oscillation mid-range, from an unknown history: no sample is scored, so nothing
    was held out. The summary line must not call its one figure a held-out RMS (it did: 'held-out
    RMS 3.87 um -> 3.87 um' on a 401-sample piezo cut)."""
    n = 400
    t = np.arange(n) / 1000.0
    u = 1.0 + 0.05 * np.sin(2 * np.pi * 10 * t)
    rec = tmp_path / "mid.csv"
    write_recording(rec, Recording({"time_s": t, "current_A": u, "stress_MPa": np.full(n, -15.0),
                                    "displacement_um": 10 * u}, {}, "mid.csv"))
    code, out, err = _run(capsys, "diagnose", "--model", str(case_files / "model.yaml"), str(rec),
                          "--out", str(tmp_path / "o"))
    assert code == 0, err
    doc = json.loads((tmp_path / "o" / "diagnosis.json").read_text())
    assert [s["scored_share"] for s in doc["initial_state"]] == [0.0]
    assert "held-out RMS" not in out
    assert f"RMS {doc['rms_before_um']:.4g} um over every sample: none could be scored" in out
    # the report, the explanation and the validation say the same: no held-out figure, no 2-fold run
    report = (tmp_path / "o" / "report.html").read_text()
    assert "Held-out RMS" not in report and "none could be scored, so nothing was held out" in report
    assert "on held-out data" not in doc["explanation"] and "nothing was held out" in doc["explanation"]
    assert doc["validation"].startswith("nothing was validated") and "2-fold" not in doc["validation"]


def test_an_inverted_displacement_column_is_named_as_a_column_fault(case_files, capsys, tmp_path):
    """A displacement column of the wrong sign was taken as a recalibration gain of -1, and the
    held-out gain credited to an effect ('66.67 um -> 0.092 um')."""
    rec = read_recording(case_files / "long_run.csv")
    rec.columns["displacement_um"] = -rec.columns["displacement_um"]
    write_recording(tmp_path / "flipped.csv", rec)
    code, out, err = _run(capsys, "diagnose", "--model", str(case_files / "model.yaml"),
                          str(tmp_path / "flipped.csv"), "--out", str(tmp_path / "o"))
    assert code == 0, err
    doc = json.loads((tmp_path / "o" / "diagnosis.json").read_text())
    assert doc["outcome"] == "inconclusive" and doc["conclusive"] is False
    fault = [s for s in doc["cannot_conclude"] if "moves against the model's" in s]
    assert len(fault) == 1 and fault[0].startswith("flipped.csv:") and "flip the column's sign" in fault[0]
    assert doc["explanation"].startswith("First, a fault in the columns: flipped.csv")


def test_one_stress_cannot_test_stress_effects(case_files, capsys, tmp_path):
    rec = read_recording(case_files / "long_run.csv")
    rec.columns["stress_MPa"] = np.full(len(rec), -15.0)
    write_recording(tmp_path / "one_stress.csv", rec)
    code, out, err = _run(capsys, "diagnose", "--model", str(case_files / "model.yaml"),
                          str(tmp_path / "one_stress.csv"), "--out", str(tmp_path / "o"))
    assert code == 0, err
    doc = json.loads((tmp_path / "o" / "diagnosis.json").read_text())
    play = next(c for c in doc["candidates"] if c["effect"] == "stress_dependent_play")
    assert play["testable"] is False and "stress" in play["note"]
    assert any(s.startswith("stress_dependent_play") for s in doc["cannot_conclude"])


def test_diagnose_shares_the_initial_state_rule_and_says_which_it_used(case_files, capsys, tmp_path):
    """Issue 8: simulate, invert, diagnose and the controller share one default rule; each says
    which state it started from (on stderr and, for diagnose, in diagnosis.json). The default rule's
    run is `test_outputs_follow_the_spec`'s (the same diagnosis, checked there)."""
    code, _, err = _run(capsys, "diagnose", "--model", str(case_files / "model.yaml"), str(case_files / "long_run.csv"),
                        "--out", str(tmp_path / "d"), "--initial-state", "relaxed")
    assert code == 0
    _says_its_initial_state(json.loads((tmp_path / "d" / "diagnosis.json").read_text()), err, "relaxed", "relaxed")


def _says_its_initial_state(doc: dict, err: str, rule: str | None, words: str) -> None:
    (state,) = doc["initial_state"]
    assert state["rule"] == (rule or "estimate") and words in state["how"]
    assert f"initial state ({state['recording']}): {state['how']}" in err


def test_a_read_only_out_is_refused_before_the_work(case_files, capsys, tmp_path, monkeypatch):
    """An unwritable --out was found only after the whole analysis, naming a hidden temporary."""
    import errno
    import os

    import gma_ffc.diagnose.engine as engine

    real_open = os.open
    ro = tmp_path / "ro"
    ro.mkdir()

    def read_only(path, flags, *args, **kwargs):
        if flags & os.O_CREAT and str(path).startswith(str(ro)):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))
        return real_open(path, flags, *args, **kwargs)

    def no_work(*args, **kwargs):
        raise AssertionError("the analysis started")

    monkeypatch.setattr(os, "open", read_only)
    monkeypatch.setattr(engine, "diagnose", no_work)
    code, out, err = _run(capsys, "diagnose", "--model", str(case_files / "model.yaml"),
                          str(case_files / "long_run.csv"), "--out", str(ro / "diag"))
    assert code == 2 and err.count("\n") == 1, err
    assert f"{ro / 'diag'}: cannot write in {ro}: Read-only file system" in err


def test_a_full_disk_leaves_the_earlier_diagnosis_whole(case_files, capsys, tmp_path, monkeypatch):
    """A full disk on report.html left a new extended_model.yaml beside the old report and json,
    and said 'error: : No space left on device'."""
    import errno
    import os

    from gma_ffc import atomic

    rec = _short(tmp_path, "short.csv", n=600)
    argv = ("diagnose", "--model", str(case_files / "model.yaml"), str(rec), "--out", str(tmp_path / "o"))
    assert _run(capsys, *argv)[0] == 0
    before = {p.name: p.read_bytes() for p in (tmp_path / "o").iterdir()}
    real = atomic._write_temporary

    def full_at_report(target, data):
        if target.name == "report.html":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(target, data)

    monkeypatch.setattr(atomic, "_write_temporary", full_at_report)
    (tmp_path / "o" / "diagnosis.json").write_bytes(b'{"old": true}')      # an earlier run's, to tell apart
    before["diagnosis.json"] = b'{"old": true}'
    code, out, err = _run(capsys, *argv)
    assert code == 2 and err.count("\n") == 1, err
    assert f"{tmp_path / 'o' / 'report.html'}: cannot write it: No space left on device" in err
    assert {p.name: p.read_bytes() for p in (tmp_path / "o").iterdir()} == before


def test_dash_o_names_the_output_folder_as_in_the_other_commands():
    """identify, simulate and invert take -o; diagnose took only --out, and `-o DIR` was refused as
    a missing --out. Both spellings now give the same folder."""
    from gma_ffc.cli import build_parser

    short = build_parser().parse_args(["diagnose", "--model", "m.yaml", "rec.csv", "-o", "diag"])
    long = build_parser().parse_args(["diagnose", "--model", "m.yaml", "rec.csv", "--out", "diag"])
    assert short.out == long.out == "diag" and short.recordings == ["rec.csv"]


@pytest.mark.parametrize("factor, says", [(1e-3, "multiply displacement_um by 1000"),
                                          (1e3, "divide displacement_um by 1000")])
def test_a_displacement_in_another_unit_is_refused_naming_the_factor(case_files, capsys, tmp_path, factor, says):
    """A displacement logged in mm (or nm) under displacement_um: diagnose said 'unexplained: nothing in
    the vocabulary explains it', and wrote an extended model whose static gain, 0.00099, took the
    unit's place (on 1 s recordings: 'too little data'). The swing measured against the model's
    swing for the same drive is a unit slip, a sensor not reading the actuator or another
    actuator's model: refused before any fit, with the factor."""
    rec = read_recording(case_files / "long_run.csv")
    scaled = Recording({**rec.columns, "displacement_um": rec.displacement_um * factor}, dict(rec.metadata))
    write_recording(tmp_path / "scaled.csv", scaled)
    out_dir = tmp_path / "out"
    code, out, err = _run(capsys, "diagnose", "--model", str(case_files / "model.yaml"), str(tmp_path / "scaled.csv"),
                          "--out", str(out_dir))
    assert code == 2, err
    assert says in err and "scaled.csv" in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out_dir.exists()


def test_an_extended_model_is_diagnosed_through_its_base_as_the_service_does(case_files, capsys, tmp_path,
                                                                            memoised_rounds):
    """diagnose refused an extended model: 'diagnose its base sdpi/mpi model instead', advice a user
    holding only extended_model.yaml (a colleague's, a service's diagnosis folder) could not follow:
    no command writes the base out. The service's background diagnosis runs the base the extended model
    keeps; the command now does the same, and says so. The base and the recording are
    test_outputs_follow_the_spec's: their round searches are computed once for both (`memoised_rounds`)."""
    from gma_ffc.extended import ExtendedModel

    base = load_model(case_files / "model.yaml")
    save_model(ExtendedModel(base, {"creep": {"gain": 0.01, "tau_s": 3.0}}, ["creep"]), tmp_path / "extended.yaml")
    out_dir = tmp_path / "diag"
    code, out, err = _run(capsys, "diagnose", "--model", str(tmp_path / "extended.yaml"),
                          str(case_files / "long_run.csv"), "--out", str(out_dir))
    assert code == 0, err
    assert "extended.yaml is an extended model (creep)" in err and "diagnosed through the" in err
    doc = json.loads((out_dir / "diagnosis.json").read_text())
    assert doc["verdict"] == ["thermal_drift"]
