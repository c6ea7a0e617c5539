"""`gma-ffc invert`: the open-loop drive that makes the actuator follow a reference."""

from __future__ import annotations

import argparse
import sys

import numpy as np

from ..errors import InputError
from ..modelio import load_model
from ..recordings import Recording, read_recording, write_recording
from ._common import add_stress_option, stress_for

HELP = """\
Compute the feedforward drive for a reference displacement with the model's analytic inverse
(seed paper (17)-(22), sign typos fixed). REF is a recording with time_s, reference_um and, for
an SDPI model, stress_MPa. The output is a recording whose current_A is the drive (plus the
reference and stress). The drive is limited to --limit LO HI when given; a drive leaving the
range the model was identified on is reported.

example:
  gma-ffc invert --model model.yaml reference.csv -o drive.csv --limit 0 3
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("invert", help="open-loop drive for a reference", description=HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", required=True, metavar="MODEL.yaml")
    p.add_argument("reference", metavar="REF.csv", help="time_s, reference_um[, stress_MPa]")
    p.add_argument("-o", "--output", required=True, metavar="OUT.csv")
    p.add_argument("--limit", nargs=2, type=float, metavar=("LO", "HI"), help="clip the drive to [LO, HI]")
    p.add_argument("--initial-drive", type=float, metavar="A",
                   help="drive the actuator rests at before the run (default: low end of the identified range)")
    add_stress_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    model = load_model(args.model)
    rec = read_recording(args.reference, require=("time_s", "reference_um"))
    stress = stress_for(model, rec, args.stress)
    kwargs = {} if args.initial_drive is None else {"initial_drive": args.initial_drive}
    drive = model.invert(rec.time_s, rec.columns["reference_um"], stress, **kwargs)
    if args.limit:
        lo, hi = args.limit
        if lo >= hi:
            raise InputError(f"--limit needs LO < HI, got {lo} {hi}")
        drive = np.clip(drive, lo, hi)
    name = getattr(model, "drive_name", "current_A")
    cols = {"time_s": rec.time_s, name: drive, "reference_um": rec.columns["reference_um"]}
    if stress is not None:
        cols["stress_MPa"] = np.broadcast_to(np.asarray(stress, float), rec.time_s.shape)
    meta = {"source": f"gma-ffc invert --model {args.model}", "input": rec.name, "model_kind": model.kind}
    write_recording(args.output, Recording(cols, meta, args.output))
    lo, hi = getattr(model, "drive_range", (-np.inf, np.inf))
    outside = int(np.count_nonzero((drive < lo - 1e-9) | (drive > hi + 1e-9)))
    if outside:
        print(f"warning: the drive leaves the identified range {lo:.4g}..{hi:.4g} at {outside} of "
              f"{len(drive)} samples (extrapolation); consider --limit", file=sys.stderr)
    print(f"drive {drive.min():.4g}..{drive.max():.4g} for {len(drive)} samples -> {args.output}")
    return 0
