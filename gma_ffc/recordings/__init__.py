"""Recordings: read, validate and write the format of docs/recordings.md.

A recording is a CSV file (optional ``# key: value`` metadata lines, a header, numeric rows) or a
MATLAB ``.mat`` file with the same variable names; LabVIEW ``.tdms`` and HDF5 ``.h5`` files with
channels so named are read too. Every command writes CSV (or ``.mat``), so every output can be fed
back in. Violations raise `RecordingError` naming the file, the line and what is wrong.

Modules, each importing only those above it:
- `recording`: the `Recording` and the column names every reader and writer agrees on;
- `checks`: what the columns must be, with the message that says how to mend each violation;
- `csv_reader`: CSV text, with metadata, dialects, empty cells and a torn last line;
- `formats`: `.mat`, `.tdms` and HDF5;
- `files`: `read_recording` by suffix, `write_recording`, `fingerprint`.
"""

from .checks import (MAGNITUDE_BOUNDS, check_column_name, gap_note, refuse_absurd_magnitude, refuse_non_finite,
                     rename_advice, time_gaps, validate)
from .files import check_output_name, fingerprint, format_metadata, read_recording, write_recording
from .recording import (DEFAULT_TIME_STEP_S, DISPLACEMENT, DRIVE_COLUMNS, REFERENCE, STRESS, TIME, Recording, plain,
                        time_text)

__all__ = ["DEFAULT_TIME_STEP_S", "DISPLACEMENT", "DRIVE_COLUMNS", "MAGNITUDE_BOUNDS", "REFERENCE", "STRESS", "TIME",
           "Recording", "check_column_name", "check_output_name", "fingerprint", "format_metadata", "gap_note", "plain",
           "read_recording", "refuse_absurd_magnitude", "refuse_non_finite", "rename_advice", "time_gaps",
           "time_text", "validate", "write_recording"]
