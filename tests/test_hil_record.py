"""Recordings from the simulated GMA: spec format, right experiments, no effect labels, deterministic."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from gma_ffc.errors import InputError
from gma_ffc.recordings import read_recording
from hil_sim.__main__ import main
from hil_sim.plant import EFFECTS, GMAPlant, PlantConfig
from hil_sim.record import (COLUMN_ORDER, IDENTIFICATION_STRESSES_MPA, RISING_STRESSES_MPA, STRESS_CHANGE_MASSES_KG,
                            make_recording, make_recordings)

REQUIRED = ("time_s", "drive", "displacement_um", "stress_MPa")


def test_identification_recording_has_the_spec_columns_stress_and_rate() -> None:
    rec = make_recording("identification", stress_MPa=-15.2, effects=["noise"])
    assert tuple(rec.columns) == COLUMN_ORDER
    assert rec.metadata["sample_rate_hz"] == 2000.0
    assert len(rec) == int(round(4 * 2000 / 3.0))                  # four 3 Hz periods
    # the preload spring adds ~0.2 MPa over a 55 um stroke (0.2 N/um on a phi 7 mm rod)
    assert np.mean(rec.stress_MPa) == pytest.approx(-15.2, abs=0.25)
    assert rec.columns["current_cmd_A"].max() == pytest.approx(3.0, abs=1e-3)
    assert 10.0 < np.ptp(rec.displacement_um) < 100.0
    assert np.abs(rec.columns["current_A"] - rec.columns["current_cmd_A"]).max() < 0.01   # noise only


def test_minor_loops_shrink_after_the_full_ones() -> None:
    rec = make_recording("identification", stress_MPa=-11.3, minor_loops=True)
    period = 2000 / 3.0
    cmd = rec.columns["current_cmd_A"]
    peaks = [cmd[int(k * period):int((k + 1) * period)].max() for k in range(round(len(cmd) / period))]
    assert peaks[:4] == pytest.approx([3.0] * 4, abs=1e-3)
    assert peaks[4:] == pytest.approx([2.4, 1.8, 1.2], abs=1e-3)


def test_stress_change_stress_column_follows_the_load_masses() -> None:
    rec = make_recording("stress_change", effects=["noise"])
    cfg = PlantConfig()
    hold = int(4.0 * 2000)
    for k, mass in enumerate(STRESS_CHANGE_MASSES_KG):
        block = rec.stress_MPa[k * hold + 100:(k + 1) * hold]
        assert np.median(block) == pytest.approx(cfg.stress_for_mass(mass), abs=0.3)
    assert np.ptp(rec.stress_MPa) > 10.0


def test_other_kinds_have_their_drives() -> None:
    multi = make_recordings("multifreq", frequencies=[1.0, 200.0])
    assert [r.metadata["drive"] for r in multi] == ["1 Hz sine 0-3 A", "200 Hz sine 0-3 A"]
    assert all(r.metadata["sample_rate_hz"] == 10000.0 for r in multi)
    long = make_recording("long", effects=["thermal"], drive_s=20.0, rest_s=10.0)
    assert long.time_s[-1] == pytest.approx(30.0, abs=0.01)
    assert np.all(long.columns["current_cmd_A"][long.time_s > 20.0] == 0.0)
    assert long.columns["temperature_C"].max() > long.columns["temperature_C"][0] + 3.0
    steps = make_recording("steps", levels=[1.0, 2.0], hold_s=2.0)
    assert sorted(set(steps.columns["current_cmd_A"])) == [0.0, 1.0, 2.0]


def test_rising_amplitude_recordings_start_at_rest_on_a_cycled_rod_and_are_scored_almost_whole() -> None:
    """The experiment labs record (issue 31): at each stress, sines whose amplitude grows from 0 A to
    the full range and decays back. The rod was cycled before, not demagnetised, so diagnose scores
    nearly every sample from the first (from a demagnetised rod the first rise is a virgin curve
    no loop's state reproduces, and is left unscored)."""
    from gma_ffc.diagnose.data import prepare
    from gma_ffc.identify import SDPIIdentifier

    segments = ((3.0, 4.0), (20.0, 2.0))
    recs = make_recordings("rising", effects=["noise"], segments=segments)
    assert [r.name for r in recs] == [f"rising_{s:.1f}MPa.csv" for s in RISING_STRESSES_MPA]
    for rec, stress in zip(recs, RISING_STRESSES_MPA):
        cmd = rec.columns["current_cmd_A"]
        assert rec.time_s[0] == 0.0 and len(rec) == 6 * 2000
        assert cmd[0] == 0.0 and cmd.max() == pytest.approx(3.0, abs=0.01)
        assert cmd[:500].max() < 0.5 and cmd[3000:5000].max() > 2.9        # the amplitude grows from 0
        assert np.mean(rec.stress_MPa) == pytest.approx(stress, abs=0.25)
    model = SDPIIdentifier().fit(make_recordings("identification", effects=["noise"],
                                                 stresses=RISING_STRESSES_MPA)).model_
    cycled = prepare(recs, model)
    assert min(d.n_scored / d.t.size for d in cycled) >= 0.95
    virgin = make_recordings("rising", effects=["noise"], segments=segments)[0]
    plain = GMAPlant(PlantConfig().with_effects(["noise"]), seed=0).run(
        virgin.time_s, virgin.columns["current_cmd_A"], load_mass_kg=float(virgin.metadata["load_mass_kg"]))
    start = slice(0, 600)                                          # the first rises, a few tenths of an A
    assert np.max(np.abs(plain["displacement_um"][start] - virgin.displacement_um[start])) > 0.05


def test_same_seed_same_recording_other_seed_other_noise() -> None:
    a = make_recording("identification", stress_MPa=-24.0, seed=4, effects=["noise"])
    b = make_recording("identification", stress_MPa=-24.0, seed=4, effects=["noise"])
    c = make_recording("identification", stress_MPa=-24.0, seed=5, effects=["noise"])
    assert all(np.array_equal(a.columns[k], b.columns[k]) for k in a.columns)
    assert not np.array_equal(a.displacement_um, c.displacement_um)


def test_cli_writes_readable_files_and_a_manifest_and_no_effect_labels(tmp_path: Path) -> None:
    out = tmp_path / "ident"
    rc = main(["record", "--kind", "identification", "--out", str(out), "--seed", "3",
               "--effects", "eddy,thermal,creep,noise"])
    assert rc == 0
    files = sorted(out.glob("*.csv"))
    assert len(files) == len(IDENTIFICATION_STRESSES_MPA)
    manifest = yaml.safe_load((out / "manifest.yaml").read_text())
    assert manifest["effects"] == ["eddy", "thermal", "creep", "noise"]
    assert sorted(e["file"] for e in manifest["files"]) == [f.name for f in files]
    stresses = []
    for path in files:
        text = path.read_text()
        header = "\n".join(line for line in text.splitlines() if line.startswith("#"))
        for name in EFFECTS + ("eddy_current", "creep", "thermal", "resonance"):
            assert not re.search(rf"\b{name}\b", header), f"{path.name} reveals '{name}'"
        rec = read_recording(path, require=REQUIRED)
        assert rec.metadata["sample_rate_hz"] == 2000.0
        assert "seed" in rec.metadata and "load_mass_kg" in rec.metadata
        stresses.append(float(np.mean(rec.stress_MPa)))
    assert sorted(stresses) == pytest.approx(sorted(IDENTIFICATION_STRESSES_MPA), abs=0.15)
    # the file holds exactly what the Python API makes for the same seed
    on_disk = read_recording(out / "identification_-19.1MPa.csv", require=REQUIRED)
    entry = next(e for e in manifest["files"] if e["file"] == "identification_-19.1MPa.csv")
    api = make_recordings("identification", seed=3, effects=["eddy", "thermal", "creep", "noise"],
                          stresses=IDENTIFICATION_STRESSES_MPA)[IDENTIFICATION_STRESSES_MPA.index(-19.1)]
    assert api.metadata["seed"] == entry["seed"]
    for name in COLUMN_ORDER:
        assert np.allclose(on_disk.columns[name], api.columns[name], rtol=1e-8, atol=1e-9), name


def test_cli_same_seed_gives_identical_files(tmp_path: Path) -> None:
    for d in ("a", "b"):
        assert main(["record", "--kind", "steps", "--out", str(tmp_path / d), "--effects", "creep,noise"]) == 0
    assert (tmp_path / "a" / "steps.csv").read_bytes() == (tmp_path / "b" / "steps.csv").read_bytes()


def test_cli_bad_input_is_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad_cfg = tmp_path / "plant.yaml"
    bad_cfg.write_text("dynamics:\n  moving_mass: 2\n")
    cases = [
        ["record", "--kind", "steps", "--out", str(tmp_path / "x"), "--config", str(bad_cfg)],
        ["record", "--kind", "steps", "--out", str(tmp_path / "x"), "--effects", "warp"],
        ["record", "--kind", "long", "--out", str(tmp_path / "x"), "--minor-loops"],
        ["record", "--kind", "steps", "--out", str(tmp_path / "x"), "--config", str(tmp_path / "none.yaml")],
        ["record", "--kind", "steps", "--out", str(tmp_path / "x"), "--seed", "-1"],
    ]
    expected = ["dynamics.moving_mass", "warp", "--minor-loops", "none.yaml", "--seed must be a whole number from 0"]
    for argv, needle in zip(cases, expected):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and needle in err and "Traceback" not in err
    assert not (tmp_path / "x").exists()                      # nothing half-written
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main(["record", "--kind", "steps", "--out", str(blocker)]) == 2
    assert "not a directory" in capsys.readouterr().err


def test_cli_help_teaches_kinds_and_effects(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["record", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    for word in ("identification", "multifreq", "long", "steps", "stress_change", "rising", *EFFECTS, "manifest.yaml"):
        assert word in text


def test_api_rejects_bad_requests() -> None:
    with pytest.raises(InputError, match="unknown recording kind"):
        make_recordings("chirp")
    with pytest.raises(InputError, match="below the preload"):
        make_recording("identification", stress_MPa=-5.0)
    with pytest.raises(InputError, match="stress_MPa"):
        make_recording("steps", stress_MPa=-15.2)
    with pytest.raises(InputError, match="at least one"):
        make_recordings("rising", segments=())
    with pytest.raises(InputError, match="below a quarter"):
        make_recordings("rising", segments=((600.0, 1.0),))
