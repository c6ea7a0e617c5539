"""Closed-loop runs of the real controller on the simulated rig, with and without learning.

One function builds a controller config for the `sim` driver (simulated clock, so a run of
minutes takes seconds), runs the real `gma_ffc.control.controller.Controller` and returns the
per-period tracking RMS from its telemetry. `scripts/bench_learning.py`, the tests and the demo
use it, so the figures they quote come from the code a lab runs.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import yaml

# The rig the learning must cope with (issue 12): sensor noise, a transport delay, eddy currents;
# the load step is in the schedule. The controller's lead covers the delay it knows about.
RIG_EFFECTS = {"noise": {"enabled": True}, "delay": {"enabled": True, "delay_ms": 1.0},
               "eddy": {"enabled": True, "time_constant_ms": 0.5}}


@dataclass
class LoopRun:
    """Per-period tracking RMS (um) of one run, and the controller's final status."""

    frequency_hz: float
    learning: bool
    period_rms_um: np.ndarray
    status: dict[str, Any]


def run_tracking(model_path: str | Path, frequency_hz: float, periods: int, *, learning: dict | None = None,
                 rate_hz: float = 1000.0, amplitude_um: float = 12.0, offset_um: float = 20.0,
                 load_schedule: Sequence[Sequence[float]] = ((0.0, 0.0),), lead_s: float = 0.001,
                 plant_effects: dict | None = None, seed: int = 0, workdir: str | Path | None = None) -> LoopRun:
    """Track a sine for `periods` periods on the simulated rig through the real controller."""
    from gma_ffc.control.config import validate_config
    from gma_ffc.control.controller import Controller
    from gma_ffc.recordings import read_recording

    tmp = tempfile.TemporaryDirectory() if workdir is None else None
    folder = Path(workdir if workdir is not None else tmp.name)  # type: ignore[union-attr]
    try:
        plant_path = folder / "plant.yaml"
        plant_path.write_text(yaml.safe_dump(RIG_EFFECTS if plant_effects is None else plant_effects))
        tag = f"{frequency_hz:g}Hz_{'learn' if learning else 'ff'}"
        data = {
            "rate_hz": rate_hz, "clock": "simulated", "model": str(model_path),
            "driver": {"kind": "sim", "plant_config": str(plant_path), "seed": seed,
                       "load_mass_kg": float(load_schedule[0][1]),
                       "load_schedule": [[float(a), float(b)] for a, b in load_schedule[1:]]},
            "reference": {"kind": "sine", "frequency_hz": frequency_hz, "amplitude_um": amplitude_um,
                          "offset_um": offset_um, "lead_s": lead_s},
            "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0},
            "telemetry": {"path": str(folder / f"{tag}.csv"), "flush_interval_s": 0.5},
        }
        if learning:
            data["learning"] = dict(learning)
        cfg = validate_config(data)
        ctrl = Controller(cfg)
        status = ctrl.run(duration_s=periods / frequency_hz)
        rec = read_recording(cfg.telemetry["path"])
        err = rec.columns["reference_um"] - rec.displacement_um
        n = int(round(rate_hz / frequency_hz))
        k = len(err) // n
        rms = np.sqrt(np.mean(err[: k * n].reshape(k, n) ** 2, axis=1))
        return LoopRun(frequency_hz, bool(learning), rms, status)
    finally:
        if tmp is not None:
            tmp.cleanup()
