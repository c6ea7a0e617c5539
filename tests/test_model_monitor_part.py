"""The model-fit monitor as a part of the split controller (issue 30 on issue 34's seams): built by
the builder, off the loop (it fills its columns in the telemetry writer's thread), a reload's
model prepared in the reloading thread and adopted before the next block, a restart-only key
refused."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from gma_ffc.control.config import validate_config
from gma_ffc.control.manager import ControllerManager
from gma_ffc.control.model_monitor import ModelMonitor
from gma_ffc.errors import ConfigError
from gma_ffc.recordings import read_recording
from gma_ffc.sil import cached_sdpi_and_mpi
from hil_sim.plant import PlantConfig

RATE = 250.0
REFERENCE = {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 25.5, "offset_um": 26.0}
LIMITS = {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0}


@pytest.fixture(scope="module")
def model(request):
    return cached_sdpi_and_mpi(request.config.cache.mkdir("gma_ffc_sil_models"), None)[0]


def config(tmp_path, **extra):
    return validate_config({"rate_hz": RATE, "clock": "simulated", "model": "unused.yaml", "reference": REFERENCE,
                            "limits": LIMITS, "driver": {"kind": "sim", "load_mass_kg": PlantConfig().mass_for_stress(-15.2)},
                            "telemetry": {"path": str(tmp_path / "telemetry.csv")}, "monitor": {"window_s": 2.0},
                            **extra})


def test_the_prediction_and_residual_are_in_the_recording_beside_the_displacement(tmp_path, model):
    ctrl = ControllerManager(config(tmp_path), model=model)
    monitors = [b for b in ctrl.broadcasters if isinstance(b, ModelMonitor)]
    assert len(monitors) == 1
    assert not monitors[0].on_the_loop, "the monitor costs the loop nothing: the loop does not call it"
    summary = ctrl.run(duration_s=6.0)
    assert summary["ok"] and summary["monitor"]["state"] == "ok", summary["monitor"]
    rec = read_recording(tmp_path / "telemetry.csv")
    names = list(rec.columns)
    at = names.index("displacement_um")
    assert names[at + 1:at + 3] == ["predicted_um", "residual_um"]
    d, p, r = (rec.columns[c] for c in ("displacement_um", "predicted_um", "residual_um"))
    judged = np.isfinite(r)
    assert judged.mean() > 0.95
    np.testing.assert_allclose(r[judged], d[judged] - p[judged], atol=1e-6)     # the CSV keeps ~7 digits
    # the prediction follows the rig: its residual is a small part of the stroke
    assert np.sqrt(np.mean(r[judged] ** 2)) < 0.05 * np.ptp(d[judged])


def test_no_telemetry_cell_is_nan_or_inf_text_a_missing_value_is_an_empty_cell(tmp_path, model):
    """The first row has no prediction yet and the stop ramp's rows no residual: those cells are
    empty (docs/recordings.md), never 'nan' text, and the file still reads back."""
    summary = ControllerManager(config(tmp_path), model=model).run(duration_s=0.5)
    assert summary["ok"]
    text = (tmp_path / "telemetry.csv").read_text()
    rows = [line.split(",") for line in text.splitlines() if line and not line.startswith("#")][1:]
    cells = [cell.strip().lower() for row in rows for cell in row]
    assert not [c for c in cells if "nan" in c or "inf" in c]
    assert "" in cells, "the rows without a prediction or residual hold empty cells"
    rec = read_recording(tmp_path / "telemetry.csv")
    assert len(rec) == len(rows) and np.isnan(rec.columns["predicted_um"][0])


def test_without_the_monitor_the_recording_keeps_its_old_columns(tmp_path, model):
    ctrl = ControllerManager(config(tmp_path, monitor={"enabled": False}), model=model)
    summary = ctrl.run(duration_s=0.5)
    assert summary["monitor"] == {"state": "off", "reason": "monitor.enabled is false"}
    assert "predicted_um" not in read_recording(tmp_path / "telemetry.csv").columns


def test_a_reload_while_running_replays_the_new_model_off_the_loop_and_adopts_it(tmp_path, model):
    cfg = config(tmp_path)
    ctrl = ControllerManager(cfg, model=model)
    done = {}
    loop = threading.Thread(target=lambda: done.setdefault("summary", ctrl.run(duration_s=600.0)), daemon=True)
    loop.start()
    end = time.monotonic() + 120
    while ctrl.stats.count < 4 * RATE and time.monotonic() < end:
        time.sleep(0.01)
    ctrl.reload(cfg, model=model)
    # the simulated clock runs as fast as the machine allows: the run lasts until the loop has
    # adopted the prepared model (or two minutes pass), not a fixed simulated time the replay may outlast
    while "replayed" not in ctrl.status().get("monitor", {}).get("prediction", "") and time.monotonic() < end:
        time.sleep(0.01)
    ctrl.request_stop("test over")
    loop.join(timeout=300)
    monitor = done["summary"]["monitor"]
    assert done["summary"]["ok"] and "replayed over the last" in monitor["prediction"], monitor


def test_switching_the_monitor_on_or_off_is_refused_by_a_reload(tmp_path, model):
    ctrl = ControllerManager(config(tmp_path), model=model)
    running = ctrl.setup
    with pytest.raises(ConfigError, match="monitor.enabled"):
        ctrl.reload(config(tmp_path, monitor={"enabled": False}), model=model)
    assert ctrl.setup is running

