"""`gma-ffc identify`: fit an SDPI (several stresses) or an MPI (one stress) from recordings."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Sequence

from ..errors import InputError
from ..modelio import save_model
from ..progress import Progress
from ..recordings import DEFAULT_TIME_STEP_S, time_text
from ._common import add_group_option, finite_float, note_gaps, read_all, refuse_repeats, refuse_same_rows

HELP = """\
Fit a stress-dependent Prandtl-Ishlinskii model (SDPI, seed paper section 3.3) from recordings at
several stresses, or a stress-independent MPI from recordings at one stress or without a
stress_MPa column. Recordings follow docs/recordings.md (time_s, current_A,
displacement_um, stress_MPa). Quasi-static drives (a few Hz) sweeping the full current range
give the best models; the first sweep of each recording is skipped while the model's memory
settles.

example:
  gma-ffc identify id_11.3MPa.csv id_15.2MPa.csv id_19.1MPa.csv id_24MPa.csv -o model.yaml --plot loops.png
"""


def play_count(text: str) -> int:
    """argparse type for --plays: a whole number, at least 1 (the zero-threshold play)."""
    n = _whole(text)
    if n < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: a model needs at least 1 play (try 10, the default)")
    return n


def deadzone_count(text: str) -> int:
    """argparse type for --deadzones: an odd whole number (2l+1: l negative, one centre, l positive)."""
    n = _whole(text)
    if n < 1 or n % 2 == 0:
        hint = f"try {n + 1 if n >= 0 else 1}" if n % 2 == 0 else "try 7, the default"
        raise argparse.ArgumentTypeError(f"{text!r}: the dead-zones come as l below the centre, one at it and "
                                         f"l above, so their number is odd ({hint})")
    return n


def _whole(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("identify", help="fit an SDPI/MPI model from recordings", description=HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("recordings", nargs="+", metavar="REC", help="recording files (.csv or .mat)")
    p.add_argument("-o", "--output", required=True, metavar="MODEL.yaml", help="model file to write")
    p.add_argument("--plays", type=play_count, default=10, metavar="N", help="number of play operators (default 10)")
    p.add_argument("--deadzones", type=deadzone_count, default=7, metavar="N",
                   help="number of dead-zone operators, odd (default 7)")
    p.add_argument("--reference-stress", type=finite_float, metavar="MPA",
                   help="stress of the paper's step 1, within the recordings' stresses (default: the least "
                        "compressive in the data)")
    p.add_argument("--no-refine", action="store_true",
                   help="skip the output-error refinement (the paper's equation-error fit (15) alone)")
    p.add_argument("--zero", choices=("shared", "per-recording"), default="shared",
                   help="shared (default): every recording measures displacement from one zero, so the model's "
                        "offset may follow stress; per-recording: the sensor was zeroed before each run, so "
                        "each recording's zero is fitted on its own (the model's offset is then one constant)")
    p.add_argument("--plot", metavar="PNG", help="also save measured vs modelled loops to this image")
    add_group_option(p)
    p.set_defaults(func=run)


def _check_outputs(args: argparse.Namespace) -> None:
    """The model file and the plot, checked now, not after the fit: names, inputs, writable folders."""
    from ..atomic import check_folder_writable, refuse_overwrite

    refuse_overwrite(args.output, args.recordings)
    if not args.output.endswith((".yaml", ".yml")):
        raise InputError(f"model file must end in .yaml, got {args.output}")
    check_folder_writable(Path(args.output).parent, args.output)
    if args.plot:
        from ..plots import check_plot_name

        refuse_overwrite(args.plot, args.recordings, "plot")     # the graver mistake, said first
        check_plot_name(args.plot)
        check_folder_writable(Path(args.plot).parent, args.plot)


def record_identification_files(model: Any, paths: Sequence[str | Path]) -> None:
    """Each identification file as it was read (name, size, SHA-256) in the model's provenance, so
    `diagnose --ident` can check it is given the same ones. `identify` and the demo both write it."""
    from ..recordings import fingerprint

    model.provenance["identification_files"] = [fingerprint(p) for p in paths]


def run(args: argparse.Namespace) -> int:
    from ..identify import SDPIIdentifier

    _check_outputs(args)
    refuse_repeats(args.recordings)
    recs = read_all(args.recordings, require=("time_s", "drive", "displacement_um"), group=args.group)
    refuse_same_rows(recs)
    note_gaps(recs)
    # no total: a recording that sweeps late, or zeros fitted per recording, fit again (the steps
    # then say so); a count of four went to 100 % and started over
    with Progress("identify") as prog:
        ident = SDPIIdentifier(n_play=args.plays, n_deadzone=args.deadzones,
                               reference_stress_MPa=args.reference_stress, refine=not args.no_refine,
                               zero=args.zero.replace("-", "_"),
                               progress=lambda stage: prog.advance(note=stage))
        ident.fit(recs)
    model = ident.model_
    record_identification_files(model, args.recordings)
    if args.plot:
        from ..plots import plot_loops

        plot_loops(model, recs, args.plot, [f.fitted_from for f in ident.report_])   # as the table scores them
    save_model(model, args.output)
    for note in ident.notes_:
        print(f"note: {note}", file=sys.stderr)
    rng = "" if model.stress_range_MPa is None else \
        f", stress {model.stress_range_MPa[0]:.4g}..{model.stress_range_MPa[1]:.4g} MPa"
    print(f"{model.kind.upper()} model, {model.n_play} plays, {model.n_deadzone} dead-zones{rng} -> {args.output}")
    at = ["-" if f.max_at_s is None else time_text(f.max_at_s, DEFAULT_TIME_STEP_S) for f in ident.report_]
    w = max([9] + [len(a) for a in at])          # a logger's absolute timestamps are wider than 9
    print(f"{'recording':<32} {'stress MPa':>10} {'RMS um':>9} {'% stroke':>9} {'max um':>9} {'at s':>{w}}")
    for f, a in zip(ident.report_, at):
        stress = "-" if f.stress_MPa is None else f"{f.stress_MPa:.4g}"
        print(f"{f.name[:32]:<32} {stress:>10} {f.rms_um:>9.4f} {f.rms_pct_stroke:>9.3f} {f.max_abs_um:>9.4f} {a:>{w}}")
    if args.plot:
        print(f"loops plotted to {args.plot}")
    return 0
