"""The model-fit monitor alone (issue 30): its maths against batch numpy, its states, its noise
floor, where it says the residual sits, and its prediction in blocks off the loop."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from gma_ffc.control.fit_monitor import (CLEAR_RATIO, DRIFT_RATIO, DRIFTING, OK, UNKNOWN, FitMonitor,
                                         identification_error_um)
from gma_ffc.control.prediction import FAULTED, RAMPING, Prediction, predict_block
from gma_ffc.control.recent import RecentRows

RATE = 1000.0


BLOCK = 10      # ticks per call, as the service's polls feed it


def feed(mon, t0, residual, drive=None, tracking=None):
    drive = np.full(residual.size, 1.0) if drive is None else drive
    tracking = np.zeros(residual.size) if tracking is None else tracking
    for a in range(0, residual.size, BLOCK):
        b = min(a + BLOCK, residual.size)
        mon.feed(t0 + (b - 1) / RATE, residual[a:b], drive[a:b], tracking[a:b])
    return t0 + residual.size / RATE


@settings(max_examples=40, deadline=None)
@given(st.integers(2, 20), st.integers(1, 700), st.integers(0, 2**31 - 1), st.floats(0.0, 0.3))
def test_window_rms_and_noise_floor_equal_batch_numpy(blocks, n, seed, gaps):
    """The window is the last whole blocks holding `window` judged ticks; NaN ticks are not judged
    and break the second differences."""
    rng = np.random.default_rng(seed)
    window = blocks * BLOCK
    r = rng.normal(0.0, rng.uniform(0.01, 3.0), n) + rng.uniform(-1, 1)
    r[rng.random(n) < gaps] = np.nan
    mon = FitMonitor(max(window, 16), 1 / RATE, 0.1, (0.0, 3.0))
    feed(mon, 0.0, r)
    s = mon.status()
    # batch: drop whole blocks from the front while the rest still holds a window of judged ticks
    start = 0
    ok = np.isfinite(r)
    while start + BLOCK < n and ok[start + BLOCK:].sum() >= max(window, 16) and ok[start:start + BLOCK].any():
        start += BLOCK
    while start < n and not ok[start:start + BLOCK].any():      # a block without a judged tick is never kept
        start += BLOCK
    kept = r[start:]
    if not np.isfinite(kept).any():
        return
    assert s["residual_rms_um"] == pytest.approx(np.sqrt(np.nanmean(kept ** 2)), rel=1e-9)
    d2 = np.diff(r, 2)[max(start, 2) - 2:]
    d2 = d2[np.isfinite(d2)]
    if d2.size:
        assert s["noise_floor_um"] == pytest.approx(np.sqrt(np.mean(d2 ** 2) / 6), rel=1e-9)
    if np.isfinite(kept).sum() < max(window, 16):
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
    assert mon.state == OK and mon.status()["since_s"] == pytest.approx(0.499)     # at the block that filled it
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
    # 91 ticks of 1 um^2 pass 0.09 um^2 * 1000: at the end of the block holding the 91st
    assert mon.status()["since_s"] - t == pytest.approx(0.099, abs=1e-9)


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


def _row_by_row(model, t, drive, stress, flags, gap_s):
    """The monitor's rule written tick by tick (as the loop ran it before it moved off the loop)."""
    pred = Prediction(model, 1e-3, 0.0)
    last_t, out = -math.inf, []
    for tk, u, s, f in zip(t, drive, stress, flags):
        if int(f) & FAULTED:
            if s == s:
                pred.next_um = pred.stepper.step(u, s)
            pred.next_um = math.nan
            out.append(math.nan)
            continue
        if tk - last_t > gap_s:
            pred.next_um = math.nan
        last_t = tk
        out.append(pred.next_um)
        if s == s:
            pred.next_um = pred.stepper.step(u, s)
        else:
            pred.next_um = math.nan
    return np.array(out)


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 400), st.integers(0, 2**31 - 1), st.floats(0.0, 0.2), st.integers(1, 60))
def test_block_prediction_is_the_tick_by_tick_rule(n, seed, odd, block):
    """Off the loop, in blocks of any size, the prediction is the one the tick-by-tick rule gives:
    faults (stepped with the safe current, then forgotten), ramps, invalid stresses and gaps in the
    ticks included."""
    from pathlib import Path

    from gma_ffc.modelio import load_model

    model = load_model(Path(__file__).resolve().parents[1] / "config" / "models" / "sim_sdpi.yaml")
    rng = np.random.default_rng(seed)
    t = np.cumsum(np.where(rng.random(n) < odd, rng.uniform(1e-3, 8e-3, n), 1e-3))
    drive = 1.5 + 1.4 * np.sin(np.arange(n) / 37.0)
    stress = np.where(rng.random(n) < odd, np.nan, -15.0 + rng.normal(0, 2, n))
    flags = np.where(rng.random(n) < odd, FAULTED, np.where(rng.random(n) < odd, RAMPING, 0)).astype(float)
    want = _row_by_row(model, t, drive, stress, flags, 2.5e-3)
    pred = Prediction(model, 1e-3, 0.0)
    got = np.concatenate([predict_block(pred, t[a:a + block], drive[a:a + block], stress[a:a + block],
                                        flags[a:a + block], 2.5e-3) for a in range(0, n, block)])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert np.isnan(got).tolist() == np.isnan(want).tolist()


def test_prediction_is_the_forward_model_one_write_behind():
    from pathlib import Path

    from gma_ffc.modelio import load_model

    model = load_model(Path(__file__).resolve().parents[1] / "config" / "models" / "sim_sdpi.yaml")
    pred = Prediction(model, 1e-3, 0.0)
    drive = 1.5 - 1.5 * np.cos(np.linspace(0, 4 * np.pi, 300))
    ref = model.forward_stepper(1e-3, initial_drive=0.0)
    assert math.isnan(pred.next_um)
    for u in drive:
        pred.run(np.array([u]), np.array([-15.0]))
        assert pred.next_um == ref.step(float(u), -15.0)


def test_recent_rows_last_is_in_order_and_bounded():
    rows = RecentRows(10, 2, 3)
    for k in range(25):
        rows.push(np.array([k, -k], dtype=float))
    got = rows.last(10)
    assert got[:, 0].tolist() == list(range(15, 25))
    assert rows.last(100).shape == (10, 2)
    assert RecentRows(10, 2, 3).last(5).shape == (0, 2)


def test_a_model_that_never_fit_says_so_from_the_start():
    """Drifting at the first judgement: the conditions (small loops the model fits worse than its
    identification loops), or a change that began before the first window was full (a coil heating
    from the start). The status says it may be either, not that it is no change (a new user's
    sweep, 2026-11-30: that was said of a heating coil)."""
    mon = FitMonitor(500, 1 / RATE, 0.1)
    feed(mon, 0.0, np.full(600, 1.0))
    assert mon.state == DRIFTING and mon.status()["from_start"] is True
    later = FitMonitor(500, 1 / RATE, 0.1)
    t = feed(later, 0.0, np.zeros(600))
    feed(later, t, np.full(600, 1.0))
    assert later.state == DRIFTING and later.status()["from_start"] is False
    from gma_ffc.service.status import model_fit_rows

    words = " ".join(text for _, text in model_fit_rows({"monitor": mon.status()}))
    assert "a change began before the window was full" in words and "not a change" not in words


def test_switching_the_monitor_on_or_off_needs_a_restart():
    from pathlib import Path

    from gma_ffc.control.model_watch import ModelWatch
    from gma_ffc.errors import ConfigError
    from gma_ffc.modelio import load_model

    model = load_model(Path(__file__).resolve().parents[1] / "config" / "models" / "sim_sdpi.yaml")
    cols = ["time_s", "reference_um", "current_cmd_A", "current_A", "stress_MPa", "displacement_um",
            "predicted_um", "residual_um", "outside_model"]
    watch = ModelWatch({"enabled": True, "window_s": 1.0}, ("current_A", "displacement_um"), cols, 1e-3)
    watch.start(model, 0.0)
    with pytest.raises(ConfigError, match="monitor.enabled"):
        watch.prepare(model, None, {"enabled": False, "window_s": 1.0})
    assert watch.prepare(model, None, {"enabled": True, "window_s": 2.0}) is not None
