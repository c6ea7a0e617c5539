"""What a recording's columns must be, and the message that says how to mend each violation: names
with units (and the rename or factor for a name that is nearly right), finite values in the required
columns, magnitudes no actuator logs, a lone spike, time that moves forward, and gaps in it. Pure
checks on data already read: no I/O."""

from __future__ import annotations

import re
from typing import Iterable, Sequence

import numpy as np

from ..errors import RecordingError
from .recording import DISPLACEMENT, DRIVE_COLUMNS, REFERENCE, Recording, STRESS, TIME, time_text


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


def _at_line(source: str, line: int) -> str:
    """Where a header's message points: the file and its line, or the file alone when it has no
    lines (.mat, .tdms, .h5: `header_line` 0)."""
    return f"{source}, line {line}" if line > 0 else source


def _at_row(rec: Recording, row: int) -> str:
    """Where a row's message points: its line in a text file, else its sample number (from 1, as
    MATLAB indexes it)."""
    in_file = row if rec.file_rows is None else int(rec.file_rows[row])
    return f"{rec.source}, line {rec.header_line + 1 + in_file}" if rec.header_line > 0 else f"{rec.source}, sample {row + 1}"


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
