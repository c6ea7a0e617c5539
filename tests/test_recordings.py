"""The recording format of shared/spec/recordings.md: what is accepted, what is refused and how."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gma_ffc.errors import RecordingError
from gma_ffc.recordings import Recording, read_recording, write_recording

GOOD = """# source: bench rig 2
# sample_rate_hz: 2000
stress_MPa,time_s,displacement_um,current_A,force_N
-15.2,0.0000,0.012,0.0,435
-15.2,0.0005,0.015,0.00012,436
-15.2,0.0010,0.019,0.00030,437
"""


def write(tmp_path: Path, text: str, name: str = "rec.csv") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_reads_columns_in_any_order_with_metadata_and_extra_columns(tmp_path: Path) -> None:
    rec = read_recording(write(tmp_path, GOOD))
    assert rec.metadata == {"source": "bench rig 2", "sample_rate_hz": 2000}
    np.testing.assert_allclose(rec.drive, [0.0, 0.00012, 0.0003])
    assert rec.drive_name == "current_A"
    np.testing.assert_allclose(rec.stress_MPa, -15.2)
    assert "force_N" in rec.columns


def test_voltage_drive_is_accepted(tmp_path: Path) -> None:
    rec = read_recording(write(tmp_path, "time_s,voltage_V,displacement_um\n0,0,0\n1,1,2\n"))
    assert rec.drive_name == "voltage_V"


@pytest.mark.parametrize("text, message", [
    ("time_s,displacement_um\n0,0\n1,1\n", r"rec\.csv, line 1: missing drive column"),
    ("time_s,current_A\n0,0\n1,1\n", r"rec\.csv, line 1: missing required column 'displacement_um'"),
    ("time,current_A,displacement_um\n0,0,0\n1,1,1\n", r"line 1: column 'time' has no unit \(did you mean 'time_s'\?\)"),
    ("# a: 1\ntime_s,current_A,displacement_um\n0,0,0\n1,abc,1\n", r"line 4: cell 2 'abc' is not a number"),
    ("time_s,current_A,displacement_um\n0,0,0\n1,nan,1\n", r"line 3: 'current_A' is nan"),
    ("time_s,current_A,displacement_um\n0,0,0\n1,1,1\n0.5,2,2\n", r"line 4: time does not increase"),
    ("time_s,current_A,displacement_um\n0,0,0\n1,1\n", r"line 3: 2 cells, header has 3"),
    ("time_s,current_A,displacement_um\n", r"no data rows"),
    ("", r"no header line"),
])
def test_refusals_name_the_file_the_line_and_the_problem(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(RecordingError, match=message):
        read_recording(write(tmp_path, text))


def test_nan_in_an_optional_column_is_carried(tmp_path: Path) -> None:
    rec = read_recording(write(tmp_path, "time_s,current_A,displacement_um,temperature_C\n0,0,0,nan\n1,1,1,25\n"))
    assert np.isnan(rec.columns["temperature_C"][0])


def test_missing_file_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="no such file"):
        read_recording(tmp_path / "nope.csv")


@pytest.mark.parametrize("suffix", [".csv", ".mat"])
def test_write_then_read_round_trips(tmp_path: Path, suffix: str) -> None:
    t = np.linspace(0, 1, 50)
    rec = Recording({"time_s": t, "current_A": np.sin(t), "displacement_um": 3 * t,
                     "stress_MPa": np.full(50, -19.1)}, {"source": "test", "sample_rate_hz": 49})
    path = tmp_path / f"out{suffix}"
    write_recording(path, rec)
    back = read_recording(path)
    for name, values in rec.columns.items():
        np.testing.assert_allclose(back.columns[name], values, rtol=1e-11)
    assert back.metadata["source"] == "test"
    assert not list(tmp_path.glob(".*.tmp"))  # no temporary left behind


def test_written_metadata_is_yaml_readable(tmp_path: Path) -> None:
    rec = Recording({"time_s": [0.0, 1.0], "current_A": [0.0, 1.0], "displacement_um": [0.0, 1.0]},
                    {"note": "contains: a colon", "start_unix_s": 1.7e9, "mass_kg": np.float64(12.5)})
    write_recording(tmp_path / "m.csv", rec)
    assert read_recording(tmp_path / "m.csv").metadata == {"note": "contains: a colon", "start_unix_s": 1.7e9,
                                                           "mass_kg": 12.5}
