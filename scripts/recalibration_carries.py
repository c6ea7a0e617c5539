#!/usr/bin/env python3
"""Does the static recalibration a diagnosis fits carry to other loads, rates and shapes? (issue 31)

    python scripts/recalibration_carries.py [--only PREFIX ...]

Every extended model holds a static map beside its effects: gain, offset, curvature, stress gain
and loop-width corrections, fitted on the one diagnosis recording. On the eleventh never-tuned
draw's heating-with-creep pair, that map cost the probes most of their gain: with it set to the
identity they gained far more (docs/BENCHMARKS.md). This asks whether that holds in general.

For each case of the development draw (`benchmarks.general`, diagnosed with its identification
loops, as `scripts/bench_diagnose.py --set general` does), it prints the pooled probe RMS, in um,
of the base, of the extended model as fitted, and of the same model with the recalibration cut to
gain and offset (curvature, stress gain and loop-width corrections zeroed; the effects as fitted),
and each one's gain over the base.
"""

from __future__ import annotations

import argparse
import copy
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.general import general_cases  # noqa: E402
from benchmarks.probes import two_models_on_probes  # noqa: E402
from gma_ffc.effects.static import StaticMap  # noqa: E402


def affine_only(extended: Any) -> Any:
    """A copy of the extended model whose static map keeps its gain and offset alone."""
    out = copy.deepcopy(extended)
    for block in out.chain:
        if isinstance(block, StaticMap):
            block.static["quadratic_per_um"] = 0.0
            block.static["stress_gain_per_MPa"] = 0.0
            block.coefficients = np.zeros_like(block.coefficients)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", default=(), metavar="PREFIX",
                    help="only the cases whose effect names start so (e.g. thermal_drift creep)")
    args = ap.parse_args(argv)
    cases = [c for c in general_cases() if c.name.split(":")[-1].startswith(tuple(args.only))]
    print(f"{'case':45s} {'verdict':38s} {'base':>7} {'fitted':>7} {'affine':>7} {'gain':>6} {'affine':>6}")
    for case in cases:
        dg, base, fit, aff = two_models_on_probes(case, lambda dg: affine_only(dg.extended))
        print(f"{case.name:45s} {','.join(dg.verdict) or '-':38s} {base:7.4f} {fit:7.4f} {aff:7.4f} "
              f"{base / fit:6.2f} {base / aff:6.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
