"""How long `diagnose` takes with the identification loops (`--ident`), as the tests run it: three
cases at half length (a resonance, creep, eddy currents beside a resonance), each diagnosis in a
fresh process. With `--baseline-src DIR`, the package in DIR runs the same diagnoses, interleaved
with the current one round by round, and the ratio of the medians is printed, with whether the
verdicts, RMS and parameters came out the same.

    python scripts/bench_diagnose_ident.py [--baseline-src DIR] [--rounds 2] [--only res,creep,pair]

DIR holds an older tree (`git worktree add /tmp/base SHA`). The first round of each tree includes
numba's compilation where its cache is cold: take the medians of two rounds or more.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CASES = {   # name: (draw's seed constant, case-name prefix, case suffix)
    "res": ("GENERAL_SEED", "gen", "mechanical_dynamics@default"),
    "creep": ("GENERAL_SIXTH_SEED", "sixth", "creep@other"),
    "pair": ("GENERAL_FOURTH_SEED", "fourth", "rate_dependence+mechanical_dynamics"),
}
ONE = """
import json, sys, time
sys.path.insert(0, {tree!r})
from benchmarks import general
from benchmarks.cases import case_recordings
from gma_ffc.diagnose.engine import diagnose
case = {{c.name: c for c in general.general_cases(general.{seed}, prefix={prefix!r})}}[{prefix!r} + ":" + {suffix!r}]
model, ident, rec = case_recordings(case, scale=0.5)
t = time.perf_counter()
dg = diagnose(model, [rec], identification=ident)
s = time.perf_counter() - t
params = {{c.effect: {{k: float(f"{{v:.5g}}") for k, v in c.params.items()}} for c in dg.candidates if c.effect in dg.verdict}}
print(json.dumps({{"s": s, "verdict": sorted(dg.verdict), "rms": float(f"{{dg.rms_after_um:.5g}}"), "params": params}}))
"""


def run_one(tree: Path, case: str) -> dict:
    seed, prefix, suffix = CASES[case]
    code = ONE.format(tree=str(tree), seed=seed, prefix=prefix, suffix=suffix)
    res = subprocess.run([sys.executable, "-c", code], cwd=tree, capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"{tree}: the {case} diagnosis failed:\n{res.stderr.strip()[-2000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline-src", type=Path, metavar="DIR", help="a tree with the old gma_ffc")
    ap.add_argument("--rounds", type=int, default=2, help="runs of each diagnosis per tree (default 2)")
    ap.add_argument("--only", default=",".join(CASES), help=f"comma-separated cases of {', '.join(CASES)}")
    args = ap.parse_args(argv)
    cases = [c for c in args.only.split(",") if c]
    unknown = [c for c in cases if c not in CASES]
    if unknown or args.rounds < 1:
        ap.error(f"--only takes {', '.join(CASES)} (got {', '.join(unknown)}); --rounds at least 1")
    base = args.baseline_src
    if base is not None and not (base / "gma_ffc" / "__init__.py").is_file():
        ap.error(f"--baseline-src {base}: no gma_ffc package there; make one with `git worktree add {base} SHA`")
    trees = {"current": ROOT} | ({"baseline": base.resolve()} if base is not None else {})
    for case in cases:
        runs: dict[str, list[dict]] = {name: [] for name in trees}
        for _ in range(args.rounds):
            for name, tree in trees.items():
                runs[name].append(run_one(tree, case))
                print(f"  {case} {name}: {runs[name][-1]['s']:.1f} s", flush=True)
        med = {name: statistics.median(r["s"] for r in rs) for name, rs in runs.items()}
        line = f"{case}: current {med['current']:.1f} s, verdict {runs['current'][-1]['verdict']}"
        if "baseline" in med:
            same = all({k: v for k, v in r.items() if k != "s"} == {k: v for k, v in runs["baseline"][-1].items()
                                                                     if k != "s"} for r in runs["current"])
            line += (f"; baseline {med['baseline']:.1f} s; current/baseline {med['current'] / med['baseline']:.2f}x; "
                     f"results {'the same' if same else 'DIFFERENT'} (verdict, RMS and parameters to 5 digits)")
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
