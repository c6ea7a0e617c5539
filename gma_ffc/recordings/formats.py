"""Reading the binary formats labs log to: MATLAB `.mat` (v7 and older), LabVIEW `.tdms` and HDF5,
each with its columns as variables or channels named as in a CSV recording; a variable that is not
one numeric vector is named with what it is and how to save it."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import RecordingError
from .recording import DISPLACEMENT, DRIVE_COLUMNS, REFERENCE, Recording, STRESS, TIME, plain
from .checks import check_column_name, validate


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
