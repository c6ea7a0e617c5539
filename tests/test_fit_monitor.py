"""The model-fit monitor alone (issue 30): its maths against batch numpy, its states, its noise
floor, where it says the residual sits, and that a tick allocates nothing."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from allocation import worst_call_allocation
from gma_ffc.control.fit_monitor import (CLEAR_RATIO, DRIFT_RATIO, DRIFTING, OK, UNKNOWN, FitMonitor,
                                         identification_error_um)
from gma_ffc.control.prediction import Prediction
from gma_ffc.control.recent import RecentRows

RATE = 1000.0


def feed(mon, t0, residual, drive=None, tracking=None):
    drive = np.full(residual.size, 1.0) if drive is None else drive
    tracking = np.zeros(residual.size) if tracking is None else tracking
    for k, r in enumerate(residual):
        mon.update(t0 + k / RATE, float(r), float(drive[k]), float(tracking[k]))
    return t0 + residual.size / RATE


@settings(max_examples=40, deadline=None)
@given(st.integers(16, 200), st.integers(1, 700), st.integers(0, 2**31 - 1))
def test_window_rms_and_noise_floor_equal_batch_numpy(window, n, seed):
    rng = np.random.default_rng(seed)
    r = rng.normal(0.0, rng.uniform(0.01, 3.0), n) + rng.uniform(-1, 1)
    mon = FitMonitor(window, 1 / RATE, 0.1, (0.0, 3.0))
    feed(mon, 0.0, r)
    s = mon.status()
    last = r[-min(n, window):]
    assert s["residual_rms_um"] == pytest.approx(np.sqrt(np.mean(last ** 2)), rel=1e-9)
    if n >= window:          # the noise floor of the last whole window, from its second differences
        end = (n // window) * window
        d2 = np.diff(r, 2)[max(end - window, 2) - 2:end - 2]       # d2[j-2] = r[j] - 2 r[j-1] + r[j-2]
        assert s["noise_floor_um"] == pytest.approx(np.sqrt(np.mean(d2 ** 2) / 6), rel=1e-9)
    else:
        assert s["state"] == UNKNOWN and s["ratio"] is None


def test_noise_floor_finds_white_noise_under_a_slow_model_error():
    """A 3 Hz model error of 1 um plus 0.02 um of sensor noise at 1 kHz: the floor is the noise."""
    t = np.arange(5000) / RATE
    rng = np.random.default_rng(3)
    r = 1.0 * np.sin(2 * np.pi * 3 * t) + rng.normal(0, 0.02, t.size)
    mon = FitMonitor(2000, 1 / RATE, 0.1)
    feed(mon, 0.0, r)
    assert mon.status()["noise_floor_um"] == pytest.approx(0.02, rel=0.1)


def test_states_in_order_with_hysteresis_between_thresholds():
    mon = FitMonitor(500, 1 / RATE, 0.1)
    rng = np.random.default_rng(0)
    t = feed(mon, 0.0, rng.normal(0, 0.1, 400))
    assert mon.state == UNKNOWN                             # not a whole window yet
    t = feed(mon, t, rng.normal(0, 0.1, 200))
    assert mon.state == OK and mon.status()["since_s"] == pytest.approx(0.499)
    expected = math.hypot(0.1, mon.status()["noise_floor_um"])

    def level(ratio, n):      # the same noise (so the same floor) on an offset giving this ratio
        return rng.normal(0, 0.1, n) + math.sqrt((ratio * expected) ** 2 - 0.01)

    between = 0.5 * (DRIFT_RATIO + CLEAR_RATIO)
    t = feed(mon, t, level(between, 1000))
    assert mon.state == OK
    t = feed(mon, t, level(2 * DRIFT_RATIO, 1000))
    assert mon.state == DRIFTING
    since = mon.status()["since_s"]
    # back between the thresholds: stays drifting (no flapping); below the lower one: ok again
    t = feed(mon, t, level(between, 1000))
    assert mon.state == DRIFTING and mon.status()["since_s"] == since
    feed(mon, t, rng.normal(0, 0.1, 1000))
    assert mon.state == OK and mon.status()["ratio"] < CLEAR_RATIO


def test_drift_enters_within_the_window_it_needs():
    """A step of 1 um against a 0.1 um model: drifting as soon as the window's mean square passes
    (3x)^2 of the expected, here 0.1 s into a 1 s window."""
    mon = FitMonitor(1000, 1 / RATE, 0.1)
    t = feed(mon, 0.0, np.zeros(1500))
    assert mon.state == OK
    feed(mon, t, np.full(200, 1.0))
    assert mon.state == DRIFTING
    assert mon.status()["since_s"] - t == pytest.approx(0.091, abs=0.002)   # 91 ticks of 1 um^2 > 0.09 um^2 * 1000


def test_without_identification_error_the_first_window_is_the_reference():
    mon = FitMonitor(500, 1 / RATE, None)
    rng = np.random.default_rng(1)
    feed(mon, 0.0, rng.normal(0, 0.5, 500))
    s = mon.status()
    assert s["state"] == OK and 0.6 < s["ratio"] <= 1.0     # its own RMS against itself plus the noise
    assert "first whole window" in s["reference"]
    feed(mon, 0.5, rng.normal(0, 0.5, 500) + 4.0)
    assert mon.state == DRIFTING


def test_where_names_the_drive_band_and_rate_band_of_the_residual():
    """A residual only where the drive is high and moving fast: the status points there."""
    t = np.arange(4000) / RATE
    drive = 1.5 - 1.5 * np.cos(2 * np.pi * 2 * t)           # 0..3 A at 2 Hz: up to ~19 A/s
    rate = np.abs(np.gradient(drive, t))
    residual = np.where((drive > 2.25) & (drive < 2.625) & (rate > 9.5), 1.0, 0.01)
    mon = FitMonitor(2000, 1 / RATE, 0.05, (0.0, 3.0))
    feed(mon, 0.0, residual, drive)
    where = mon.status()["where"]
    assert where["drive"]["range"] == pytest.approx([2.25, 2.625])
    lo, hi = where["drive_rate_per_s"]["range"]
    assert lo <= 12 <= hi and lo >= 2.8


def test_identification_error_from_provenance():
    class M:
        provenance = {"fit_rms_um": {"a.csv": 0.1, "b.csv": 0.2}}

    class E:
        base = M()

    assert identification_error_um(M()) == pytest.approx(math.sqrt(0.025))
    assert identification_error_um(E()) == pytest.approx(math.sqrt(0.025))
    assert identification_error_um(object()) is None


def test_a_tick_allocates_nothing():
    # a window shorter than the measurement's warm-up: floats stored before tracing started are all
    # replaced by traced ones before the first measured call (else their replacement counts)
    mon = FitMonitor(16, 1 / RATE, 0.1, (0.0, 3.0))
    rows = RecentRows(8, 8, 4)
    row = np.arange(8.0)
    values = [0.1 * math.sin(k / 7.0) for k in range(997)]

    def tick(k):
        mon.update(k * 1e-3, values[k % 997], 1.5 + values[k % 997], 0.3)
        mon.skip() if k % 101 == 0 else None
        rows.push(row)

    for k in range(2000):      # through several wraps before measuring
        tick(k)
    worst, peak = worst_call_allocation(tick, 1000)   # spans 60 wraps (publishing the bands)
    assert worst <= 0, f"retained {worst} bytes"
    assert peak <= 128, f"allocated up to {peak} bytes on the way"


def test_prediction_is_the_forward_model_one_write_behind():
    from pathlib import Path

    from gma_ffc.modelio import load_model

    model = load_model(Path(__file__).resolve().parents[1] / "config" / "models" / "sim_sdpi.yaml")
    pred = Prediction(model, 1e-3, 0.0)
    drive = 1.5 - 1.5 * np.cos(np.linspace(0, 4 * np.pi, 300))
    ref = model.forward_stepper(1e-3, initial_drive=0.0)
    assert math.isnan(pred.next_um)
    for u in drive:
        pred.after_write(float(u), -15.0)
        assert pred.next_um == ref.step(float(u), -15.0)


def test_recent_rows_last_is_in_order_and_bounded():
    rows = RecentRows(10, 2, 3)
    for k in range(25):
        rows.push(np.array([k, -k], dtype=float))
    got = rows.last(10)
    assert got[:, 0].tolist() == list(range(15, 25))
    assert rows.last(100).shape == (10, 2)
    assert RecentRows(10, 2, 3).last(5).shape == (0, 2)
