#!/usr/bin/env python3
"""The initial-state fit of this checkout against a baseline checkout: the same fits?

    python scripts/compare_initial_state.py --baseline-src /tmp/base [--seeds 11 12] [--cases 200] [--cache DIR]

Two checks, each run once per checkout in a fresh process (PYTHONPATH=the checkout):
  - random models: the state fit's cases of tests/test_real_recordings.py (`random_case`, seeds
    SEED x 0..CASES-1: random SDPI models, drives and unseen prehistories). The state is estimated
    from the true output, and the run simulated from it. Its error is judged against the truth.
  - the measured piezo recording: a model identified on 3-7 s simulates nine windows cut
    mid-history, and four one-period windows each identify a model that predicts 7-10 s.

Printed: per check, how many cases the two fits differ by more than the tolerance (1e-4 of
the stroke), which way, the largest difference, and the seconds per fit (from when each checkout
ran: with --cache, the baseline's may be older). Then seconds per fit with the two checkouts
interleaved in one process (--timing). Exit 1 when a fit of this checkout is worse than the
baseline's by more than the tolerance.
"""

from __future__ import annotations

import argparse
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TOLERANCE = 1e-4          # of the stroke: the "same fits"
PIEZO_WINDOWS = (0.0, 2.0, 3.4, 3.73, 4.1, 5.5, 6.0, 7.3, 8.0)     # test_real_recordings' windows
ONE_CYCLE_STARTS = (4.3, 5.1, 5.77, 6.0)


# ---- the worker: runs inside one checkout --------------------------------------------------------

def random_model_fits(seeds: list[int], cases: int) -> list[dict[str, Any]]:
    """Per case: the errors of the run simulated from the estimated state against the truth."""
    from gma_ffc.initial_state import resolve, settled_index
    from test_real_recordings import random_case

    out = []
    for base in seeds:
        for k in range(cases):
            model, x, stress, pre = random_case(base, k)
            stepper = model.forward_stepper(initial_drive=float(pre[0]))
            for v in np.r_[pre, x[0]]:
                stepper.step(float(v), float(stress[0]))
            y_true = model.simulate(None, x, stress, initial_play_state=stepper._state[: model.n_play].copy())
            t0 = time.perf_counter()
            start = resolve(model, x, stress, "estimate", y_true)
            seconds = time.perf_counter() - t0
            y_est = model.simulate(None, x, stress, initial_play_state=start.play_state)
            out.append({"case": f"{base}/{k}", "y": y_est, "truth": y_true, "stroke": max(float(np.ptp(y_true)), 1e-9),
                        "settled": settled_index(model, x), "seconds": seconds})
    return out


def piezo_fits(path: Path) -> list[dict[str, Any]]:
    """Per window: the run simulated from the estimated state against the measurement."""
    from gma_ffc.identify import SDPIIdentifier
    from gma_ffc.recordings import read_recording
    from test_real_recordings import cut

    rec = read_recording(path)
    model = SDPIIdentifier().fit([cut(rec, 3.0, 7.0, "train")]).model_
    out = []
    for a in PIEZO_WINDOWS:
        w = cut(rec, a)
        t0 = time.perf_counter()
        y = model.simulate(w.time_s, w.drive, measured_um=w.displacement_um)
        out.append({"case": f"window from {a:g} s", "y": y, "truth": w.displacement_um,
                    "stroke": float(np.ptp(w.displacement_um)), "seconds": time.perf_counter() - t0})
    unseen = cut(rec, 7.0)
    for a in ONE_CYCLE_STARTS:
        t0 = time.perf_counter()
        m = SDPIIdentifier().fit([cut(rec, a, a + 1.0, "one_cycle")]).model_
        y = m.simulate(unseen.time_s, unseen.drive, measured_um=unseen.displacement_um)
        out.append({"case": f"one period from {a:g} s, 7-10 s predicted", "y": y, "truth": unseen.displacement_um,
                    "stroke": float(np.ptp(unseen.displacement_um)), "seconds": time.perf_counter() - t0})
    return out


def worker(tree: Path, out: Path, seeds: list[int], cases: int, piezo: Path) -> None:
    import gma_ffc

    assert Path(gma_ffc.__file__).resolve().is_relative_to(tree.resolve()), (gma_ffc.__file__, tree)
    result = {"random": random_model_fits(seeds, cases), "piezo": piezo_fits(piezo) if piezo.exists() else []}
    out.write_bytes(pickle.dumps(result))


def interleaved_timing(baseline: Path, cases: int) -> None:
    """Seconds per state fit, the two checkouts' initial_state modules alternating case by case in
    one process (the baseline's file loaded beside this one), so both see the same machine load."""
    import importlib.util
    import statistics

    import gma_ffc.initial_state as this
    from test_real_recordings import random_case

    spec = importlib.util.spec_from_file_location("gma_ffc._baseline_initial_state",
                                                  baseline / "gma_ffc" / "initial_state.py")
    assert spec is not None and spec.loader is not None
    base = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = base
    spec.loader.exec_module(base)
    times: dict[str, list[float]] = {"this": [], "baseline": []}
    for k in range(cases):
        model, x, stress, pre = random_case(13, k)
        y = model.simulate(None, x, stress, initial_state="relaxed")
        for name, mod in (("this", this), ("baseline", base))[:: 1 if k % 2 else -1]:
            t0 = time.perf_counter()
            mod.resolve(model, x, stress, "estimate", y)
            times[name].append(time.perf_counter() - t0)
    a, b = statistics.median(times["this"]), statistics.median(times["baseline"])
    print(f"\nseconds per state fit, {cases} random models (seed 13), interleaved in one process: "
          f"this {a:.3f}, baseline {b:.3f} (median; ratio {a / b:.2f}; load average {os.getloadavg()[0]:.1f})")


# ---- the comparison --------------------------------------------------------------------------------

def clean_commit(tree: Path) -> str | None:
    """The checkout's commit when it has no uncommitted change (its results can be kept), else None."""
    def git(*a: str) -> str:
        return subprocess.run(["git", "-C", str(tree), *a], capture_output=True, text=True).stdout.strip()
    return None if git("status", "--porcelain", "--untracked-files=no") else (git("rev-parse", "HEAD") or None)


def run_tree(tree: Path, args: argparse.Namespace, tmp: Path) -> dict[str, list[dict[str, Any]]]:
    """The worker's results on `tree`; with --cache, a clean commit's are kept and reused."""
    commit = clean_commit(tree)
    key = f"{commit}-{'_'.join(map(str, args.seeds))}-{args.cases}-{args.piezo.name}.pkl"
    out = args.cache / key if args.cache and commit else tmp / f"{abs(hash(str(tree)))}.pkl"
    if not out.exists():
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tree), str(ROOT / "tests")]))
        subprocess.run([sys.executable, __file__, "--worker", str(tree), "--out", str(out), "--piezo",
                        str(args.piezo), "--cases", str(args.cases), "--seeds", *map(str, args.seeds)],
                       check=True, env=env, cwd=tree)
    result: dict[str, list[dict[str, Any]]] = pickle.loads(out.read_bytes())
    return result


def rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(e ** 2)))


def compare(name: str, new: list[dict[str, Any]], old: list[dict[str, Any]], detail: bool) -> bool:
    """Print how the fits differ; True when none of `new` is worse than `old` beyond TOLERANCE."""
    assert [c["case"] for c in new] == [c["case"] for c in old]
    err_new = np.array([rms(c["y"] - c["truth"]) / c["stroke"] for c in new])
    err_old = np.array([rms(c["y"] - c["truth"]) / c["stroke"] for c in old])
    apart = np.array([float(np.nanmax(np.abs(a["y"] - b["y"]))) / a["stroke"] for a, b in zip(new, old)])
    gain = err_old - err_new
    better, worse = int(np.sum(gain > TOLERANCE)), int(np.sum(gain < -TOLERANCE))
    t_new, t_old = (np.median([c["seconds"] for c in x]) for x in (new, old))
    print(f"\n{name}: {len(new)} cases; RMS error against the truth as a fraction of the stroke")
    print(f"  this checkout better by > {TOLERANCE:g}: {better}; worse by > {TOLERANCE:g}: {worse}")
    print(f"  largest change of the RMS error: better {max(0.0, gain.max()):.2e}, worse {max(0.0, -gain.min()):.2e}")
    print(f"  largest |difference| between the two fitted runs: {apart.max():.2e} of the stroke "
          f"({int(np.sum(apart > TOLERANCE))} cases over {TOLERANCE:g})")
    print(f"  mean RMS error: this {err_new.mean():.3e}, baseline {err_old.mean():.3e}")
    print(f"  median seconds per fit: this {t_new:.3f}, baseline {t_old:.3f}")
    for k in np.flatnonzero((np.abs(gain) > TOLERANCE) | detail):
        print(f"    {new[k]['case']:<42} this {err_new[k]:.3e}  baseline {err_old[k]:.3e}  runs apart {apart[k]:.2e}")
    return worse == 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline-src", type=Path, help="the checkout to compare with (e.g. git worktree add /tmp/base main)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[11, 12])
    ap.add_argument("--cases", type=int, default=200, help="random models per seed")
    ap.add_argument("--piezo", type=Path, default=ROOT.parent / "shared" / "data" / "real" / "piezo_150V_1Hz"
                    / "piezo_150V_1Hz.csv")
    ap.add_argument("--cache", type=Path, metavar="DIR",
                    help="keep each clean commit's results here and reuse them (the baseline runs once)")
    ap.add_argument("--timing", type=int, default=40, metavar="N",
                    help="also time the fit on N random models, the two checkouts interleaved (0: skip)")
    ap.add_argument("--worker", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker(args.worker, args.out, args.seeds, args.cases, args.piezo)
        return 0
    if args.baseline_src is None:
        ap.error("--baseline-src DIR is required (e.g. git worktree add /tmp/base main)")
    print(f"this checkout {ROOT}, baseline {args.baseline_src}; seeds {args.seeds} x {args.cases} random models; "
          f"load average {os.getloadavg()[0]:.1f}")
    if args.cache:
        args.cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        new, old = run_tree(ROOT, args, Path(tmp)), run_tree(args.baseline_src.resolve(), args, Path(tmp))
    ok = compare("random models", new["random"], old["random"], detail=False)
    if new["piezo"]:
        ok &= compare(f"measured piezo ({args.piezo.name})", new["piezo"], old["piezo"], detail=True)
    else:
        print(f"\nmeasured piezo: {args.piezo} not found, not compared")
    if args.timing:
        sys.path.insert(0, str(ROOT / "tests"))
        interleaved_timing(args.baseline_src.resolve(), args.timing)
    print(f"\n(load average {os.getloadavg()[0]:.1f} at the end)")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
