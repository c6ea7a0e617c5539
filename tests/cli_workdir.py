"""The CLI tests' shared folder: identification runs of the Preisach test rig at four stresses, a
3 Hz reference, and the model `gma-ffc identify` makes of them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gma_ffc.cli import main
from gma_ffc.recordings import Recording, write_recording
from preisach import PreisachActuator

STRESSES = (-11.3, -15.2, -19.1, -24.0)


def make_cli_workdir(d: Path, *identify_extra: str) -> Path:
    """Fill `d` (id_*.csv, ref.csv, model.yaml) and return it; `identify_extra` goes to identify."""
    rig = PreisachActuator(noise_um=0.02, seed=3)
    t = np.arange(0, 1.2, 1e-3)
    x = 1.5 - 1.5 * np.cos(2 * np.pi * 3 * t)
    for s in STRESSES:
        write_recording(d / f"id_{-s}.csv", Recording(
            {"time_s": t, "current_A": x, "stress_MPa": np.full_like(t, s), "displacement_um": rig.run(x, s)},
            {"source": "preisach test rig", "sample_rate_hz": 1000}))
    ref = 22.0 + 12.0 * np.sin(2 * np.pi * 3 * t)
    write_recording(d / "ref.csv", Recording({"time_s": t, "reference_um": ref, "stress_MPa": np.full_like(t, -17.0)}))
    assert main(["identify", *map(str, sorted(d.glob("id_*.csv"))), "-o", str(d / "model.yaml"),
                 *identify_extra]) == 0
    return d
