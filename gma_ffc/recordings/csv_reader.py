"""Reading a CSV recording: `# key: value` metadata, the header, and the rows, with pyarrow's parser
where the file is plain and a line-by-line one that names the line where it is not (a decimal comma,
a semicolon, an empty cell, a torn last line)."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import yaml

from ..errors import RecordingError
from .recording import Recording
from .checks import check_column_name, validate


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
    except IsADirectoryError:      # a glob's folder (a telemetry folder's diagnoses/)
        raise RecordingError(f"{source} is a folder, not a recording: give the recordings in it, e.g. "
                             f"{path / '*.csv'}, or leave it out") from None
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


# Files a folder's glob (`gma-ffc identify rec/*`) takes in beside the recordings, by suffix: the
# manifest.yaml `hil_sim record` writes, and the NAME.csv.lock a controller leaves beside its telemetry.
# Read as a CSV, each was "column '...' has no unit", which named no cause.
NOT_RECORDINGS = {".yaml": "a YAML file", ".yml": "a YAML file",
                  ".lock": "a controller's telemetry lock file (it holds the writer's pid)"}


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
    what = NOT_RECORDINGS.get(path.suffix.lower())
    if what is not None:
        raise RecordingError(f"{source} is {what}, not a recording (.csv, .mat, .tdms or .h5; "
                             f"docs/recordings.md): leave it out, e.g. give {path.parent / '*.csv'}")
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
    keep, words = _telemetry_rows_kept(columns, meta, header_line)
    file_rows = None
    if keep is not None:
        file_rows = np.flatnonzero(keep)
        columns = {n: c[keep] for n, c in columns.items()}
        notes.extend(f"{source}: {w}; they were left out" for w in words)
    rec = Recording(columns, meta, source, notes, file_rows=file_rows)
    return validate(rec, require, header_line)


def _telemetry_rows_kept(columns: Mapping[str, np.ndarray], meta: Mapping[str, Any],
                         header_line: int) -> tuple[Any, list[str]]:
    """In a gma-ffc telemetry file, the rows to keep (None: all) and what was left out. The controller
    writes the last good stress, so only rows before the load cell's first good reading have none;
    a displacement reading the sensor did not give is empty. One such row (a transmitter settling, a
    dropped sample) made the whole run's telemetry unreadable to simulate and diagnose. A column
    empty throughout is left to the checks (nothing would be left)."""
    if not str(meta.get("source", "")).startswith("gma-ffc controller"):
        return None, []
    keep = np.ones(len(next(iter(columns.values()), ())), dtype=bool)
    words = []
    stress, shown = columns.get("stress_MPa"), columns.get("displacement_um")
    if stress is not None and np.isfinite(stress).any() and not np.isfinite(stress[0]):
        first = int(np.argmax(np.isfinite(stress)))
        keep[:first] = False
        words.append(f"the first {first} rows (lines {header_line + 1}-{header_line + first}) have no stress (the "
                     "load cell had given no good reading yet, and the controller held the safe current)")
    if shown is not None and np.isfinite(shown).any() and not np.isfinite(shown[keep]).all():
        missing = keep & ~np.isfinite(shown)
        keep &= ~missing
        n = int(missing.sum())
        words.append(f"{n} {'row has' if n == 1 else 'rows have'} no displacement (readings the sensor did not "
                     f"give; the first at line {header_line + 1 + int(np.argmax(missing))})")
    return (keep, words) if words else (None, [])


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
