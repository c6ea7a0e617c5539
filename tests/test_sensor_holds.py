"""A displacement reading that holds while the drive moves on (a sensor at the end of its range, or
a stalled sensor or logger) is the sensor's: diagnose leaves those samples unscored and says why,
with the recording to make, and identify says it fits them. The rig is a Preisach actuator, not the
model class fitted."""

from __future__ import annotations

import numpy as np
import pytest

from gma_ffc.diagnose.engine import diagnose
from gma_ffc.identify import SDPIIdentifier
from gma_ffc.recordings import Recording
from gma_ffc.sensor_holds import CLIP_DRIVE_SHARE, REPEATS_RARE, held_samples
from preisach import PreisachActuator

FS = 1000.0
RIG = PreisachActuator(noise_um=0.02, seed=4)


def clipped_samples(y: np.ndarray, u: np.ndarray) -> np.ndarray:
    return held_samples(y, u)[0]


def sine(seconds: float, freq_hz: float) -> np.ndarray:
    t = np.arange(int(seconds * FS)) / FS
    return 1.5 * (1 - np.cos(2 * np.pi * freq_hz * t))


def test_a_flat_top_over_a_moving_drive_is_clipping():
    u = sine(2.0, 2.0)
    y = 30.0 * u / 3.0
    top = float(np.quantile(y, 0.9))
    got = clipped_samples(np.minimum(y, top), u)
    assert np.array_equal(got, y >= top)


def test_a_quantised_turning_point_and_a_held_drive_are_not():
    u = sine(2.0, 2.0)
    y = np.round(30.0 * u / 3.0, 2)                       # a sensor of 10 nm steps: the peak repeats
    assert np.sum(y == y.max()) > 1 and not clipped_samples(y, u).any()
    held = np.r_[u, np.full(500, u[-1])]                   # the drive held: the reading may hold too
    assert not clipped_samples(np.r_[y, np.full(500, y.max() + 1.0)], held).any()
    # a flat top over less drive than CLIP_DRIVE_SHARE of its span is left alone (its reason: the
    # clipping it hides is small), one over more is found
    smooth = 30.0 * u / 3.0
    for share, found in ((0.5 * CLIP_DRIVE_SHARE, False), (2.0 * CLIP_DRIVE_SHARE, True)):
        assert clipped_samples(np.minimum(smooth, 30.0 * (1 - share)), u).any() == found


@pytest.mark.parametrize("freq_hz", [4.0, 6.0])
def test_a_slow_quantised_sensor_logged_faster_is_not_clipping(freq_hz):
    """A 100 Hz sensor of 50 nm steps in 1 kHz rows repeats each reading ten times, and its peaks
    repeat the same value, while the drive moves over 1 % of its span: ten of the sensor's steps
    (CLIP_STEPS) are more than that, so it is not clipping. Its top clipped is."""
    u = sine(2.0, freq_hz)
    y = np.repeat(np.round(30.0 * u / 3.0 / 0.05)[::10] * 0.05, 10)
    assert np.sum(y == y.max()) > 10
    assert not clipped_samples(y, u).any()
    assert clipped_samples(np.minimum(y, float(np.quantile(y, 0.7))), u).any()


def _stall(y: np.ndarray, at: int, rows: int) -> np.ndarray:
    out = y.copy()
    out[at: at + rows] = y[at]
    return out


def test_a_stalled_reading_inside_the_range_is_found_where_repeats_are_otherwise_rare():
    u = sine(2.0, 2.0)
    y = 30.0 * u / 3.0 + np.random.default_rng(5).normal(0, 0.01, u.size)
    clipped, stalled = held_samples(_stall(y, 350, 40), u)          # 40 ms frozen on the way down
    assert not clipped.any() and np.flatnonzero(stalled).tolist() == list(range(350, 390))
    # just after the drive turns, hysteresis itself holds the output (AFTER_REVERSAL): not called a stall
    assert not held_samples(_stall(y, 255, 40), u)[1].any()
    assert not any(held_samples(y, u)[1])                           # nothing stalls: nothing found


def test_where_the_sensor_repeats_itself_a_hold_inside_the_range_is_not_called_a_stall():
    """A sensor slower than the logger, or noise-free data, repeats most rows: REPEATS_RARE's gate."""
    u = sine(2.0, 2.0)
    slow = np.repeat((30.0 * u / 3.0 + np.random.default_rng(5).normal(0, 0.01, u.size))[::4], 4)
    assert np.mean(np.diff(slow) == 0) > REPEATS_RARE
    assert not held_samples(_stall(slow, 300, 40), u)[1].any()
    steps = np.floor(30.0 * u / 3.0)                                 # noise-free, in 1 um steps: holds between them
    assert not held_samples(steps, u)[1].any()


@pytest.fixture(scope="module")
def model():
    rec = Recording({"time_s": np.arange(3000) / FS, "current_A": sine(3.0, 3.0),
                     "displacement_um": RIG.run(sine(3.0, 3.0), -11.3)}, {}, "id.csv")
    return SDPIIdentifier().fit([rec]).model_


def test_diagnose_leaves_a_clipped_top_unscored_and_says_what_to_record(model):
    t = np.arange(12000) / FS
    drive = 1.5 * (1 - np.cos(2 * np.pi * np.where(t < 6, 2.0, 7.0) * t))
    y = RIG.run(drive, -11.3)
    whole = Recording({"time_s": t, "current_A": drive, "displacement_um": y}, {}, "run.csv")
    top = float(np.quantile(y, 0.92))
    clipped = Recording({**whole.columns, "displacement_um": np.minimum(y, top)}, {}, "clipped.csv")
    dg_whole, dg_clipped = diagnose(model, [whole]), diagnose(model, [clipped])
    note = next(n for n in dg_clipped.cannot_conclude if "the sensor at the end of its range" in n)
    assert f"{top:.6g} um, its largest value" in note and "record with the sensor's range covering" in note
    assert dg_clipped.data[0].n_scored < dg_whole.data[0].n_scored - 0.05 * t.size    # about the 8 % clipped
    # the base's error is judged on what the sensor saw, not on the clipped tops
    assert dg_clipped.rms_before_um == pytest.approx(dg_whole.rms_before_um, rel=0.15)
    assert not any("the sensor at the end of its range" in n for n in dg_whole.cannot_conclude)


def test_diagnose_leaves_a_stalled_logger_unscored_and_says_so(model):
    t = np.arange(12000) / FS
    drive = 1.5 * (1 - np.cos(2 * np.pi * np.where(t < 6, 2.0, 7.0) * t))
    y = RIG.run(drive, -11.3)
    stalled = _stall(_stall(y, 2125, 60), 8320, 30)                 # each well after the drive turned
    dg = diagnose(model, [Recording({"time_s": t, "current_A": drive, "displacement_um": stalled}, {}, "log.csv")])
    note = next(n for n in dg.cannot_conclude if "a stalled sensor or logger" in n)
    assert "stops changing 2 time(s)" in note and "0.8% of the samples" in note     # 90 of 12,000 rows


def test_identify_says_when_it_fits_a_sensor_at_the_end_of_its_range(model):
    drive = sine(3.0, 3.0)
    y = RIG.run(drive, -11.3)
    top = float(np.quantile(y, 0.85))
    clipped = Recording({"time_s": np.arange(drive.size) / FS, "current_A": drive,
                         "displacement_um": np.minimum(y, top)}, {}, "id_clipped.csv")
    notes = SDPIIdentifier().fit([clipped]).notes_
    assert any(f"id_clipped.csv: the displacement holds at {top:.6g} um" in n and "fitted to them" in n for n in notes)
    assert not any("the sensor at the end of its range" in n for n in model.provenance.get("notes", []))
