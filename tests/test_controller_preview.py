"""A transport delay found by `gma-ffc diagnose` is compensated in the control loop: the controller
asks for the reference `preview_s` ahead, and telemetry still records the reference for now."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from gma_ffc.control.config import validate_config
from gma_ffc.control.manager import ControllerManager
from gma_ffc.sil import cached_sdpi_and_mpi, tracking_rms_um
from gma_ffc.extended import ExtendedModel
from gma_ffc.recordings import read_recording

DELAY_S = 0.006


@pytest.fixture(scope="module")
def sdpi(request):
    return cached_sdpi_and_mpi(request.config.cache.mkdir("gma_ffc_sil_models"))[0]


def run(tmp_path, model, name: str) -> tuple[float, dict]:
    plant = tmp_path / "delayed_plant.yaml"
    plant.write_text(yaml.safe_dump({"delay": {"enabled": True, "delay_ms": DELAY_S * 1e3}}))
    cfg = validate_config({
        "rate_hz": 1000, "clock": "simulated", "model": "unused.yaml",
        "driver": {"kind": "sim", "load_mass_kg": 15.0, "plant_config": str(plant)},
        "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 12.0, "offset_um": 15.0},
        "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0},
        "telemetry": {"path": str(tmp_path / f"{name}.csv")},
    })
    ctrl = ControllerManager(cfg, model=model)
    summary = ctrl.run(duration_s=1.5)
    assert summary["ok"], summary["faults"]
    rec = read_recording(cfg.telemetry["path"], require=("time_s", "drive", "displacement_um", "reference_um"))
    t = rec.time_s
    # the recorded reference is the one for now (the sine at t), whatever the look-ahead
    expected = 15.0 + 12.0 * np.sin(2 * np.pi * 3.0 * t - np.pi / 2)
    assert np.max(np.abs(rec.columns["reference_um"] - expected)) < 1e-6
    return tracking_rms_um(rec, skip_s=1 / 3), rec.metadata


def test_delay_block_makes_the_loop_look_ahead_and_track_better(tmp_path, sdpi) -> None:
    plain, _ = run(tmp_path, sdpi, "plain")
    extended = ExtendedModel(sdpi, {"delay": {"delay_s": DELAY_S}})
    assert extended.preview_s == pytest.approx(DELAY_S)
    compensated, meta = run(tmp_path, extended, "extended")
    assert meta["command_lead_s"] == pytest.approx(DELAY_S)
    # 6 ms at 3 Hz and 12 um amplitude is ~0.96 um RMS of pure lag; the preview removes it
    assert compensated <= 0.5 * plain, (compensated, plain)


def test_learning_runs_on_an_extended_model_as_on_the_plain_one(tmp_path, sdpi) -> None:
    """'gma-ffc reload --model DIR/extended_model.yaml' (the status's own advice after a background
    diagnosis) was refused with 'time_s and drive must be 1-D of equal, non-zero length' whenever
    learning was on: its gain table simulated the model without times (a new user's sweep,
    2026-11-30). An extended model gives the plain one's gain where its effects are slow."""
    from gma_ffc.control.learning import model_gain_table

    extended = ExtendedModel(sdpi, {"thermal": {"tau_s": 60.0, "gain_um_per_A2": 1.3},
                                    "delay": {"delay_s": DELAY_S}})
    plain_gain, extended_gain = model_gain_table(sdpi), model_gain_table(extended)
    assert plain_gain is not None and extended_gain is not None
    for stress in np.linspace(*sdpi.stress_range_MPa, 5):
        assert extended_gain(stress) == pytest.approx(plain_gain(stress), rel=0.05)
    cfg = validate_config({
        "rate_hz": 1000, "clock": "simulated", "model": "unused.yaml", "driver": {"kind": "sim", "load_mass_kg": 15.0},
        "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 12.0, "offset_um": 15.0},
        "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0},
        "learning": {"kind": "repetitive"}, "telemetry": {"path": str(tmp_path / "learn.csv")}})
    summary = ControllerManager(cfg, model=extended).run(duration_s=1.0)
    assert summary["ok"], summary["fault_messages"]
