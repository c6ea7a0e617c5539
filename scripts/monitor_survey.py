#!/usr/bin/env python3
"""The model-fit monitor's ratio with nothing missing and with one effect switched on (issue 30):
what its thresholds (fit_monitor.DRIFT_RATIO, CLEAR_RATIO) stand against.

The real controller on the simulated rig (sim driver, simulated clock, sensor noise on) tracks a
sine for 40 s with the SDPI model identified from the rig's quasi-static 3 Hz recordings; the
monitor's ratio over its last 10 s window is printed per condition: stroke (full, half, small
loops), reference frequency, stress. Then the same at the default condition with each plant effect
switched on from the start.

    .venv/bin/python scripts/monitor_survey.py
"""

from __future__ import annotations

import itertools
import sys
import tempfile
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

STROKES = {"full": (25.5, 26.0), "half": (12.0, 20.0), "small": (6.0, 20.0)}
FREQUENCIES = (1.0, 3.0, 10.0)
LOADS_KG = {-11.3: 0.0, -15.2: 15.3, -21.5: 39.0}
EFFECTS = {"none": {}, "thermal": {"thermal": {"enabled": True}},
           "creep": {"creep": {"enabled": True}}, "delay 2 ms": {"delay": {"enabled": True, "delay_ms": 2.0}},
           "eddy 1 ms": {"eddy": {"enabled": True, "time_constant_ms": 1.0}},
           "dynamics": {"dynamics": {"enabled": True}}}


def ratio(model, folder: Path, stroke, frequency, load_kg, effects) -> float:
    from gma_ffc.control.config import validate_config
    from gma_ffc.control.manager import ControllerManager

    plant = folder / "plant.yaml"
    plant.write_text(yaml.safe_dump({"noise": {"enabled": True}, **effects}))
    amplitude, offset = stroke
    cfg = validate_config({
        "rate_hz": 1000.0, "clock": "simulated", "model": "unused.yaml",
        "driver": {"kind": "sim", "plant_config": str(plant), "load_mass_kg": load_kg, "seed": 7},
        "reference": {"kind": "sine", "frequency_hz": frequency, "amplitude_um": amplitude, "offset_um": offset},
        "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0},
        "telemetry": {"path": None}, "monitor": {"window_s": 10.0}})
    status = ControllerManager(cfg, model=model).run(duration_s=40.0)
    return float(status["monitor"]["ratio"])


def main() -> int:
    from gma_ffc.sil import cached_sdpi_and_mpi

    model = cached_sdpi_and_mpi(Path(tempfile.gettempdir()) / "gma_ffc_bench_models")[0]
    with tempfile.TemporaryDirectory() as tmp:
        print("nothing missing: ratio over the last 10 s of 40 s (1 kHz)")
        print(f"{'stroke':6s} {'f_Hz':>5s} " + " ".join(f"{s:>8g}MPa" for s in LOADS_KG))
        worst = {}
        for name, f in itertools.product(STROKES, FREQUENCIES):
            row = [ratio(model, Path(tmp), STROKES[name], f, m, {}) for m in LOADS_KG.values()]
            worst[name] = max(worst.get(name, 0.0), *row)
            print(f"{name:6s} {f:5g} " + " ".join(f"{r:11.2f}" for r in row), flush=True)
        print("largest per stroke: " + ", ".join(f"{k} {v:.2f}" for k, v in worst.items()))
        print("\none effect on from the start (full stroke, 3 Hz, -15.2 MPa): ratio over the last 10 s of 40 s")
        for name, eff in EFFECTS.items():
            print(f"  {name:11s} {ratio(model, Path(tmp), STROKES['full'], 3.0, 15.3, eff):6.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
