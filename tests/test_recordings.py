"""The recording format of shared/spec/recordings.md: what is accepted, what is refused and how."""

from __future__ import annotations

import re
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
    ("time_s,current_A,displacement_um\n0,0,0\n1,,1\n", r"line 3: 'current_A' is nan or empty"),
    ("time_s,current_A,displacement_um\n0,0,0\n1,x,\n", r"line 3: cell 2 'x' is not a number"),
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


@pytest.mark.parametrize("rows", ["0,0,0,\n1,1,1,25\n", "0,0,0,\n# a comment: the careful parser\n1,1,1,25\n"])
def test_an_empty_cell_in_an_optional_column_is_a_missing_value(tmp_path: Path, rows: str) -> None:
    rec = read_recording(write(tmp_path, "time_s,current_A,displacement_um,temperature_C\n" + rows))
    assert np.isnan(rec.columns["temperature_C"][0]) and rec.columns["temperature_C"][1] == 25


def test_a_value_that_does_not_exist_is_written_as_an_empty_cell_and_read_back(tmp_path: Path) -> None:
    rec = Recording({"time_s": np.arange(3.0), "current_A": np.ones(3), "displacement_um": np.ones(3),
                     "residual_um": np.array([np.nan, 1.0, np.inf])}, {"source": "test"})
    write_recording(tmp_path / "out.csv", rec)
    text = (tmp_path / "out.csv").read_text()
    assert "nan" not in text.lower() and "inf" not in text.lower()
    back = read_recording(tmp_path / "out.csv")
    assert np.isnan(back.columns["residual_um"][[0, 2]]).all() and back.columns["residual_um"][1] == 1.0


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


@pytest.mark.parametrize("glitch", [9.9e37, 1e12, 1e4, -1e4])
def test_a_displacement_spike_is_refused_naming_its_line(tmp_path: Path, glitch: float) -> None:
    """One overload value (9.9e37) or dropped digit sent identify in circles ('fit fewer dead-zones'
    again and again) and gave simulate an RMS of 1.9e36 um."""
    t = np.arange(400) / 1000.0
    x = 1.5 - 1.5 * np.cos(2 * np.pi * 3 * t)
    y = 20 * x + 0.03 * np.random.default_rng(1).standard_normal(t.size)
    y[123] = glitch
    path = tmp_path / "glitch.csv"
    write_recording(path, Recording({"time_s": t, "current_A": x, "displacement_um": y}, {}, "glitch.csv"))
    header = next(i for i, line in enumerate(path.read_text().splitlines(), 1) if line.startswith("time_s"))
    with pytest.raises(RecordingError, match=rf"glitch\.csv, line {header + 124}: 'displacement_um' is "
                                             rf"{re.escape(f'{glitch:.6g}')}, more than .* from both its neighbours.*"
                                             r"a sensor overload value or a glitch; fix or remove"):
        read_recording(path)


def test_a_step_of_a_whole_stroke_is_not_a_spike(tmp_path: Path) -> None:
    """A step drive moves the displacement a whole stroke within a sample, and a brief pulse is rare
    among the samples: neither is a glitch."""
    y = np.zeros(5000)
    y[2500:2510] = 50.0                                # 10 samples up: 0.2 % of the column
    y[4000] = 5.0                                      # one sample, a blip under the 1 um floor's reach
    path = tmp_path / "steps.csv"
    write_recording(path, Recording({"time_s": np.arange(5000) / 1e3, "current_A": y / 20, "displacement_um": y},
                                    {}, "steps.csv"))
    assert len(read_recording(path)) == 5000
@pytest.mark.parametrize("name, words", [
    ("out.h5", "got '.h5'; name it {d}/out.csv"), ("out.tdms", "got '.tdms'"), ("out.txt", "got '.txt'"),
    ("out", "got no extension; name it {d}/out.csv"),
])
def test_an_output_name_gma_ffc_would_not_read_back_is_refused(tmp_path: Path, name: str, words: str) -> None:
    """`-o x.h5` wrote CSV text under a name the HDF5 reader then refused."""
    rec = Recording({"time_s": np.arange(3.0), "current_A": np.zeros(3), "displacement_um": np.zeros(3)})
    with pytest.raises(RecordingError, match=re.escape(words.format(d=tmp_path))):
        write_recording(tmp_path / name, rec)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("mu", ["\u00b5", "\u03bc"])
def test_a_micro_sign_in_a_unit_is_answered_with_its_ascii_name(tmp_path: Path, mu: str) -> None:
    path = tmp_path / "mu.csv"
    path.write_text(f"time_s,current_A,displacement_{mu}m\n0,0,0\n0.001,0.1,1\n", encoding="utf-8")
    with pytest.raises(RecordingError, match=f"column 'displacement_{mu}m' has no unit \\(did you mean 'displacement_um'\\?\\)"):
        read_recording(path)


def test_rows_keeps_every_column_and_the_metadata_of_the_samples_kept() -> None:
    t = np.arange(10) * 0.1
    rec = Recording({"time_s": t, "current_A": t * 2, "displacement_um": t * 3}, {"load_kg": 12.0}, "/data/run.csv")
    keep = (t >= 0.25) & (t < 0.75)
    part = rec.rows(keep, "part.csv")
    assert part.name == "part.csv" and part.metadata == {"load_kg": 12.0} and part.metadata is not rec.metadata
    assert set(part.columns) == set(rec.columns)
    assert np.array_equal(part.time_s, t[keep]) and np.array_equal(part.drive, 2 * t[keep])
    assert rec.rows(keep).source == "/data/run.csv"


# ---- times as text: a logger's absolute timestamps keep their digits
from hypothesis import given, strategies as st  # noqa: E402

from gma_ffc.recordings import gap_note, time_text  # noqa: E402


@given(st.floats(0.0, 2e9), st.floats(1e-6, 10.0))
def test_a_time_as_text_reads_back_to_within_half_its_step(t, step):
    assert abs(float(time_text(t, step)) - t) <= step / 2 * 1.003 + 1e-15 * t   # 0.1 % in the log: time_text


def test_two_samples_of_an_absolute_timestamp_read_apart():
    """Significant digits printed 1.7e+09 for both ends of a located window."""
    t0 = 1_700_000_000.0
    assert time_text(t0, 5e-4) != time_text(t0 + 5e-4, 5e-4)
    assert time_text(33.6234, 0.042) == "33.62"        # a window's ends, as before, on a recording from zero


def test_a_gap_in_a_timestamped_recording_is_placed_to_the_sample():
    t = 1_700_000_000.0 + np.r_[np.arange(0, 10, 0.01), np.arange(12, 20, 0.01)]
    rec = Recording({"time_s": t, "current_A": np.zeros(t.size), "displacement_um": np.zeros(t.size)}, {}, "log.csv")
    assert "at t = 1700000009.99 s" in gap_note(rec)


# ---- column names a lab's logger writes: the advice names the fix, and the fix reads
def _logged(tmp_path, header: str, scale_time: float = 1.0) -> Path:
    t = np.arange(50) * 1e-3 * scale_time
    rows = "\n".join(f"{a:.6f},{0.5 + 0.4 * np.sin(a):.6f},{np.sin(3 * a):.6f}" for a in t)
    path = tmp_path / "log.csv"
    path.write_text(f"{header}\n{rows}\n")
    return path


def _advised_fix(message: str) -> tuple[str, str]:
    m = re.search(r"rename it '?([A-Za-z_]+)'?", message)
    return m.group(1), m.group(0)


def test_units_in_brackets_are_named_and_renaming_as_advised_reads(tmp_path):
    path = _logged(tmp_path, "Time (s),Current (A),Displacement (um)")
    with pytest.raises(RecordingError, match=r"rename it 'time_s' \(and the other columns likewise\)"):
        read_recording(path)
    path.write_text(path.read_text().replace("Time (s),Current (A),Displacement (um)",
                                             "time_s,current_A,displacement_um"))
    assert len(read_recording(path)) == 50


def test_a_name_in_another_case_is_named_and_renaming_reads(tmp_path):
    path = _logged(tmp_path, "Time_s,current_A,displacement_um")
    with pytest.raises(RecordingError, match="Time_s: rename it time_s") as err:
        read_recording(path)
    want, _ = _advised_fix(str(err.value))
    path.write_text(path.read_text().replace("Time_s", want))
    assert len(read_recording(path)) == 50


def test_time_in_ms_says_how_to_convert_and_the_conversion_reads(tmp_path):
    path = _logged(tmp_path, "time_ms,current_A,displacement_um", scale_time=1000.0)
    with pytest.raises(RecordingError, match="time_ms is in ms, gma-ffc reads s: divide it by 1000 into a column named time_s"):
        read_recording(path)
    t_ms, current, disp = np.loadtxt(path, delimiter=",", skiprows=1, unpack=True)   # converted as advised
    fixed = Recording({"time_s": t_ms / 1000, "current_A": current, "displacement_um": disp}, {}, "fixed.csv")
    write_recording(tmp_path / "fixed.csv", fixed)
    np.testing.assert_allclose(read_recording(tmp_path / "fixed.csv").time_s, np.arange(50) * 1e-3)


def test_a_displacement_in_mm_is_not_read_silently(tmp_path):
    """Optional for simulate, so not refused; but a note says it was not compared, and how to fix it."""
    path = _logged(tmp_path, "time_s,current_A,displacement_mm")
    rec = read_recording(path, require=("time_s", "drive"))
    assert any("displacement_mm is in mm, gma-ffc reads um: multiply it by 1000" in n for n in rec.notes)


def test_invert_on_a_measured_run_says_how_to_make_it_a_reference(tmp_path):
    path = _logged(tmp_path, "time_s,current_A,displacement_um")
    with pytest.raises(RecordingError, match="copy its displacement_um into a column named reference_um"):
        read_recording(path, require=("time_s", "reference_um"))
    t, _, disp = np.loadtxt(path, delimiter=",", skiprows=1, unpack=True)            # done as advised
    write_recording(tmp_path / "ref.csv", Recording({"time_s": t, "reference_um": disp}, {}, "ref.csv"))
    assert len(read_recording(tmp_path / "ref.csv", require=("time_s", "reference_um"))) == 50


@pytest.mark.parametrize("column, value", [("time_s", 2e11), ("current_A", -2e6), ("voltage_V", 3e6),
                                           ("displacement_um", 2e9), ("stress_MPa", -2e6)])
def test_a_value_beyond_a_columns_physical_bound_is_refused_naming_the_line(tmp_path: Path, column: str,
                                                                            value: float) -> None:
    drive = "voltage_V" if column == "voltage_V" else "current_A"
    cols = {"time_s": [0.0, 1.0, 2.0, 3.0], drive: [0.0, 1.0, 2.0, 1.0], "displacement_um": [0.0, 1.0, 2.0, 1.0],
            "stress_MPa": [-10.0] * 4}
    cols[column][3] = value
    text = ",".join(cols) + "\n" + "".join(",".join(repr(cols[c][k]) for c in cols) + "\n" for k in range(4))
    with pytest.raises(RecordingError, match=rf"rec\.csv, line 5: '{column}' is {re.escape(f'{value:.6g}')}, "
                                             r"beyond any physical .*remove that row"):
        read_recording(write(tmp_path, text))
    cols[column][3] = value / 1e3 if column != "time_s" else 3.0     # within the bound: read
    text = ",".join(cols) + "\n" + "".join(",".join(repr(cols[c][k]) for c in cols) + "\n" for k in range(4))
    assert len(read_recording(write(tmp_path, text))) == 4


# ---- a stress column under another name was ignored, and the recording modelled without stress
def _with_stress_as(tmp_path, name: str, scale: float) -> Path:
    """A recording at -15.2 MPa whose stress column is `name`, its values in that column's unit."""
    t = np.arange(50) * 1e-3
    rows = "\n".join(f"{a:.6f},{0.5 + 0.4 * np.sin(a):.6f},{-15.2 * scale:.6g},{np.sin(3 * a):.6f}" for a in t)
    path = tmp_path / "stress.csv"
    path.write_text(f"time_s,current_A,{name},displacement_um\n{rows}\n")
    return path


@pytest.mark.parametrize("name, scale, advice", [
    ("Stress_MPa", 1.0, "Stress_MPa: rename it stress_MPa (names are case-sensitive)"),
    ("stress_mpa", 1.0, "stress_mpa: rename it stress_MPa (names are case-sensitive)"),
    ("sigma_MPa", 1.0, "sigma_MPa: rename it stress_MPa"),
    ("stress_N/mm^2", 1.0, "stress_N/mm^2: rename it stress_MPa (1 N/mm^2 is 1 MPa)"),
    ("stress_kPa", 1e3, "stress_kPa is in kPa, gma-ffc reads MPa: divide it by 1000 into a column named stress_MPa"),
    ("stress_kpa", 1e3, "stress_kpa is in kpa, gma-ffc reads MPa: divide it by 1000 into a column named stress_MPa"),
    ("sigma_kPa", 1e3, "sigma_kPa is in kPa, gma-ffc reads MPa: divide it by 1000 into a column named stress_MPa"),
    ("stress_Pa", 1e6, "stress_Pa is in Pa, gma-ffc reads MPa: divide it by 1e+06 into a column named stress_MPa"),
    ("stress_GPa", 1e-3, "stress_GPa is in GPa, gma-ffc reads MPa: multiply it by 1000 into a column named stress_MPa"),
])
def test_a_stress_under_another_name_is_refused_naming_the_fix_and_the_fix_reads(tmp_path, name, scale, advice):
    """Read as an unknown column it was dropped, and identify fitted a stress-independent MPI."""
    path = _with_stress_as(tmp_path, name, scale)
    why = f"column '{name}' is named with a unit gma-ffc does not read" if "/" in name else "no stress_MPa column"
    for require in (("time_s", "drive", "displacement_um"), ("time_s", "drive")):
        with pytest.raises(RecordingError, match=re.escape(f"stress.csv, line 1: {why}; {advice}")):
            read_recording(path, require=require)
    lines = path.read_text().splitlines()
    factor = 1.0 / scale                                              # done as advised
    rows = [",".join(c if i != 2 else repr(float(c) * factor) for i, c in enumerate(ln.split(","))) for ln in lines[1:]]
    path.write_text("\n".join([lines[0].replace(name, "stress_MPa"), *rows]) + "\n")
    np.testing.assert_allclose(read_recording(path).stress_MPa, -15.2)


def test_a_misnamed_stress_dropped_as_advised_reads_without_stress(tmp_path):
    path = _with_stress_as(tmp_path, "Stress_MPa", 1.0)
    with pytest.raises(RecordingError, match="or drop that column to model the recording stress-independently"):
        read_recording(path)
    t, current, _, disp = np.loadtxt(path, delimiter=",", skiprows=1, unpack=True)
    write_recording(path, Recording({"time_s": t, "current_A": current, "displacement_um": disp}, {}, str(path)))
    assert read_recording(path).stress_MPa is None


@pytest.mark.parametrize("name", ["stress_est_MPa", "force_N", "stress_level", "temperature_C"])
def test_columns_that_are_not_the_stress_are_still_carried_without_a_word(tmp_path, name):
    rec = read_recording(_with_stress_as(tmp_path, name, 1.0))
    assert name in rec.columns and rec.stress_MPa is None and rec.notes == []


def test_a_commanded_current_alone_is_told_to_be_named_current_a_and_renamed_it_reads(tmp_path):
    """The spec: current_A is the current measured, 'else commanded'; current_cmd_A is the commanded
    one when current_A is the measured. A file with only the commanded current names it current_A."""
    path = _logged(tmp_path, "time_s,current_cmd_A,displacement_um")
    with pytest.raises(RecordingError, match=re.escape(
            "current_cmd_A: rename it current_A (a commanded current is the drive when the rig measures none")) as err:
        read_recording(path)
    want, _ = _advised_fix(str(err.value))
    path.write_text(path.read_text().replace("current_cmd_A", want))
    assert read_recording(path).drive_name == "current_A"
