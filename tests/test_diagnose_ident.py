"""`diagnose --ident` (issue 31): the identification recordings, checked against the model's record,
and leave-one-recording-out selection.

- `identify` keeps each identification file's name, size and SHA-256 in the model's provenance.
- diagnose says whether the files given match that record, refuses files that differ, and says
  what it could not test without them.
- With them, stress-dependent play identifies the core again through a loop-width law fitted on the
  identification loops; the extended model then predicts a load the diagnosis never saw.
- With two or more recordings, an effect whose law does not improve the recording left out is not
  accepted, and diagnosis.json reports the leave-one-out figures.
"""

from __future__ import annotations

import dataclasses
import glob

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from gma_ffc.cli import main
from gma_ffc.cli.diagnose import HELP as DIAGNOSE_HELP
from gma_ffc.diagnose.engine import diagnose
from gma_ffc.diagnose.identification import check, split_by_record
from gma_ffc.effects.stress_play import WidenedCore
from gma_ffc.errors import InputError
from gma_ffc.identify import SDPIIdentifier
from gma_ffc.modelio import load_model
from gma_ffc.recordings import Recording, fingerprint, write_recording
from preisach import PreisachActuator

ID_STRESSES = (-11.3, -15.2, -19.1, -24.0)
FS = 1000.0


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


# ------------------------------------------------------------------ the record and its check
class _Model:
    def __init__(self, provenance: dict) -> None:
        self.provenance = provenance


def _fp(name: str, size: int, digest: str) -> dict:
    return {"name": name, "bytes": size, "sha256": digest}


def test_the_check_matches_names_sizes_and_hashes_and_says_what_is_missing() -> None:
    model = _Model({"recordings": ["a.csv", "b.csv"],
                    "identification_files": [_fp("a.csv", 10, "aa"), _fp("b.csv", 20, "bb")]})
    both = check(model, ["a.csv", "b.csv"], [_fp("a.csv", 10, "aa"), _fp("b.csv", 20, "bb")])
    assert both.status == "match" and both.verified and "name, size and content" in both.words()
    one = check(model, ["a.csv"], [_fp("a.csv", 10, "aa")])
    assert one.status == "partial" and one.missing == ("b.csv",) and "not given: b.csv" in one.words()
    with pytest.raises(InputError, match="content differs"):
        check(model, ["a.csv"], [_fp("a.csv", 10, "ab")])          # same name, other content
    with pytest.raises(InputError, match="not identified on it"):
        check(model, ["c.csv"], [_fp("c.csv", 10, "aa")])
    none = check(model, [])
    assert none.status == "not_given" and "--ident" in none.words() and "a.csv" in none.words()
    # an identification recording given to diagnose (the measured piezo, identified and diagnosed
    # alone) was told "the identification recordings (a.csv) were not given"
    own = dataclasses.replace(none, diagnosed=("a.csv",))
    assert "a.csv bears the name of one of the model's identification recordings" in own.words()
    assert "Give a.csv with --ident, and diagnose other runs" in own.words() and "not given" not in own.words()
    assert own.to_json()["diagnosed"] == ["a.csv"]
    # a model written before identify kept fingerprints: names only, and said so
    old = check(_Model({"recordings": ["a.csv"]}), ["a.csv"], [_fp("a.csv", 1, "x")])
    assert old.status == "match" and not old.verified and "by name" in old.words()
    unknown = check(_Model({}), ["a.csv"])
    assert unknown.status == "unchecked" and "could not be checked" in unknown.words()


def test_files_after_ident_are_split_by_the_record() -> None:
    model = _Model({"identification_files": [_fp("a.csv", 10, "aa")]})
    fps = [_fp("r.csv", 5, "rr"), _fp("a.csv", 10, "aa"), _fp("a.csv", 11, "aa")]   # the last: same name, other size
    assert split_by_record(model, ["r", "a", "a2"], fps) == ([1], [0, 2])


# ------------------------------------------------------------------ end to end on a Preisach rig
@pytest.fixture(scope="module")
def rig_files(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A Preisach rig (not an SDPI: no inverse crime): identification loops at four loads, identified
    by the CLI; two diagnosis recordings at two other loads and rates."""
    d = tmp_path_factory.mktemp("ident")
    rig = PreisachActuator(noise_um=0.02, seed=5)
    t = np.arange(0, 1.2, 1 / FS)
    x = 1.5 - 1.5 * np.cos(2 * np.pi * 3 * t)
    for s in ID_STRESSES:
        write_recording(d / f"id_{-s}.csv", Recording(
            {"time_s": t, "current_A": x, "stress_MPa": np.full_like(t, s), "displacement_um": rig.run(x, s)}, {}))
    assert main(["identify", *map(str, sorted(d.glob("id_*.csv"))), "-o", str(d / "model.yaml")]) == 0
    for name, f_hz, s in (("run_a.csv", 2.0, -13.0), ("run_b.csv", 5.0, -21.0)):
        t = np.arange(0, 4.0, 1 / FS)
        u = 1.5 - 1.5 * np.cos(2 * np.pi * f_hz * t)
        write_recording(d / name, Recording({"time_s": t, "current_A": u, "stress_MPa": np.full_like(t, s),
                                             "displacement_um": rig.run(u, s)}, {}))
    return d


def test_identify_records_each_file_name_size_and_hash(rig_files: Path) -> None:
    model = load_model(rig_files / "model.yaml")
    files = model.provenance["identification_files"]
    assert [f["name"] for f in files] == [p.name for p in sorted(rig_files.glob("id_*.csv"))]
    for f in files:
        p = rig_files / f["name"]
        assert f["bytes"] == p.stat().st_size and f == fingerprint(p) and len(f["sha256"]) == 64


@pytest.mark.slow
def test_diagnose_checks_the_ident_files_and_reports_leave_one_out(rig_files: Path, capsys, tmp_path) -> None:
    ids = [str(p) for p in sorted(rig_files.glob("id_*.csv"))]
    runs = [str(rig_files / "run_a.csv"), str(rig_files / "run_b.csv")]
    code, _, err = _run(capsys, "diagnose", "--model", str(rig_files / "model.yaml"), *runs, "--ident", *ids,
                        "--out", str(tmp_path / "with"))
    assert code == 0, err
    doc = json.loads((tmp_path / "with" / "diagnosis.json").read_text())
    assert doc["identification"]["status"] == "match" and doc["identification"]["verified"]
    assert "identification recordings: All 4" in err
    assert not any("--ident" in note for note in doc["cannot_conclude"])
    loo = doc["leave_one_out"]                       # two recordings at two loads: each left out in turn
    assert loo["applies"] and [r["recording"] for r in loo["per_recording"]] == ["run_a.csv", "run_b.csv"]
    assert all(math.isfinite(r["rms_recalibrated_um"]) and r["rms_recalibrated_um"] > 0 for r in loo["per_recording"])
    assert "left out in turn" in doc["validation"]
    # without them: the same diagnosis, and it says what it could not test (the loads span 8 MPa)
    code, _, err = _run(capsys, "diagnose", "--model", str(rig_files / "model.yaml"), *runs,
                        "--out", str(tmp_path / "without"))
    assert code == 0, err
    doc = json.loads((tmp_path / "without" / "diagnosis.json").read_text())
    assert doc["identification"]["status"] == "not_given"
    assert any(n.startswith("stress_dependent_play:") and "--ident" in n for n in doc["cannot_conclude"])


def test_ident_files_alone_after_the_flag_are_told_apart_by_the_record(rig_files: Path, capsys, tmp_path) -> None:
    ids = [str(p) for p in sorted(rig_files.glob("id_*.csv"))]
    code, _, err = _run(capsys, "diagnose", "--model", str(rig_files / "model.yaml"), "--out", str(tmp_path / "o"),
                        "--ident", *ids, str(rig_files / "run_a.csv"))
    assert code == 0, err
    doc = json.loads((tmp_path / "o" / "diagnosis.json").read_text())
    assert doc["identification"]["status"] == "match" and [d["recording"] for d in doc["located"]] == ["run_a.csv"]


def test_the_help_example_that_ends_the_ident_list_with_dashes_runs_as_written(rig_files: Path, capsys, tmp_path,
                                                                             monkeypatch) -> None:
    """`diagnose --help` says how to end the --ident list with --; its example, run word for word
    (the shell's glob expanded), works: --out before --ident, as after -- every word is a recording."""
    with pytest.raises(SystemExit):
        main(["diagnose", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "end the list with --: --out DIR --ident ID_REC... -- REC..." in text
    example = next(line.split() for line in DIAGNOSE_HELP.splitlines() if " -- " in line)
    assert example[:2] == ["gma-ffc", "diagnose"] and example.index("--out") < example.index("--ident")
    for p in [rig_files / "model.yaml", *rig_files.glob("id_*.csv")]:
        shutil.copy(p, tmp_path / p.name)
    shutil.copy(rig_files / "run_a.csv", tmp_path / "long_run.csv")
    monkeypatch.chdir(tmp_path)
    argv = [w for word in example[1:] for w in (sorted(glob.glob(word)) if "*" in word else [word])]
    code, _, err = _run(capsys, *argv)
    assert code == 0, err
    doc = json.loads((tmp_path / "diagnosis" / "diagnosis.json").read_text())
    assert doc["identification"]["status"] == "match" and [d["recording"] for d in doc["located"]] == ["long_run.csv"]


def test_an_ident_file_whose_content_changed_is_refused_in_one_line(rig_files: Path, capsys, tmp_path) -> None:
    changed = tmp_path / "id_11.3.csv"                # same name as a recorded file, one value edited
    shutil.copy(rig_files / "id_11.3.csv", changed)
    lines = changed.read_text().splitlines()
    cells = lines[-1].split(",")
    cells[-1] = str(float(cells[-1]) + 1.0)
    lines[-1] = ",".join(cells)
    changed.write_text("\n".join(lines) + "\n")
    code, out, err = _run(capsys, "diagnose", "--model", str(rig_files / "model.yaml"), str(rig_files / "run_a.csv"),
                          "--ident", str(changed), "--out", str(tmp_path / "o"))
    assert code == 2 and "content differs" in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "o" / "diagnosis.json").exists()


# ------------------------------------------------------------------ a loop width that follows stress
TRUE_KAPPA = 0.08       # per MPa: the loop widens 8 % per MPa of extra compression


def _widened(core: WidenedCore, t: np.ndarray, u: np.ndarray, s: float, name: str, seed: int) -> Recording:
    y = core.simulate(t, u, np.full(t.size, s), initial_drive=float(u[0]))
    y = y + np.random.default_rng(seed).normal(0, 0.01, t.size)
    return Recording({"time_s": t, "current_A": u, "stress_MPa": np.full(t.size, s), "displacement_um": y}, {}, name)


def widened_rig() -> tuple[WidenedCore, list[Recording], list[Recording]]:
    """A made-up actuator whose loop width follows stress, its identification loops at four loads,
    and two runs at two loads and rates."""
    truth = load_model(Path(__file__).resolve().parents[1] / "config" / "models" / "sim_sdpi.yaml")
    lo, hi = truth.drive_range
    s_lo, s_hi = truth.stress_range_MPa
    plant = WidenedCore(truth, TRUE_KAPPA, float(s_hi))
    t = np.arange(0, 3.0, 1 / FS)
    loop = lo + 0.5 * (hi - lo) * (1 - np.cos(2 * np.pi * 3.0 * t))
    ident = [_widened(plant, t, loop, s, f"id_{k}.csv", k) for k, s in enumerate(np.linspace(s_lo, s_hi, 4))]
    t = np.arange(0, 4.0, 1 / FS)
    runs = []
    for k, (f_hz, frac) in enumerate(((2.0, 0.3), (5.0, 0.7))):
        u = lo + 0.5 * (hi - lo) * (1 - np.cos(2 * np.pi * f_hz * t))
        runs.append(_widened(plant, t, u, s_lo + frac * (s_hi - s_lo), f"run_{k}.csv", 10 + k))
    return plant, ident, runs


@pytest.mark.slow
def test_with_ident_the_loop_width_law_is_fitted_on_the_loops_and_predicts_another_load() -> None:
    """An actuator whose loop width follows stress, an SDPI identified on its loops at four loads
    (which cannot follow the width), diagnosed on runs at two loads: with the identification
    loops, stress-dependent play identifies the core again through a width law fitted on them, and
    the extended model predicts a load and a rate the diagnosis never saw far better than the base."""
    plant, ident, runs = widened_rig()
    lo, hi = plant.base.drive_range
    s_lo = plant.base.stress_range_MPa[0]
    base = SDPIIdentifier().fit(ident).model_
    dg = diagnose(base, runs, identification=ident)
    assert dg.identification["status"] == "match"
    assert "stress_dependent_play" in dg.verdict, (dg.verdict, dg.explanation)
    kappa = dg.extended.blocks()["loop_width"]["kappa_per_MPa"]
    assert 0.5 * TRUE_KAPPA <= kappa <= 2.0 * TRUE_KAPPA, kappa
    # a load (the most compressive) and a rate (1 Hz) the diagnosis never saw
    t = np.arange(0, 3.0, 1 / FS)
    u = lo + 0.5 * (hi - lo) * (1 - np.cos(2 * np.pi * 1.0 * t))
    probe = _widened(plant, t, u, float(s_lo), "probe.csv", 99)
    s = probe.stress_MPa
    settle = t >= 1.0                                # after the first loop (both models start relaxed)
    err = {name: float(np.sqrt(np.mean((m.simulate(t, u, s, measured_um=probe.displacement_um)
                                        - probe.displacement_um)[settle] ** 2)))
           for name, m in (("base", base), ("extended", dg.extended))}
    assert err["extended"] < 0.5 * err["base"], err


# ------------------------------------------------------------------ leave one recording out
def _delayed(model, f_hz: float, s: float, delay_s: float, name: str, seed: int) -> Recording:
    t = np.arange(0, 4.0, 1 / FS)
    lo, hi = model.drive_range
    drive = lambda tt: lo + 0.5 * (hi - lo) * (1 - np.cos(2 * np.pi * f_hz * tt))    # noqa: E731
    y = model.simulate(t, drive(np.maximum(t - delay_s, 0.0)), np.full(t.size, s), initial_drive=float(lo))
    y = y + np.random.default_rng(seed).normal(0, 0.01, t.size)
    return Recording({"time_s": t, "current_A": drive(t), "stress_MPa": np.full(t.size, s), "displacement_um": y},
                     {}, name)


@pytest.mark.slow
@pytest.mark.parametrize("delays_ms, named", [((4.0, 4.0), True), ((4.0, 0.0), False)])
def test_leave_one_recording_out_figures_follow_what_each_recording_holds(delays_ms, named) -> None:
    """Two runs at two loads and rates. A delay in both is physics of the rig: it is named, and
    fitted on either run it improves the other (each recording left out in turn). A delay in one
    run only (a DAQ setting changed between sessions) is not named. Each left-out figure is an
    honest prediction: the recording's gains come from the other run, at another load, so a stress
    gain the other run cannot determine is not extrapolated (it was: 21 um on a 3 um residual)."""
    model = load_model(Path(__file__).resolve().parents[1] / "config" / "models" / "sim_sdpi.yaml")
    s_lo, s_hi = model.stress_range_MPa
    runs = [_delayed(model, f, s, d / 1000.0, f"run_{k}.csv", k)
            for k, (f, s, d) in enumerate(zip((3.0, 7.0), (s_lo + 2.0, s_hi - 2.0), delays_ms))]
    dg = diagnose(model, runs)
    loo = dg.leave_one_out
    assert loo["applies"] and len(loo["per_recording"]) == 2
    assert loo["rms_recalibrated_um"] < 1.5 * dg.rms_before_um, (loo, dg.rms_before_um)
    delay = next(c for c in dg.candidates if c.effect == "time_delay")
    assert ("time_delay" in dg.verdict) == named, (dg.verdict, delay.reason)
    if named:
        assert math.isfinite(delay.leave_one_out_mse) and loo["rms_after_um"] < loo["rms_recalibrated_um"]
        for row in loo["per_recording"]:
            assert row["rms_after_um"] < row["rms_recalibrated_um"], row
    else:
        assert loo["rms_after_um"] is None       # the base kept: nothing to leave out beyond it
