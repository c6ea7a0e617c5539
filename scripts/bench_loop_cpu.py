"""CPU per tick of the controller loop: the package as it was (a baseline source tree), against
this tree with the model-fit monitor on and off, interleaved in one process on a simulated clock.

The loop thread's CPU time (`time.thread_time`) counts only this thread's work, so other
processes on the core do not enter the figure. Issue 34 asks the split controller to cost within
1.1x of the old one; issue 30 asks the same of the monitor.

    python scripts/bench_loop_cpu.py --baseline-src DIR [--rounds 16] [--rate 1000]
                                     [--telemetry] [--real-clock [--child]]

On the simulated clock a run of 3000 ticks takes ~30 ms, so the telemetry writer's work (with the
monitor on: the prediction and the residual) is squeezed beside the loop, and the ring's
back-pressure (a simulated loop waits for a full ring to drain) puts wake-ups on the loop thread:
monitor on reads ~1.25x off there, though the loop's own Python work is 1.02x. `--telemetry
--real-clock` runs every variant as the service does (recording; ticks at the rate, sleeping
without the final spin): the loop thread's CPU is then its work plus the wake-up from each sleep.
`--child` adds what the service adds: a background diagnosis running while the monitor's variant runs.

DIR holds a gma_ffc package, e.g. `git archive d0686ce | tar -x -C DIR`.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_controller as bench  # noqa: E402  (the controllers are built as bench_controller builds them)


def controllers(baseline: Path, rate: float, folder: Path | None, real_clock: bool) -> dict[str, Any]:
    from gma_ffc.control import config

    bench._load_as(baseline.resolve(), "gma_ffc_baseline")
    model = bench._models()[0].to_dict()

    def file(name: str) -> Path | None:
        return None if folder is None else folder / f"{name}.csv"

    out = {"before": bench._simulated("gma_ffc_baseline", rate, model, file("before"), real_clock),
           "after, monitor on": bench._simulated("gma_ffc", rate, model, file("on"), real_clock)}
    validate = config.validate_config

    def monitor_off(d: dict[str, Any], *args: Any, **kwargs: Any) -> Any:
        return validate({**d, "monitor": {"enabled": False}}, *args, **kwargs)

    config.validate_config = monitor_off
    try:
        out["after, monitor off"] = bench._simulated("gma_ffc", rate, model, file("off"), real_clock)
    finally:
        config.validate_config = validate
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline-src", type=Path, required=True, metavar="DIR", help="a tree with the old gma_ffc")
    ap.add_argument("--rounds", type=int, default=16, help="interleaved rounds (default 16)")
    ap.add_argument("--rate", type=float, default=1000.0, help="loop rate, Hz (default 1000)")
    ap.add_argument("--seconds", type=float, default=3.0, help="seconds of loop time per run (default 3)")
    ap.add_argument("--telemetry", action="store_true",
                    help="every variant records telemetry (a temporary file), as the shipped configs do; "
                         "without it, only the monitor's variant keeps rows (for its watch)")
    ap.add_argument("--real-clock", action="store_true",
                    help="tick on the real clock at the rate (sleeping, no spin), so the writer thread's "
                         "work beside the loop comes at the service's pace, not compressed into a fast run")
    ap.add_argument("--child", action="store_true",
                    help="with --real-clock: a real `gma-ffc diagnose` child (nice 19, restarted as it ends) "
                         "runs while the monitor's variant runs, as the service's background diagnosis would")
    args = ap.parse_args(argv)
    if args.child and not args.real_clock:
        raise SystemExit("--child needs --real-clock: on the simulated clock a run lasts ~30 ms, less than "
                         "the child takes to start")
    if not (args.baseline_src / "gma_ffc" / "__init__.py").is_file():
        raise SystemExit(f"--baseline-src {args.baseline_src}: no gma_ffc package there; make one with "
                         "`git archive <commit> | tar -x -C DIR`")
    with tempfile.TemporaryDirectory(prefix="gma-ffc-bench-") as folder:
        ctrls = controllers(args.baseline_src, args.rate, Path(folder) if args.telemetry else None, args.real_clock)
        child = _child(Path(folder)) if args.child else contextlib.nullcontext
        return _measure(args, ctrls, child)


def _child(folder: Path) -> Any:
    """A maker of contexts, each keeping a diagnosis child running while it is open (bench_monitor's
    child, on its 30 s window)."""
    import bench_monitor

    files = bench_monitor._child_files(bench._models()[0], folder)
    return lambda: bench_monitor.DiagnosisChild(*files)


def _measure(args: argparse.Namespace, ctrls: dict[str, Any], child: Any) -> int:
    per_tick: dict[str, list[float]] = {k: [] for k in ctrls}
    children = 0
    for _ in range(args.rounds):
        for name, ctrl in ctrls.items():
            with child() if name == "after, monitor on" else contextlib.nullcontext() as running:
                seen, started = ctrl.stats.count, time.thread_time()
                summary = ctrl.run(duration_s=args.seconds)
                per_tick[name].append((time.thread_time() - started) / (summary["ticks"] - seen) * 1e6)
            children += getattr(running, "runs", 0)
    before = statistics.median(per_tick["before"])
    started_children = f"; {children} diagnosis children started" if args.child else ""
    print(f"CPU per tick of the loop thread at {args.rate:g} Hz, {args.rounds} interleaved rounds "
          f"(load average {os.getloadavg()[0]:.1f}{started_children}):")
    for name, values in per_tick.items():
        median = statistics.median(values)
        print(f"  {name:<20} median {median:6.2f} us ({median / before:.2f}x before), min {min(values):.2f} us")
    # issue 30's figure: the monitor on against off, round by round (each pair ran back to back)
    paired = [on / off for on, off in zip(per_tick["after, monitor on"], per_tick["after, monitor off"])]
    print(f"  monitor on / off, per round: median {statistics.median(paired):.2f}x "
          f"(rounds {min(paired):.2f}-{max(paired):.2f}x)")
    # A count, so the machine's load cannot move it: the loop thread's Python work per tick (the
    # monitor's work runs in the telemetry writer's thread, which is not traced; numba's is not counted)
    work = {name: bench._traced_work(ctrl, args.rate) for name, ctrl in ctrls.items()}
    print("Python work per tick of the loop thread (sys.settrace; load-independent):")
    for name, (calls, ops) in work.items():
        print(f"  {name:<20} {calls:6.1f} calls, {ops:7.1f} bytecodes ({ops / work['before'][1]:.2f}x before)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
