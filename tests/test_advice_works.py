"""Advice in a refusal must work (issue 31): each test gets a refusal, does what its words say,
and shows the outcome change. The rig is a Preisach actuator, not the model class fitted."""

from __future__ import annotations

import re

import numpy as np
import pytest

from gma_ffc.diagnose.engine import diagnose
from gma_ffc.errors import InputError
from gma_ffc.identify import SDPIIdentifier
from gma_ffc.recordings import Recording
from preisach import PreisachActuator

FS = 1000.0
RIG = PreisachActuator(noise_um=0.02, seed=4)


def recording(drive: np.ndarray, name: str = "r.csv") -> Recording:
    t = np.arange(drive.size) / FS
    return Recording({"time_s": t, "current_A": drive, "displacement_um": RIG.run(drive, -11.3)}, {}, name)


def cycles(freq_hz: float, seconds: float, amplitude: np.ndarray | float = 1.0) -> np.ndarray:
    t = np.arange(int(seconds * FS)) / FS
    return 1.5 * amplitude * (1 - np.cos(2 * np.pi * freq_hz * t))


def test_too_few_samples_then_as_many_as_it_asks_for():
    short = recording(cycles(10.0, 0.1))                      # one cycle in 100 samples
    with pytest.raises(InputError) as err:
        SDPIIdentifier().fit([short])
    need = int(re.search(r"record at least (\d+) samples over at least one full drive cycle", str(err.value)).group(1))
    fewer = re.search(r"--plays (\d+) --deadzones (\d+)", str(err.value))
    assert fewer is not None
    one_cycle = 1.5 * (1 - np.cos(2 * np.pi * np.arange(need) / need))              # `need` samples
    model = SDPIIdentifier().fit([recording(one_cycle)]).model_
    assert model.invertibility_violations() == []
    model = SDPIIdentifier(n_play=int(fewer.group(1)), n_deadzone=int(fewer.group(2))).fit([short]).model_
    assert model.n_play == int(fewer.group(1))


def test_a_drive_that_never_comes_back_then_a_full_cycle():
    up = recording(np.linspace(0.0, 3.0, 600))
    with pytest.raises(InputError, match=r"record at least one full drive cycle \(min to max and back\)"):
        SDPIIdentifier().fit([up])
    model = SDPIIdentifier().fit([recording(cycles(1.0, 1.0))]).model_          # min to max and back
    assert model.invertibility_violations() == []


@pytest.fixture(scope="module")
def model():
    return SDPIIdentifier().fit([recording(cycles(3.0, 3.0), "id.csv")]).model_


def test_too_little_data_then_the_recording_it_names(model):
    dg = diagnose(model, [recording(cycles(3.0, 1.3), "short.csv")])
    assert dg.outcome == "inconclusive"
    advice = " ".join(dg.cannot_conclude)
    m = re.search(r">= (\d+) full loops, >= (\d+) samples\) at two or more drive frequencies", advice)
    assert m is not None, advice
    loops, samples = int(m.group(1)), int(m.group(2))
    # as asked: that many loops and samples, at two frequencies
    drive = np.r_[cycles(3.0, loops / 2 / 3.0 + 1), cycles(7.0, loops / 2 / 7.0 + 1)]
    assert drive.size >= samples
    dg = diagnose(model, [recording(drive, "as_asked.csv")])
    assert dg.conclusive and dg.outcome != "inconclusive", dg.cannot_conclude
    assert not any("too little data" in c for c in dg.cannot_conclude)


def test_nothing_scored_then_a_recording_that_starts_at_the_drives_minimum(model):
    """A small oscillation in the middle of the range, from an unknown history: none of it is
    scored. The advice: start at rest at an end of the drive range, e.g. a sine whose amplitude
    grows from the drive's minimum; that recording, just as short, is scored (most of it: where the
    measurement shows the model's start differing from the state a history in the range leaves, a
    stretch at its start is not)."""
    t = np.arange(400) / FS
    cut = 1.5 + 0.2 * np.sin(2 * np.pi * 10.0 * t)
    history = recording(np.r_[cycles(1.0, 0.8), cut])             # the rig's history, then the recording
    dg = diagnose(model, [Recording({k: v[800:] for k, v in history.columns.items()}, {}, "cut.csv")])
    assert dg.data[0].n_scored == 0
    note = next(c for c in dg.cannot_conclude if "none of it is scored" in c)
    assert "amplitude grows from the drive's minimum" in note
    rising = cycles(5.0, cut.size / FS, amplitude=t / t[-1])
    dg = diagnose(model, [recording(rising, "rising.csv")])
    assert dg.data[0].n_scored >= 0.8 * cut.size
    assert not any("none of it is scored" in c for c in dg.cannot_conclude)


def test_a_recording_none_of_which_is_scored_is_located_by_its_whole_residual(model):
    """The same unscored cut, 2 um off: its located residual was reported as 0 um, '0.0x the median
    window', while the base missed it by about 1 um (the residual handed to `locate` had every unscored
    sample zeroed). It is the whole residual now, as rms_before and cannot_conclude describe it."""
    t = np.arange(400) / FS
    history = recording(np.r_[cycles(1.0, 0.8), 1.5 + 0.2 * np.sin(2 * np.pi * 10.0 * t)])
    cols = {k: v[800:] for k, v in history.columns.items()}
    cols["displacement_um"] = cols["displacement_um"] + 2.0
    dg = diagnose(model, [Recording(cols, {}, "off.csv")])
    assert dg.data[0].n_scored == 0 and dg.outcome == "inconclusive"
    loc = dg.located[0]
    assert loc.residual_rms_um == pytest.approx(dg.rms_before_um) and loc.residual_rms_um > 0.5      # was 0
    assert float(loc.where.split("(")[1].split("x the median")[0]) >= 1.0


def test_a_drive_beyond_the_identified_range_then_a_model_identified_over_it(model):
    """Too little data to test saturation, on a drive a third beyond the model's range: the note
    names the share and both ranges, and says to identify over the drive used; a model so
    identified gets no such note."""
    drive = cycles(3.0, 1.3, amplitude=1.5)                      # 0..4.5 A, the model 0..3 A
    dg = diagnose(model, [recording(drive, "wide.csv")])
    assert dg.outcome == "inconclusive"
    note = next(c for c in dg.cannot_conclude if "beyond the range the model was identified on" in c)
    assert "(0..3 A; this recording 0..4.5 A)" in note and "identify the model from recordings over the whole" in note
    wide_model = SDPIIdentifier().fit([recording(cycles(3.0, 3.0, amplitude=1.5), "id_wide.csv")]).model_
    dg = diagnose(wide_model, [recording(drive, "wide.csv")])
    assert not any("beyond the range" in c for c in dg.cannot_conclude)


def test_a_start_the_drive_never_forgets_then_a_cycle_over_the_whole_range(request):
    """The demo's SDPI on hil_sim's rig, whose rod starts demagnetised, a state no history inside the drive range leaves, and a
    quiet sensor (2 nm) shows it. A run tracking in the lower part of the range (as a controller's
    telemetry) never forgets that start, so none of it was scored, and the advice was to start at an
    end of the range or record a full drive cycle: the run did both. The advice now names the cycle
    that makes the model forget the start; with it before the same run, the run is scored."""
    from gma_ffc.sil import cached_sdpi_and_mpi
    from hil_sim.plant import GMAPlant, PlantConfig

    cfg = PlantConfig().with_effects(["noise"])
    cfg.noise.displacement_std_um, cfg.noise.displacement_quantum_um = 0.002, 0.001

    def rig(drive: np.ndarray, name: str) -> Recording:
        t = np.arange(drive.size) / FS
        out = GMAPlant(cfg, seed=1).run(t, drive, load_mass_kg=cfg.mass_for_stress(-15.2))
        return Recording({k: out[k] for k in ("current_A", "stress_MPa", "displacement_um")} | {"time_s": t}, {}, name)

    model = cached_sdpi_and_mpi(request.config.cache.mkdir("gma_ffc_sil_models"))[0]
    tracking = 0.6 * cycles(3.0, 3.0)                                     # 0 .. 1.8 A of 0 .. 3 A
    dg = diagnose(model, [rig(tracking, "tracking.csv")])
    note = next(c for c in dg.cannot_conclude if "none of it is scored" in c)
    m = re.search(r"drive one full cycle from (\S+) to (\S+) A and back before the run", note)
    assert m is not None, note
    lo, hi = float(m.group(1)), float(m.group(2))
    cycle = lo + (hi - lo) * 0.5 * (1 - np.cos(2 * np.pi * np.arange(int(FS)) / FS))     # one cycle in 1 s
    dg = diagnose(model, [rig(np.r_[cycle, tracking], "cycled_first.csv")])
    assert not any("none of it is scored" in c for c in dg.cannot_conclude)
    assert dg.data[0].n_scored >= 0.8 * tracking.size


def test_the_advice_held_within_the_controllers_drive_limits_then_each_step_it_asks_for(request):
    """The same start, diagnosed as the service does for a controller limited to 0..2 A of the
    model's 0..3 A: the cycle asked for stayed the model's (0..3 A), beyond the limits. Now it is
    held within them; a run after that cycle, still not scored (the widest plays kept the start),
    is told to identify a model over the drive allowed; and so identified, the run is scored."""
    from gma_ffc.sil import cached_sdpi_and_mpi
    from hil_sim.plant import GMAPlant, PlantConfig

    cfg = PlantConfig().with_effects(["noise"])
    cfg.noise.displacement_std_um, cfg.noise.displacement_quantum_um = 0.002, 0.001

    def rig(drive: np.ndarray, name: str, stress: float = -15.2, seed: int = 1) -> Recording:
        t = np.arange(drive.size) / FS
        out = GMAPlant(cfg, seed=seed).run(t, drive, load_mass_kg=cfg.mass_for_stress(stress))
        return Recording({k: out[k] for k in ("current_A", "stress_MPa", "displacement_um")} | {"time_s": t}, {}, name)

    model = cached_sdpi_and_mpi(request.config.cache.mkdir("gma_ffc_sil_models"))[0]
    limits = (0.0, 2.0)
    assert model.drive_range[1] > limits[1]
    tracking = 0.6 * cycles(3.0, 3.0)                                     # 0 .. 1.8 A
    dg = diagnose(model, [rig(tracking, "tracking.csv")], drive_limits=limits)
    note = next(c for c in dg.cannot_conclude if "none of it is scored" in c)
    m = re.search(r"drive one full cycle from (\S+) to (\S+) A \(the model's range 0 to 3 A, held within the drive "
                  r"limits\) and back before the run", note)
    assert m is not None, note
    lo, hi = float(m.group(1)), float(m.group(2))
    assert limits[0] <= lo < hi <= limits[1]
    cycle = lo + (hi - lo) * 0.5 * (1 - np.cos(2 * np.pi * np.arange(int(FS)) / FS))
    cycled = rig(np.r_[cycle, tracking], "cycled_first.csv")
    dg = diagnose(model, [cycled], drive_limits=limits)
    note = next(c for c in dg.cannot_conclude if "none of it is scored" in c)
    m = re.search(r"still did not: identify a model over the drive the controller allows \((\S+) to (\S+) A\)", note)
    assert m is not None and "drive one full cycle" not in note, note
    low, high = float(m.group(1)), float(m.group(2))
    ident = [rig(low + (high - low) / 3.0 * cycles(3.0, 3.0), f"id{s}.csv", s, seed=2) for s in (-11.3, -15.2, -19.1)]
    within = SDPIIdentifier(n_play=10, n_deadzone=7).fit(ident).model_
    dg = diagnose(within, [cycled], drive_limits=limits)
    assert not any("none of it is scored" in c for c in dg.cannot_conclude)
    assert dg.data[0].n_scored >= 0.8 * tracking.size


def test_a_drive_outside_the_model_is_told_a_range_within_the_drive_limits(model):
    """Recordings that never enter the model's 0..3 A, diagnosed for a controller limited to
    0..2 A: the range to record in is the limits' part of the model's, and a recording there is
    taken."""
    with pytest.raises(InputError) as err:
        diagnose(model, [recording(4.0 + 0.3 * cycles(3.0, 2.0), "high.csv")], drive_limits=(0.0, 2.0))
    m = re.search(r"record inside (\S+)\.\.(\S+) \(the model's range 0 to 3 A, held within the drive limits\)",
                  str(err.value))
    assert m is not None, str(err.value)
    lo, hi = float(m.group(1)), float(m.group(2))
    assert (lo, hi) == (0.0, 2.0)
    inside = lo + (hi - lo) / 3.0 * cycles(3.0, 2.0)
    assert diagnose(model, [recording(inside, "inside.csv")], drive_limits=(0.0, 2.0)).data[0].n_scored > 0


def test_a_model_diagnosed_on_its_own_identification_recording_is_told_to_give_it_with_ident(model):
    """Identified on id.csv and diagnosed on id.csv: the note said 'the identification recordings
    (id.csv) were not given', beside the very file."""
    dg = diagnose(model, [recording(cycles(3.0, 3.0), "id.csv")])
    note = dg.to_json()["identification"]["note"]
    assert note.startswith("id.csv bears the name of one of the model's identification recordings")
    assert "not given" not in note


def test_a_load_cell_logging_compression_as_positive_then_the_column_negated():
    """Compression is negative in recordings; a rig that logs it positive is told to negate the
    column (not to identify anew), and negated it runs. At other loads it is not told to."""
    from gma_ffc.errors import ModelError
    from gma_ffc.model import stress_sign_advice

    recs = []
    for k, sigma in enumerate((-12.0, -16.0, -20.0)):
        d = cycles(3.0, 2.0)
        recs.append(Recording({"time_s": np.arange(d.size) / FS, "current_A": d, "stress_MPa": np.full(d.size, sigma),
                               "displacement_um": RIG.run(d, sigma)}, {}, f"id{k}.csv"))
    sdpi = SDPIIdentifier().fit(recs).model_
    drive = cycles(3.0, 1.0)
    logged = np.full(drive.size, 15.0)                    # 15 MPa of compression, logged positive
    with pytest.raises(ModelError, match="negate the stress_MPa column"):
        sdpi.simulate(None, drive, logged)
    assert np.all(np.isfinite(sdpi.simulate(None, drive, -logged)))
    assert stress_sign_advice(np.full(10, -30.0), sdpi.stress_range_MPa) == ""    # another load: no flip advised
    assert stress_sign_advice(np.full(10, -15.0), sdpi.stress_range_MPa) == ""    # inside: nothing to advise
    flipped = [Recording({**r.columns, "stress_MPa": -r.columns["stress_MPa"]}, {}, r.source) for r in recs]
    assert any("negate the column before identifying" in n for n in SDPIIdentifier().fit(flipped).notes_)
    assert not any("negate the column" in n for n in SDPIIdentifier().fit(recs).notes_)


def test_a_recording_of_three_samples_then_the_recording_the_refusal_asks_for(model):
    """diagnose stopped on an internal IndexError on a recording of 2-4 samples."""
    with pytest.raises(InputError) as err:
        diagnose(model, [recording(cycles(3.0, 0.003), "three.csv")])
    m = re.search(r"only 3 samples; .*record at least (\d+) samples over (\d+) or more full drive cycles, "
                  r"at two or more drive frequencies", str(err.value))
    assert m is not None and "\n" not in str(err.value), str(err.value)
    samples, loops = int(m.group(1)), int(m.group(2))
    drive = np.r_[cycles(3.0, loops / 2 / 3.0 + 1), cycles(7.0, loops / 2 / 7.0 + 1)]     # as asked
    assert drive.size >= samples
    dg = diagnose(model, [recording(drive, "as_asked.csv")])
    assert dg.conclusive and not any("too little data" in c for c in dg.cannot_conclude), dg.cannot_conclude


def test_a_short_recording_that_never_sweeps_is_told_so_not_to_fit_fewer_operators():
    """30 samples of a half sweep were told '--plays 2 --deadzones 1', which then failed with 'the drive
    never sweeps ... back': the real fault comes first. A full cycle in as few samples is told to fit
    fewer operators, and doing so fits."""
    with pytest.raises(InputError) as err:
        SDPIIdentifier().fit([recording(np.linspace(0.0, 3.0, 30))])
    assert "never sweeps" in str(err.value) and "--plays" not in str(err.value), str(err.value)
    one_cycle = 1.5 * (1 - np.cos(2 * np.pi * np.arange(30) / 30))
    with pytest.raises(InputError) as err:
        SDPIIdentifier().fit([recording(one_cycle)])
    fewer = re.search(r"--plays (\d+) --deadzones (\d+)", str(err.value))
    assert fewer is not None, str(err.value)
    model = SDPIIdentifier(n_play=int(fewer.group(1)), n_deadzone=int(fewer.group(2))).fit([recording(one_cycle)]).model_
    assert model.n_play == int(fewer.group(1))


def test_recordings_whose_stresses_disagree_in_sign_name_the_positive_one_and_negated_it_fits_compression():
    """A recording at -11.3 MPa and one logged at +15.2 MPa gave an SDPI over -11.3..15.2 MPa and no
    word; the note names the positive one, and negated as it says the model spans compression only."""
    d = cycles(3.0, 2.0)
    t = np.arange(d.size) / FS
    neg = Recording({"time_s": t, "current_A": d, "stress_MPa": np.full(d.size, -11.3),
                     "displacement_um": RIG.run(d, -11.3)}, {}, "neg.csv")
    pos = Recording({"time_s": t, "current_A": d, "stress_MPa": np.full(d.size, 15.2),
                     "displacement_um": RIG.run(d, -15.2)}, {}, "pos.csv")
    notes = SDPIIdentifier().fit([neg, pos]).notes_
    said = [n for n in notes if "negate their stress_MPa column" in n]
    assert len(said) == 1 and "positive in pos.csv (+15.2 MPa) but negative in 1 other" in said[0], notes
    assert "neg.csv" not in said[0]
    negated = pos.with_column("stress_MPa", -pos.columns["stress_MPa"])                 # done as advised
    fitted = SDPIIdentifier().fit([neg, negated])
    assert not any("negate" in n for n in fitted.notes_)
    assert fitted.model_.stress_range_MPa == pytest.approx((-15.2, -11.3))


def two_rates(amplitude: float) -> np.ndarray:
    """Enough loops at two drive frequencies for effects to be told apart, from 0 to 3 A x amplitude."""
    return np.r_[cycles(3.0, 3.0, amplitude), cycles(7.0, 2.0, amplitude)]


def _saturation(dg):
    return next(c for c in dg.candidates if c.effect == "saturation")


def test_saturation_on_a_rig_held_to_the_identified_range_is_not_advised_beyond_its_limits(model):
    """The model's 0..3 A, the controller's limits 0..3 A, a drive inside: saturation beyond them
    cannot be tested and does not matter there; no advice asks for a drive beyond the limits."""
    dg = diagnose(model, [recording(two_rates(0.9), "inside.csv")], drive_limits=(0.0, 3.0))
    note = next(c for c in dg.cannot_conclude if c.startswith("saturation:"))
    assert "already reaches the drive limits (0..3 A)" in note and "does not matter on a rig held to" in note
    assert "beyond that range" not in note and "record" not in note, note


def test_saturation_advice_goes_to_the_drive_limit_and_a_recording_there_tests_it(model):
    """Limits wider than the model's range: the note asks for a drive up to the upper limit, not
    beyond it; a recording that does just that (and stays within the limits) makes it testable."""
    limits = (0.0, 3.6)
    dg = diagnose(model, [recording(two_rates(0.9), "inside.csv")], drive_limits=limits)
    note = next(c for c in dg.cannot_conclude if c.startswith("saturation:"))
    m = re.search(r"record with a drive up to (\S+) A, to the end of the drive limits \(0\.\.3\.6 A\)", note)
    assert m is not None and "down to" not in note, note
    top = float(m.group(1))
    assert top == limits[1]
    as_asked = two_rates(top / 3.0)                               # 0..3.6 A: up to the limit, no further
    assert as_asked.max() <= limits[1] + 1e-12
    dg = diagnose(model, [recording(as_asked, "to_the_limit.csv")], drive_limits=limits)
    assert _saturation(dg).testable, _saturation(dg).reason
    assert not any(c.startswith("saturation:") for c in dg.cannot_conclude)
