"""`gma-ffc invert`: the open-loop drive that makes the actuator follow a reference."""

from __future__ import annotations

import argparse
import sys
from typing import Any

import numpy as np

from ..errors import InputError
from ..initial_state import InitialStateSpec
from ..model import SDPIModel
from ..modelio import load_model
from ..recordings import Recording, read_recording, write_recording
from ..atomic import refuse_overwrite
from ._common import add_group_option, add_initial_state_option, add_stress_option, stress_for

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
                   help="the drive, written as a recording (never over REF)")
    p.add_argument("--limit", nargs=2, type=float, metavar=("LO", "HI"),
                   help="clip the drive to [LO, HI]; the command says how many samples it clipped and where")
    p.add_argument("--initial-drive", type=float, metavar="A",
                   help="start relaxed at this drive instead (overrides --initial-state)")
    add_initial_state_option(p)
    add_stress_option(p)
    add_group_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    refuse_overwrite(args.output, [args.reference, args.model])
    if args.limit and args.limit[0] >= args.limit[1]:
        raise InputError(f"--limit needs LO < HI, got {args.limit[0]} {args.limit[1]}")
    model = load_model(args.model)
    rec = read_recording(args.reference, require=("time_s", "reference_um"), group=args.group)
    stress = stress_for(model, rec, args.stress)
    kwargs, how = _start(model, args, rec, stress)
    drive = model.invert(rec.time_s, rec.columns["reference_um"], stress, **kwargs)
    clipped_note = ""
    if args.limit:
        lo, hi = args.limit
        clipped = (drive < lo) | (drive > hi)
        if clipped.any():
            where = np.flatnonzero(clipped)
            clipped_note = (f"warning: --limit clipped {where.size} of {len(drive)} samples "
                            f"({100 * where.size / len(drive):.1f} %; {np.count_nonzero(drive < lo)} below {lo:g}, "
                            f"{np.count_nonzero(drive > hi)} above {hi:g}), first at t = {rec.time_s[where[0]]:.6g} s, "
                            f"last at t = {rec.time_s[where[-1]]:.6g} s: the actuator will not follow the "
                            "reference there")
        drive = np.clip(drive, lo, hi)
    name = model.drive_name
    cols = {"time_s": rec.time_s, name: drive, "reference_um": rec.columns["reference_um"]}
    if stress is not None:
        cols["stress_MPa"] = np.broadcast_to(np.asarray(stress, float), rec.time_s.shape)
    meta = {"source": f"gma-ffc invert --model {args.model}", "input": rec.name, "model_kind": model.kind}
    write_recording(args.output, Recording(cols, meta, args.output))
    lo, hi = model.drive_range
    outside = int(np.count_nonzero((drive < lo - 1e-9) | (drive > hi + 1e-9)))
    if outside:
        print(f"warning: the drive leaves the identified range {lo:.4g}..{hi:.4g} at {outside} of "
              f"{len(drive)} samples (extrapolation); consider --limit", file=sys.stderr)
    if clipped_note:
        print(clipped_note, file=sys.stderr)
    print(f"drive {drive.min():.4g}..{drive.max():.4g} for {len(drive)} samples -> {args.output}")
    print(f"initial state: {how}")
    return 0


def _start(model: Any, args: argparse.Namespace, rec: Recording, stress: Any) -> tuple[dict[str, Any], str]:
    """How the inverse starts (`model.invert`'s keywords) and the words that say so."""
    if not isinstance(model, SDPIModel):
        if args.initial_drive is not None or args.initial_state.kind != "estimate":
            raise InputError(f"{args.model}: an {model.kind} model's inverse always starts from its core's stepper at "
                             "the low end of the identified drive; --initial-drive and --initial-state apply to sdpi "
                             "and mpi models: leave them out")
        return {}, "the model kind's own start (its core's stepper at the low end of the identified drive)"
    spec = args.initial_state if args.initial_drive is None else InitialStateSpec("drive", args.initial_drive)
    if spec.kind == "drive":                    # relaxed there, as the help says (not the file's stepper rule)
        return {"initial_state": spec}, f"relaxed at drive {spec.drive:g}"
    if spec.kind == "relaxed":
        return {"initial_state": spec}, "relaxed at the drive whose output is the reference's first value"
    s0 = None if stress is None else float(np.ravel(stress)[0])
    return {"initial_state": args.initial_state}, model.invert_initial_state(rec.columns["reference_um"], s0)[1]
