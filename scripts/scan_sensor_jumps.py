#!/usr/bin/env python
"""The sensor-jump detector (`gma_ffc.diagnose.jumps`) over every diagnose benchmark recording.

For each recording (development, never-tuned and stress-dependent-play variants): the jumps
found on the base model's residual as recorded (there should be none: no case has a sensor
event), and whether a 1 um step of the sensor's zero is found at its time and size, added
  - in the middle of the recording's longest drive hold after the initial state has settled
    (where a lab re-zeroes a sensor), and
  - at the middle of the recording, wherever the drive is then (a knock during motion: harder,
    as the base model's error moves fast there too when an effect is missing).

    .venv/bin/python scripts/scan_sensor_jumps.py          # all 49 recordings, about 2 minutes
    .venv/bin/python scripts/scan_sensor_jumps.py --only null,creep
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))      # benchmarks/ is a checkout folder, not part of the package

from gma_ffc.diagnose.data import prepare
from gma_ffc.diagnose.jumps import sensor_jumps
from benchmarks.cases import cases, holdout_cases, make_case, sdp_variant_cases

STEP_UM = 1.0


def longest_hold_middle(u: np.ndarray, first: int) -> int:
    """The middle sample of the longest stretch (after `first`) where the drive holds: it changes
    by no more than 0.2 % of its range from one sample to the next (its noise, not a slow sine)."""
    still = np.r_[False, np.abs(np.diff(u)) <= 0.002 * max(float(np.ptp(u)), 1e-12)]
    still[:first] = False
    best, best_len, start = first, 0, None
    for i, s in enumerate(np.r_[still, False]):
        if s and start is None:
            start = i
        elif not s and start is not None:
            if i - start > best_len:
                best, best_len = (start + i) // 2, i - start
            start = None
    return best


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", default="", help="comma-separated case-name prefixes")
    args = ap.parse_args(argv)
    prefixes = [p for p in args.only.split(",") if p]
    todo = [c for c in cases() + holdout_cases() + sdp_variant_cases()
            if not prefixes or any(c.name.startswith(p) for p in prefixes)]
    false_found, missed = 0, {"hold": 0, "middle": 0}
    print(f"{'recording':36s} {'as recorded':>12s} {'in a hold':>22s} {'mid-recording':>22s}")
    for case in todo:
        model, rec = make_case(case)
        d = prepare([rec], model)[0]
        yc = model.simulate(d.t, d.u, d.s if model.stress_range_MPa is not None else None, initial_state=d.start)
        stress = d.recorded_stress
        plain = sensor_jumps(d.y, yc, d.u, stress, d.t, d.dt_med, d.settled)
        false_found += len(plain.found) + plain.excess
        cells = []
        for where, k in (("hold", longest_hold_middle(d.u, d.settled)), ("middle", d.y.size // 2)):
            stepped = d.y + np.where(np.arange(d.y.size) >= k, STEP_UM, 0.0)
            found = sensor_jumps(stepped, yc, d.u, stress, d.t, d.dt_med, d.settled).found
            hit = [j for j in found if abs(j.index - k) <= 2 and abs(j.um - STEP_UM) < 0.2 * STEP_UM]
            missed[where] += not hit
            cells.append(f"{d.t[k]:7.3f}s: " + (f"{hit[0].um:.3f} um" if hit else "missed"))
        print(f"{case.name:36s} {len(plain.found) + plain.excess:>12d} {cells[0]:>22s} {cells[1]:>22s}", flush=True)
    n = len(todo)
    print(f"\njumps found where none was added: {false_found} in {n} recordings (target 0)")
    print(f"1 um steps found at their sample and within 20 % of their size: in a hold {n - missed['hold']}/{n}, "
          f"mid-recording {n - missed['middle']}/{n}")
    return 0 if false_found == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
