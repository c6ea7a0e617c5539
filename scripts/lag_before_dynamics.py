#!/usr/bin/env python3
"""What the load's dynamics must be fed when a lag comes before them (issue 31; tried, not kept).

    python scripts/lag_before_dynamics.py

The model's load dynamics (`effects/rod_load`) are discretised exactly for an input held over
each sample interval. On hil_sim's rig, eddy currents make the free stroke a lagged signal that
moves within the interval. So the model fed the lag's end value leads the rig by about half a
sample, which a delay beside eddy currents and a resonance can stand in for. Feeding the dynamics
the lag's interval mean inside `diagnose` was tried (2026-11-28): on the probes of four
eddy-and-resonance pairs it gained 8.23x, 4.54x, 3.49x and 8.62x against 8.77x, 7.34x, 4.53x and
5.16x, so it was not kept (docs/BENCHMARKS.md).

For each eddy time constant and load this prints the RMS miss, in um, of the dynamics (the
plant's own frequency and damping) against the plant's displacement, fed:
  - `end value`: the lagged stroke at each sample (what the model feeds);
  - `interval mean`: its mean over each interval (the same rig sampled 20x finer, trapezoid rule);
  - `end + delay`: the end value delayed by the best shift (what a diagnosis named beside them).
Drive: 3, 23 and 61 Hz tones at 2 kHz, the first 1 s left out.
What the mean leaves is the plant's own: it leads the mean's response by about 25 us (its
semi-implicit Euler at 25 us sub-steps), and a delay cannot take a lead. The best delay takes
some of it through the shape of the lag's rise, so `end + delay` ends below `interval mean`.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gma_ffc.effects import rod_load_kernels as RK  # noqa: E402
from hil_sim.plant import GMAPlant, PlantConfig  # noqa: E402

FS = 2000.0
UP = 20          # the finer sampling that gives the interval mean


def main() -> int:
    t = np.arange(int(4 * FS)) / FS
    drive = 1.5 + 0.6 * np.sin(2 * np.pi * 3 * t) + 0.4 * np.sin(2 * np.pi * 23 * t) + 0.2 * np.sin(2 * np.pi * 61 * t)
    fine_t = np.arange(t.size * UP) / (FS * UP) - (UP - 1) / (FS * UP)     # UP points ending on each sample
    dt, s = np.full(t.size, 1 / FS), np.zeros(t.size)
    print(f"{'eddy tau ms':>11} {'load kg':>8} {'end value':>10} {'interval mean':>14} {'end + delay':>12} {'delay ms':>9}")
    for tau_ms in (0.6, 1.5, 4.0):
        for mass in (0.0, 30.0):
            def run(effects: list[str], tt: np.ndarray, ii: np.ndarray) -> np.ndarray:
                cfg = PlantConfig().with_effects(effects)
                cfg.eddy.time_constant_ms = tau_ms
                return GMAPlant(cfg, seed=1).run(tt, ii, load_mass_kg=mass)["displacement_um"]

            plant = run(["eddy", "dynamics"], t, drive)
            end = run(["eddy"], t, drive)
            fine = run(["eddy"], fine_t, np.repeat(drive, UP)).reshape(-1, UP)
            start = np.r_[fine[0, 0], fine[:-1, -1]]            # each interval's start: the last one's end
            mean = (0.5 * start + fine[:, :-1].sum(axis=1) + 0.5 * fine[:, -1]) / UP     # trapezoid
            cfg = PlantConfig()
            w, zeta = 2 * np.pi * cfg.resonance_hz(mass), cfg.dynamics.damping_ratio

            def fed(u: np.ndarray) -> np.ndarray:
                return RK.forward(u, dt, s, w, zeta, 0.0, 0.0, float(u[0]))

            def rms(e: np.ndarray) -> float:
                return float(np.sqrt(np.mean(e[int(FS):] ** 2)))

            from_end = fed(end)
            best = min((rms(np.interp(t - d, t, from_end) - plant), d) for d in np.linspace(0.0, 0.5 / FS, 26))
            print(f"{tau_ms:>11.1f} {mass:>8.0f} {rms(from_end - plant):>10.4f} {rms(fed(mean) - plant):>14.4f} "
                  f"{best[0]:>12.4f} {best[1] * 1e3:>9.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
