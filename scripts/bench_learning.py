#!/usr/bin/env python3
"""Learning feedforward on the simulated rig: tracking RMS per period, feedforward alone vs with
repetitive learning, at 3 Hz and 20 Hz, through a load step (-11.3 -> -19.1 MPa at half time).

The rig (hil_sim) has sensor noise, a 1 ms transport delay and eddy currents; the model is the
shipped SDPI identified from the rig without them (config/models/sim_sdpi.yaml), so the learning
has real unmodelled physics to remove. Both runs go through the real controller (sim driver,
simulated clock) with identical seeds; only `learning:` differs. Prints a table and, with
--plot, a figure.

    python scripts/bench_learning.py [--periods 40] [--plot learning.png]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gma_ffc.sil import run_tracking  # noqa: E402

MODEL = ROOT / "config" / "models" / "sim_sdpi.yaml"
STEP_MASS_KG = 30.6     # -19.1 MPa on the paper's rig


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--periods", type=int, default=40, help="periods per run at 3 Hz (20 Hz runs 3x as many)")
    ap.add_argument("--plot", metavar="PNG", help="save a per-period RMS figure")
    args = ap.parse_args()
    rows = []
    runs = {}
    for f, periods in ((3.0, args.periods), (20.0, 3 * args.periods)):
        sched = ((0.0, 0.0), (0.5 * periods / f, STEP_MASS_KG))
        ff = run_tracking(MODEL, f, periods, load_schedule=sched)
        ln = run_tracking(MODEL, f, periods, learning={"kind": "repetitive"}, load_schedule=sched)
        runs[f] = (ff, ln)
        step = periods // 2
        for label, a, b in (("periods 10-19 (before the step)", 10, 20),
                            ("the period of the load step", step, step + 1),
                            ("last 10 periods (after the step)", periods - 10, periods)):
            r_ff = float(np.mean(ff.period_rms_um[a:b]))
            r_ln = float(np.mean(ln.period_rms_um[a:b]))
            rows.append((f, label, r_ff, r_ln, r_ln / r_ff))
    print(f"{'ref':>6}  {'window':<34}{'feedforward':>12}{'+ learning':>12}{'ratio':>8}")
    for f, label, a, b, r in rows:
        print(f"{f:>4g}Hz  {label:<34}{a:>9.3f} um{b:>9.3f} um{r:>8.2f}")
    print("\nper-period RMS (um), every period:")
    for f, (ff, ln) in runs.items():
        print(f"  {f:g} Hz feedforward: " + " ".join(f"{v:.3f}" for v in ff.period_rms_um))
        print(f"  {f:g} Hz + learning:  " + " ".join(f"{v:.3f}" for v in ln.period_rms_um))
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), constrained_layout=True)
        for ax, (f, (ff, ln)) in zip(axes, runs.items()):
            k = np.arange(1, len(ff.period_rms_um) + 1)
            ax.semilogy(k, ff.period_rms_um, "o-", ms=3, label="SDPI feedforward")
            ax.semilogy(k, ln.period_rms_um, "o-", ms=3, label="SDPI + learning")
            ax.axvline(len(k) / 2 + 0.5, color="0.5", ls="--", lw=0.8)
            ax.set_title(f"{f:g} Hz sine, load step at the dashed line", fontsize=10)
            ax.set_xlabel("period")
            ax.set_ylabel("tracking RMS (um)")
        axes[0].legend(loc="upper right", fontsize=8)
        fig.savefig(args.plot, dpi=110)
        print(f"\nfigure: {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
