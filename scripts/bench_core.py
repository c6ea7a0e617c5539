#!/usr/bin/env python3
"""Benchmark the hysteresis core and print the figures issue #2 asks for.

1. Batch simulation of a 1,000,000-sample recording (10 plays, 7 dead-zones, stress varying):
   the numba kernel vs a straightforward numpy loop (Python over time, numpy over operators),
   both timed in this run; the figure is the ratio.
2. One stateful inverse step as the control loop calls it: median and p99 in microseconds,
   with the same step written as a numpy loop for scale; then an extended model's (as diagnose
   writes one), as a ratio to it.
3. `identify` on seven 10,000-sample recordings from the independent hil_sim plant, end to end
   through the CLI entry point (reading CSVs, fitting, writing the model).

    python scripts/bench_core.py                 # full sizes
    python scripts/bench_core.py --samples 200000 --baseline-samples 50000   # quicker
"""

from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
import time
from pathlib import Path

import gma_ffc  # noqa: F401  (single-threaded BLAS before numpy loads)
import numpy as np

from gma_ffc import operators as ops
from gma_ffc.identify import SDPIIdentifier
from gma_ffc.model import SDPIModel


def reference_model() -> SDPIModel:
    """A realistic SDPI: identified from the hil_sim plant (not hand-made)."""
    from hil_sim.record import make_recordings

    return SDPIIdentifier().fit(make_recordings("identification", seed=11)).model_


def numpy_loop_forward(model: SDPIModel, x: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """The baseline: Python loop over time, numpy over operators."""
    r_h, w_h, r_s, c = model.play_thresholds, model.play_weights, model.deadzone_thresholds, model.deadzone_coeffs
    o = model.output_coeffs
    state = model.forward_state(x[0])[: model.n_play].copy()
    pos, neg = r_s > 0, r_s < 0
    out = np.empty_like(x)
    for k in range(x.size):
        v = x[k] - model.input_offset
        state = np.maximum(v - r_h, np.minimum(v + r_h, state))
        z = w_h @ state
        s = sigma[k]
        w = c[0] + s * (c[1] + s * c[2])
        dz = np.where(pos, np.maximum(z - r_s, 0.0), np.where(neg, np.minimum(z - r_s, 0.0), z))
        out[k] = o[0] + s * (o[1] + s * o[2]) + w @ dz
    return out


def bench_batch(model: SDPIModel, n: int, n_base: int) -> None:
    t = np.arange(n) / 10_000.0
    x = 1.5 - 1.4 * np.cos(2 * np.pi * 3 * t) * (0.6 + 0.4 * np.cos(2 * np.pi * 0.05 * t))
    lo, hi = model.stress_range_MPa
    sigma = 0.5 * (lo + hi) + 0.45 * (hi - lo) * np.sin(2 * np.pi * 0.01 * t)
    model.simulate(t[:100], x[:100], sigma[:100])  # compile outside the timing
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        y = model.simulate(t, x, sigma, initial_drive=float(x[0]))   # the baseline starts relaxed there too
        best = min(best, time.perf_counter() - t0)
    t0 = time.perf_counter()
    y_base = numpy_loop_forward(model, x[:n_base], sigma[:n_base])
    base = time.perf_counter() - t0
    assert np.allclose(y_base, y[:n_base], atol=1e-9), "baseline and kernel disagree"
    per_kernel, per_base = best / n, base / n_base
    print(f"batch simulate, {n:,} samples, {model.n_play} plays + {model.n_deadzone} dead-zones:")
    print(f"  numba kernel      {best * 1e3:9.1f} ms   ({per_kernel * 1e9:6.1f} ns/sample)")
    print(f"  numpy loop        {base * n / n_base * 1e3:9.1f} ms   ({per_base * 1e9:6.1f} ns/sample"
          f"{'' if n_base == n else f', timed on {n_base:,} samples'})")
    print(f"  speed-up          {per_base / per_kernel:9.0f} x   (target >= 30 x)")


def _step_times(step, ref: np.ndarray, sig: np.ndarray) -> np.ndarray:
    """Nanoseconds per call of step(ref[k], sig[k]) after a 1000-call warm-up."""
    for k in range(1000):
        step(ref[k], sig[k])
    times = np.empty(ref.size)
    clock = time.perf_counter_ns
    for k in range(ref.size):
        t0 = clock()
        step(ref[k], sig[k])
        times[k] = clock() - t0
    return times


def bench_step(model: SDPIModel, n: int = 200_000) -> np.ndarray:
    lo, hi = model.stress_range_MPa
    stepper = model.inverse_stepper(1e-3, initial_drive=0.0)
    ref = 20 + 15 * np.sin(np.linspace(0, 200 * np.pi, n))
    sig = np.linspace(lo, hi, n)
    times = _step_times(stepper.step, ref, sig)
    clock = time.perf_counter_ns
    overhead = np.empty(10_000)
    for k in range(overhead.size):
        t0 = clock()
        overhead[k] = clock() - t0
    med = np.median(times) / 1e3
    print(f"inverse step (control loop form), {n:,} calls:")
    print(f"  median {med:.2f} us, p99 {np.percentile(times, 99) / 1e3:.2f} us, "
          f"max {times.max() / 1e3:.1f} us (timer overhead {np.median(overhead) / 1e3:.2f} us)   (target median <= 5 us)")
    return times


def bench_extended_step(model: SDPIModel, core_times: np.ndarray, n: int = 50_000) -> None:
    """An extended model as diagnose writes one (recalibration with play corrections, stress plays,
    saturation, creep): its inverse solves each sample's core input (a few core-inverse tries), so
    its step is quoted as a ratio to the plain core's, timed above in this process."""
    from gma_ffc.extended import ExtendedModel

    lo, hi = model.stress_range_MPa
    d_lo, d_hi = model.drive_range
    th = [0.05 * (d_hi - d_lo) * k for k in (1, 2, 4)]
    ext = ExtendedModel(model, {
        "static": {"offset_um": 0.2, "gain": 1.02, "stress_gain_per_MPa": 0.002, "quadratic_per_um": 1e-4,
                   "center_um": 20.0, "stress_ref_MPa": 0.5 * (lo + hi)},
        "play_correction": {"thresholds": th, "coefficients": [0.3, -0.5, 0.2]},
        "stress_play": {"thresholds": th[:2], "coefficients_per_MPa": [0.02, -0.01]},
        "saturation": {"lo": d_lo, "hi": d_hi, "lin_lo": 0.0, "quad_lo": 0.0, "lin_hi": -0.5, "quad_hi": -0.2},
        "creep": {"gain": 0.02, "tau_s": 0.5}})
    ref = 20 + 15 * np.sin(np.linspace(0, 50 * np.pi, n))
    sig = np.linspace(lo, hi, n)
    stepper = ext.inverse_stepper(1e-3, initial_drive=d_lo)
    times = _step_times(stepper.step, ref, sig)
    drive = ext.invert(np.arange(n) * 1e-3, ref, sig)
    err = ext.simulate(np.arange(n) * 1e-3, drive, sig, initial_drive=d_lo) - ref
    ratio = np.median(times) / np.median(core_times)
    print(f"extended-model inverse step (5 effect blocks, core input solved each sample), {n:,} calls:")
    print(f"  median {np.median(times) / 1e3:.2f} us ({ratio:.1f}x the plain core's), p99 "
          f"{np.percentile(times, 99) / 1e3:.2f} us, max {times.max() / 1e3:.1f} us; "
          f"round trip max error {np.max(np.abs(err)):.2g} um")


def bench_identify(n_rec: int = 7, n_samples: int = 10_000) -> None:
    from hil_sim.record import make_recordings

    from gma_ffc.cli import main
    from gma_ffc.recordings import write_recording

    stresses = list(np.linspace(-11.3, -24.0, n_rec))
    fs = 2000.0
    periods = int(np.ceil(n_samples / fs * 3.0))
    recs = make_recordings("identification", seed=5, stresses=stresses, fs=fs, periods=periods)
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for k, rec in enumerate(recs):
            cols = {name: v[:n_samples] for name, v in rec.columns.items()}
            rec.columns = cols
            p = Path(tmp) / f"id_{k}.csv"
            write_recording(p, rec)
            paths.append(str(p))
        with contextlib.redirect_stdout(io.StringIO()):  # JIT caches warm
            main(["identify", paths[0], paths[1], "-o", str(Path(tmp) / "warm.yaml")])
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()) as out:
            rc = main(["identify", *paths, "-o", str(Path(tmp) / "model.yaml")])
        elapsed = time.perf_counter() - t0
    assert rc == 0
    print(f"gma-ffc identify, {n_rec} recordings x {n_samples:,} samples (hil_sim plant, CSV in, YAML out):")
    print(f"  {elapsed:.2f} s   (target < 5 s)")
    print("  " + out.getvalue().strip().replace("\n", "\n  "))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--baseline-samples", type=int, default=None,
                    help="samples for the numpy-loop baseline (default: all; it takes ~10-20 s)")
    args = ap.parse_args()
    model = reference_model()
    bench_batch(model, args.samples, args.baseline_samples or args.samples)
    core_times = bench_step(model)
    bench_extended_step(model, core_times)
    bench_identify()


if __name__ == "__main__":
    main()
