"""Does a change to the diagnosis leave its results as they were, and how much faster is it?

Diagnoses benchmark cases from benchmarks/general.py at half length (a resonance with eddy
currents, heating with creep, stress-dependent play, a null) with two source trees, one case at a
time and the trees alternating (this host's speed drifts; alternating keeps the comparison fair),
each run a fresh process with one search thread. Prints per case the CPU time of each tree's
diagnosis and their ratio (the wall time too: on a host shared with other jobs it drifts by more
than the change, so the ratio quoted is the CPU time's), and whether the verdict, the outcome, every candidate's parameters and held-out
figures and the RMS figures are equal to the last digit.

    python scripts/check_diagnose_unchanged.py BEFORE_TREE AFTER_TREE [--case NAME ...]

A tree is a checkout's root (e.g. `git archive main | tar -x -C /tmp/before`). Exit status 1 when
any result differs.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

CASES = ("gen:rate_dependence+mechanical_dynamics", "gen:thermal_drift+creep",
         "gen:stress_dependent_play@default", "gen:null#1@default")
SCALE = 0.5        # the length the resonance tests diagnose at: long enough to name each effect


def fingerprint(name: str) -> dict:
    """One case diagnosed in this process (the tree on sys.path): what must not change, exactly
    (floats by repr), and the wall time."""
    from benchmarks.cases import case_recordings
    from benchmarks.general import general_cases
    from gma_ffc.diagnose.engine import diagnose

    case = {c.name: c for c in general_cases()}[name]
    model, ident, rec = case_recordings(case, scale=SCALE)
    started, cpu_started = time.perf_counter(), time.process_time()
    dg = diagnose(model, [rec], identification=ident)
    wall, cpu = time.perf_counter() - started, time.process_time() - cpu_started
    candidates = [{"effect": c.effect, "accepted": c.accepted, "reason": c.reason, "round": c.round,
                   "params": {k: repr(v) for k, v in c.params.items()},
                   "figures": [repr(v) for v in (c.cv_mse, c.cv_loss, c.loglik_gain, c.evidence, c.leave_one_out_mse)]}
                  for c in dg.candidates]
    return {"wall_s": wall, "cpu_s": cpu, "result": {
        "verdict": list(dg.verdict), "outcome": dg.outcome, "tentative": list(dg.tentative),
        "cannot_conclude": list(dg.cannot_conclude), "candidates": candidates,
        "rms": [repr(v) for v in (dg.rms_before_um, dg.rms_recalibrated_um, dg.rms_after_um, dg.noise_um)]}}


def run_in(tree: str, name: str) -> dict:
    """`fingerprint(name)` in a fresh process with `tree`'s code first on the path."""
    env = {**os.environ, "PYTHONPATH": tree, "GMA_FFC_CPUS": "1"}
    res = subprocess.run([sys.executable, os.path.abspath(__file__), "--one", name], cwd=tree, env=env,
                         capture_output=True, text=True, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("trees", nargs="*", help="BEFORE_TREE AFTER_TREE")
    ap.add_argument("--case", action="append", help=f"a case of general_cases() (default: {', '.join(CASES)})")
    ap.add_argument("--one", help=argparse.SUPPRESS)       # the child: one case, its JSON on stdout
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps(fingerprint(args.one)))
        return 0
    if len(args.trees) != 2:
        ap.error("give two trees: BEFORE_TREE AFTER_TREE")
    before_tree, after_tree = args.trees
    same_everywhere, totals = True, [0.0, 0.0]     # CPU s
    for name in args.case or CASES:
        before, after = run_in(before_tree, name), run_in(after_tree, name)
        same = before["result"] == after["result"]
        same_everywhere &= same
        totals[0] += before["cpu_s"]
        totals[1] += after["cpu_s"]
        print(f"{name}: CPU {before['cpu_s']:.1f} s -> {after['cpu_s']:.1f} s ({before['cpu_s'] / after['cpu_s']:.2f}x), "
              f"wall {before['wall_s']:.1f} s -> {after['wall_s']:.1f} s; verdict {after['result']['verdict']}, "
              f"results {'identical' if same else 'DIFFER'}", flush=True)
        if not same:
            print(json.dumps({"before": before["result"], "after": after["result"]}, indent=1))
    print(f"all: CPU {totals[0]:.1f} s -> {totals[1]:.1f} s ({totals[0] / totals[1]:.2f}x); "
          f"results {'identical' if same_everywhere else 'DIFFER'}")
    return 0 if same_everywhere else 1


if __name__ == "__main__":
    sys.exit(main())
