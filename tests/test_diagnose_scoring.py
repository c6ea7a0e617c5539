"""Which samples diagnose scores (issue 31): where the drive has decided the model's output, not
only after a full sweep; never the start of a demagnetised rod, whose first rise is a virgin curve;
and a located window's ratio over scored windows only."""

from __future__ import annotations

import dataclasses

import numpy as np

from benchmarks import cases as bench
from gma_ffc.diagnose.data import RecData, prepare
from gma_ffc.diagnose.locate import locate
from gma_ffc.identify import SDPIIdentifier
from gma_ffc.initial_state import settled_index
from gma_ffc.recordings import Recording
from hil_sim.plant import GMAPlant, PlantConfig

FS = 2000.0
RISING = {c.name: c for c in bench.rising_cases()}


def _rising(seconds: float) -> np.ndarray:
    t = np.arange(int(seconds * FS)) / FS
    return 1.9 * np.sin(np.pi * t / seconds) ** 2 * 0.5 * (1 - np.cos(2 * np.pi * 4.0 * t))


def test_a_rising_amplitude_recording_is_scored_from_its_first_sample_where_a_sweep_would_wait():
    case = dataclasses.replace(RISING["rising:null#1"])
    model, rec = bench.make_case(case, scale=0.4)
    d = prepare([rec], model)[0]
    assert d.n_scored >= 0.9 * d.t.size and d.settled < 0.02 * d.t.size
    assert settled_index(model, rec.drive) > 0.05 * d.t.size     # what a full sweep would have left out


def test_a_demagnetised_rods_virgin_rise_is_not_scored_but_a_cycled_rods_is():
    """hil_sim starts from a demagnetised rod: its first rise from zero current is a virgin curve,
    below every loop a history inside the drive range leaves. The measurement shows it, so that
    stretch is not scored; the same run on a rod cycled and at rest before is scored whole."""
    cfg = PlantConfig().with_effects(["noise"])
    t = np.arange(int(3 * FS)) / FS
    ident = bench.record(cfg, t, 0.5 * 2.0 * (1 - np.cos(2 * np.pi * 3 * t)), 20.0, "id.csv", 1, preconditioned=True)
    model = SDPIIdentifier().fit([ident]).model_
    drive = _rising(4.0)
    tt = np.arange(drive.size) / FS
    virgin = bench.record(cfg, tt, drive, 20.0, "virgin.csv", 2)
    cycled = bench.record(cfg, tt, drive, 20.0, "cycled.csv", 2, preconditioned=True)
    d_virgin, d_cycled = prepare([virgin, cycled], model)
    assert d_cycled.n_scored >= 0.95 * d_cycled.t.size
    first_rise = slice(0, int(0.125 * FS))                      # the first cycle's rise at 4 Hz
    assert not d_virgin.mask[first_rise].any()
    assert "held within" not in d_virgin.start.how


def test_a_sensor_zeroed_elsewhere_changes_neither_the_state_nor_what_is_scored():
    model, rec = bench.make_case(RISING["rising:null#2"], scale=0.4)
    cut = Recording({k: v[3000:] for k, v in rec.columns.items()}, {}, "cut.csv")   # starts mid-history
    moved = Recording({**cut.columns, "displacement_um": cut.columns["displacement_um"] + 3.0}, {}, "moved.csv")
    a, b = prepare([cut, moved], model)
    assert np.array_equal(a.mask, b.mask) and 0 < a.n_scored < a.t.size
    # the states may differ only where the measurement cannot see them: not on a scored sample
    ya, yb = (model.simulate(d.t, d.u, d.s, initial_state=d.start) for d in (a, b))
    assert np.max(np.abs(ya - yb)[a.mask]) <= 1e-9 * np.ptp(ya)


def test_a_located_window_is_compared_over_scored_windows_against_a_positive_floor():
    """Measured piezo captures gave '503019229737.9x the median window': the median window was an
    unscored one, all zeros. Windows hold scored samples only, and the typical one's RMS is floored."""
    rng = np.random.default_rng(2)
    n = 20000
    t = np.arange(n) / FS
    u = 1 + np.sin(2 * np.pi * 5 * t)
    scored = np.arange(n) >= int(0.7 * n)                       # the first 70 % not scored
    resid = np.where(scored, rng.normal(0, 0.05, n), 0.0)
    resid[-500:] += 0.3                                          # a real excess at the end
    d = RecData("r.csv", t, np.full(n, 1 / FS), 1 / FS, u, rng.normal(0, 0.05, n), np.zeros(n), None,
                np.zeros(n, np.int8), np.arange(n), scored=scored)
    loc = locate(d, resid, resid)
    ratio = float(loc.where.split("(")[1].split("x the median")[0])
    assert 2.0 < ratio < 20.0
    assert loc.window_s[0] >= t[int(0.7 * n)]
    assert abs(loc.residual_rms_um - float(np.sqrt(np.mean(resid[scored] ** 2)))) < 1e-12
    quiet = RecData("q.csv", t, np.full(n, 1 / FS), 1 / FS, u, np.zeros(n), np.zeros(n), None,
                    np.zeros(n, np.int8), np.arange(n), scored=scored)
    spike = np.where(scored, 0.0, 0.0)
    spike[-1] = 1.0                                              # a noise-free record: the floor is the max's share
    assert float(locate(quiet, spike, spike).where.split("(")[1].split("x the median")[0]) <= 1000.0


def test_recordings_whose_starts_are_not_scored_share_one_note():
    """Seven runs of a frequency sweep each start unscored: cannot_conclude says so once, naming
    each run and how long, not seven times the same sentence; one such run keeps its own note, and
    a recording scored from its first sample adds nothing."""
    from gma_ffc.diagnose.data import unscored_note, unscored_starts_note

    def rec(name, n, settled):
        t = np.arange(n) / FS
        return RecData(name, t, np.full(n, 1 / FS), 1 / FS, np.zeros(n), np.zeros(n), np.zeros(n), None,
                       np.zeros(n, np.int8), np.arange(n), settled=settled)

    runs = [rec(f"run_{k}.csv", 1000, 10 * (k + 1)) for k in range(7)]
    note = unscored_starts_note(runs + [rec("whole.csv", 1000, 0)])
    assert note.startswith("the starts of 7 recordings are not scored (run_0.csv: the first 0.005 s;")
    assert note.count("hysteresis state at the start") == 1 and "whole.csv" not in note
    assert unscored_starts_note(runs[:1]) == unscored_note(runs[0])
    assert unscored_starts_note([rec("whole.csv", 1000, 0)]) == ""
