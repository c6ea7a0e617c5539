"""Pieces the subcommands share: reading inputs with the contract's errors, stress handling."""

from __future__ import annotations

import argparse
import math
import os
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable, Sequence, TypeVar

import numpy as np

from ..drive import drive_unit
from ..errors import InputError
from ..model import stress_beyond
from ..protocols import Model
from ..atomic import check_folder_writable, refuse_overwrite
from ..recordings import Recording, check_output_name, gap_note, read_recording

T = TypeVar("T")


def check_recording_output(output: str, inputs: Sequence[str]) -> None:
    """Before any work, for a command that writes one recording: the output is none of the inputs
    (nor a device: said first, the graver mistake), is named .csv or .mat, and its folder takes a
    new file."""
    refuse_overwrite(output, inputs)
    check_output_name(output)
    check_folder_writable(Path(output).parent, output)


def read_all(paths: Sequence[str], require: Sequence[str], group: str | None = None) -> list[Recording]:
    return [read_recording(p, require=require, group=group) for p in paths]


def refuse_repeats(paths: Sequence[str]) -> None:
    """InputError naming both when two of `paths` are one recording: the same file, or files with the
    same content. A copy counts twice in a fit, and stays in it when its twin is left out."""
    seen: dict[tuple[int, int], str] = {}                  # (device, inode) -> the path that named it
    by_size: dict[int, list[str]] = {}
    for path in paths:
        try:
            st = os.stat(path)
        except OSError:
            continue                                        # the read says what is wrong with it
        first = seen.get((st.st_dev, st.st_ino))
        if first is not None:
            twice = f"{path} is given twice" if first == path else f"{first} and {path} are the same file"
            raise InputError(f"{twice}: give each recording once")
        seen[(st.st_dev, st.st_ino)] = path
        by_size.setdefault(st.st_size, []).append(path)
    for same_size in by_size.values():
        if len(same_size) > 1:
            _refuse_same_content(same_size)


def _refuse_same_content(paths: Sequence[str]) -> None:
    from ..recordings import fingerprint

    digests: dict[str, str] = {}
    for path in paths:
        first = digests.setdefault(fingerprint(path)["sha256"], path)
        if first != path:
            raise InputError(f"{first} and {path} have the same content, one recording given twice: "
                             "give each recording once")


def refuse_same_rows(recs: Sequence[Recording]) -> None:
    """InputError naming both when two recordings, as read, hold the same rows: the same columns by
    name with the same values, whatever the bytes (line endings, column order, metadata lines). A
    re-saved copy counts twice in a fit as a byte copy does (`refuse_repeats`)."""
    seen: dict[str, str] = {}
    for rec in recs:
        first = seen.setdefault(_rows_digest(rec), rec.source)
        if first != rec.source:
            raise InputError(f"{first} and {rec.source} hold the same rows (the same columns and values, saved "
                             "differently), one recording given twice: give each recording once")


def _rows_digest(rec: Recording) -> str:
    """SHA-256 of a recording's columns, by name in sorted order, and their values as doubles."""
    import hashlib

    h = hashlib.sha256()
    for name in sorted(rec.columns):
        h.update(name.encode("utf-8") + b"\0")
        h.update(np.ascontiguousarray(rec.columns[name], dtype="<f8").tobytes())
    return h.hexdigest()


def note_gaps(recs: Sequence[Recording]) -> None:
    """Say on stderr which recordings have dropouts in time (they run, bridged; the user should know)
    and what reading them left out (a torn last line)."""
    for rec in recs:
        for read_note in rec.notes:
            print(f"note: {read_note}", file=sys.stderr)
        note = gap_note(rec)
        if note is not None:
            print(f"note: {note}", file=sys.stderr)


def add_group_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--group", metavar="NAME",
                   help="for .tdms and .h5 recordings: the group holding the channels (needed when there are several)")


READING_NOISE_MARGIN = 5.0
"""Stress readings beyond the model's identified range by at most this many times the recording's
own load-cell noise are noise about a load the model knows, not another load: the range's ends are
the identification loops' noisiest readings, and the largest of a million Gaussian readings is about
5 sigma above their mean. They are clamped into the range (as the controller does by default), and
the command says so; a reading further out is another load, and refused."""


def stress_for(model: Model, rec: Recording, override: float | None) -> np.ndarray | float | None:
    """The stress to run `model` at for `rec`: --stress wins, else the recording's column (its
    readings beyond the identified range by noise, or by the load's inertial force, clamped into it:
    `_clamped_to_known_load`)."""
    if override is not None:
        check_stress_option(model, float(override))
        return float(override)
    if rec.stress_MPa is not None:
        return _clamped_to_known_load(model, rec, rec.stress_MPa)
    if model.stress_range_MPa is not None:
        lo, hi = model.stress_range_MPa
        raise InputError(f"{rec.source}: no stress_MPa column, and this {model.kind} model depends on stress "
                         f"(identified on {lo:.3g}..{hi:.3g} MPa); add the column or pass --stress MPA")
    return None


def inward_text(lo: float, hi: float) -> tuple[str, str]:
    """`lo` and `hi` as text, rounded inwards to 1/10000 of the span: a value copied from the text is
    inside [lo, hi] (rounded to nearest, an end could print a hair outside it and be refused)."""
    step = 10.0 ** (math.floor(math.log10(hi - lo)) - 4)
    return f"{math.ceil(lo / step) * step:.6g}", f"{math.floor(hi / step) * step:.6g}"


def check_stress_option(model: Model, stress: float) -> None:
    """InputError, naming --stress, when it lies outside the model's identified stress range (the
    model's own message would advise negating a stress_MPa column the recording may not have):
    -stress when that is inside (compression is negative here), else a value inside."""
    rng = getattr(model, "stress_range_MPa", None)
    if rng is None:
        return
    lo, hi = rng
    tol = 1e-6 * max(1.0, abs(lo), abs(hi))        # the model's own: a stress that far out is at its end
    if lo - tol <= stress <= hi + tol:
        return
    advice = (f"compression is negative in gma-ffc (docs/recordings.md): pass --stress {-stress:g}"
              if lo - tol <= -stress <= hi + tol else "pass a --stress from {} to {}".format(*inward_text(lo, hi)))
    raise InputError(f"--stress {stress:g} MPa is outside the model's identified range {lo:.4g}..{hi:.4g} MPa; "
                     f"{advice}")


def recorded_stress(rec: Recording, stress: Any, override: float | None) -> np.ndarray:
    """The stress column an output recording keeps: the input's own readings (not those
    `stress_for` clamped for the model), or --stress where it was given or there is no column."""
    written = rec.stress_MPa if override is None and rec.stress_MPa is not None else stress
    return np.broadcast_to(np.asarray(written, float), rec.time_s.shape)


def _clamped_to_known_load(model: Model, rec: Recording, s: np.ndarray) -> np.ndarray:
    """`s` with the readings that leave the model's stress range by noise alone clamped into it
    (said on stderr); any other stress as it is, for the model to judge. A model that reads the load
    cell through its own dynamics (an extended model's rod_load) gets the same: it low-passes the
    readings to the load's static stress, so readings clamped by noise keep that inside the range
    (left raw, they were refused where the plain model ran). Readings further out whose static stress
    stays inside are the load's inertial force about a load the model knows, and are clamped too."""
    from ..diagnose.noise import second_difference_sigma

    rng = model.stress_range_MPa
    if rng is None or not np.all(np.isfinite(s)):
        return s
    lo, hi = rng
    beyond = stress_beyond(s, lo, hi)
    if beyond == 0.0:
        return s
    noise = second_difference_sigma(np.asarray(s, dtype=float))
    outside = (f"note: {rec.name}: {int(np.count_nonzero((s < lo) | (s > hi)))} stress readings lie up to "
               f"{beyond:.2g} MPa outside the model's identified range {lo:.4g}..{hi:.4g} MPa")
    if beyond <= READING_NOISE_MARGIN * noise:
        print(f"{outside}, within {READING_NOISE_MARGIN:g} x the load cell's noise ({noise:.2g} MPa): clamped into it",
              file=sys.stderr)
        return np.clip(s, lo, hi)
    from ..effects.rod_load import STATIC_STRESS_HZ

    if rec.time_s.size < 2 or stress_beyond(_static(rec, s), lo, hi) > READING_NOISE_MARGIN * noise:
        return s
    print(f"{outside}, but the load's static stress (the readings low-passed at {STATIC_STRESS_HZ:g} Hz) stays "
          "within it: they are the load's inertial force, as when the drive rings a resonance, not another load; "
          "clamped into it", file=sys.stderr)
    return np.clip(s, lo, hi)


def _static(rec: Recording, s: np.ndarray) -> np.ndarray:
    """The load's static stress under readings `s` (`rod_load.static_stress`), on the recording's own steps."""
    from ..effects.base import time_steps
    from ..effects.rod_load import static_stress

    return static_stress(np.asarray(s, dtype=float), time_steps(rec.time_s)[0])


def beyond_drive_range(model: Model, rec: Recording) -> str | None:
    """One sentence when `rec`'s drive leaves the range `model` was identified on (the prediction
    there is an extrapolation), else None."""
    from ..drive import outside_range, unit_slip

    lo, hi = (float(v) for v in model.drive_range)
    outside = outside_range(rec.drive, (lo, hi))
    if not outside.any():
        return None
    unit = drive_unit(model.drive_name)
    where = np.flatnonzero(outside)
    advice = (unit_slip(rec.drive, (lo, hi), rec.drive_name) or
              "identify the model from recordings over the whole drive range used")
    return (f"{rec.source}: the drive ({float(rec.drive.min()):.4g}..{float(rec.drive.max()):.4g} {unit}) leaves the "
            f"range the model was identified on ({lo:.4g}..{hi:.4g} {unit}) at {where.size} of {len(rec)} samples, "
            f"first at t = {rec.time_text(where[0])} s: the prediction there is an extrapolation; {advice}")


def check_drive_name(model: Model, rec: Recording) -> None:
    name = model.drive_name
    if rec.drive_name != name:
        raise InputError(f"{rec.source}: drive column is {rec.drive_name} but the model was identified on {name}")


def add_initial_state_option(p: argparse.ArgumentParser, plays: bool = False) -> None:
    """--initial-state; with `plays` (diagnose) it also takes plays:FILE, a known state."""
    known = (", or plays:FILE (the play outputs at the first sample, known: a JSON file such as the "
             "service writes beside a background diagnosis's window; every sample is then scored)") if plays else ""
    p.add_argument("--initial-state", default="estimate", metavar="RULE",
                   type=_initial_state_or_plays if plays else _initial_state,
                   help="hysteresis state at the first sample: estimate (default: fitted to the measured "
                        "displacement where there is one, else consistent with the drive's first monotone "
                        f"stretch), relaxed, or drive:VALUE (relaxed at that drive){known}")


def _initial_state(text: str) -> Any:
    from ..initial_state import InitialStateSpec

    try:
        return InitialStateSpec.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _initial_state_or_plays(text: str) -> Any:
    """`_initial_state`, and plays:FILE read here (argparse's type: a bad file is one line, exit 2)."""
    if not str(text).strip().startswith("plays:"):
        try:
            return _initial_state(text)
        except argparse.ArgumentTypeError as exc:
            raise argparse.ArgumentTypeError(f"{exc}, or plays:FILE") from None
    from ..known_state import read_play_state

    try:
        return read_play_state(str(text).strip().split(":", 1)[1])
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def check_known_plays(model: Any, spec: Any, n_recordings: int) -> None:
    """InputError unless a plays:FILE state fits: one recording (the state is its first sample's)
    and one value per play of the model's core."""
    if getattr(spec, "kind", None) != "plays":
        return
    if n_recordings != 1:
        raise InputError(f"--initial-state {spec} gives the state at one recording's first sample: "
                         f"give that recording alone (got {n_recordings})")
    core = getattr(model, "base", model)
    n = int(np.asarray(core.play_thresholds).size)
    if len(spec.plays) != n:
        raise InputError(f"--initial-state {spec}: {len(spec.plays)} play values, but the model has {n} plays "
                         "(the state must come from this model)")


def check_initial_drive(model: Any, drive: float | None, option: str) -> None:
    """InputError unless a start `drive` given on the command line (`--initial-state drive:V`,
    `--initial-drive`) lies in the model's drive range widened by `drive.RANGE_MARGIN`: beyond it the
    model only extrapolates, and far beyond it (1e300) every play saturates into inf. A model
    without a finite range is held to the drive column's physical bound (`recordings.MAGNITUDE_BOUNDS`)."""
    from ..drive import RANGE_MARGIN
    from ..recordings import MAGNITUDE_BOUNDS

    if drive is None:
        return
    lo, hi = (float(v) for v in model.drive_range)
    if math.isfinite(hi - lo) and hi > lo:
        wide = RANGE_MARGIN * (hi - lo)
        lo, hi, what = lo - wide, hi + wide, "the drive range the model was identified on"
    else:
        bound = MAGNITUDE_BOUNDS[model.drive_name]
        lo, hi, what = -bound, bound, "a physical drive"
    if not lo <= drive <= hi:
        low, high = inward_text(lo, hi)
        raise InputError(f"{option}{drive:g} is outside {what}: give a drive from {low} to {high} "
                         f"{drive_unit(model.drive_name)}")


def finite_float(text: str) -> float:
    """argparse type: a number, refused when NaN or infinite (it would reach the outputs as one)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def add_stress_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--stress", type=finite_float, metavar="MPA",
                   help="constant stress in MPa (compression negative) for recordings without stress_MPa")


def read_while(work: Callable[[], T], path: str, require: Sequence[str],
               group: str | None = None) -> tuple[T, Recording]:
    """`work()` here (loading the model, `warm_up`), the recording read meanwhile in another thread.

    Arrow parses without holding the GIL, so on a large recording the read and the model's start-up
    (importing numba, loading its compiled kernels) overlap instead of adding up. A model error
    still comes first, as if the two ran one after the other; a recording error comes after.
    """
    with ThreadPoolExecutor(1, thread_name_prefix="read") as pool:
        reading = pool.submit(read_recording, path, require=require, group=group)
        result = work()
        return result, reading.result()


def warm_up(model: Any, initial_state: Any) -> None:
    """Run `model` once on three samples of made-up data: numba loads the kernels the real run
    calls from its cache (about a quarter second on first use), and the initial-state fit's
    optimisers (scipy.optimize, 0.2 s to import) are imported when the state will be estimated.
    Only ever called next to a read (see `read_while`), where that time is otherwise spent
    waiting. Nothing here decides anything: an error is left for the real run to meet and report."""
    span = getattr(model, "stress_range_MPa", None)
    stress = None if span is None else 0.5 * (span[0] + span[1])
    t = np.array([0.0, 1e-3, 2e-3])
    drive = np.zeros(3)
    try:
        if getattr(initial_state, "kind", None) == "estimate":
            import scipy.optimize  # noqa: F401  (the state fit's, gma_ffc.initial_state)

            model.simulate(t, drive, stress, initial_state="estimate", measured_um=np.zeros(3))
        else:
            model.simulate(t, drive, stress, initial_state="relaxed")
    except Exception:       # noqa: BLE001 - a warm-up never reports; the real call will
        pass
