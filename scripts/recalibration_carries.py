#!/usr/bin/env python3
"""Does the static recalibration a diagnosis fits carry to other loads, rates and shapes? (issue 31)

    python scripts/recalibration_carries.py [--draw DRAW] [--only PREFIX ...]

Every extended model holds a static map beside its effects: gain, offset, curvature, stress gain
and loop-width corrections, fitted on the one diagnosis recording. On the eleventh never-tuned
draw's heating-with-creep pair, that map cost the probes most of their gain: with it set to the
identity they gained far more (docs/BENCHMARKS.md). This asks whether that holds in general.

For each case of a general draw (`--draw`: the development draw by default, or a later one by its
`scripts/bench_diagnose.py --set general-DRAW` name; diagnosed with its identification loops, as
that benchmark does), it prints the pooled probe RMS, in um, of the base and of the extended model:
as fitted; with the recalibration cut to gain and offset (curvature, stress gain and loop-width
corrections zeroed); and with the recalibration left out (the identity map). The effects stay as
fitted. Then each one's gain over the base.
"""

from __future__ import annotations

import argparse
import copy
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_diagnose import LATER_DRAWS  # noqa: E402
from benchmarks.general import GENERAL_SEED, general_cases  # noqa: E402
from benchmarks.probes import models_on_probes  # noqa: E402
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


def identity_map(extended: Any) -> Any:
    """A copy of the extended model without its recalibration: the static map the identity."""
    out = affine_only(extended)
    for block in out.chain:
        if isinstance(block, StaticMap):
            block.static["gain"], block.static["offset_um"] = 1.0, 0.0
    return out


DRAWS = {"general": GENERAL_SEED, **{prefix: seed for prefix, _, seed, _ in LATER_DRAWS}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draw", choices=DRAWS, default="general",
                    help="which general draw: the development one (default) or a later one")
    ap.add_argument("--only", nargs="+", default=(), metavar="PREFIX",
                    help="only the cases whose effect names start so (e.g. thermal_drift creep)")
    args = ap.parse_args(argv)
    cases = [c for c in general_cases(DRAWS[args.draw], prefix=args.draw)
             if not args.only or c.name.split(":")[-1].startswith(tuple(args.only))]
    print(f"{'case':45s} {'verdict':38s} {'base':>7} {'fitted':>7} {'affine':>7} {'none':>7} "
          f"{'gain':>6} {'affine':>6} {'none':>6}")
    for case in cases:
        dg, base, fit, other = models_on_probes(case, {"affine": lambda dg: affine_only(dg.extended),
                                                       "none": lambda dg: identity_map(dg.extended)})
        aff, none = other["affine"], other["none"]
        print(f"{case.name:45s} {','.join(dg.verdict) or '-':38s} {base:7.4f} {fit:7.4f} {aff:7.4f} {none:7.4f} "
              f"{base / fit:6.2f} {base / aff:6.2f} {base / none:6.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
