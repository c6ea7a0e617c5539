"""A recording file as a whole: `read_recording` picks the reader by suffix, `write_recording`
writes CSV or `.mat` atomically (never over an input, never half-written), and `fingerprint`
identifies a file by name, size and content hash."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import yaml

from ..atomic import atomic_write
from ..errors import RecordingError
from .recording import DISPLACEMENT, Recording, TIME, plain
from .csv_reader import read_csv
from .formats import GROUPED_READERS, read_mat


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


def format_metadata(meta: Mapping[str, Any]) -> str:
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
        fh.write((format_metadata(rec.metadata) + ",".join(names) + "\n").encode("utf-8"))
        if table is not None and table.num_rows:
            # One call, one thread: formatting blocks on two threads measured no faster (0.41 s
            # against 0.42 s for 1M rows on 2 idle cores) for a third more CPU.
            pacsv.write_csv(table, fh, write_options=pacsv.WriteOptions(include_header=False,
                                                                        quoting_style="none"))
