"""`gma-ffc diagnose`: locate where a model and recordings differ, name the missing physics, model it."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ..errors import InputError
from ._common import (add_group_option, add_initial_state_option, check_drive_name, check_initial_drive, check_known_plays,
                      finite_float, note_gaps, refuse_repeats, refuse_same_rows)

HELP = """\
Compare a model with recordings, locate where they differ (time windows, frequency bands, drive
rate, amplitude, stress, after steps, cumulative heating), and test a catalog of physical
extensions the model leaves out: rate_dependence (eddy currents), mechanical_dynamics,
thermal_drift, creep, time_delay, stress_dependent_play and saturation. Each is fitted on some
time blocks of the recordings and judged on the others; an effect is named only when it clearly
beats a recalibrated base model on data it did not see. Writes DIR/diagnosis.json,
DIR/report.html (plots first) and DIR/extended_model.yaml, which simulate, invert and run
accept like any model.

Give recordings that differ in what matters: several drive frequencies (rate effects, delay,
dynamics), minutes with current on/off phases (heating), steps with holds (creep), several
loads (stress effects). With --ident, also the recordings the model was identified on (checked
against the model's record of them): every fit is then held to those measured loops, and an
effect may identify the core again on them (a loop width that follows stress).

examples:
  gma-ffc diagnose --model model.yaml long_run.csv sweep_19MPa.csv --out diagnosis/
  gma-ffc diagnose --model model.yaml long_run.csv --ident id_*.csv --out diagnosis/
  gma-ffc diagnose --model model.yaml --out diagnosis/ --ident id_*.csv -- long_run.csv
(after --, every word is a recording: give --out and the other options before --ident)
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("diagnose", help="name the physics a model leaves out, model it, prove it",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", required=True, metavar="MODEL.yaml", help="sdpi or mpi model to check")
    p.add_argument("recordings", nargs="*", metavar="REC", help="recordings (.csv or .mat) with displacement_um")
    p.add_argument("--ident", nargs="+", default=[], metavar="ID_REC",
                   help="the recordings the model was identified on (checked against the model's record); "
                        "give them after the recordings to diagnose, or give every other option (--out too) "
                        "first and end the list with --: --out DIR --ident ID_REC... -- REC...")
    p.add_argument("-o", "--out", required=True, metavar="DIR",
                   help="folder for diagnosis.json, report.html, extended_model.yaml (-o as in the other commands)")
    p.add_argument("--max-effects", type=int, default=3, metavar="N",
                   help="at most this many effects are named (default 3)")
    p.add_argument("--drive-limits", nargs=2, type=finite_float, metavar=("LO", "HI"),
                   help="the drive the rig's controller allows (its limits.current_min_A and current_max_A): "
                        "advice on what to record stays within it, e.g. --drive-limits 0 3")
    add_initial_state_option(p, plays=True)
    add_group_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..modelio import load_model
    from ..progress import Progress
    from ..recordings import read_recording
    from ..diagnose.engine import diagnose
    from ..diagnose.report import write_outputs
    from ..diagnose.results import rms_summary, verdict_words, written_summary

    if args.max_effects < 1:
        raise InputError(f"--max-effects must be at least 1, got {args.max_effects}")
    if args.drive_limits and args.drive_limits[0] >= args.drive_limits[1]:
        raise InputError(f"--drive-limits needs LO < HI, got {args.drive_limits[0]:g} {args.drive_limits[1]:g}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out} exists and is not a folder")
    from ..atomic import check_folder_writable

    model = _diagnosable(load_model(args.model), args.model)
    _refuse_outputs_over_inputs(args, out)
    refuse_repeats([*args.recordings, *args.ident])
    check_folder_writable(out, str(out))          # now, not after the whole analysis
    check_initial_drive(model, args.initial_state.drive, "--initial-state drive:")
    paths, ident_paths, fingerprints = _split_paths(model, args.recordings, args.ident)
    check_known_plays(model, args.initial_state, len(paths))
    recs = [read_recording(p, require=("time_s", "drive", "displacement_um"), group=args.group) for p in paths]
    ident = [read_recording(p, require=("time_s", "drive", "displacement_um"), group=args.group)
             for p in ident_paths]
    refuse_same_rows(recs + ident)
    for rec in recs + ident:
        check_drive_name(model, rec)
    note_gaps(recs)
    with Progress("diagnose") as prog:
        dg = diagnose(model, recs, max_effects=args.max_effects, progress=lambda msg: prog.advance(note=msg),
                      initial_state=args.initial_state, identification=ident, fingerprints=fingerprints,
                      drive_limits=tuple(args.drive_limits) if args.drive_limits else None)
        prog.advance(note="writing report")
        doc = write_outputs(dg, out)
    words = {"within_noise": "the model explains the recordings within their noise",
             "effects_named": "missing physics found, modelled and shown to help on held-out data",
             "unexplained": "the residual is well above the noise and nothing in the vocabulary explains it",
             "inconclusive": "the data cannot decide; see 'cannot conclude' for the recording that would"}
    print(f"outcome: {doc['outcome']}: {words[doc['outcome']]}")
    print(f"verdict: {verdict_words(doc['verdict'], doc['tentative'])}")
    print(rms_summary(doc))
    written = written_summary(doc)
    if written:
        print(written)
    print(f"identification recordings: {doc['identification']['note']}", file=sys.stderr)
    for state in doc["initial_state"]:
        print(f"initial state ({state['recording']}): {state['how']}", file=sys.stderr)
    for note in doc["cannot_conclude"]:
        print(f"cannot conclude: {note}", file=sys.stderr)
    print(f"wrote {out / 'diagnosis.json'}, {out / 'report.html'}, {out / 'extended_model.yaml'}")
    return 0


OUTPUTS = ("diagnosis.json", "report.html", "extended_model.yaml")


def _diagnosable(model: Any, path: str) -> Any:
    """The model to diagnose: an extended model (diagnose's own output, adopted or handed on) through
    the sdpi/mpi model it extends, as the service's background diagnosis does, said on stderr. It was
    refused with 'diagnose its base instead', which no command lets a user holding only it follow."""
    if getattr(model, "kind", None) != "extended":
        return model
    effects = ", ".join(model.effects) or "no effects"
    print(f"note: {path} is an extended model ({effects}); diagnosed through the {model.base.kind} model it extends, "
          "as the controller's background diagnosis does: 'before' is that model, and the effects are searched "
          "again from it", file=sys.stderr)
    return model.base


def _refuse_outputs_over_inputs(args: argparse.Namespace, out: Path) -> None:
    """InputError if a file diagnose writes in `out` is one of its inputs. The names are the
    command's, so the advice is the one thing the user chooses: the folder."""
    from ..atomic import refuse_overwrite

    for produced in OUTPUTS:
        refuse_overwrite(out / produced, [*args.recordings, *args.ident, args.model], f"--out {out}: its file",
                         f"choose another --out folder (diagnose always names its files {', '.join(OUTPUTS)})")


def _split_paths(model: Any, recordings: list[str], ident: list[str]) -> tuple[list[str], list[str], list[dict]]:
    """The recordings to diagnose and the identification recordings (with their files' fingerprints).

    `--ident` takes every file after it; when nothing is left for the recordings, the files the
    model's record names (same name, size and content) are the identification recordings and the
    rest are diagnosed."""
    from ..diagnose.identification import split_by_record
    from ..recordings import fingerprint

    for p in ident:
        if not Path(p).is_file():
            raise InputError(f"--ident {p}: no such file")
    fingerprints = [fingerprint(p) for p in ident]
    if recordings or not ident:
        if not recordings:
            raise InputError("give at least one recording to diagnose (REC ...)")
        return recordings, ident, fingerprints
    own, rest = split_by_record(model, ident, fingerprints)
    if not rest:
        raise InputError("give at least one recording to diagnose besides the identification recordings: put "
                         "them before --ident, or end the --ident list with -- (gma-ffc diagnose --model M "
                         "--out DIR --ident ID... -- REC...)")
    if not own:
        raise InputError("--ident: none of the files after it is one the model records as identified on; put "
                         "the recordings to diagnose before --ident, or end the --ident list with -- after every "
                         "other option (gma-ffc diagnose --model M --out DIR --ident ID... -- REC...)")
    return [ident[k] for k in rest], [ident[k] for k in own], [fingerprints[k] for k in own]
