#!/usr/bin/env python3
"""Recording I/O at lab scale: read, simulate and write 1,000,000 rows, the Arrow-based reader and
writer against the previous numpy/Python-level ones, in the same process on the same file; then
the whole `gma-ffc simulate` command as a user runs it (a fresh process: interpreter, imports,
numba, read, initial state, simulate, write).

    python scripts/bench_io.py [--rows 1000000] [--runs 7] [--baseline-src DIR]

Prints seconds per stage, best of --repeat runs, and new/old ratios. The whole command is timed
cold (numba's cache empty: every kernel compiled, as on the first run after an install) and warm
(the median of --runs), with the default initial state (estimate: fitted to the measured
displacement) and with --initial-state relaxed, wall clock and CPU (user + sys, all threads).
--baseline-src runs the same commands on another checkout of the package (PYTHONPATH=DIR, e.g. a
`git worktree` of an older commit) interleaved with these, so both see the same machine load.
The load average is printed: on a shared machine the wall clock is only as good as it.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gma_ffc.modelio import load_model  # noqa: E402
from gma_ffc.recordings import Recording, format_metadata, read_recording, write_recording  # noqa: E402
from gma_ffc.recordings.csv_reader import _parse_rows  # noqa: E402


def old_read(path: Path) -> np.ndarray:
    """The previous reader's work: Python-level split of the text, numpy.loadtxt on the rows."""
    lines = path.read_text(encoding="utf-8").splitlines()
    header = next(i for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("#"))
    ncols = len(lines[header].split(","))
    return _parse_rows(lines[header + 1:], ncols, str(path), header + 1)


def old_write(path: Path, rec: Recording) -> None:
    names = list(rec.columns)
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(format_metadata(rec.metadata) + ",".join(names) + "\n")
        np.savetxt(fh, np.column_stack([rec.columns[n] for n in names]), delimiter=",", fmt="%.12g")


def best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def whole_process(cmd: list[str], env: dict[str, str]) -> tuple[float, float]:
    """(wall, CPU user+sys) seconds of one fresh process running `cmd`."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def bench_command(src: Path, out: Path, runs: int, baseline: Path | None) -> None:
    """The whole `gma-ffc simulate` on `src`: cold, then the median of `runs` warm runs."""
    model = str(ROOT / "config" / "models" / "sim_sdpi.yaml")
    trees = {"this": ROOT} | ({"baseline": baseline} if baseline else {})
    print(f"\n`gma-ffc simulate --model sim_sdpi.yaml {src.name} -o out.csv` as a fresh process "
          f"({os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at start)")
    print(f"{'code':<10}{'initial state':<15}{'cold wall':>10}{'warm wall':>10}{'(min)':>8}{'warm CPU':>10}")
    for flags in ([], ["--initial-state", "relaxed"]):
        for name, tree in trees.items():
            with tempfile.TemporaryDirectory() as cache:
                # an empty numba cache of its own: the first run compiles, later runs load
                env = dict(os.environ, PYTHONPATH=str(tree), NUMBA_CACHE_DIR=cache)
                cmd = [sys.executable, "-m", "gma_ffc.cli", "simulate", "--model", model, str(src), "-o", str(out),
                       *flags]
                cold, _ = whole_process(cmd, env)
                warm = [whole_process(cmd, env) for _ in range(runs)]
            walls = [w for w, _ in warm]
            cpu = statistics.median(c for _, c in warm)
            print(f"{name:<10}{(flags[-1] if flags else 'estimate'):<15}{cold:>10.2f}{statistics.median(walls):>10.2f}"
                  f"{min(walls):>8.2f}{cpu:>10.2f}")
    print(f"(load average {os.getloadavg()[0]:.1f} at the end)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--runs", type=int, default=7, help="warm runs of the whole command (median)")
    ap.add_argument("--baseline-src", type=Path, metavar="DIR",
                    help="another checkout of the package to time the same command on (e.g. a git worktree)")
    args = ap.parse_args()
    model = load_model(ROOT / "config" / "models" / "sim_sdpi.yaml")
    n = args.rows
    t = np.arange(n) / 2000.0
    drive = 1.5 - 1.5 * np.cos(2 * np.pi * 3 * t)
    stress = -15.2 + 0.01 * np.sin(t)
    rec = Recording({"time_s": t, "current_A": drive, "stress_MPa": stress,
                     "displacement_um": model.simulate(t, drive, stress, initial_state="relaxed")},
                    {"source": "bench_io"}, "in.csv")
    with tempfile.TemporaryDirectory() as tmp:
        src, out = Path(tmp) / "in.csv", Path(tmp) / "out.csv"
        write_recording(src, rec)
        loaded = read_recording(src)
        assert np.array_equal(old_read(src)[:, 1], loaded.drive)
        rows = {
            "read": (best(lambda: old_read(src), args.repeat), best(lambda: read_recording(src), args.repeat)),
            "simulate (model only)": (best(lambda: model.simulate(t, drive, stress, initial_state="relaxed"),
                                           args.repeat),) * 2,
            "write": (best(lambda: old_write(out, rec), args.repeat), best(lambda: write_recording(out, rec), args.repeat)),
        }
        print(f"{n:,} rows, 4 columns, best of {args.repeat}")
        print(f"{'stage':<24}{'old (s)':>10}{'new (s)':>10}{'new/old':>9}")
        for stage, (a, b) in rows.items():
            print(f"{stage:<24}{a:>10.3f}{b:>10.3f}{b / a:>9.2f}")
        total_old = sum(a for a, _ in rows.values())
        total_new = sum(b for _, b in rows.values())
        print(f"{'read+simulate+write':<24}{total_old:>10.3f}{total_new:>10.3f}{total_new / total_old:>9.2f}")
        bench_command(src, out, args.runs, args.baseline_src.resolve() if args.baseline_src else None)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
