#!/usr/bin/env python3
"""What the model-fit monitor costs the loop (issue 30): the service at 1 kHz on the sim driver,
real clock, in three variants interleaved in one process, round after round:

  off      monitor.enabled: false, no metrics
  off-again  the same as `off`, run again: its ratio to `off` is the bench's own spread (an A/A
           control), against which the others' ratios are read
  monitor  the monitor (prediction, fit monitor, recent rows), nothing else
  on       the monitor, and a real `gma-ffc diagnose` child running throughout (nice 19,
           SCHED_OTHER, as the service starts it)
  scraped  as `on`, with the metrics endpoint scraped over HTTP 10 times a second (a Prometheus
           server scrapes every 15 s by default)

Per variant: period jitter p99 and compute time per tick p50/p99 (the loop's own histograms), as
medians over the rounds and as ratios against `off`. The load average is printed beside them:
the machine is shared, so only the interleaved ratios mean anything.

A p99 from one round of a few seconds rests on a few dozen ticks, and a shared machine's bursts
land on one round and not the next (the A/A rounds ranged 0.36-2.36x). So the loop's histograms
are also pooled: every round's counts are added per variant, and the percentiles are read from
the sums. Many short rounds then spread the bursts over all variants alike, and the A/A ratio says
how finely the pool resolves. With --one-child, a single diagnosis child serves the whole run: it
is continued (SIGCONT) while `on` or `scraped` runs and stopped (SIGSTOP) otherwise, so that short
rounds measure a diagnosis at work, not one importing scipy at its start.

    .venv/bin/python scripts/bench_monitor.py --rounds 5 --duration 10 [--realtime-priority 50] [--telemetry]
    .venv/bin/python scripts/bench_monitor.py --rounds 40 --duration 2 --one-child --realtime-priority 50
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
VARIANTS = ("off", "off-again", "monitor", "on", "scraped")
OFF = ("off", "off-again")      # the same service twice: their ratio is what the bench itself resolves


def _config(variant: str, duration: float, priority: int, telemetry: Path | None = None) -> Any:
    from gma_ffc.control.config import validate_config

    data = {"rate_hz": 1000.0, "clock": "real", "model": "unused.yaml", "watchdog_s": 1.0,
            "driver": {"kind": "sim", "load_mass_kg": 15.3},
            "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 25.5, "offset_um": 26.0},
            "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0},
            "telemetry": {"path": str(telemetry) if telemetry else None}, "scheduler": {"realtime_priority": priority},
            "monitor": {"enabled": variant not in OFF, "window_s": min(30.0, duration / 2), "on_drift": "warn"}}
    if variant == "scraped":
        data["metrics"] = {"port": 0}
    return validate_config(data)


class DiagnosisChild:
    """A real diagnosis, restarted whenever it finishes, for as long as the variant runs."""

    def __init__(self, model_path: Path, window: Path, out: Path, loop_started: Any = lambda: True) -> None:
        self.loop_started = loop_started
        self.argv = [sys.executable, "-m", "gma_ffc.service.diagnose_child", str(os.getpid()), "--", "diagnose",
                     "--model", str(model_path), str(window), "--out", str(out)]
        self.out = out
        self.child: subprocess.Popen | None = None
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.runs = 0

    def _run(self) -> None:
        from gma_ffc.service.diagnosis import SINGLE_THREAD

        # as the service starts one: while the loop runs (its environment then names the loop's CPU)
        while not self.stop.wait(0.01) and not self.loop_started():
            pass
        while not self.stop.is_set():
            for name in ("diagnosis.json", "report.html", "extended_model.yaml"):
                (self.out / name).unlink(missing_ok=True)
            self.child = subprocess.Popen(self.argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                          env={**os.environ, **SINGLE_THREAD})
            self.runs += 1
            while self.child.poll() is None and not self.stop.wait(0.2):
                pass

    def __enter__(self) -> "DiagnosisChild":
        self.thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop.set()
        if self.child is not None and self.child.poll() is None:
            self.child.kill()
            self.child.wait()
        self.thread.join(timeout=10)


class PausedChild(DiagnosisChild):
    """One diagnosis child for the whole run, at work only while a variant that has one runs."""

    def __init__(self, *files: Path) -> None:
        super().__init__(*files)
        self.lock = threading.Lock()      # a child started while another thread pauses is paused too
        self.paused = True

    def _run(self) -> None:
        from gma_ffc.service.diagnosis import SINGLE_THREAD

        while not self.stop.is_set():
            for name in ("diagnosis.json", "report.html", "extended_model.yaml"):
                (self.out / name).unlink(missing_ok=True)
            with self.lock:
                self.child = subprocess.Popen(self.argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                              env={**os.environ, **SINGLE_THREAD})
                if self.paused:
                    self.child.send_signal(signal.SIGSTOP)
            self.runs += 1
            while self.child.poll() is None and not self.stop.wait(0.2):
                pass

    def resume(self) -> None:
        self._signal(False)

    def pause(self) -> None:
        self._signal(True)

    def _signal(self, paused: bool) -> None:
        with self.lock:
            self.paused = paused
            if self.child is not None and self.child.poll() is None:
                self.child.send_signal(signal.SIGSTOP if paused else signal.SIGCONT)

    def __exit__(self, *exc: Any) -> None:
        self.resume()          # a stopped process takes SIGKILL too, but leave none stopped behind
        super().__exit__(*exc)


SCRAPER = """
import sys, time, urllib.request
url, n = sys.argv[1], 0
while True:
    try:
        with urllib.request.urlopen(url, timeout=5) as reply:
            reply.read()
        n += 1
        print(n, flush=True)
    except OSError:
        if n:
            break
    time.sleep(0.1)
"""


def _scrape(url_of: Any, stop: threading.Event, counts: list[int]) -> None:
    """Scrape at 10 Hz from a process of its own, as a Prometheus server would (from elsewhere)."""
    while not stop.wait(0.05) and not url_of():
        pass
    if stop.is_set():
        return
    proc = subprocess.Popen([sys.executable, "-c", SCRAPER, url_of()], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            counts[0] = int(line)
            if stop.is_set():
                break
    finally:
        proc.kill()
        proc.wait()


def run_variant(variant: str, model: Any, duration: float, priority: int, child_files: tuple[Path, Path, Path],
                telemetry: Path | None = None, shared_child: PausedChild | None = None) -> dict:
    from gma_ffc.control.manager import ControllerManager
    from gma_ffc.service.runner import Service

    cfg = _config(variant, duration, priority, telemetry)
    ctrl = ControllerManager(cfg, model=model)
    svc = Service("bench.yaml", duration_s=duration, load_config=lambda p: cfg, make_controller=lambda c: ctrl,
                  install_signal_handlers=False)
    stop, scrapes = threading.Event(), [0]
    scraper = threading.Thread(target=_scrape, args=(lambda: (svc.status().get("metrics") or {}).get("url"), stop,
                                                      scrapes), daemon=True)
    if variant == "scraped":
        scraper.start()
    try:
        if variant in OFF + ("monitor",):
            svc.run()
            runs = 0
        elif shared_child is not None:
            shared_child.resume()
            try:
                svc.run()
            finally:
                shared_child.pause()
            runs = 1
        else:
            with DiagnosisChild(*child_files, loop_started=lambda: ctrl.stats.count > 0) as child:
                svc.run()
                runs = child.runs
    finally:
        stop.set()
    s = ctrl.status()
    return {"jitter_p99_us": s["jitter_p99_us"], "compute_p50_us": s["compute_p50_us"],
            "compute_p99_us": s["compute_p99_us"], "overruns": s["overruns"], "ticks": s["ticks"],
            "diagnoses": runs, "scrapes": scrapes[0], "load": os.getloadavg()[0],
            "jitter_counts": ctrl.stats.jitter.counts.copy(), "compute_counts": ctrl.stats.compute.counts.copy()}


def _child_files(model: Any, folder: Path) -> tuple[Path, Path, Path]:
    """The model and a 30 s full-stroke window of the simulated rig for the diagnosis child."""
    import numpy as np

    from gma_ffc.modelio import save_model
    from gma_ffc.recordings import Recording, write_recording
    from hil_sim.plant import GMAPlant, PlantConfig

    pc = PlantConfig().with_effects(["noise", "thermal"])
    t = np.arange(30000) / 1000.0
    drive = 1.5 - 1.45 * np.cos(2 * np.pi * 3 * t)
    out = GMAPlant(pc, seed=3).run(t, drive, load_mass_kg=15.3)
    write_recording(folder / "window.csv", Recording({"time_s": t, "current_A": out["current_A"],
                                                      "stress_MPa": out["stress_MPa"],
                                                      "displacement_um": out["displacement_um"]}, {}, "window.csv"))
    save_model(model, folder / "model.yaml")
    return folder / "model.yaml", folder / "window.csv", folder


def pooled_percentiles(rounds: list[dict], key: str, qs: tuple[float, ...] = (50.0, 99.0)) -> list[float]:
    """Percentiles of the histograms of all `rounds` added together (upper bin edges, as the loop reads)."""
    from gma_ffc.control.scheduler import _Histogram

    h = _Histogram()
    h.counts = sum(r[key] for r in rounds)
    h.max_us = float("inf")
    return [float(h.percentile(q) or 0.0) for q in qs]


def print_pooled(results: dict[str, list[dict]]) -> None:
    """Each variant's ticks over all rounds in one histogram, read against `off`'s; the halves of
    the rounds (even, odd) apart, to show how far the pooled ratio moves with the rounds drawn."""
    halves = {"all": slice(None), "even": slice(0, None, 2), "odd": slice(1, None, 2)}
    print("\npooled over the rounds (every tick of a variant in one histogram; ratios against off):")
    for v in VARIANTS:
        cells = []
        for key, label in (("jitter_counts", "jitter"), ("compute_counts", "compute")):
            for q_index, q in enumerate((50, 99)):
                ratios = {}
                for name, part in halves.items():
                    mine = pooled_percentiles(results[v][part], key)[q_index]
                    base = pooled_percentiles(results["off"][part], key)[q_index]
                    ratios[name] = (mine, mine / max(base, 1e-9))
                value, ratio = ratios["all"]
                cells.append(f"{label} p{q} {value:6.1f} us {ratio:.2f}x "
                             f"({ratios['even'][1]:.2f}/{ratios['odd'][1]:.2f})")
        ticks = sum(int(r["jitter_counts"].sum()) for r in results[v])
        print(f"  {v:9s} {ticks:7d} ticks  " + "  ".join(cells))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--duration", type=float, default=10.0, help="seconds per variant per round")
    p.add_argument("--realtime-priority", type=int, default=0)
    p.add_argument("--telemetry", action="store_true",
                   help="every variant records its telemetry to a file, as the shipped configs do "
                        "(default: none, so `off` has no writer thread at all)")
    p.add_argument("--one-child", action="store_true",
                   help="one diagnosis child for the whole run, stopped (SIGSTOP) while the variants "
                        "without one run (default: a child started afresh for each variant that has one)")
    args = p.parse_args(argv)
    from gma_ffc.sil import cached_sdpi_and_mpi

    model = cached_sdpi_and_mpi(Path(tempfile.gettempdir()) / "gma_ffc_bench_models")[0]
    results: dict[str, list[dict]] = {v: [] for v in VARIANTS}
    with tempfile.TemporaryDirectory() as tmp, contextlib.ExitStack() as stack:
        files = _child_files(model, Path(tmp))
        shared = stack.enter_context(PausedChild(*files)) if args.one_child else None
        for r in range(args.rounds):
            order = VARIANTS if r % 2 == 0 else VARIANTS[::-1]       # neither goes first every time
            for v in order:
                res = run_variant(v, model, args.duration, args.realtime_priority, files,
                                  Path(tmp) / f"telemetry_{v}_{r}.csv" if args.telemetry else None, shared)
                results[v].append(res)
                print(f"round {r + 1} {v:8s} jitter p99 {res['jitter_p99_us']:7.1f} us  compute p50 "
                      f"{res['compute_p50_us']:6.1f} p99 {res['compute_p99_us']:6.1f} us  overruns {res['overruns']:3d}  "
                      f"diagnoses {res['diagnoses']}  scrapes {res['scrapes']:3d}  load {res['load']:.1f}", flush=True)
        child_runs = shared.runs if shared is not None else None
    print(f"\nmedians over {args.rounds} rounds of {args.duration:g} s at 1 kHz (sim driver, realtime priority "
          f"{args.realtime_priority}); load average now {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    base = {k: statistics.median(x[k] for x in results["off"]) for k in ("jitter_p99_us", "compute_p50_us", "compute_p99_us")}
    for v in VARIANTS:
        med = {k: statistics.median(x[k] for x in results[v]) for k in base}
        ratio = "  ".join(f"{k} {med[k]:7.1f} us ({med[k] / base[k]:.2f}x)" for k in base)
        print(f"  {v:8s} {ratio}")
    # the same figures as ratios within each round (variant / off of that round), so a machine whose
    # speed drifts between rounds moves both sides of a ratio alike: the median and range of those
    print("\nratios within each round (median, range):")
    for v in VARIANTS[1:]:
        cells = []
        for k in base:
            rs = [x[k] / max(o[k], 1e-9) for x, o in zip(results[v], results["off"])]
            cells.append(f"{k} {statistics.median(rs):.2f}x ({min(rs):.2f}-{max(rs):.2f})")
        print(f"  {v:8s} " + "  ".join(cells))
    print_pooled(results)
    if child_runs is not None:
        print(f"one diagnosis child at a time, {child_runs} started over the run, at work only in on and scraped")
    return 0


if __name__ == "__main__":
    sys.exit(main())
