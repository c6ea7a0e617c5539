"""Recordings: read, validate and write the format of docs/recordings.md.

A recording is a CSV file (optional ``# key: value`` metadata lines, a header, numeric rows) or a
MATLAB ``.mat`` file with the same variable names; LabVIEW ``.tdms`` and HDF5 ``.h5`` files with
channels so named are read too. Every command writes CSV (or ``.mat``), so every output can be fed
back in. Violations raise `RecordingError` naming the file, the line and what is wrong.
"""

from __future__ import annotations

import io
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import yaml

from .atomic import atomic_write
from .errors import RecordingError

DRIVE_COLUMNS = ("current_A", "voltage_V")
TIME = "time_s"
DISPLACEMENT = "displacement_um"
STRESS = "stress_MPa"
REFERENCE = "reference_um"

# Quantities users commonly write without a unit; the message suggests the spec's name.
_UNITLESS_HINTS = {
    "time": TIME, "t": TIME, "current": "current_A", "i": "current_A", "voltage": "voltage_V",
    "displacement": DISPLACEMENT, "disp": DISPLACEMENT, "x": DISPLACEMENT, "y": DISPLACEMENT,
    "stress": STRESS, "sigma": STRESS, "reference": REFERENCE, "force": "force_N",
    "temperature": "temperature_C", "temp": "temperature_C",
}
_NAME_WITH_UNIT = re.compile(r"^[A-Za-z][A-Za-z0-9]*(?:_[A-Za-z0-9]+)*_[A-Za-z%]+[A-Za-z0-9]*$")
_UNIT_IN_BRACKETS = re.compile(r"^\s*([A-Za-z][A-Za-z0-9 _]*?)\s*[\(\[]\s*([^\)\]\s]+)\s*[\)\]]\s*$")   # 'Time (s)'
# the units a lab may log a required quantity in, as multiples of the unit gma-ffc reads
_OTHER_UNITS = {
    "s": {"ms": 1e-3, "us": 1e-6, "min": 60.0}, "A": {"mA": 1e-3}, "V": {"mV": 1e-3, "kV": 1e3},
    "um": {"nm": 1e-3, "mm": 1e3, "m": 1e6},
    "MPa": {"kPa": 1e-3, "Pa": 1e-6, "GPa": 1e3, "N/mm^2": 1.0, "N/mm2": 1.0, "Nmm2": 1.0},
}
# Other names a lab gives a quantity, and why each is that quantity: the SDPI paper writes stress as
# sigma; a commanded current is the drive where the rig measures none (shared/spec/recordings.md)
_QUANTITY_ALIASES = {"stress": {"sigma": ""},
                     "current": {"current_cmd": " (a commanded current is the drive when the rig measures "
                                                "none: docs/recordings.md)"}}


DEFAULT_TIME_STEP_S = 1e-3   # a time's resolution when none is known: a millisecond, finer than any window quoted


def time_text(t_s: float, step_s: float) -> str:
    """A recording's time as text, to `step_s` (a sample period, a window's hundredth): fixed point,
    so that a logger's absolute timestamps (1.7e9 s) keep the digits that tell two times apart,
    where a number of significant digits would print both as 1.7e+09."""
    if not math.isfinite(step_s) or step_s <= 0:
        step_s = DEFAULT_TIME_STEP_S
    # a step a hair under a power of ten is that power (a period of 0.01 s differenced from timestamps
    # near 1.7e9 s comes out 0.00999999): allow 0.1 % in the logarithm
    decimals = min(9, max(0, math.ceil(-math.log10(step_s) - 1e-3)))
    return f"{t_s:.{decimals}f}"


@dataclass
class Recording:
    """One experiment: columns of equal length keyed by their unit-bearing names, plus metadata."""

    columns: dict[str, np.ndarray]
    metadata: dict[str, Any] = field(default_factory=dict)
    source: str = "<memory>"
    notes: list[str] = field(default_factory=list)      # what reading it left out, said to the user
    header_line: int = 0            # the header's line in the file (0: no lines, .mat/.tdms/.h5); `validate` sets it

    def __post_init__(self) -> None:
        self.columns = {k: np.ascontiguousarray(v, dtype=float) for k, v in self.columns.items()}
        lengths = {len(v) for v in self.columns.values()}
        if len(lengths) > 1:
            raise RecordingError(f"{self.source}: columns have different lengths {sorted(lengths)}")

    def __len__(self) -> int:
        return len(self.time_s)

    @property
    def name(self) -> str:
        return Path(self.source).name

    @property
    def time_s(self) -> np.ndarray:
        return self.columns[TIME]

    @property
    def drive_name(self) -> str:
        for name in DRIVE_COLUMNS:
            if name in self.columns:
                return name
        raise RecordingError(f"{self.source}: no drive column (one of {', '.join(DRIVE_COLUMNS)})")

    @property
    def drive(self) -> np.ndarray:
        return self.columns[self.drive_name]

    @property
    def displacement_um(self) -> np.ndarray | None:
        return self.columns.get(DISPLACEMENT)

    def column(self, name: str) -> np.ndarray:
        """A column the caller cannot do without (`read_recording(require=...)` checked it);
        RecordingError naming the file if it is missing after all."""
        if name not in self.columns:
            raise RecordingError(f"{self.source}: no {name} column")
        return self.columns[name]

    @property
    def stress_MPa(self) -> np.ndarray | None:
        return self.columns.get(STRESS)

    @property
    def sample_period_s(self) -> float:
        """Median sample period (sampling need not be uniform)."""
        return float(np.median(np.diff(self.time_s))) if len(self) > 1 else float("nan")

    def time_text(self, index: int) -> str:
        """Sample `index`'s time as text, to the sample period (`time_text`)."""
        return time_text(float(self.time_s[index]), self.sample_period_s)

    def rows(self, keep: np.ndarray, source: str | None = None) -> "Recording":
        """A copy of the samples where `keep` is True (a window of a run, a stretch cut out), named
        `source` (default: this recording's own)."""
        return Recording({k: v[keep] for k, v in self.columns.items()}, dict(self.metadata),
                         self.source if source is None else source)

    def with_column(self, name: str, values: np.ndarray) -> "Recording":
        """A copy with one column added or replaced (for predictions and drives)."""
        cols = dict(self.columns)
        cols[name] = np.asarray(values, dtype=float)
        return Recording(cols, dict(self.metadata), self.source)


def _at_line(source: str, line: int) -> str:
    """Where a header's message points: the file and its line, or the file alone when it has no
    lines (.mat, .tdms, .h5: `header_line` 0)."""
    return f"{source}, line {line}" if line > 0 else source


def _at_row(rec: Recording, row: int) -> str:
    """Where a row's message points: its line in a text file, else its sample number (from 1, as
    MATLAB indexes it)."""
    return f"{rec.source}, line {rec.header_line + 1 + row}" if rec.header_line > 0 else f"{rec.source}, sample {row + 1}"


def check_column_name(name: str, source: str, line: int) -> None:
    if _NAME_WITH_UNIT.match(name):
        return
    hint = _UNITLESS_HINTS.get(name.strip().lower())
    ascii_name = name.replace("\u00b5", "u").replace("\u03bc", "u")      # micro sign, Greek mu: 'um' in ASCII
    if ascii_name != name and _NAME_WITH_UNIT.match(ascii_name):
        hint = ascii_name
    bracketed = _UNIT_IN_BRACKETS.match(ascii_name)
    if bracketed:                          # 'Time (s)', 'Displacement [um]': the unit after an underscore
        want = f"{'_'.join(bracketed.group(1).lower().split())}_{bracketed.group(2)}"
        raise RecordingError(f"{_at_line(source, line)}: column '{name}': a unit follows an underscore in a column "
                             f"name; rename it '{want}' (and the other columns likewise)")
    misnamed_stress = _column_fix(ascii_name, STRESS)        # 'stress_N/mm^2': a unit with a slash
    if misnamed_stress:
        raise RecordingError(f"{_at_line(source, line)}: column '{name}' is named with a unit gma-ffc does not "
                             f"read; {misnamed_stress}")
    suggestion = f" (did you mean '{hint}'?)" if hint else " (names end in a unit, e.g. time_s, current_A)"
    raise RecordingError(f"{_at_line(source, line)}: column '{name}' has no unit{suggestion}")


def rename_advice(found: Iterable[str], wanted: Sequence[str]) -> str:
    """'' or what to do with a column that is one of `wanted` in another case, another unit or under
    another name ('; Time_s: rename it time_s (names are case-sensitive)', '; time_ms is in ms: ...',
    '; sigma_MPa: rename it stress_MPa')."""
    for have in found:
        for want in wanted:
            fix = _column_fix(have, want)
            if fix:
                return f"; {fix}"
    if REFERENCE in wanted and DISPLACEMENT in found:
        return f"; to follow a measured run, copy its {DISPLACEMENT} into a column named {REFERENCE}"
    return ""


def _column_fix(have: str, want: str) -> str:
    """'' or how column `have` becomes `want`: a rename (another case, an alias of the quantity, a
    unit equal to gma-ffc's) or a conversion by a factor (another unit of the quantity)."""
    if "_" not in have or have == want:
        return ""
    if have.lower() == want.lower():
        return f"{have}: rename it {want} (names are case-sensitive)"
    quantity, unit = want.rsplit("_", 1)
    q, u = have.rsplit("_", 1)
    aliases = _QUANTITY_ALIASES.get(quantity, {})
    if q.lower() != quantity and q.lower() not in aliases:
        return ""
    factor = 1.0 if u.lower() == unit.lower() else _unit_factor(unit, u)
    if factor is None:
        return ""
    if factor == 1.0:
        same = "" if u.lower() == unit.lower() else f" (1 {u} is 1 {unit})"
        return f"{have}: rename it {want}{same}{aliases.get(q.lower(), '')}"
    op = f"multiply it by {factor:g}" if factor >= 1 else f"divide it by {1 / factor:g}"
    return f"{have} is in {u}, gma-ffc reads {unit}: {op} into a column named {want}"


def _unit_factor(unit: str, other: str) -> float | None:
    """How many `unit` one `other` is, for a unit a lab logs `unit`'s quantity in; None for any
    other. Case is forgiven where no two of the quantity's units differ only by it (stress_kpa)."""
    units = _OTHER_UNITS.get(unit, {})
    if other in units:
        return units[other]
    by_lower = {u.lower(): f for u, f in units.items()}
    if len(by_lower) < len(units) or unit.lower() in by_lower:
        return None
    return by_lower.get(other.lower())


def validate(rec: Recording, require: Sequence[str] = (TIME, "drive", DISPLACEMENT),
             header_line: int = 1) -> Recording:
    """Check a recording against the spec; `require` may name 'drive' for current_A/voltage_V."""
    src = rec.source
    rec.header_line = header_line
    for name in require:
        if name == "drive":
            if not any(d in rec.columns for d in DRIVE_COLUMNS):
                raise RecordingError(
                    f"{_at_line(src, header_line)}: missing drive column: need current_A "
                    f"(or voltage_V for a voltage-driven actuator); found {', '.join(rec.columns)}"
                    f"{rename_advice(rec.columns, DRIVE_COLUMNS)}")
        elif name not in rec.columns:
            raise RecordingError(
                f"{_at_line(src, header_line)}: missing required column '{name}'; found {', '.join(rec.columns)}"
                f"{rename_advice(rec.columns, [name])}")
    if "drive" in require and all(d in rec.columns for d in DRIVE_COLUMNS):
        raise RecordingError(
            f"{_at_line(src, header_line)}: both current_A and voltage_V are columns, and gma-ffc reads one drive: "
            "drop the column that is not the actuator's drive (or rename it, e.g. to coil_voltage_V, to keep it)")
    _refuse_a_misnamed_stress(rec, header_line)
    if len(rec) < 2:
        raise RecordingError(f"{src}: needs at least two samples, has {len(rec)}")
    required_cols = [TIME] + [c for c in require if c != "drive" and c != TIME]
    if "drive" in require:
        required_cols.append(rec.drive_name)
    for name in required_cols:
        refuse_non_finite(rec, name, "required columns")
    if STRESS in rec.columns and STRESS not in required_cols:
        # every model that reads stress reads every sample of it: a present column is as good as required
        refuse_non_finite(rec, STRESS, "stress_MPa, when a recording has the column: put the stress at that "
                                       "time in the cell")
    if DISPLACEMENT in rec.columns:         # an isolated overload value: the spike's message says more
        _refuse_a_spike(rec, DISPLACEMENT)
    for name in rec.columns:
        refuse_absurd_magnitude(rec, name)
    if DISPLACEMENT not in rec.columns:
        advice = rename_advice(rec.columns, [DISPLACEMENT])
        if advice:                   # optional here, so not refused: but the user meant it to be read
            rec.notes.append(f"{src}: no {DISPLACEMENT} column, so nothing is compared with a measurement{advice}")
    steps = np.diff(rec.time_s)
    if (steps <= 0).any():
        row = int(np.argmax(steps <= 0)) + 1
        raise RecordingError(
            f"{_at_row(rec, row)}: time does not increase "
            f"({time_text(float(rec.time_s[row - 1]), 1e-9)} s then {time_text(float(rec.time_s[row]), 1e-9)} s)")
    return rec


def _refuse_a_misnamed_stress(rec: Recording, header_line: int) -> None:
    """RecordingError when a column is evidently the stress under another name (Stress_MPa,
    stress_kPa, sigma_MPa) and there is no stress_MPa: read as an unknown column, it would be
    ignored and the recording modelled stress-independently, a worse model with no word why."""
    if STRESS in rec.columns:
        return
    advice = rename_advice(rec.columns, [STRESS])
    if advice:
        raise RecordingError(f"{_at_line(rec.source, header_line)}: no {STRESS} column{advice}; or drop that "
                             "column to model the recording stress-independently")


# The largest magnitude each column gma-ffc reads may hold: generous beyond any bench, yet small
# enough that squares and sums of squares of a million samples stay finite (1e9 squared is 1e18).
# A value past its bound is a logger's overload code or a unit gone wrong, never a measurement.
MAGNITUDE_BOUNDS = {
    TIME: 1e11,             # s: over 3000 years; a Unix timestamp (1.7e9 s) is well inside
    "current_A": 1e6,       # A: a lightning stroke's current; an actuator's coil takes a few amperes
    "voltage_V": 1e6,       # V: a megavolt; a piezo stack's amplifier gives at most a few kV
    DISPLACEMENT: 1e9,      # um: a kilometre, no smart-material actuator's stroke (they move um to mm)
    REFERENCE: 1e9,         # um: as displacement_um, which a reference is followed in
    STRESS: 1e6,            # MPa: a terapascal, ten times the strength of diamond
}


def refuse_absurd_magnitude(rec: Recording, name: str) -> None:
    """RecordingError naming the file, the column and the line of the first finite cell of `name`
    beyond its MAGNITUDE_BOUNDS (columns without a bound are not read as quantities: not checked;
    NaN and inf are the finite-cell rules' to refuse)."""
    bound = MAGNITUDE_BOUNDS.get(name)
    if bound is None:
        return
    x = rec.columns[name]
    with np.errstate(invalid="ignore"):
        bad = np.abs(x) > bound
    bad &= np.isfinite(x)
    if bad.any():
        row = int(np.argmax(bad))
        raise RecordingError(f"{_at_row(rec, row)}: '{name}' is {x[row]:.6g}, beyond any physical "
                             f"{name.rsplit('_', 1)[0]} (|value| up to {bound:g} {name.rsplit('_', 1)[1]} is read): "
                             f"{_magnitude_advice(int(bad.sum()), len(x))}")


def _magnitude_advice(count: int, rows: int) -> str:
    """What to do about `count` of `rows` cells past a column's bound: one is an overload value,
    many a column logged in another unit or scaling."""
    if count == 1:
        return "a logger's overload value or a glitch; fix or remove that row"
    return (f"{count} of {rows} rows are: the column is logged in another unit or scaling; check the logger's "
            "setting for it and convert the column")


SPIKE_SPREADS = 10.0
"""A displacement sample this many times the column's spread (its 0.5-99.5 % percentile range)
away from both its neighbours, in the same direction, is a glitch: a sensor's overload value
(9.9e37), a dropped digit. No actuator moves ten strokes out and back within one sample."""
SPIKE_FLOOR_UM = 1.0
"""The least spread a spike is measured against: a column that holds still (all one value, or a
few quantisation steps) would otherwise make a one-count blip a glitch."""


def _refuse_a_spike(rec: Recording, name: str) -> None:
    """RecordingError naming the first isolated sample far beyond the rest of the column."""
    x = np.asarray(rec.columns[name], dtype=float)
    if x.size < 3 or not np.isfinite(x).any():
        return
    lo, hi = np.nanpercentile(x, [0.5, 99.5])
    reach = SPIKE_SPREADS * max(hi - lo, SPIKE_FLOOR_UM)
    with np.errstate(invalid="ignore", over="ignore"):      # 1e308 - (-1e308) is inf: not a spike's test
        up = (x[1:-1] - x[:-2] > reach) & (x[1:-1] - x[2:] > reach)
        down = (x[:-2] - x[1:-1] > reach) & (x[2:] - x[1:-1] > reach)
    spikes = np.flatnonzero((up | down) & np.isfinite(x[1:-1]))     # NaN and inf: the finite-cell rules
    if spikes.size:
        row = int(spikes[0]) + 1
        raise RecordingError(
            f"{_at_row(rec, row)}: '{name}' is {x[row]:.6g}, more than "
            f"{reach:.4g} from both its neighbours ({SPIKE_SPREADS:g} times the column's spread, {hi - lo:.4g}): a sensor "
            f"overload value or a glitch{f' ({spikes.size} such samples)' if spikes.size > 1 else ''}; "
            "fix or remove that row")


def refuse_non_finite(rec: Recording, name: str, where: str) -> None:
    """RecordingError naming the file and the line of the first NaN or infinite cell of column `name`;
    `where` ends the sentence "NaN, infinite or empty cells are not allowed in ..." (and says what to do)."""
    bad = ~np.isfinite(rec.columns[name])
    if bad.any():
        row = int(np.argmax(bad))
        value = rec.columns[name][row]
        raise RecordingError(f"{_at_row(rec, row)}: '{name}' is {value}{' or empty' if np.isnan(value) and rec.header_line else ''} "
                             f"(NaN, infinite or empty cells are not allowed in {where})")


GAP_STEPS = 5.0     # a time step this many times the median one is a gap (a dropout), not jitter


def time_gaps(rec: Recording) -> list[tuple[float, float]]:
    """(start time, length) in s of each gap in time_s: a step over GAP_STEPS times the median
    step. The models run across a gap (per-sample steps) as if the drive moved in a straight line
    through it, so whatever happened there is not in the recording."""
    if len(rec) < 2:
        return []
    steps = np.diff(rec.time_s)
    where = np.flatnonzero(steps > GAP_STEPS * rec.sample_period_s)
    return [(float(rec.time_s[k]), float(steps[k])) for k in where]


def gap_note(rec: Recording) -> str | None:
    """One sentence on a recording's gaps in time, or None when it has none."""
    gaps = time_gaps(rec)
    if not gaps:
        return None
    start, length = max(gaps, key=lambda g: g[1])
    return (f"{rec.source}: {len(gaps)} gap(s) in time_s, the longest {length:.4g} s at t = "
            f"{time_text(start, rec.sample_period_s)} s "
            f"({length / rec.sample_period_s:.0f} sample steps): each is bridged as if the drive moved in a straight line, so "
            "what happened there is not in the fit; check the logger if the gaps were not intended")


def _parse_metadata(lines: Iterable[tuple[int, str]], source: str) -> dict[str, Any]:
    meta: dict[str, Any] = {}
    for lineno, text in lines:
        body = text.lstrip("#").strip()
        if not body:
            continue
        try:
            parsed = yaml.safe_load(body)
        except yaml.YAMLError:
            parsed = None
        if isinstance(parsed, dict):
            meta.update(parsed)
        # A comment that is not "key: value" is kept out of metadata but is not an error.
    return meta


def _head_lines(path: Path, source: str) -> list[str]:
    """The first 64 KiB of a CSV file as text lines (UTF-8, a byte-order mark dropped)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(65536)
    except FileNotFoundError:
        raise RecordingError(f"{source}: no such file") from None
    except OSError as exc:
        raise RecordingError(f"{source}: cannot read ({exc})") from None
    try:
        return head.decode("utf-8-sig").splitlines()
    except UnicodeDecodeError:
        # a cut multi-byte character at the 64 KiB boundary is fine; anything else is not UTF-8
        try:
            return head[:-4].decode("utf-8-sig").splitlines()
        except UnicodeDecodeError as exc:
            raise RecordingError(f"{source}: cannot read ({exc}); a recording is UTF-8 text (or .mat, .tdms, .h5)") from None


def _metadata_and_header(lines: list[str], source: str) -> tuple[list[tuple[int, str]], int]:
    """The '#' metadata lines before the header (with their line numbers), and the header's index."""
    meta_lines: list[tuple[int, str]] = []
    for idx, line in enumerate(lines):
        stripped = line.strip()
        if stripped.startswith("#"):
            meta_lines.append((idx + 1, stripped))
        elif stripped:
            return meta_lines, idx
    raise RecordingError(f"{source}: no header line (expected e.g. 'time_s,current_A,displacement_um')")


def read_csv(path: Path, require: Sequence[str]) -> Recording:
    """A CSV recording: Arrow's multi-threaded C++ parser for the rows, this module's checks and
    messages for everything else. Spreadsheet exports are understood: a UTF-8 byte-order mark is
    dropped, and a ';'- or tab-separated file, with decimal commas or points, is read as such."""
    source = str(path)
    lines = _head_lines(path, source)
    meta_lines, header_idx = _metadata_and_header(lines, source)
    header = lines[header_idx]
    if header.strip().replace(" ", "") == "format:gma-ffc-model":
        raise RecordingError(f"{source} is a gma-ffc model file, not a recording: give a recording here (time_s, the "
                             "drive, displacement_um; docs/recordings.md), and a model, where a command takes one, "
                             "with --model")
    first_row = next((ln for ln in lines[header_idx + 1:] if ln.strip() and not ln.lstrip().startswith("#")), "")
    delimiter, decimal = _dialect(header, first_row)
    names = [n.strip().strip('"') for n in header.split(delimiter)]
    trailing = len(names) > 1 and names[-1] == ""      # a spreadsheet's export ends every line with a delimiter
    names = names[:-1] if trailing else names
    header_line = header_idx + 1
    for name in names:
        check_column_name(name, source, header_line)
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise RecordingError(f"{source}, line {header_line}: column '{dup}' appears twice")
    meta = _parse_metadata(meta_lines, source)
    torn = _torn_last_line(path, meta, len(names), delimiter, decimal, trailing)
    data_source: Any = path
    notes = []
    if torn is not None:                 # read up to the last whole line, and say so
        with open(path, "rb") as fh:
            data_source = _arrow_buffer(fh.read(torn[0]))
        notes.append(f"{source}: the last line (line {torn[1]}) is incomplete, as when its writer was cut off "
                     "mid-line (a killed controller's last flush); it was left out")
    columns = _parse_rows_fast(data_source, header_idx, names, delimiter, decimal, trailing)
    if columns is None:      # Arrow could not: the careful parser finds the line and says what is wrong
        try:
            raw = path.read_bytes()[:torn[0]] if torn is not None else path.read_bytes()
            text = raw.decode("utf-8-sig")
        except (OSError, UnicodeDecodeError) as exc:
            raise RecordingError(f"{source}: cannot read ({exc})") from None
        body = text.splitlines()[header_idx + 1:]
        if trailing:
            body = [ln.rstrip()[:-1] if ln.rstrip().endswith(delimiter) else ln for ln in body]
        data = _parse_rows(body, len(names), source, header_line, delimiter, decimal)
        columns = {n: data[:, k] for k, n in enumerate(names)}
    rec = Recording(columns, meta, source, notes)
    return validate(rec, require, header_line)


TORN_TAIL_BYTES = 65536      # a data line is far shorter than this


def _torn_last_line(path: Path, meta: Mapping[str, Any], ncols: int, delimiter: str,
                    decimal: str, trailing: bool = False) -> tuple[int, int] | None:
    """(bytes up to it, its line number) when the file's last line is torn: not ended by a newline,
    and either written by gma-ffc (whose every line ends in one) or not a whole row. A spreadsheet
    export that only lacks its final newline keeps its last row."""
    with open(path, "rb") as fh:
        size = fh.seek(0, 2)
        start = max(0, size - TORN_TAIL_BYTES)
        fh.seek(start)
        tail = fh.read()
    if not tail or tail.endswith(b"\n"):
        return None
    newline = tail.rfind(b"\n")
    if newline < 0:
        return None                      # one line only: the header's own problem, said elsewhere
    last = tail[newline + 1:].decode("utf-8", "replace")
    if trailing and last.rstrip().endswith(delimiter):
        last = last.rstrip()[:-1]
    if not (str(meta.get("source", "")).startswith("gma-ffc") or not _whole_row(last, ncols, delimiter, decimal)):
        return None
    with open(path, "rb") as fh:
        line_number = sum(chunk.count(b"\n") for chunk in iter(lambda: fh.read(1 << 20), b"")) + 1
    return start + newline + 1, line_number


def _whole_row(line: str, ncols: int, delimiter: str, decimal: str) -> bool:
    cells = line.split(delimiter)
    return len(cells) == ncols and all(_is_number(cell, decimal) for cell in cells)


def _arrow_buffer(data: bytes) -> Any:
    import pyarrow as pa

    return pa.BufferReader(data)


def _dialect(header: str, first_row: str) -> tuple[str, str]:
    """(delimiter, decimal mark): ',' and '.'; a spreadsheet's ';' (decimal commas in a European
    locale); or tabs, LabVIEW's spreadsheet files (decimal commas too, in that locale)."""
    for delimiter in (";", "\t"):
        if delimiter in header and "," not in header:
            return delimiter, ("," if "," in first_row else ".")
    return ",", "."


def _parse_rows_fast(path: Any, header_idx: int, names: list[str], delimiter: str,
                     decimal: str, trailing: bool = False) -> dict[str, np.ndarray] | None:
    """The columns as float arrays via pyarrow.csv, or None if anything is not plainly numeric
    (words, ragged rows, comment lines among the rows): the slow path explains. An empty cell is a
    value that does not exist (a telemetry row's prediction before there is one): NaN, which
    `validate` refuses in a required column.
    Each column is copied once, out of Arrow's chunks into one contiguous array (no row-major
    stack in between: `Recording` would copy every strided column out of it again)."""
    import pyarrow as pa
    from pyarrow import csv as pacsv

    try:
        table = pacsv.read_csv(
            path,
            read_options=pacsv.ReadOptions(skip_rows=header_idx + 1, encoding="utf8",
                                           column_names=names + ([" trailing"] if trailing else [])),
            parse_options=pacsv.ParseOptions(delimiter=delimiter, ignore_empty_lines=True),
            convert_options=pacsv.ConvertOptions(column_types={n: pa.float64() for n in names}, include_columns=names,
                                                 decimal_point=decimal, strings_can_be_null=False,
                                                 null_values=[""], quoted_strings_can_be_null=False))
    except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError, OSError):
        return None
    if table.num_rows == 0:
        return None
    columns = {}
    for n in names:
        col = table.column(n)
        arr = col.to_numpy()              # one chunk: a read-only view of Arrow's buffer; several, or nulls: a copy (NaN)
        columns[n] = arr.copy() if col.num_chunks == 1 or not arr.flags.writeable else arr
    return columns


def _is_number(cell: str, decimal: str) -> bool:
    try:
        float(cell.replace(",", ".") if decimal == "," else cell)
    except ValueError:
        return False
    return True


def _empty_as_nan(line: str, delimiter: str) -> str:
    """A data line with each empty cell as 'nan' (a value that does not exist), as the fast path reads it."""
    cells = line.split(delimiter)
    return delimiter.join(cell if cell.strip() else "nan" for cell in cells) if "" in map(str.strip, cells) else line


def _parse_rows(body: list[str], ncols: int, source: str, header_line: int, delimiter: str = ",",
                decimal: str = ".") -> np.ndarray:
    """Careful parse line by line: finds the first offending line and says what is wrong there."""
    rows = [ln for ln in body if ln.strip() and not ln.lstrip().startswith("#")]
    if not rows:
        raise RecordingError(f"{source}: header but no data rows")
    if decimal == ",":
        rows = [ln.replace(",", ".") for ln in rows]
    rows = [_empty_as_nan(ln, delimiter) for ln in rows]
    try:
        data = np.loadtxt(io.StringIO("\n".join(rows)), delimiter=delimiter, ndmin=2, dtype=float)
        if data.shape[1] == ncols:
            return data
    except ValueError:
        pass
    for offset, line in enumerate(body):
        lineno = header_line + 1 + offset
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        cells = line.split(delimiter)
        if len(cells) != ncols:
            more = ("; a ';'-separated file with decimal commas is read as such only when its header "
                    "uses ';' too") if delimiter == "," and ";" in line else ""
            raise RecordingError(f"{source}, line {lineno}: {len(cells)} cells, header has {ncols}{more}")
        numeric = [_is_number(cell, decimal) for cell in cells]
        if not any(numeric):             # a units row, or a second header: nothing in it is data
            raise RecordingError(f"{source}, line {lineno}: no cell is a number ('{line.strip()[:60]}'); a row of "
                                 "units or a second header? Units belong in the column names (time_s, current_A): "
                                 "delete the line")
        bad = [not (number or not cell.strip()) for number, cell in zip(numeric, cells)]     # empty: no value
        if any(bad):
            col = bad.index(True)
            raise RecordingError(f"{source}, line {lineno}: cell {col + 1} '{cells[col].strip()}' is not a number")
    raise RecordingError(f"{source}: could not parse the data rows")


# The variables of a .mat file gma-ffc reads as quantities: one so named that is not one numeric
# vector (a matrix, complex, text, a single value) is refused saying what it is, not ignored
MAT_COLUMNS = (TIME, *DRIVE_COLUMNS, DISPLACEMENT, STRESS, REFERENCE)


def read_mat(path: Path, require: Sequence[str]) -> Recording:
    """A MATLAB v7 (or older) file: each column a numeric vector variable named like it; numeric
    scalars and text become metadata."""
    source = str(path)
    raw = _load_mat(path)
    columns: dict[str, np.ndarray] = {}
    meta: dict[str, Any] = {}
    for key, value in raw.items():
        if key.startswith("__"):
            continue
        arr = np.asarray(value)
        if arr.dtype.kind in "fiub" and arr.ndim == 1 and arr.size > 1:
            check_column_name(key, source, 0)
            columns[key] = arr.astype(float)
        elif key in MAT_COLUMNS:
            raise RecordingError(f"{source}: {_mat_variable_problem(key, arr)}")
        elif arr.dtype.kind in "fiu" and arr.size == 1:
            meta[key] = arr.item()
        elif arr.dtype.kind == "U":
            meta[key] = str(arr)
    _refuse_columns_in_a_struct(raw, columns, source)
    rec = Recording(columns, meta, source)
    return validate(rec, require, header_line=0)


def _mat_variable_problem(name: str, arr: np.ndarray) -> str:
    """What is wrong with .mat variable `name`, one of MAT_COLUMNS that is not one numeric vector,
    and how to save it so that it is."""
    if arr.dtype.kind == "c":
        return f"variable '{name}' is complex; save its real part (in MATLAB, {name} = real({name}))"
    if arr.dtype.kind in "US":
        return (f"variable '{name}' is text ('{str(arr)[:30]}'), not numbers; save it as a numeric vector "
                f"(in MATLAB, {name} = str2num({name}) if the text is its numbers)")
    if arr.dtype.kind not in "fiub":
        return (f"variable '{name}' is a cell array or struct, not numbers; save it as a numeric vector "
                f"(in MATLAB, {name} = cell2mat({name}) for a cell array of numbers)")
    if arr.ndim > 1:
        shape = "x".join(str(n) for n in arr.shape)
        return (f"variable '{name}' is a {shape} matrix, not one vector; save one row or column of it as "
                f"'{name}' (in MATLAB, {name} = {name}(1, :) keeps the first row) and any other under a name of its own")
    if arr.size == 0:
        return f"variable '{name}' is empty; save the recorded vector, one value per sample"
    return _mat_single_value(name, float(arr.item()))


def _mat_single_value(name: str, value: float) -> str:
    """A column saved as one number. A constant stress is a vector as long as time_s, or --stress
    where a command takes one (simulate, invert); any other column has one value per sample."""
    if name != STRESS:
        return f"variable '{name}' is a single value ({value:g}), not one per sample; save the recorded vector"
    return (f"variable '{name}' is a single value ({value:g}), not one per sample; for a constant stress, save it "
            f"as a vector as long as time_s (in MATLAB, {name} = repmat({value:g}, size(time_s))), or, for "
            f"simulate and invert, leave it out and pass --stress {value:g}")


def _refuse_columns_in_a_struct(raw: Mapping[str, Any], columns: Mapping[str, np.ndarray], source: str) -> None:
    """RecordingError when a MATLAB struct variable holds fields named like MAT_COLUMNS that are not
    variables of the file: gma-ffc reads variables, and would say the columns are missing."""
    for key, value in raw.items():
        fields = [f for f in getattr(value, "_fieldnames", None) or [] if f in MAT_COLUMNS and f not in columns]
        if not key.startswith("__") and fields:
            raise RecordingError(
                f"{source}: variable '{key}' is a MATLAB struct with fields {', '.join(value._fieldnames)}; gma-ffc "
                f"reads each column as a variable of its own: save its fields as variables (in MATLAB, "
                f"save(f, '-struct', '{key}', '-v7'))")


def _load_mat(path: Path) -> dict[str, Any]:
    """scipy's loadmat, its errors as one line naming the file. An empty or cut-off file raises
    MatReadError, IndexError, struct errors and more (scipy has no one type for a damaged file)."""
    import scipy.io

    source = str(path)
    try:
        return scipy.io.loadmat(str(path), squeeze_me=True, struct_as_record=False)
    except NotImplementedError:
        raise RecordingError(
            f"{source}: MATLAB v7.3 (HDF5) files are not supported; save with `save(..., '-v7')`") from None
    except FileNotFoundError:
        raise RecordingError(f"{source}: no such file") from None
    except Exception as exc:   # noqa: BLE001 - any damage is the file's, said in one line
        what = "empty (0 bytes)" if path.is_file() and path.stat().st_size == 0 else \
            f"not a readable .mat file, damaged or cut off ({type(exc).__name__}: {exc})"
        raise RecordingError(f"{source}: {what}; save it again from MATLAB with save(..., '-v7') or "
                             "give it as .csv") from None


def read_tdms(path: Path, require: Sequence[str], group: str | None = None) -> Recording:
    """LabVIEW TDMS (npTDMS): channels named like the columns, in one group (or `group`); time
    from a time_s channel or from the waveform's wf_increment; properties become metadata."""
    from nptdms import TdmsFile

    source = str(path)
    try:
        tdms = TdmsFile.read(str(path))
    except FileNotFoundError:
        raise RecordingError(f"{source}: no such file") from None
    except Exception as exc:  # npTDMS raises ValueError/KeyError/... on damaged files
        raise RecordingError(f"{source}: not a readable TDMS file ({type(exc).__name__}: {exc})") from None
    groups = {g.name: g for g in tdms.groups()}
    if group is not None:
        if group not in groups:
            raise RecordingError(f"{source}: no group {group!r}; the file has: {', '.join(groups) or 'none'}")
        chosen = groups[group]
    else:
        with_data = [g for g in groups.values() if g.channels()]
        if not with_data:
            raise RecordingError(f"{source}: not a readable TDMS file with channels (no group holds any); is it "
                                 "a LabVIEW TDMS recording?")
        if len(with_data) != 1:
            raise RecordingError(f"{source}: {len(with_data)} groups hold channels ({', '.join(g.name for g in with_data)}); "
                                 "choose one with --group NAME")
        chosen = with_data[0]
    columns: dict[str, np.ndarray] = {}
    increment = None
    for ch in chosen.channels():
        check_column_name(ch.name, f"{source}, group {chosen.name!r}", 0)
        columns[ch.name] = np.asarray(ch[:], dtype=float)
        increment = increment or ch.properties.get("wf_increment")
    if TIME not in columns and columns:
        if not increment:
            raise RecordingError(f"{source}: no time_s channel and no wf_increment property to build time from")
        n = len(next(iter(columns.values())))
        columns = {TIME: np.arange(n) * float(increment), **columns}
    meta = {str(k): plain(v) for k, v in {**tdms.properties, **chosen.properties}.items()}
    return validate(Recording(columns, meta, source), require, header_line=0)


def read_hdf5(path: Path, require: Sequence[str], group: str | None = None) -> Recording:
    """HDF5 (h5py): 1-D datasets named like the columns, at the root or in `group`; attributes
    become metadata."""
    import h5py

    source = str(path)
    try:
        fh = h5py.File(str(path), "r")
    except FileNotFoundError:
        raise RecordingError(f"{source}: no such file") from None
    except OSError as exc:
        raise RecordingError(f"{source}: not a readable HDF5 file ({exc})") from None
    with fh:
        node = fh
        if group is not None:
            if group not in fh or not isinstance(fh[group], h5py.Group):
                raise RecordingError(f"{source}: no group {group!r}; {_hdf5_groups_hint(fh)}")
            node = fh[group]
        columns = {}
        for name, item in node.items():
            if _is_column(item):
                check_column_name(name, source, 0)
                columns[name] = np.asarray(item[()], dtype=float)
        if not columns:
            raise RecordingError(f"{source}: no 1-D numeric datasets at {node.name}; {_hdf5_groups_hint(fh)}")
        meta = {str(k): plain(v) for k, v in {**fh.attrs, **node.attrs}.items()}
    return validate(Recording(columns, meta, source), require, header_line=0)


def _is_column(item: Any) -> bool:
    import h5py

    return isinstance(item, h5py.Dataset) and item.ndim == 1 and item.dtype.kind in "fiu"


def _hdf5_groups_hint(fh: Any) -> str:
    """Which groups of the file hold 1-D numeric datasets, at any depth, as --group takes them."""
    import h5py

    found: list[str] = []

    def visit(name: str, item: Any) -> None:
        if isinstance(item, h5py.Group) and any(_is_column(v) for v in item.values()):
            found.append(name)

    fh.visititems(visit)
    if not found:
        return "no group in the file holds any: is it a recording?"
    return f"choose a group with --group: {', '.join(found)} hold{'s' if len(found) == 1 else ''} them"


GROUPED_READERS = {".tdms": read_tdms, ".h5": read_hdf5, ".hdf5": read_hdf5}   # formats with groups


def read_recording(path: str | Path, require: Sequence[str] = (TIME, "drive", DISPLACEMENT),
                   group: str | None = None) -> Recording:
    """Read and validate a recording (.csv, .mat, .tdms, .h5/.hdf5); RecordingError on any violation.
    `group` picks the TDMS or HDF5 group holding the channels."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in (".tdms", ".h5", ".hdf5"):
        return GROUPED_READERS[suffix](p, require, group)
    if group is not None:
        raise RecordingError(f"{p}: --group applies to .tdms and .h5 files only")
    if suffix == ".mat":
        return read_mat(p, require)
    return read_csv(p, require)


def fingerprint(path: str | Path) -> dict[str, Any]:
    """A recording file's name, size in bytes and SHA-256 of its content: what `identify` keeps of
    each identification file, so `diagnose --ident` can tell whether it was given the same files."""
    import hashlib

    p = Path(path)
    h = hashlib.sha256()
    with open(p, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return {"name": p.name, "bytes": p.stat().st_size, "sha256": h.hexdigest()}


def plain(value: Any) -> Any:
    """Numpy scalars/arrays and other objects -> what YAML can write (metadata never blocks a write)."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)


def _format_meta(meta: Mapping[str, Any]) -> str:
    out = []
    for key, value in meta.items():
        dumped = yaml.safe_dump({str(key): plain(value)}, default_flow_style=True, width=10_000).strip()
        if dumped.startswith("{") and dumped.endswith("}"):
            dumped = dumped[1:-1]
        out.append(f"# {dumped}\n")
    return "".join(out)


# What `write_recording` writes, by suffix: the two that `read_recording` reads back as the same
# recording (a .tdms or .h5 name would hold CSV text its reader refuses; other names mislead)
WRITTEN_SUFFIXES = (".csv", ".mat")


def check_output_name(path: str | Path) -> None:
    """RecordingError, before any work, unless `path` names a recording file gma-ffc writes and can
    read back (docs/recordings.md: every output can be fed back in): .csv or .mat."""
    if str(path) == "-":
        raise RecordingError("output -: recordings are written to a file, not to standard output; "
                             "give a file name ending in .csv or .mat")
    p = Path(path)
    if p.suffix.lower() not in WRITTEN_SUFFIXES:
        what = f"'{p.suffix}'" if p.suffix else "no extension"
        raise RecordingError(f"{path}: output recordings are written as .csv or .mat (what gma-ffc reads back), "
                             f"got {what}; name it {p.with_suffix('.csv')}")


def write_recording(path: str | Path, rec: Recording) -> None:
    """Write atomically: the file appears complete or not at all. `path` ends in .csv or .mat.

    Every value is written in its shortest form that reads back to the same double (Arrow's
    writer), so a round trip is exact and no digit is noise.
    """
    check_output_name(path)
    p = Path(path)
    names = list(rec.columns)
    if p.suffix.lower() == ".mat":
        import scipy.io

        with atomic_write(p, "wb") as fh:
            scipy.io.savemat(fh, {**{k: v for k, v in rec.columns.items()},
                                  **{k: v for k, v in rec.metadata.items() if isinstance(v, (int, float, str))}})
        return
    import pyarrow as pa
    from pyarrow import csv as pacsv

    # a value that does not exist (NaN; inf, which no reader takes) is an empty cell, never 'nan' text
    table = pa.table({n: pa.array(rec.columns[n], mask=~np.isfinite(rec.columns[n])) for n in names}) if names else None
    with atomic_write(p, "wb") as fh:
        fh.write((_format_meta(rec.metadata) + ",".join(names) + "\n").encode("utf-8"))
        if table is not None and table.num_rows:
            # One call, one thread: formatting blocks on two threads measured no faster (0.41 s
            # against 0.42 s for 1M rows on 2 idle cores) for a third more CPU.
            pacsv.write_csv(table, fh, write_options=pacsv.WriteOptions(include_header=False,
                                                                        quoting_style="none"))


def finite_or_none(value: float) -> float | None:
    return value if math.isfinite(value) else None
