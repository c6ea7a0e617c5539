#!/usr/bin/env python3
"""Does leaving out the recalibration terms that do not carry across loads help the probes? (issue 31)

    python scripts/recalibration_levels.py [--seed SEED] [--only PREFIX ...]

For each case of a general draw (`benchmarks.general`, diagnosed with its identification loops, as
`scripts/bench_diagnose.py --set general` does), one diagnosis: the extended model just before the
recalibration's curvature and stress gain are judged by leave-one-stress-level-out
(`recalibration.carried`) and the one after; the pooled probe RMS, in um, of the
base and of both, each one's gain over the base, and the terms left out.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.general import GENERAL_SEED, general_cases  # noqa: E402
from benchmarks.probes import two_models_on_probes  # noqa: E402
from gma_ffc.diagnose import recalibration  # noqa: E402
from gma_ffc.diagnose.scoring import build_extended  # noqa: E402

SEEN: dict[str, Any] = {}
_carried = recalibration.carried


def _spy(problem: Any, sel: Any) -> Any:
    """The extended model before the rule (as the guard would build it), then the rule."""
    f = problem.fitter
    SEEN["before"] = (build_extended(f.plain_core(sel.fit.specs[2]), f, sel.fit.specs[2], sel.fit.coef_all,
                                     sel.fit.names, list(sel.accepted)) if sel.fit.names else None)
    out = _carried(problem, sel)
    SEEN["off"] = sorted(f.static_off)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=GENERAL_SEED)
    ap.add_argument("--only", nargs="+", default=(), metavar="PREFIX")
    args = ap.parse_args(argv)
    recalibration.carried = _spy       # type: ignore[assignment]
    cases = [c for c in general_cases(seed=args.seed)
             if not args.only or c.name.split(":")[-1].startswith(tuple(args.only))]
    print(f"{'case':34s} {'verdict':34s} {'base':>7} {'before':>7} {'after':>7} {'gain':>6} {'after':>6}  left out")
    for case in cases:
        SEEN.clear()     # the same model before as after where nothing was left out
        dg, base, a, b = two_models_on_probes(case, lambda dg: SEEN["before"] if SEEN.get("off") else dg.extended)
        print(f"{case.name:34s} {','.join(dg.verdict) or '-':34s} {base:7.4f} {b:7.4f} {a:7.4f} "
              f"{base / b:6.2f} {base / a:6.2f}  {','.join(SEEN.get('off', [])) or '-'}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
