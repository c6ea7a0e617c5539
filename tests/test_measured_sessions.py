"""A second measured actuator, two sessions (tests/fixtures/piezo_yan9a.README.md): a piezo run
at 1 Hz for 40 s, and a later run of 37 s, also at 1 Hz, with smaller, decaying and growing sines
and a hold. Issue 31's measured-session check on it, and what one drive frequency can and cannot
tell. Never tuned to: the thresholds these pass through were set on simulated actuators."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import yaml
import pytest

from gma_ffc.cli import main
from gma_ffc.modelio import load_model
from gma_ffc.recordings import read_recording, write_recording
from measured import yan9a_csv


def _fresh(folder: Path) -> Path:
    """`folder`, empty (a run before it that failed half-way may have left files)."""
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    return folder


@pytest.fixture(scope="module")
def sessions(session_folder):
    """The first 20 s of the model run identify the model; its last 20 s are diagnosed, with the
    first as --ident; the later run is neither's. Once per session, in the folder the xdist workers
    share (`session_cache`): a worker that runs one of this file's tests need not diagnose again."""
    from session_cache import once_per_session

    def make():
        folder = _fresh(session_folder / "yan9a")
        run = read_recording(yan9a_csv("model", folder))
        half = run.time_s < 20.0
        write_recording(folder / "ident.csv", run.rows(half, "ident.csv"))
        write_recording(folder / "diagnosed.csv", run.rows(~half, "diagnosed.csv"))
        assert main(["identify", str(folder / "ident.csv"), "-o", str(folder / "model.yaml")]) == 0
        assert main(["diagnose", "--model", str(folder / "model.yaml"), str(folder / "diagnosed.csv"),
                     "--ident", str(folder / "ident.csv"), "-o", str(folder / "diag")]) == 0
        return folder, read_recording(yan9a_csv("later", folder))
    return once_per_session(session_folder, "yan9a sessions", make)


def test_one_drive_frequency_leaves_the_form_of_a_phase_lag_open(sessions):
    """Whatever phase lag fits best at 1 Hz, a delay, a lag and a resonance fit it too: the outcome
    is inconclusive, and the advice names a second frequency. Before the rule this run was told it
    had 'a resonance at 4.288 Hz', and the whole 40 s run, diagnosed against a model of itself, creep."""
    folder, _ = sessions
    doc = json.loads((folder / "diag" / "diagnosis.json").read_text())
    assert doc["outcome"] == "inconclusive", doc["outcome"]
    lags = {"time_delay", "rate_dependence", "mechanical_dynamics"}
    if set(doc["verdict"]) & lags:
        words = " ".join(doc["cannot_conclude"])
        assert "the drives hold one frequency" in words and "record at a second frequency" in words
        for other in lags - set(doc["verdict"]):      # a look-alike that came second did not lose
            assert f"The runner-up, {other}, lost" not in doc["explanation"]
        headline = (folder / "diag" / "report.html").read_text().split("<h1", 1)[1].split("</h1>", 1)[0]
        assert "Inconclusive" in headline and "(tentative)" in headline      # docs/cli.md: effects marked tentative


def test_a_later_session_is_predicted_to_within_one_percent_of_its_stroke_of_the_base(sessions):
    """Issue 31's measured-session bound: the extended model predicts the later run no worse than
    the base by more than 1 % of that run's peak-to-peak (it was 0.05 % worse: better on the
    decaying and growing sines, worse on the hold; the sessions differ by a 4 % gain, which
    neither model knows)."""
    folder, later = sessions
    y = later.displacement_um
    settled = later.time_s >= 1.0          # the sensor's start-up transient and the hysteresis state
    rms = {}
    for name in ("model.yaml", "diag/extended_model.yaml"):
        model = load_model(folder / name)
        pred = np.asarray(model.simulate(later.time_s, later.drive, None, measured_um=y), dtype=float)
        rms[name] = float(np.sqrt(np.mean((pred - y)[settled] ** 2)))
    assert np.isfinite(list(rms.values())).all()
    assert rms["diag/extended_model.yaml"] <= rms["model.yaml"] + 0.01 * float(np.ptp(y)), rms


@pytest.fixture(scope="module")
def whole_run(session_folder):
    """The model identified on the whole first run, the later run diagnosed against it (no --ident):
    the tester's case of a resonance named at the heaviest damping. Once per session, as `sessions`."""
    from session_cache import once_per_session

    def make():
        folder = _fresh(session_folder / "yan9a_whole")
        assert main(["identify", str(yan9a_csv("model", folder)), "-o", str(folder / "pz.yaml")]) == 0
        assert main(["diagnose", "--model", str(folder / "pz.yaml"), str(yan9a_csv("later", folder)),
                     "-o", str(folder / "diag")]) == 0
        return folder, json.loads((folder / "diag" / "diagnosis.json").read_text())
    return once_per_session(session_folder, "yan9a whole run", make)


def test_no_resonance_is_named_at_the_heaviest_damping(whole_run):
    """docs/cli.md: a resonance whose fit runs to the heaviest damping is a lag, not a peak. The
    backward pass zoomed the resonance again without the delay dropped beside it, it ran to the
    bound, and no check saw it: 'a resonance at 8.824 Hz (damping ratio 0.5)' was named. Every step
    that searches an accepted effect again now keeps a fit only where its signature check holds."""
    from gma_ffc.effects.dynamics import MAX_ZETA, PEAK_ZETA_MAX

    folder, doc = whole_run
    model = yaml.safe_load((folder / "diag" / "extended_model.yaml").read_text())
    dyn = model["blocks"].get("dynamics")
    if dyn is not None:
        assert dyn["zeta"] < PEAK_ZETA_MAX, dyn
    for c in doc["candidates"]:
        if c["effect"] == "mechanical_dynamics" and c["accepted"]:
            assert c["params"]["zeta"] < PEAK_ZETA_MAX, c
    assert f"damping ratio {MAX_ZETA:.2g})" not in doc["explanation"]


def test_the_selection_story_is_told_once_and_agrees_with_the_verdict(whole_run):
    """The story contradicted itself: time_delay 'replaced rate_dependence', yet the verdict was
    mechanical_dynamics alone; rate_dependence, accepted in round 1, was listed unaccepted with no
    note. A swap that a later pass undid is told as such, and every effect accepted and later
    dropped carries a note why."""
    _, doc = whole_run
    text = doc["explanation"]
    notes = {c["effect"]: c.get("note", "") for c in doc["candidates"] if not c["accepted"]}
    for old, new in re.findall(r"(\w+) explains the held-out data better \([^)]*\), so it replaced (\w+)", text):
        old, new = new, old
        assert notes.get(old), (old, notes)          # the one replaced says so
        assert f"replaced by {new}" in notes[old]
        if new not in doc["verdict"]:                # the replacement undone later is told as such
            assert f"{new} was then dropped" in text, text
            assert notes.get(new), (new, notes)
    for name in doc["verdict"]:
        assert f"{name} was then dropped" not in text and f"so it replaced {name}." not in text
    if doc["verdict"] and "The runner-up" in text:   # a runner-up of a winner no longer named is that round's
        winner = re.search(r"against [\d.]+ um for (\w+)", text.split("The runner-up", 1)[1]).group(1)
        assert winner in doc["verdict"] or "In the first round, the runner-up" in text, text


def test_a_voltage_drive_without_stress_is_told_in_its_own_words(whole_run):
    """The piezo's residual 'follows the integral of V^2 (cumulative heating)', and its thermal drift was
    reported per A^2 alone. The integral stays (a fact of the residual); a voltage drive's is not heating.
    The extended model file keeps its key (`gain_um_per_A2`, files written so far use it), and
    diagnosis.json gives the same figure per V^2 beside it."""
    folder, doc = whole_run
    words = doc["explanation"] + " " + " ".join(loc["where"] for loc in doc["located"] + doc["located_after"])
    assert "heating" not in words.replace("self-heating", ""), words
    thermal = next(c for c in doc["candidates"] if c["effect"] == "thermal_drift")
    if thermal["params"]:
        assert thermal["params"]["gain_um_per_V2"] == thermal["params"]["gain_um_per_A2"]
    note = doc["identification"]["note"]
    assert "eddy" not in note and "stress" not in note, note
    assert "stress(es)" not in doc["validation"]
