"""A known hysteresis state at a recording's first sample (``--initial-state plays:FILE``): the
file (`gma_ffc.known_state`), the rule (`gma_ffc.initial_state`), what diagnose scores with it
(`gma_ffc.diagnose.data`), the command line's refusals, and the controller side that knows the
state (`gma_ffc.control.play_memory`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gma_ffc.control.play_memory import PlayMemory, start_plays, step_plays
from gma_ffc.diagnose.data import start_and_scored
from gma_ffc.initial_state import InitialStateSpec, resolve
from gma_ffc.known_state import read_play_state, write_play_state
from gma_ffc.modelio import load_model
from gma_ffc.recordings import Recording, write_recording

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "config" / "models" / "sim_sdpi.yaml"


@pytest.fixture(scope="module")
def model():
    return load_model(MODEL)


def _narrow(model, n=3000, rate=500.0):
    """A run that starts at rest at 0 A, rises to a narrow sine (0.6-1.6 A of 0-3 A) and stays
    there; the drive and the plays after each sample, from the start."""
    t = np.arange(n) / rate
    u = np.minimum(t / 0.5, 1.0) * (1.1 - 0.5 * np.cos(2 * np.pi * 3 * t))
    p0 = start_plays(model, 0.0, None)
    out = np.empty((n, model.n_play))
    from gma_ffc import operators as ops

    ops.play_outputs(np.ascontiguousarray(u - model.input_offset), model.play_thresholds, p0, out)
    return t, u, out


def _state_file(tmp_path, plays, name="state.json"):
    path = tmp_path / name
    write_play_state(path, plays, time_s=1.0, drive=0.5, stress_MPa=-15.2, how="test")
    return path


def test_the_file_reads_back_as_a_plays_spec_and_parse_stays_pure(tmp_path, model):
    plays = np.linspace(-0.3, 0.4, model.n_play)
    path = _state_file(tmp_path, plays)
    spec = read_play_state(path)
    assert spec.kind == "plays" and spec.plays == tuple(plays) and spec.drive is None
    assert str(spec) == f"plays:{path}" and InitialStateSpec.parse(spec) is spec
    doc = json.loads(path.read_text())
    assert doc["format"] == "gma-ffc play state" and doc["stress_MPa"] == -15.2
    with pytest.raises(ValueError, match="taken by gma-ffc diagnose only"):
        InitialStateSpec.parse(f"plays:{path}")             # no I/O in the pure rule
    # the existing kinds are as they were
    assert InitialStateSpec.parse("relaxed") == InitialStateSpec("relaxed")
    assert InitialStateSpec.parse("drive:0.5") == InitialStateSpec("drive", 0.5)
    assert str(InitialStateSpec.parse("estimate")) == "estimate"


def test_a_known_state_is_settled_from_the_first_sample_and_gives_the_true_history(model):
    t, u, plays = _narrow(model)
    k = 1500                                        # a window from the middle of the run
    spec = InitialStateSpec("plays", plays=tuple(plays[k]), source="test")
    got = resolve(model, u[k:], spec=spec)
    assert got.settled_index == 0 and got.how.startswith("known")
    np.testing.assert_allclose(got.play_state, plays[k])
    s = np.full(t.size, -15.2)
    whole = model.simulate(t, u, s, initial_play_state=start_plays(model, 0.0, None))
    window = model.simulate(t[k:], u[k:], s[k:], initial_state=spec)
    np.testing.assert_allclose(window, whole[k:], atol=1e-9)        # as if run from the start
    with pytest.raises(ValueError, match=f"the model has {model.n_play} plays, the state gives 3"):
        resolve(model, u[k:], spec=InitialStateSpec("plays", plays=(0.0, 0.1, 0.2), source="f"))


def test_diagnose_scores_every_sample_from_a_known_state_where_the_estimate_scores_none(model):
    """The defect: a narrow tracking run never sweeps the model's range, so with the state unknown
    nothing of a window from its middle is scored; with it known, all of it is."""
    t, u, plays = _narrow(model)
    k = 1500
    s = np.full(t.size - k, -15.2)
    y = model.simulate(t, u, np.full(t.size, -15.2), initial_play_state=start_plays(model, 0.0, None))[k:]
    y = y + np.random.default_rng(1).normal(0.0, 0.03, y.size)
    _, unknown, _ = start_and_scored(model, u[k:], s, "estimate", y, t[k:])
    known_spec = InitialStateSpec("plays", plays=tuple(plays[k]), source="test")
    start, known, outside = start_and_scored(model, u[k:], s, known_spec, y, t[k:])
    assert not unknown.any()
    assert known.all() and not outside and start.settled_index == 0


def test_a_core_identified_again_estimates_its_own_state(model):
    """The known plays are the base's on the recorded drive; a core identified again through an
    input effect sees another drive, so its state is estimated (`selection._restarted`)."""
    import dataclasses

    from gma_ffc.diagnose.selection import _restarted

    t, u, plays = _narrow(model, n=600)
    y = model.simulate(t, u, np.full(t.size, -15.2), initial_play_state=start_plays(model, 0.0, None))
    d = dataclasses.make_dataclass("D", ["u", "s", "y", "t", "start"])(u, np.full(t.size, -15.2), y, t, None)
    spec = InitialStateSpec("plays", plays=tuple(plays[0]), source="test")
    (again,) = _restarted(model, [d], spec)
    assert again.start.how.startswith("estimated") or again.start.how.startswith("consistent")


def _recording(tmp_path, model, name="window.csv"):
    t, u, _ = _narrow(model, n=600)
    y = model.simulate(t, u, np.full(t.size, -15.2), initial_play_state=start_plays(model, 0.0, None))
    path = tmp_path / name
    write_recording(path, Recording({"time_s": t, "current_A": u, "stress_MPa": np.full(t.size, -15.2),
                                     "displacement_um": y}, {"sample_rate_hz": 500.0}, name))
    return path


@pytest.mark.parametrize("content, words", [
    (None, "cannot read it"),
    ("not json", "not JSON"),
    ('{"plays": []}', 'no "plays" list'),
    ('{"plays": [0.1, NaN, 0.2]}', "must all be finite numbers"),
    ('{"plays": [0.1, 0.2, 0.3]}', "3 play values, but the model has 10 plays"),
])
def test_bad_state_files_are_one_line_and_exit_2(tmp_path, capsys, content, words):
    rec = _recording(tmp_path, load_model(MODEL))
    state = tmp_path / "state.json"
    if content is not None:
        state.write_text(content)
    code = _main(["diagnose", "--model", str(MODEL), str(rec), "--out", str(tmp_path / "out"),
                  "--initial-state", f"plays:{state}"])
    err = capsys.readouterr().err
    assert code == 2 and words in err and len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err


def _main(argv):
    """The command line's exit code, whether argparse (SystemExit) or main (its return) refused."""
    from gma_ffc.cli import main

    try:
        return main(argv)
    except SystemExit as exc:
        return exc.code


def test_a_state_for_two_recordings_and_plays_in_simulate_are_refused(tmp_path, capsys, model):
    from gma_ffc.cli import main

    a, b = _recording(tmp_path, model, "a.csv"), _recording(tmp_path, model, "b.csv")
    b.write_text(b.read_text().replace("-15.2", "-15.3"))     # not the same rows twice
    state = _state_file(tmp_path, np.zeros(model.n_play))
    assert main(["diagnose", "--model", str(MODEL), str(a), str(b), "--out", str(tmp_path / "o"),
                 "--initial-state", f"plays:{state}"]) == 2
    err = capsys.readouterr().err
    assert "give that recording alone (got 2)" in err and len(err.strip().splitlines()) == 1, err
    with pytest.raises(SystemExit) as exit_:
        main(["simulate", "--model", str(MODEL), str(a), "-o", str(tmp_path / "s.csv"),
              "--initial-state", f"plays:{state}"])
    assert exit_.value.code == 2 and "taken by gma-ffc diagnose only" in capsys.readouterr().err


def test_the_play_memory_recovers_the_state_at_any_retained_row(model):
    """Blocks as the telemetry writer hands them; the state at a row long after the start, from
    the rows retained (the last 40 s only), equals the plays stepped from the run's start."""
    rate = 250.0
    n = int(120 * rate)
    t = np.arange(n) / rate
    u = np.minimum(t / 0.5, 1.0) * (1.1 - 0.7 * np.cos(2 * np.pi * 3 * t))
    u[5000:5003] = np.nan                               # a missing reading: not stepped
    memory = PlayMemory.of(model, 0.0, None, keep_s=60.0)
    assert memory is not None and memory.follows(model)
    for a in range(0, n, 25):
        memory.advance(t[a:a + 25], u[a:a + 25])
    kept = slice(n - int(40 * rate), n)
    first = n - int(30 * rate) + 7
    got = memory.state_at(t[kept], u[kept], float(t[first]))
    ok = np.isfinite(u[:first + 1])
    want = step_plays(model.play_thresholds, model.input_offset, start_plays(model, 0.0, None), u[:first + 1][ok])
    np.testing.assert_allclose(got, want, atol=1e-12)
    assert memory.state_at(t[kept], u[kept], float(t[kept][0]) - 1.0) is None      # before what is kept
