"""`gma-ffc simulate`: predict the displacement for a recording's drive and stress."""

from __future__ import annotations

import argparse
import sys
from typing import Any

import numpy as np

from ..errors import InputError
from ..modelio import load_model
from ..recordings import DISPLACEMENT, MAGNITUDE_BOUNDS, Recording, refuse_non_finite, write_recording
from ._common import (add_group_option, add_initial_state_option, add_stress_option, beyond_drive_range,
                      check_drive_name, check_initial_drive, check_recording_output, note_gaps, read_while,
                      recorded_stress, stress_for, warm_up)

HELP = """\
Run a model (any kind: sdpi, mpi, or an extended model from `gma-ffc diagnose`) on the drive and
stress of a recording. The output is itself a recording: the same time_s, drive and stress
columns, displacement_um = the prediction, the measured displacement (if the input had one)
kept as measured_displacement_um, and the input's other columns carried along (reference_um,
force_N, temperature_C, ...). A drive beyond the range the model was identified on is
reported (the prediction there is an extrapolation).

A recording starts in the middle of a hysteresis history the file does not show. By default
(--initial-state estimate) the model's state at the first sample is fitted to the measured
displacement where the recording has one, and otherwise taken consistent with the drive's first
monotone stretch; the command says which it used.

example:
  gma-ffc simulate --model model.yaml run_19MPa.csv -o predicted.csv
  gma-ffc simulate --model model.yaml run_19MPa.csv -o predicted.csv --initial-state relaxed
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="predict displacement with a model", description=HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", required=True, metavar="MODEL.yaml",
                   help="a model file from gma-ffc identify or gma-ffc diagnose (extended_model.yaml)")
    p.add_argument("recording", metavar="REC", help="recording with time_s, drive and (for SDPI) stress_MPa")
    p.add_argument("-o", "--output", required=True, metavar="OUT.csv",
                   help="the prediction, written as a recording: .csv or .mat (never over REC)")
    add_stress_option(p)
    add_initial_state_option(p)
    add_group_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_recording_output(args.output, [args.recording, args.model])

    def prepare() -> Any:      # numba is imported here (by the model), beside the read, not at --help
        model = load_model(args.model)
        warm_up(model, args.initial_state)
        return model

    model, rec = read_while(prepare, args.recording, require=("time_s", "drive"), group=args.group)
    check_drive_name(model, rec)
    check_initial_drive(model, args.initial_state.drive, "--initial-state drive:")
    measured = rec.displacement_um
    if measured is not None:    # compared and fitted to at every sample, and written out: a hole cannot be
        refuse_non_finite(rec, DISPLACEMENT, "the measured displacement_um: fill the cell in, or leave the "
                                             "column out to predict without a comparison")
    note_gaps([rec])
    stress = stress_for(model, rec, args.stress)
    spec, rest, from_file = _initial_state_of(args.initial_state, rec, measured, model)
    start = model.resolve_initial_state(rec.drive, stress, spec, measured, rec.time_s)
    if rest is None:
        pred = model.simulate(rec.time_s, rec.drive, stress, initial_state=start)
        how = start.how
    else:
        pred = model.simulate(rec.time_s, rec.drive, stress, initial_drive=rest)
        how = f"at rest at {rest:g} by the model's own stepper rule"
    _refuse_an_unreadable_prediction(pred, rec, model)
    cols = _output_columns(rec, None if stress is None else recorded_stress(rec, stress, args.stress), pred)
    meta = {"source": f"gma-ffc simulate --model {args.model}", "input": rec.name, "model_kind": model.kind}
    write_recording(args.output, Recording(cols, meta, args.output))
    note = beyond_drive_range(model, rec)
    if note is not None:
        print(f"warning: {note}", file=sys.stderr)
    _warn_of_a_scale_slip(rec, pred, model)
    print(f"predicted {len(rec)} samples -> {args.output}{_fit_words(rec, pred, start)}")
    print(f"initial state: {how}" + (" (the start `gma-ffc invert` gave this drive, from the file's metadata)"
                                     if from_file else ""))
    return 0


def _output_columns(rec: Recording, stress: np.ndarray | None, pred: np.ndarray) -> dict[str, np.ndarray]:
    """simulate's output: time_s, the drive, the stress run at, displacement_um = the prediction and
    the measured one as measured_displacement_um; then every other column of the input, carried
    along as docs/recordings.md says unknown columns are (reference_um, force_N, temperature_C), and
    never over one of these."""
    cols = {"time_s": rec.time_s, rec.drive_name: rec.drive}
    if stress is not None:
        cols["stress_MPa"] = stress
    cols["displacement_um"] = pred
    if rec.displacement_um is not None:
        cols["measured_displacement_um"] = rec.displacement_um
    for name, values in rec.columns.items():
        cols.setdefault(name, values)
    return cols


def _warn_of_a_scale_slip(rec: Recording, pred: np.ndarray, model: Any) -> None:
    """A measured displacement 30x off the prediction's swing (mm under displacement_um): the RMS
    printed beside it compares two units, so say so, with the factor (diagnose refuses it)."""
    if rec.displacement_um is None:
        return
    from ..diagnose.checks import displacement_scale_words

    words = displacement_scale_words(rec.drive, model.drive_range, rec.displacement_um, pred)
    if words:
        print(f"warning: {rec.source}: {words}", file=sys.stderr)


def _refuse_an_unreadable_prediction(pred: np.ndarray, rec: Recording, model: Any) -> None:
    """A prediction not finite, or past the displacement column's physical bound (`MAGNITUDE_BOUNDS`):
    written, the file would be refused by every command that reads it. A drive far beyond the range
    the model was identified on extrapolates that far; the advice is then to identify over it."""
    bound = MAGNITUDE_BOUNDS[DISPLACEMENT]
    bad = ~(np.abs(pred) <= bound)          # NaN compares False: caught with the values past the bound
    if not bad.any():
        return
    k = int(np.argmax(bad))
    beyond = beyond_drive_range(model, rec)
    why = (beyond.split(": ", 1)[1] if beyond else
           "the drive stays in the model's identified range, so the model file is not one that fits this actuator: "
           "identify it again from this actuator's recordings (gma-ffc identify)")
    raise InputError(f"{rec.source}: the prediction reaches {pred[k]:.4g} um at t = {rec.time_text(k)} s, past the "
                     f"{bound:g} um a recording may hold, so nothing is written: {why}")


def _fit_words(rec: Recording, pred: np.ndarray, start: Any) -> str:
    """" (RMS vs measured ...)", with the RMS once the initial state no longer matters; "" without a
    measurement."""
    from ..model import rms

    measured = rec.displacement_um
    if measured is None:
        return ""
    err = pred - measured
    words = f" (RMS vs measured {rms(err):.4f} um"
    if 0 < start.settled_index < len(rec):
        words += f"; {rms(err[start.settled_index:]):.4f} um once the initial state is forgotten, " \
                 f"from t = {rec.time_text(start.settled_index)} s"
    return words + ")"


def _initial_state_of(asked: Any, rec: Any, measured: Any, model: Any) -> tuple[Any, float | None, bool]:
    """The initial-state rule to simulate with, the drive an extended model rests at instead (None:
    the rule), and whether they came from the file. A drive written by `gma-ffc invert` names the
    start its inverse assumed (`initial_state`, or an extended model's `initial_drive`: at rest at the
    low end of its range by its own stepper rule); with no measurement and no rule asked for, it is used."""
    from ..initial_state import InitialStateSpec
    from ..model import SDPIModel

    meta = rec.metadata
    if measured is not None or asked != InitialStateSpec():
        return asked, None, False
    rest = meta.get("initial_drive")
    if not isinstance(model, SDPIModel) and isinstance(rest, (int, float)) and np.isfinite(rest):
        return asked, float(rest), True
    try:
        return (InitialStateSpec.parse(meta["initial_state"]), None, True) if isinstance(
            meta.get("initial_state"), str) else (asked, None, False)
    except ValueError:
        return asked, None, False
