"""`gma-ffc invert`: the open-loop drive that makes the actuator follow a reference."""

from __future__ import annotations

import argparse
import sys
from typing import Any

import numpy as np

from ..errors import InputError
from ..initial_state import InitialStateSpec
from ..model import SDPIModel
from ..model_reach import reach_exceeded
from ..modelio import load_model
from ..recordings import MAGNITUDE_BOUNDS, Recording, read_recording, write_recording
from ._common import (add_group_option, add_initial_state_option, add_stress_option, check_initial_drive,
                      check_recording_output, finite_float, recorded_stress, stress_for)

HELP = """\
Compute the feedforward drive for a reference displacement with the model's analytic inverse
(seed paper (17)-(22), sign typos fixed). REF is a recording with time_s, reference_um and, for
an SDPI model, stress_MPa. The output is a recording whose current_A is the drive (plus the
reference and stress). The drive is limited to --limit LO HI when given; a drive leaving the
range the model was identified on is reported.

The run starts, by default, in the hysteresis state whose output is the reference's first
value, consistent with the direction the drive first moves, so that `gma-ffc simulate` on the
output (same default) returns the reference from the first sample.

example:
  gma-ffc invert --model model.yaml reference.csv -o drive.csv --limit 0 3
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("invert", help="open-loop drive for a reference", description=HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", required=True, metavar="MODEL.yaml",
                   help="a model file from gma-ffc identify or gma-ffc diagnose (extended_model.yaml)")
    p.add_argument("reference", metavar="REF.csv", help="time_s, reference_um[, stress_MPa]")
    p.add_argument("-o", "--output", required=True, metavar="OUT.csv",
                   help="the drive, written as a recording: .csv or .mat (never over REF)")
    p.add_argument("--limit", nargs=2, type=finite_float, metavar=("LO", "HI"),
                   help="clip the drive to [LO, HI]; the command says how many samples it clipped and where")
    p.add_argument("--initial-drive", type=finite_float, metavar="A",
                   help="start relaxed at this drive instead (overrides --initial-state)")
    add_initial_state_option(p)
    add_stress_option(p)
    add_group_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_recording_output(args.output, [args.reference, args.model])
    if args.limit and args.limit[0] >= args.limit[1]:
        raise InputError(f"--limit needs LO < HI, got {args.limit[0]} {args.limit[1]}")
    model = load_model(args.model)
    check_initial_drive(model, args.initial_state.drive, "--initial-state drive:")
    check_initial_drive(model, args.initial_drive, "--initial-drive ")
    rec = read_recording(args.reference, require=("time_s", "reference_um"), group=args.group)
    stress = stress_for(model, rec, args.stress)
    if not args.limit:
        _refuse_a_reference_beyond_reach(model, rec)
    kwargs, how, start_spec = _start(model, args, rec, stress)
    with np.errstate(all="ignore"):         # a diverging inverse is refused below, in one line
        drive = model.invert(rec.time_s, rec.columns["reference_um"], stress, **kwargs)
    _refuse_a_diverged_inverse(drive, rec, model)
    clipped_note = ""
    if args.limit:
        lo, hi = args.limit
        clipped = (drive < lo) | (drive > hi)
        if clipped.any():
            where = np.flatnonzero(clipped)
            clipped_note = (f"warning: --limit clipped {where.size} of {len(drive)} samples "
                            f"({100 * where.size / len(drive):.1f} %; {np.count_nonzero(drive < lo)} below {lo:g}, "
                            f"{np.count_nonzero(drive > hi)} above {hi:g}), first at t = {rec.time_text(where[0])} s, "
                            f"last at t = {rec.time_text(where[-1])} s: the actuator will not follow the "
                            "reference there")
        drive = np.clip(drive, lo, hi)
    _refuse_an_unreadable_drive(drive, rec, model)
    name = model.drive_name
    cols = {"time_s": rec.time_s, name: drive, "reference_um": rec.columns["reference_um"]}
    if stress is not None:
        cols["stress_MPa"] = recorded_stress(rec, stress, args.stress)
    meta = {"source": f"gma-ffc invert --model {args.model}", "input": rec.name, "model_kind": model.kind}
    if start_spec:          # simulate starts this file where the inverse did (its default rule may not)
        meta.update(start_spec)
    write_recording(args.output, Recording(cols, meta, args.output))
    lo, hi = model.drive_range
    slack = 1e-6 * (hi - lo)      # the range as printed below (6 digits): a drive that far out is inside
    outside = int(np.count_nonzero((drive < lo - slack) | (drive > hi + slack)))
    if outside:
        print(f"warning: the drive leaves the identified range {lo:.6g}..{hi:.6g} at {outside} of "
              f"{len(drive)} samples (extrapolation): the reference asks for more than the actuator gave "
              f"when identified; add --limit {lo:.6g} {hi:.6g} to clip the drive to that range", file=sys.stderr)
    if clipped_note:
        print(clipped_note, file=sys.stderr)
    print(f"drive {drive.min():.4g}..{drive.max():.4g} for {len(drive)} samples -> {args.output}")
    print(f"initial state: {how}")
    return 0


def _refuse_a_reference_beyond_reach(model: Any, rec: Recording) -> None:
    """A reference over REFERENCE_BEYOND_REACH_FACTOR times the model's reach is most likely a unit
    slip: refused, as the controller refuses it, unless --limit says the drive is to be clipped."""
    ref = rec.columns["reference_um"]
    k = int(np.argmax(np.abs(ref)))
    reach = reach_exceeded(model, float(ref[k]))
    if reach is None:
        return
    lo, hi = model.drive_range
    raise InputError(f"{rec.source}: the reference reaches {ref[k]:.4g} um at t = {rec.time_text(k)} s, "
                     f"{abs(ref[k]) / reach:.0f}x the most the model gives over its identified drive range "
                     f"({reach:.3g} um): check the reference's unit (micrometres, not nanometres), or add "
                     f"--limit {lo:.6g} {hi:.6g} to clip the drive to that range; {_reach_advice(model, rec)}")


def _refuse_a_diverged_inverse(drive: np.ndarray, rec: Recording, model: Any) -> None:
    """An inverse asked for more than its model can give (beyond a saturation, through a lag) runs
    away to inf and NaN: refuse, naming where it left the identified drive range for good."""
    bad = ~np.isfinite(drive)
    if not bad.any():
        return
    k = int(np.argmax(bad))
    lo, hi = model.drive_range
    inside = np.isfinite(drive[:k]) & (drive[:k] >= lo) & (drive[:k] <= hi)
    start = int(np.flatnonzero(inside)[-1]) + 1 if inside.any() else 0
    ref = rec.columns["reference_um"]
    raise InputError(f"{rec.source}: the inverse runs away from t = {rec.time_text(start)} s (reference "
                     f"{ref[start]:.4g} um; the drive leaves the identified range {lo:.4g}..{hi:.4g} there and is not "
                     f"finite from t = {rec.time_text(k)} s): the model cannot follow that reference; "
                     f"{_reach_advice(model, rec)}")


def _refuse_an_unreadable_drive(drive: np.ndarray, rec: Recording, model: Any) -> None:
    """A finite drive past the drive column's physical bound (`MAGNITUDE_BOUNDS`): written, the file
    would be refused by every command that reads it (a reference far beyond the model's stroke asks
    for that). Refused, with the --limit that clips the drive to the identified range."""
    name = model.drive_name
    bound = MAGNITUDE_BOUNDS[name]
    past = np.abs(drive) > bound
    if not past.any():
        return
    k = int(np.argmax(past))
    lo, hi = model.drive_range
    unit = name.rsplit("_", 1)[1]
    raise InputError(f"{rec.source}: the drive this reference needs reaches {drive[k]:.4g} {unit} at t = "
                     f"{rec.time_text(k)} s, past the {bound:g} {unit} a recording may hold: the model cannot follow "
                     f"that reference; add --limit {lo:.6g} {hi:.6g} to clip the drive to its identified range, or "
                     f"{_reach_advice(model, rec)}")


def _reach_advice(model: Any, rec: Recording) -> str:
    """Start the reference where the model rests and keep it within its stroke, with the figures
    (an exact inverse of a lag turns a step at t = 0 into a drive spike)."""
    lo, hi = model.drive_range
    s = rec.columns.get("stress_MPa")
    s0 = None if s is None or model.stress_range_MPa is None else float(np.clip(s[0], *model.stress_range_MPa))
    try:
        with np.errstate(all="ignore"):
            y = model.simulate(np.arange(201) * 1e-3, np.linspace(lo, hi, 201), s0)
    except Exception:      # the advice without figures rather than no refusal
        y = np.array([np.nan])
    if not np.all(np.isfinite(y)):
        return "start the reference at the model's output at rest and keep it within its stroke"
    return (f"start the reference at the model's output at rest ({y[0]:.4g} um, the drive at {lo:g}) and keep it "
            f"within the stroke the model gives over its drive range (about {y.min():.4g}..{y.max():.4g} um)")


def _start(model: Any, args: argparse.Namespace, rec: Recording,
           stress: Any) -> tuple[dict[str, Any], str, dict[str, Any]]:
    """How the inverse starts (`model.invert`'s keywords), the words that say so, and the metadata
    that starts `simulate` there (`initial_state`, or an extended model's `initial_drive`; none when
    simulate's default rule already does)."""
    if not isinstance(model, SDPIModel):
        if args.initial_drive is not None or args.initial_state.kind != "estimate":
            raise InputError(f"{args.model}: an {model.kind} model's inverse always starts from its core's stepper at "
                             "the low end of the identified drive; --initial-drive and --initial-state apply to sdpi "
                             "and mpi models: leave them out")
        x0 = model.inverse_start_drive
        return {}, f"the model kind's own start (its core's stepper at rest at {x0:g}, the low end of the identified " \
                   "drive)", {"initial_drive": x0}
    spec = args.initial_state if args.initial_drive is None else InitialStateSpec("drive", args.initial_drive)
    if spec.kind == "drive":                    # relaxed there, as the help says (not the file's stepper rule)
        return {"initial_state": spec}, f"relaxed at drive {spec.drive:g}", {"initial_state": f"drive:{spec.drive!r}"}
    if spec.kind == "relaxed":
        return {"initial_state": spec}, "relaxed at the drive whose output is the reference's first value", {"initial_state": "relaxed"}
    s0 = None if stress is None else float(np.ravel(stress)[0])
    return {"initial_state": args.initial_state}, model.invert_initial_state(rec.columns["reference_um"], s0)[1], {}
