"""`gma-ffc simulate`: predict the displacement for a recording's drive and stress."""

from __future__ import annotations

import argparse
import numpy as np

from ..model import rms
from ..modelio import load_model
from ..recordings import Recording, write_recording
from ._common import add_stress_option, check_drive_name, stress_for

HELP = """\
Run a model (any kind: sdpi, mpi, or an extended model from `gma-ffc diagnose`) on the drive and
stress of a recording. The output is itself a recording: the same time_s, drive and stress
columns, displacement_um = the prediction, and the measured displacement (if the input had one)
kept as measured_displacement_um.

example:
  gma-ffc simulate --model model.yaml run_19MPa.csv -o predicted.csv
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="predict displacement with a model", description=HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", required=True, metavar="MODEL.yaml")
    p.add_argument("recording", metavar="REC", help="recording with time_s, drive and (for SDPI) stress_MPa")
    p.add_argument("-o", "--output", required=True, metavar="OUT.csv")
    add_stress_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..recordings import read_recording

    model = load_model(args.model)
    rec = read_recording(args.recording, require=("time_s", "drive"))
    check_drive_name(model, rec)
    stress = stress_for(model, rec, args.stress)
    pred = model.simulate(rec.time_s, rec.drive, stress)
    cols = {"time_s": rec.time_s, rec.drive_name: rec.drive}
    if stress is not None:
        cols["stress_MPa"] = np.broadcast_to(np.asarray(stress, float), rec.time_s.shape)
    cols["displacement_um"] = pred
    measured = rec.displacement_um
    if measured is not None:
        cols["measured_displacement_um"] = measured
    meta = {"source": f"gma-ffc simulate --model {args.model}", "input": rec.name, "model_kind": model.kind}
    write_recording(args.output, Recording(cols, meta, args.output))
    msg = f"predicted {len(rec)} samples -> {args.output}"
    if measured is not None:
        msg += f" (RMS vs measured {rms(pred - measured):.4f} um)"
    print(msg)
    return 0
