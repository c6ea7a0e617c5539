"""What a diagnosis names on one sine, however long: the benchmark cases cut to their first 8 s.

Each case's diagnosis recording starts with 8 s of one 3-5 Hz sine (24-40 cycles, past diagnose's
floor of 16). Diagnosed on that alone, with the one-frequency rule (`EffectSelector`'s
`one_frequency_share`, the default) and without it (the share set beyond 1), per case: the truth,
the outcome and the verdict of each. Without the rule a rate case is often named as another of
its look-alikes (a delay as eddy currents' lag, a resonance as a lag); with it, such a verdict is
inconclusive and asks for a second frequency.

    python scripts/one_frequency.py                 # the rate cases and two nulls, both sets
    python scripts/one_frequency.py null#1 creep#1  # named cases
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

SECONDS = 8.0      # the mixed drive's first sine lasts 8 s (benchmarks.cases.diagnosis_drive)
DEFAULT_CASES = ("rate_dependence#1", "rate_dependence#2", "rate_dependence#3", "time_delay#1", "time_delay#2",
                 "time_delay#3", "mechanical_dynamics#1", "mechanical_dynamics#2", "mechanical_dynamics#3",
                 "holdout:rate_dependence", "holdout:time_delay", "holdout:mechanical_dynamics", "null#1",
                 "holdout:null#1")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="*", default=list(DEFAULT_CASES), help="benchmark case names")
    args = ap.parse_args(argv)
    from benchmarks import cases as bench
    from gma_ffc.diagnose.selection import EffectSelector
    from gma_ffc.drive import dominant_band

    known = {c.name: c for c in bench.cases() + bench.holdout_cases() + bench.rising_cases()
             + bench.rising_holdout_cases()}
    wrong = {"with": 0, "without": 0}
    print(f"{'case':28s} {'band':>14s}  {'with the rule':40s} without it")
    for name in args.cases:
        model, rec = bench.make_case(known[name])
        one = rec.rows(rec.time_s < rec.time_s[0] + SECONDS, "one_sine.csv")
        f0, share = dominant_band([(one.time_s, one.drive)])
        cells = []
        for label, share_needed in (("with", 0.9), ("without", float("inf"))):
            sel = EffectSelector(one_frequency_share=share_needed).fit(model, [one])
            named_wrong = sel.outcome_ == "effects_named" and set(sel.verdict_) != set(known[name].truth)
            wrong[label] += named_wrong
            cells.append(f"{sel.outcome_} {sel.verdict_}" + (" (wrong)" if named_wrong else ""))
        print(f"{name:28s} {f0:5.2f} Hz {share:4.0%}  {cells[0]:40s} {cells[1]}", flush=True)
    print(f"\nnamed with confidence and wrong: {wrong['with']} with the rule, {wrong['without']} without, "
          f"of {len(args.cases)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
