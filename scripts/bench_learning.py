#!/usr/bin/env python3
"""Learning feedforward against feedforward alone: tracking RMS per period, through the real controller.

Sections (`--only`, default: classic and limits):

  classic    3 Hz and 20 Hz sines on the simulated rig (hil_sim, in-process, simulated clock) through
             a load step (-11.3 -> -19.1 MPa at half time); the rig has sensor noise, a 1 ms transport
             delay and eddy currents, the model (config/models/sim_sdpi.yaml) was identified without them.
  limits     the three references of issue 32: one touching the current floor at every period's
             bottom, one touching the slew limit (both in-process), and one through the Modbus TCP
             emulator with 1-2 ms of random latency on every request (real time). Target: at most
             0.4x feedforward within 20 periods.
  sessions   seeded sessions through the Modbus TCP emulator, reference to the current floor, latency
             1-2 ms, 0 A floor, 50 A/s slew (benchmarks/learning_rigs.py draws frequency, amplitude and
             load from the seed). Targets: none ends worse than feedforward, median at most 0.4x.
             `--seeds tuning` (the defaults were chosen on these), `held-out` and `fresh` (never used
             to choose), `rig` (another plant: every hil_sim effect on); quote them apart.

Every learning run is paired with a feedforward run of the same seed. Through the emulator the two
run at the same time in two processes, so the machine's load hits both alike; real-time sections
print the load average beside the figures (on a shared machine the loop misses deadlines, which
is timing jitter of its own).

    python scripts/bench_learning.py [--only classic,limits,sessions] [--seeds tuning] [--count 20]
    python scripts/bench_learning.py --only sessions --seeds held-out --json out.json
    python scripts/bench_learning.py --sweep cutoff_hz=5,10,20 --count 6     # choose a default
    python scripts/bench_learning.py --only classic --plot docs/img/learning.png
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.learning_rigs import (  # noqa: E402
    FRESH_SEEDS, HELD_OUT_RIG, HELD_OUT_SEEDS, MODEL, TUNING_SEEDS, Session, SessionRun, draw_session, run_latency_sim,
    run_modbus_session)
from gma_ffc.sil import run_tracking  # noqa: E402

STEP_MASS_KG = 30.6     # -19.1 MPa on the paper's rig
TARGET = 0.4            # issue 32: at most 0.4x feedforward within 20 periods
WITHIN = 20
PERIODS = 30            # per run: 20 to reach the target, then a window to judge how it ends
FLOOR_REF = {"amplitude_um": 12.0, "offset_um": 12.0}        # 0-24 um: its bottom asks for 0 A
SLEW_LIMIT = 14.0       # A/s: the steepest ~5 % of the 3 Hz command (its 99th-percentile slope is 18 A/s)
MODBUS_REF = Session(seed=0, frequency_hz=3.0, amplitude_um=12.0, stress_MPa=-15.2, offset=18.0)  # 6-30 um


def load() -> str:
    return "load %.1f %.1f %.1f" % os.getloadavg()


# ---- classic: the figures of issue 12 ------------------------------------------------------------
def classic(periods: int, plot: str | None) -> None:
    rows, runs = [], {}
    for f, n in ((3.0, periods), (20.0, 3 * periods)):
        sched = ((0.0, 0.0), (0.5 * n / f, STEP_MASS_KG))
        ff = run_tracking(MODEL, f, n, load_schedule=sched)
        ln = run_tracking(MODEL, f, n, learning={"kind": "repetitive"}, load_schedule=sched)
        runs[f] = (ff, ln)
        step = n // 2
        for label, a, b in (("periods 10-19 (before the step)", 10, 20), ("the period of the load step", step, step + 1),
                            ("last 10 periods (after the step)", n - 10, n)):
            r_ff, r_ln = float(np.mean(ff.period_rms_um[a:b])), float(np.mean(ln.period_rms_um[a:b]))
            rows.append((f, label, r_ff, r_ln, r_ln / r_ff))
    print("== classic: sines through a load step, simulated rig in-process ==")
    print(f"{'ref':>6}  {'window':<34}{'feedforward':>12}{'+ learning':>12}{'ratio':>8}")
    for f, label, a, b, r in rows:
        print(f"{f:>4g}Hz  {label:<34}{a:>9.3f} um{b:>9.3f} um{r:>8.2f}")
    if plot:
        plot_classic(runs, plot)


def plot_classic(runs: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), constrained_layout=True)
    for ax, (f, (ff, ln)) in zip(axes, runs.items()):
        k = np.arange(1, len(ff.period_rms_um) + 1)
        ax.semilogy(k, ff.period_rms_um, "o-", ms=3, label="SDPI feedforward")
        ax.semilogy(k, ln.period_rms_um, "o-", ms=3, label="SDPI + learning")
        ax.axvline(len(k) / 2 + 0.5, color="0.5", ls="--", lw=0.8)
        ax.set_title(f"{f:g} Hz sine, load step at the dashed line", fontsize=10)
        ax.set_xlabel("period")
        ax.set_ylabel("tracking RMS (um)")
    axes[0].legend(loc="upper right", fontsize=8)
    fig.savefig(path, dpi=110)
    print(f"figure: {path}")


# ---- limits: the three references of issue 32 ----------------------------------------------------
def reached(ff: np.ndarray, ln: np.ndarray) -> tuple[float, int | None]:
    """(ratio over periods 16-20, the first period <= 20 at or under TARGET x feedforward)."""
    ratio = float(np.mean(ln[WITHIN - 5:WITHIN]) / np.mean(ff[WITHIN - 5:WITHIN]))
    ref = float(np.mean(ff[1:WITHIN]))
    first = next((k + 1 for k in range(min(WITHIN, len(ln))) if ln[k] <= TARGET * ref), None)
    return ratio, first


def limited_words(learning: dict[str, Any]) -> str:
    spans = learning.get("reference_beyond_limits") or []
    said = ", ".join(f"{s['limit']} {100 * s['share']:.1f} % at phase {s['from']:.2f}-{s['to']:.2f}" for s in spans)
    last = learning.get("limited", {})
    return (f"said at start: {said or 'nothing beyond the limits'}; last period limited "
            f"{100 * last.get('share', 0):.1f} % {last.get('by', {})}")


def limits_section(learning: dict[str, Any], out: dict[str, Any]) -> None:
    print("\n== limits: the three references of issue 32 (target <= 0.4x feedforward within 20 periods) ==")
    cases = [
        ("floor: 3 Hz 0-24 um, 0 A floor (in-process)", dict(**FLOOR_REF)),
        (f"slew: 3 Hz 8-32 um, {SLEW_LIMIT:g} A/s (in-process)", dict(limits={"slew_A_per_s": SLEW_LIMIT})),
    ]
    for label, kw in cases:
        ff = run_tracking(MODEL, 3.0, PERIODS, **kw)
        ln = run_tracking(MODEL, 3.0, PERIODS, learning=learning, **kw)
        report_limits(label, ff.period_rms_um, ln.period_rms_um, ln.status["learning"], out)
    label = (f"modbus: 3 Hz 6-30 um, 0 A floor, 50 A/s, 1-2 ms latency per request, "
             f"{MODBUS_REF.stress_MPa:g} MPa (real time, {load()})")
    ff_run, ln_run = side_by_side(MODBUS_REF, learning)
    report_limits(label, ff_run.period_rms_um, ln_run.period_rms_um, ln_run.status["learning"], out,
                  f"latency {ln_run.extra['latency_ms'][0]:.2f}-{ln_run.extra['latency_ms'][1]:.2f} ms, "
                  f"achieved {ln_run.status['achieved_rate_hz']:.0f} Hz, {ln_run.status['missed_deadlines']} "
                  f"missed deadlines, {load()}")


def report_limits(label: str, ff: np.ndarray, ln: np.ndarray, learning: dict, out: dict, note: str = "") -> None:
    ratio, first = reached(ff, ln)
    ok = "MET" if ratio <= TARGET else "NOT MET"
    print(f"{label}\n    feedforward {np.mean(ff[15:20]):.3f} um, learning {np.mean(ln[15:20]):.3f} um over periods "
          f"16-20: {ratio:.2f}x ({ok}); first period at <= {TARGET}x: {first}; stage {learning['stage']}, "
          f"back-offs {learning['backoffs']}")
    print(f"    {limited_words(learning)}")
    if note:
        print(f"    {note}")
    print("    per period, feedforward: " + " ".join(f"{v:.3f}" for v in ff))
    print("    per period, learning:    " + " ".join(f"{v:.3f}" for v in ln))
    out.setdefault("limits", []).append({"case": label, "ratio_16_20": ratio, "first_period": first,
                                         "feedforward_um": ff.tolist(), "learning_um": ln.tolist()})


# ---- sessions ------------------------------------------------------------------------------------------
def sessions_of(which: str, count: int) -> list[Session]:
    if which == "rig":
        return list(HELD_OUT_RIG[:count])
    seeds = {"tuning": TUNING_SEEDS, "held-out": HELD_OUT_SEEDS, "fresh": FRESH_SEEDS}[which]
    return [draw_session(s) for s in seeds[:count]]


TRANSPORTS = ("emulator", "latency-sim")
_FEEDFORWARD: dict[tuple, SessionRun] = {}     # latency-sim repeats exactly: one feedforward run per session


_POOL: Any = None


def side_by_side(session: Session, learning: dict[str, Any]) -> tuple[SessionRun, SessionRun]:
    """The feedforward and the learning run of a session at the same time, in two processes, each
    with its own emulator: whatever load the machine has then, it hits both alike."""
    global _POOL
    if _POOL is None:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        _POOL = ProcessPoolExecutor(max_workers=2, mp_context=multiprocessing.get_context("spawn"))
    ff = _POOL.submit(run_modbus_session, session, learning=None, periods=PERIODS)
    ln = _POOL.submit(run_modbus_session, session, learning=learning, periods=PERIODS)
    return ff.result(), ln.result()


def session_pair(session: Session, learning: dict[str, Any], transport: str = "emulator") -> dict[str, Any]:
    t0 = time.monotonic()
    ff: SessionRun
    ln: SessionRun
    if transport == "emulator":
        ff, ln = side_by_side(session, learning)
    else:
        key = (transport, session)
        ff = _FEEDFORWARD.get(key) or run_latency_sim(session, learning=None, periods=PERIODS)
        _FEEDFORWARD[key] = ff
        ln = run_latency_sim(session, learning=learning, periods=PERIODS)
    st = ln.status["learning"]
    end_ff, end_ln = ff.window(PERIODS - 4, PERIODS), ln.window(PERIODS - 4, PERIODS)
    own = st["baseline_rms_um"]
    return {"session": session.describe(), "seed": session.seed, "ff_end_um": end_ff, "learn_end_um": end_ln,
            "ratio_end": end_ln / end_ff, "ratio_own_baseline": end_ln / own if own else None,
            "ratio_16_20": ln.window(16, 20) / ff.window(16, 20), "stage": st["stage"], "backoffs": st["backoffs"],
            "held": st["held_periods"], "limited_share": st["limited"]["share"], "limited_by": st["limited"]["by"],
            "said_at_start": bool(st["reference_beyond_limits"]), "achieved_hz": ln.status["achieved_rate_hz"],
            "missed": ln.status["missed_deadlines"], "load": os.getloadavg()[0], "seconds": time.monotonic() - t0,
            "feedforward_um": ff.period_rms_um.tolist(), "learning_um": ln.period_rms_um.tolist()}


def sessions_section(which: str, count: int, learning: dict[str, Any], out: dict[str, Any],
                     transport: str = "emulator") -> list[dict]:
    chosen = sessions_of(which, count)
    where = "through the Modbus TCP emulator" if transport == "emulator" else "with the emulator's latency in simulated time"
    print(f"\n== sessions {where} ({which} seeds, {len(chosen)}): reference to the 0 A floor, "
          f"1-2 ms latency, 50 A/s; {PERIODS} periods each; ratio = learning / feedforward, mean RMS of the last "
          f"5 periods ==")
    print(f"{'session':<52}{'ff':>8}{'learn':>8}{'ratio':>7}{'own':>6}{'16-20':>7}  stage        bo held "
          f"limited        Hz  load")
    rows = []
    for s in chosen:
        r = session_pair(s, learning, transport)
        rows.append(r)
        print(f"{r['session']:<52}{r['ff_end_um']:>8.3f}{r['learn_end_um']:>8.3f}{r['ratio_end']:>7.2f}"
              f"{r['ratio_own_baseline'] or float('nan'):>6.2f}{r['ratio_16_20']:>7.2f}  {r['stage']:<12}"
              f"{r['backoffs']:>3}{r['held']:>5} {100 * r['limited_share']:>5.1f} %{'*' if r['said_at_start'] else ' '}"
              f"{r['achieved_hz']:>8.0f}{r['load']:>6.1f}", flush=True)
    ratios = np.array([r["ratio_end"] for r in rows])
    print(f"  median {np.median(ratios):.2f}x, worst {ratios.max():.2f}x, ends worse than feedforward: "
          f"{int(np.sum(ratios > 1.0))} of {len(rows)}; the learner's own feedforward baseline: median "
          f"{np.median([r['ratio_own_baseline'] for r in rows]):.2f}x")
    print("  (* = status said at start where the reference asks beyond the limits; limited = share of the last "
          "period cut by a limit)")
    out.setdefault("sessions", {})[which] = rows
    return rows


def sweep(spec: str, which: str, count: int, out: dict[str, Any], transport: str) -> None:
    key, _, values = spec.partition("=")
    summary = []
    for raw in values.split(","):
        value: Any = json.loads(raw) if raw not in ("null", "None") else None
        learning = {"kind": "repetitive", key: value}
        print(f"\n#### sweep {key} = {value}")
        rows = sessions_section(which, count, learning, out.setdefault("sweep", {}).setdefault(f"{key}={value}", {}),
                                transport)
        summary.append((value, rows))
    print(f"\n#### sweep {key} ({transport}, {which} seeds): ratio of the median of the last 10 periods to the "
          f"median feedforward period; first period at <= {TARGET}x")
    for value, rows in summary:
        r = [np.median(x["learning_um"][-10:]) / np.median(x["feedforward_um"][1:]) for x in rows]
        first = [next((i + 1 for i, y in enumerate(x["learning_um"]) if y <= TARGET * np.median(x["feedforward_um"][1:])),
                      99) for x in rows]
        print(f"  {key} = {value!s:<6} median {np.median(r):.3f}x, worst {max(r):.3f}x, first period at <= {TARGET}x: "
              f"median {np.median(first):.0f}, worst {max(first)}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", default="classic,limits", help="comma-separated: classic, limits, sessions")
    ap.add_argument("--seeds", default="tuning", choices=("tuning", "held-out", "fresh", "rig", "all"))
    ap.add_argument("--count", type=int, default=20, help="sessions per seed set (default 20)")
    ap.add_argument("--periods", type=int, default=40, help="classic: periods at 3 Hz (20 Hz runs 3x as many)")
    ap.add_argument("--learning", default="{}", metavar="JSON", help="extra learning keys, e.g. '{\"gain\": 0.3}'")
    ap.add_argument("--sweep", metavar="KEY=V1,V2", help="sessions for each value of one learning key")
    ap.add_argument("--transport", default="emulator", choices=TRANSPORTS,
                    help="sessions: through the Modbus TCP emulator in real time (default), or its latency in "
                         "simulated time (repeatable, free of the machine's load)")
    ap.add_argument("--plot", metavar="PNG", help="classic: save the per-period RMS figure")
    ap.add_argument("--json", metavar="FILE", help="write every figure to FILE")
    args = ap.parse_args()
    learning = {"kind": "repetitive", **json.loads(args.learning)}
    out: dict[str, Any] = {"learning": learning, "load_at_start": os.getloadavg()}
    print(f"gma-ffc learning benchmark; {load()} on {os.cpu_count()} cores")
    if args.sweep:
        sweep(args.sweep, args.seeds, args.count, out, args.transport)
    else:
        parts = set(args.only.split(","))
        if "classic" in parts:
            classic(args.periods, args.plot)
        if "limits" in parts:
            limits_section(learning, out)
        if "sessions" in parts:
            for which in (("tuning", "held-out", "fresh", "rig") if args.seeds == "all" else (args.seeds,)):
                sessions_section(which, args.count, learning, out, args.transport)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=float) + "\n")
        print(f"figures: {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
