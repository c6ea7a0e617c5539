"""`gma-ffc demo`: the whole job on the simulated rig, no hardware and no arguments.

The paper's experiment (Figs. 8-9), end to end through the same code a user runs: record 3 Hz
identification sets with hil_sim at four stresses, identify an SDPI model from all of them and
an MPI model from -11.3 MPa alone, then track a 3 Hz sine at -15.2 and -19.1 MPa with each
through the real controller loop on the sim driver (simulated clock: same loop, faster than real
time), and compare the RMS tracking errors with the paper's. Everything it makes goes to one
folder: recordings, models, runnable configs, telemetry, plots, results.json.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from ..errors import FaultError, InputError

if TYPE_CHECKING:
    from ..model import SDPIModel
    from ..protocols import Model
    from ..recordings import Recording

IDENTIFICATION_STRESSES_MPA = (-11.3, -15.2, -19.1, -24.0)   # the paper's four
MPI_STRESS_MPA = -11.3                                        # the paper's MPI: unloaded rod only
TRACKING_STRESSES_MPA = (-15.2, -19.1)                        # Figs. 8 and 9
# The paper's RMS tracking errors (um), SDPI vs MPI, at the tracking stresses.
PAPER_RMS_UM = {-15.2: (0.39, 0.82), -19.1: (0.39, 1.04)}
RATE_HZ = 1000.0
SINE = {"frequency_hz": 3.0, "amplitude_um": 12.0, "offset_um": 15.0}
TRACK_S = 2.0
SETTLE_S = 1.0 / 3.0   # the first period (start-up from rest) is left out of the RMS
# Learning feedforward (docs/learning.md) runs 12 periods and is scored on the last two, once it
# has learned for 10: the comparison the issue asks for ("after 10 periods").
LEARN_TRACK_S = 4.0
LEARN_SETTLE_S = 10.0 / 3.0
TRACKED_MODELS = ("sdpi", "mpi", "sdpi+learning")
# The sim driver's output latency: the command written at tick k drives the plant until tick
# k+1, where its displacement is read. The reference is evaluated this far ahead (lead_s) so the
# displacement arrives on time; the error is measured against the reference at the same instant.
LATENCY_S = 1.0 / RATE_HZ


@dataclass
class TrackingResult:
    stress_MPa: float
    model: str                 # "sdpi" | "mpi" | "sdpi+learning"
    rms_um: float
    max_abs_um: float
    measured_stress_MPa: float
    ticks: int
    telemetry: str
    config: str


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo", help="the whole job on the built-in simulated actuator",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n  gma-ffc demo\n  gma-ffc demo --out /tmp/demo --seed 3",
        description="Record identification data on the simulated rig, identify SDPI (four stresses) "
                    "and MPI (-11.3 MPa), track a 3 Hz sine at -15.2 and -19.1 MPa with each through "
                    "the real controller (simulated clock), print the comparison with the paper and "
                    "save plots, models, configs and telemetry.")
    p.add_argument("--out", default="gma-ffc-demo", metavar="DIR",
                   help="output folder (default ./gma-ffc-demo)")
    p.add_argument("--seed", type=int, default=0, help="noise seed of the simulated rig (default 0)")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from ..progress import Progress

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder; choose another --out")
    _refuse_a_folder_of_other_files(out)
    if args.seed < 0:
        raise InputError(f"--seed must be >= 0, got {args.seed}")
    steps = 1 + 2 + len(TRACKED_MODELS) * len(TRACKING_STRESSES_MPA) + 1
    with Progress("demo", total=steps) as progress:
        results = run_demo(out, seed=args.seed, progress=progress)
    print(format_table(results))
    print(f"\nsaved in {out}/: plots tracking_*.png and identification_fit.png, models/, "
          f"recordings/, configs/, telemetry/, results.json")
    return 0


def _refuse_a_folder_of_other_files(out: Path) -> None:
    """The demo writes recordings/, models/, configs/, telemetry/, plots and results.json into --out,
    over whatever has those names: a folder is taken only when new, empty, or an earlier demo's
    (its results.json the demo's own)."""
    import json

    if not out.is_dir() or not any(out.iterdir()):
        return
    try:
        earlier = json.loads((out / "results.json").read_text(encoding="utf-8"))
        if isinstance(earlier, dict) and {"runs", "comparison"} <= earlier.keys():
            return
    except (OSError, ValueError):
        pass
    names = ", ".join(sorted(p.name for p in out.iterdir())[:4])
    raise InputError(f"--out {out}: the folder holds files an earlier demo did not write ({names}...), and the demo "
                     "writes recordings/, models/, configs/, telemetry/, plots and results.json there over what has "
                     "those names: choose a new or empty folder, e.g. --out gma-ffc-demo-2")


def run_demo(out: Path, seed: int = 0, progress: Any = None) -> list[TrackingResult]:
    """Record, identify, track, plot; returns the tracking results (also in out/results.json)."""
    from ..modelio import save_model
    from ..recordings import read_recording

    def step(note: str) -> None:
        if progress is not None:
            progress.advance(note=note)

    out.mkdir(parents=True, exist_ok=True)
    rec_paths = _record(out / "recordings", seed)
    recordings = [read_recording(p) for p in rec_paths]
    step("recorded identification data")
    sdpi, mpi = _identify(recordings)
    for model in (sdpi, mpi):           # its files, as `gma-ffc identify` records them (`diagnose --ident`)
        _record_files(model, rec_paths, recordings)
    save_model(sdpi, out / "models" / "sdpi.yaml")
    save_model(mpi, out / "models" / "mpi.yaml")
    step("identified SDPI and MPI")
    _plot_fit(sdpi, recordings, out / "identification_fit.png")
    step("plotted the identification fit")

    results: list[TrackingResult] = []
    for stress in TRACKING_STRESSES_MPA:
        for name in TRACKED_MODELS:
            results.append(_track(out, name, stress, seed))
            step(f"tracked with {name.upper()} at {stress:g} MPa")
    for stress in TRACKING_STRESSES_MPA:
        _plot_tracking([r for r in results if r.stress_MPa == stress], out / f"tracking_{stress:g}MPa.png")
    _write_results(out / "results.json", results)
    step("saved plots and results")
    return results


# ---- the steps ----------------------------------------------------------------------------------
def _record(folder: Path, seed: int) -> list[Path]:
    """3 Hz identification runs at the paper's stresses, written as recordings (with manifest)."""
    from hil_sim.record import write_recordings

    return write_recordings("identification", folder, seed=seed, stresses=IDENTIFICATION_STRESSES_MPA)


def _identify(recordings: Sequence[Recording]) -> tuple[SDPIModel, SDPIModel]:
    """SDPI from every stress; MPI from the -11.3 MPa run with its stress column dropped: the SIL
    harness's fit (`gma_ffc.sil.fit_sdpi_and_mpi`), the one the SIL tests and benchmarks use."""
    from ..sil import fit_sdpi_and_mpi

    sdpi, mpi = fit_sdpi_and_mpi(recordings, MPI_STRESS_MPA)
    if sdpi.kind != "sdpi" or mpi.kind != "mpi":
        raise FaultError(f"identification gave {sdpi.kind}/{mpi.kind} models, expected sdpi/mpi")
    return sdpi, mpi


def _record_files(model: Any, paths: Sequence[Path], recordings: Sequence[Recording]) -> None:
    """The identification files a model was fitted on (those its provenance names), recorded as
    `gma-ffc identify` records them: the demo's models recorded none, so `diagnose --ident` could
    not check it was given the same files."""
    from .identify import record_identification_files

    fitted = set(model.provenance.get("recordings") or ())
    record_identification_files(model, [p for p, rec in zip(paths, recordings) if rec.name in fitted])


def _remove_lock(telemetry: Path) -> None:
    """The telemetry's lock file (`control.telemetry.TelemetryLock`), once its run has ended: the
    demo's runs are its own and over, so it leaves no `.lock` behind. Taken first, so a lock another
    process holds (a user rerunning the config meanwhile) is left alone."""
    import contextlib
    import fcntl
    import os

    lock = telemetry.with_name(telemetry.name + ".lock")
    try:
        fd = os.open(lock, os.O_RDWR | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError:
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with contextlib.suppress(FileNotFoundError):
            lock.unlink()
    except BlockingIOError:
        pass
    finally:
        os.close(fd)


def _track(out: Path, name: str, stress: float, seed: int) -> TrackingResult:
    """Write a runnable config, load it as `gma-ffc run` would, and run the real controller loop."""
    import yaml

    from hil_sim.plant import PlantConfig

    from ..atomic import atomic_write
    from ..control.config import load_config
    from ..control.manager import ControllerManager
    from ..recordings import read_recording

    learning = name.endswith("+learning")
    model_name = name.split("+")[0]
    tag = f"{name.replace('+', '_')}_{stress:g}MPa"
    track_s, settle_s = (LEARN_TRACK_S, LEARN_SETTLE_S) if learning else (TRACK_S, SETTLE_S)
    config = {
        "rate_hz": RATE_HZ,
        "clock": "simulated",
        "model": f"../models/{model_name}.yaml",
        "driver": {"kind": "sim", "seed": seed,
                   "load_mass_kg": round(PlantConfig().mass_for_stress(stress), 4)},
        "reference": {"kind": "sine", **SINE, "lead_s": LATENCY_S},
        "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0},
        "telemetry": {"path": f"../telemetry/track_{tag}.csv"},
    }
    if learning:
        config["learning"] = {"kind": "repetitive"}
    cfg_path = out / "configs" / f"track_{tag}.yaml"
    with atomic_write(cfg_path) as fh:
        fh.write(f"# gma-ffc demo: {name.upper()} feedforward at {stress:g} MPa on the simulated rig.\n"
                 f"# Rerun: gma-ffc run --config {cfg_path.name} --duration {track_s:g}\n")
        yaml.safe_dump(config, fh, sort_keys=False)
    try:
        summary = ControllerManager(load_config(cfg_path)).run(duration_s=track_s)
    finally:
        _remove_lock(out / "telemetry" / f"track_{tag}.csv")
    if not summary.get("ok", True):
        raise FaultError(f"the {name.upper()} run at {stress:g} MPa ended on a fault: "
                         f"{', '.join(summary.get('faults', [])) or summary.get('exit_reason')}")
    tel_rel = Path("telemetry") / f"track_{tag}.csv"
    rec = read_recording(out / tel_rel, require=("time_s", "drive", "displacement_um", "reference_um"))
    keep = (rec.time_s >= rec.time_s[0] + settle_s) & (rec.time_s <= rec.time_s[0] + track_s)
    err = desired_um(rec.time_s[keep] - rec.time_s[0]) - rec.column("displacement_um")[keep]
    return TrackingResult(stress, name, float(np.sqrt(np.mean(err * err))), float(np.max(np.abs(err))),
                          float(np.median(rec.column("stress_MPa"))), int(summary["ticks"]), str(tel_rel),
                          str(cfg_path.relative_to(out)))


def desired_um(t: np.ndarray) -> np.ndarray:
    """The displacement asked for at run time t: the configured sine without the lead."""
    from ..control.reference import Sine

    return Sine(SINE["frequency_hz"], SINE["amplitude_um"], SINE["offset_um"]).batch(t)


# ---- presentation ---------------------------------------------------------------------------------
def pairs(results: Sequence[TrackingResult]) -> dict[float, tuple[float, float]]:
    """{stress: (sdpi_rms, mpi_rms)}."""
    by = {(r.stress_MPa, r.model): r.rms_um for r in results}
    return {s: (by[(s, "sdpi")], by[(s, "mpi")]) for s in TRACKING_STRESSES_MPA if (s, "sdpi") in by}


def learned(results: Sequence[TrackingResult]) -> dict[float, float]:
    """{stress: sdpi+learning rms} for the stresses that have a learning run."""
    return {r.stress_MPa: r.rms_um for r in results if r.model == "sdpi+learning"}


def format_table(results: Sequence[TrackingResult]) -> str:
    """The comparison people read: ours next to the paper's."""
    lines = [f"RMS tracking error, {SINE['frequency_hz']:g} Hz sine "
             f"{SINE['offset_um'] - SINE['amplitude_um']:g}-{SINE['offset_um'] + SINE['amplitude_um']:g} um, "
             f"inverse feedforward at {RATE_HZ:g} Hz on the simulated rig",
             "(measured displacement vs the sine at the same instant; first period and stop ramp left out)",
             "",
             f"{'stress':>10}  {'SDPI':>9}  {'MPI':>9}  {'SDPI/MPI':>8}  {'SDPI+learn':>10}"
             f"   {'paper SDPI / MPI':>24}"]
    ok = True
    learn = learned(results)
    for stress, (s, m) in pairs(results).items():
        ratio = s / m if m > 0 else math.inf
        ok = ok and ratio <= 0.5
        ps, pm = PAPER_RMS_UM.get(stress, (math.nan, math.nan))
        lr = f"{learn[stress]:>7.3f} um" if stress in learn else f"{'-':>10}"
        lines.append(f"{stress:>6.1f} MPa  {s:>6.3f} um  {m:>6.3f} um  {ratio:>8.2f}  {lr}   "
                     f"{ps:.2f} / {pm:.2f} um ({ps / pm:.2f})")
    lines.append("")
    lines.append("SDPI error at most half the MPI's at every stress, as in the paper: "
                 + ("yes" if ok else "NO"))
    lines.append("(MPI identified at -11.3 MPa only; SDPI at -11.3, -15.2, -19.1 and -24 MPa. The "
                 "simulated rig is not the paper's: compare the ratios, not the micrometres.)")
    if learn:
        lines.append("(SDPI+learn: the same SDPI with learning feedforward (docs/learning.md), scored on "
                     "periods 11-12, after learning for 10; a step beyond the paper.)")
    return "\n".join(lines)


def _write_results(path: Path, results: Sequence[TrackingResult]) -> None:
    from ..atomic import atomic_write

    payload = {
        "reference": {"kind": "sine", **SINE}, "rate_hz": RATE_HZ, "track_s": TRACK_S, "settle_s": SETTLE_S,
        "identification_stresses_MPa": list(IDENTIFICATION_STRESSES_MPA), "mpi_stress_MPa": MPI_STRESS_MPA,
        "runs": [asdict(r) for r in results],
        "comparison": [{"stress_MPa": s, "sdpi_rms_um": a, "mpi_rms_um": b, "ratio": a / b,
                        "sdpi_learning_rms_um": learned(results).get(s),
                        "paper_sdpi_rms_um": PAPER_RMS_UM[s][0], "paper_mpi_rms_um": PAPER_RMS_UM[s][1]}
                       for s, (a, b) in pairs(results).items()],
    }
    with atomic_write(path) as fh:
        json.dump(payload, fh, indent=2)
        fh.write("\n")


def _plot_fit(model: Model, recordings: Sequence[Recording], path: Path) -> None:
    from ..plots import plot_loops

    plot_loops(model, recordings, path)


def _plot_tracking(runs: Sequence[TrackingResult], path: Path) -> None:
    """Reference and displacement over the last periods, and the tracking error, SDPI vs MPI."""
    from ..plots import _figure, save_figure
    from ..recordings import read_recording

    out_dir = path.parent
    fig, axes = _figure(2, 1, (8.0, 6.0))
    top, bottom = axes[0, 0], axes[1, 0]
    colours = {"sdpi": "tab:blue", "mpi": "tab:red", "sdpi+learning": "tab:green"}
    for i, run in enumerate(runs):
        rec = read_recording(out_dir / run.telemetry)
        t_run = rec.time_s - rec.time_s[0]
        # the last two periods of each run, shown on a common 0..2 periods axis
        end_s = LEARN_TRACK_S if run.model.endswith("+learning") else TRACK_S
        keep = (t_run >= end_s - 2.0 / SINE["frequency_hz"]) & (t_run <= end_s)
        t = t_run[keep]
        ref = desired_um(t)
        t_axis = t - (end_s - 2.0 / SINE["frequency_hz"])
        label = run.model.upper().replace("+LEARNING", " + learning")
        if i == 0:
            top.plot(t_axis, ref, color="0.2", lw=1.2, ls="--", label="reference")
        measured = rec.column("displacement_um")
        top.plot(t_axis, measured[keep], color=colours[run.model], lw=1.0,
                 label=f"{label} feedforward")
        bottom.plot(t_axis, ref - measured[keep], color=colours[run.model], lw=1.0,
                    label=f"{label}: RMS {run.rms_um:.3f} um")
    stress = runs[0].stress_MPa if runs else float("nan")
    top.set_title(f"Tracking a {SINE['frequency_hz']:g} Hz sine at {stress:g} MPa (simulated rig)", fontsize=11)
    top.set_ylabel("displacement [um]")
    bottom.set_ylabel("error [um]")
    for ax in (top, bottom):
        ax.set_xlabel("time within the last two periods of each run [s]")
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    save_figure(fig, path)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(_run(argparse.Namespace(out="gma-ffc-demo", seed=0)))
