"""Does the simulated actuator return to the same point after each small loop? (issue 31's play probe)

A Prandtl-Ishlinskii or Preisach core has return-point memory: after a small loop inside a large
one, the output returns exactly to where the loop began, however often the loop is repeated. The
Jiles-Atherton magnetics of hil_sim need not: each loop may leave the magnetisation a little
further on (accommodation). The two-tone part of the play cases' other-shape probe repeats small
fast loops inside slow ones, and no core identified elsewhere follows it
(`scripts/play_minor_loops.py`); this measures that mechanism directly.

For each case's actuator (effects off, noise off, at the probe's light load) the drive rises from
the minimum to MID of the range, then repeats LOOPS small loops of SMALL of the range at 20 Hz.
It prints the displacement at each return to MID: the first return (after one loop), the tenth,
the last, and the drift from the first to the last, in um and as a share of the stroke. The
case's base model (a PI core) is run on the same drive beside it.

    python scripts/return_point_memory.py                       # the twenty-fourth draw's cases
    python scripts/return_point_memory.py --draw twenty-third
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from benchmarks.cases import FS  # noqa: E402  (the cases' sampling rate)

MID = 0.5            # of the drive range, where the small loops turn back
SMALL = 0.1          # each small loop's height, of the drive range
LOOPS = 60           # repeated: the drift settles within about ten
LIGHT_LOAD_KG = 14.0  # the other-shape probe's load (12.5-15.5 kg, benchmarks.probes)


def loop_drive(peak: float) -> tuple[np.ndarray, int, int]:
    """The drive, the sample of the first return to MID, and the samples per small loop."""
    lo = 0.05
    rise = np.linspace(lo, lo + MID * (peak - lo), int(0.5 * FS))
    t = np.arange(int(FS / 20.0)) / FS
    small = rise[-1] + SMALL * (peak - lo) * 0.5 * (1.0 - np.cos(2.0 * np.pi * 20.0 * t))
    return np.concatenate([rise] + [small] * LOOPS), rise.size + small.size, small.size


def returns(y: np.ndarray, first: int, period: int) -> np.ndarray:
    return y[first + period * np.arange(LOOPS - 1)]


def one_case(case) -> None:
    from benchmarks.cases import GMAPlant, case_plant, case_recordings, run_plant

    cfg = case_plant(case).with_effects([])
    drive, first, period = loop_drive(case.drive_max)
    t = np.arange(drive.size) / FS
    out = run_plant(GMAPlant(cfg, seed=1), t, drive, np.full(drive.size, LIGHT_LOAD_KG), FS, True)
    model = case_recordings(case)[0]
    stress = np.clip(out["stress_MPa"], *model.stress_range_MPa)
    runs = {"plant": out["displacement_um"], "base": np.asarray(model.simulate(t, drive, stress), dtype=float)}
    for name, y in runs.items():
        r = returns(y, first, period)
        stroke = float(np.ptp(y))
        print(f"{case.name:44s} {name:5s} returns: 1st {r[0]:8.3f}  10th {r[9]:8.3f}  last {r[-1]:8.3f} um;"
              f"  drift {r[-1] - r[0]:+7.3f} um ({100 * abs(r[-1] - r[0]) / stroke:5.2f} % of {stroke:.1f} um)",
              flush=True)


def main(argv: list[str] | None = None) -> int:
    from play_class_bound import PLAY, each_play_case

    return each_play_case(__doc__ or "", "the displacement at each return to the loops' turning point, um",
                          one_case, argv, truths=((), (PLAY,)))


if __name__ == "__main__":
    raise SystemExit(main())
