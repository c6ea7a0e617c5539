"""The formats labs have (issue 11): TDMS and HDF5 written by their own libraries, a
spreadsheet CSV with a byte-order mark, a ';'-separated one with decimal commas and LabVIEW's
tab-separated text all give the same recording as the plain CSV; bad files get one clear message."""

from __future__ import annotations

import re

import numpy as np
import pytest

from gma_ffc.errors import RecordingError
from gma_ffc.recordings import Recording, read_recording, write_recording

N = 500


@pytest.fixture
def plain(tmp_path):
    t = np.arange(N) / 1000.0
    rec = Recording({"time_s": t, "current_A": 1.5 - 1.5 * np.cos(2 * np.pi * 3 * t),
                     "displacement_um": 20 * np.sin(t) ** 2 + 0.123456789, "stress_MPa": np.full(N, -15.2)},
                    {"source": "bench rig 2"}, "plain.csv")
    write_recording(tmp_path / "plain.csv", rec)
    return read_recording(tmp_path / "plain.csv")


def same(a: Recording, b: Recording, rtol: float = 0.0) -> None:
    assert set(a.columns) == set(b.columns)
    for k in a.columns:
        np.testing.assert_allclose(a.columns[k], b.columns[k], rtol=rtol, atol=0)


def test_tdms_from_nptdms(tmp_path, plain):
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    with TdmsWriter(str(tmp_path / "r.tdms")) as w:
        chans = [ChannelObject("run", k, v, properties={"wf_increment": 0.001}) for k, v in plain.columns.items()
                 if k != "time_s"]
        w.write_segment([RootObject(properties={"operator": "lab"}), GroupObject("run", properties={"rig": 2}),
                         *chans])
    rec = read_recording(tmp_path / "r.tdms")
    same(rec, plain, rtol=1e-12)          # time from wf_increment: i * 0.001 against the CSV's i / 1000
    assert rec.metadata["operator"] == "lab" and rec.metadata["rig"] == 2


def test_tdms_with_two_groups_needs_group(tmp_path, plain):
    from nptdms import ChannelObject, TdmsWriter

    with TdmsWriter(str(tmp_path / "two.tdms")) as w:
        w.write_segment([ChannelObject(g, k, v) for g in ("a", "b") for k, v in plain.columns.items()])
    with pytest.raises(RecordingError, match="choose one with --group"):
        read_recording(tmp_path / "two.tdms")
    same(read_recording(tmp_path / "two.tdms", group="b"), plain)


def test_hdf5_from_h5py(tmp_path, plain):
    import h5py

    with h5py.File(tmp_path / "r.h5", "w") as f:
        g = f.create_group("runs/rig2")
        for k, v in plain.columns.items():
            g[k] = v
        g.attrs["sample_rate_hz"] = 1000.0
    with pytest.raises(RecordingError, match="--group"):
        read_recording(tmp_path / "r.h5")
    rec = read_recording(tmp_path / "r.h5", group="runs/rig2")
    same(rec, plain)
    assert rec.metadata["sample_rate_hz"] == 1000.0


def test_hdf5_group_advice_names_the_groups_that_hold_datasets_and_following_it_reads(tmp_path, plain):
    """It named the root's child groups only: `runs` for data under runs/rig2, and at /runs `runs` again."""
    import h5py

    with h5py.File(tmp_path / "deep.h5", "w") as f:
        for path in ("runs/rig2", "runs/rig3/day1"):
            g = f.create_group(path)
            for k, v in plain.columns.items():
                g[k] = v
        f.create_group("empty/nothing")
    for group in (None, "runs", "nope"):
        with pytest.raises(RecordingError) as err:
            read_recording(tmp_path / "deep.h5", group=group)
        advice = str(err.value).split("choose a group with --group: ")[1]
        assert advice == "runs/rig2, runs/rig3/day1 hold them", advice
        for named in advice.split(" hold")[0].split(", "):
            same(read_recording(tmp_path / "deep.h5", group=named), plain)


def test_spreadsheet_csvs_bom_and_semicolon_with_decimal_commas(tmp_path, plain):
    text = (tmp_path / "plain.csv").read_text()
    (tmp_path / "bom.csv").write_bytes(b"\xef\xbb\xbf" + text.encode())
    same(read_recording(tmp_path / "bom.csv"), plain)
    body = [line for line in text.splitlines() if not line.startswith("#")]
    semi = "\n".join(line.replace(",", ";").replace(".", ",") for line in body) + "\n"
    (tmp_path / "semi.csv").write_bytes(b"\xef\xbb\xbf" + semi.encode())
    same(read_recording(tmp_path / "semi.csv"), plain)


@pytest.mark.parametrize("decimal", [".", ","])
def test_labview_tab_separated_text_with_decimal_points_or_commas(tmp_path, plain, decimal):
    """LabVIEW's spreadsheet files separate cells by tabs (decimal commas in a European locale);
    read as commas, the whole header was one column 'with no unit'."""
    body = [line for line in (tmp_path / "plain.csv").read_text().splitlines() if not line.startswith("#")]
    tab = "\n".join(line.replace(",", "\t").replace(".", decimal) for line in body) + "\n"
    (tmp_path / "rig.txt").write_text(tab)
    same(read_recording(tmp_path / "rig.txt"), plain)


def test_bad_files_of_each_format_get_one_clear_message(tmp_path):
    (tmp_path / "bad.tdms").write_bytes(b"not a tdms file at all")
    (tmp_path / "bad.h5").write_bytes(b"not hdf5")
    (tmp_path / "bad.csv").write_text("time_s;current_A;displacement_um\n0;1,5;2\n1;x;3\n")
    for name, msg in (("bad.tdms", "not a readable TDMS file"), ("bad.h5", "not a readable HDF5 file"),
                      ("bad.csv", "line 3: cell 2 'x' is not a number")):
        with pytest.raises(RecordingError, match=msg) as err:
            read_recording(tmp_path / name)
        assert name in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("final_newline", [True, False])
def test_a_spreadsheet_that_ends_every_line_with_a_delimiter(tmp_path, plain, final_newline):
    """An export with an empty last column (every line ends in ','): the column is dropped, the last
    row kept whether or not the file ends in a newline."""
    body = [line for line in (tmp_path / "plain.csv").read_text().splitlines() if not line.startswith("#")]
    text = "\n".join(line + "," for line in body) + ("\n" if final_newline else "")
    (tmp_path / "export.csv").write_text(text)
    same(read_recording(tmp_path / "export.csv"), plain)
    (tmp_path / "commented.csv").write_text(text.replace("\n", "\n# a note\n", 3))    # the careful parser too
    same(read_recording(tmp_path / "commented.csv"), plain)


def test_a_units_row_is_named_and_deleting_it_reads(tmp_path, plain):
    lines = [line for line in (tmp_path / "plain.csv").read_text().splitlines() if not line.startswith("#")]
    (tmp_path / "units.csv").write_text("\n".join([lines[0], "s,A,um,MPa"] + lines[1:]) + "\n")
    with pytest.raises(RecordingError, match=r"line 2: no cell is a number .* a row of units .* delete the line"):
        read_recording(tmp_path / "units.csv")
    (tmp_path / "units.csv").write_text("\n".join(lines) + "\n")          # the line deleted, as advised
    same(read_recording(tmp_path / "units.csv"), plain)


def test_a_mat_file_has_no_lines_so_its_messages_name_the_sample(tmp_path):
    """A .mat file's messages pointed at 'line 0' (and at lines it does not have); they name the
    file, and a bad sample by its number from 1, as MATLAB indexes it."""
    import scipy.io

    t = np.arange(100) / 1000.0
    y = np.sin(t)
    y[41] = np.nan
    scipy.io.savemat(tmp_path / "nan.mat", {"time_s": t, "current_A": t, "displacement_um": y})
    with pytest.raises(RecordingError, match=r"nan\.mat, sample 42: 'displacement_um' is nan"):
        read_recording(tmp_path / "nan.mat")
    scipy.io.savemat(tmp_path / "bare.mat", {"time": t, "current_A": t, "displacement_um": np.sin(t)})
    with pytest.raises(RecordingError, match=r"bare\.mat: column 'time' has no unit") as err:
        read_recording(tmp_path / "bare.mat")
    assert ", line " not in str(err.value)


# ---- .mat variables that are not one numeric vector: named, with what to save instead
def _mat_signals(n: int = 100) -> dict[str, np.ndarray]:
    t = np.arange(n) / 1000.0
    return {"time_s": t, "current_A": 1.5 - 1.5 * np.cos(2 * np.pi * 3 * t), "stress_MPa": np.full(n, -15.2),
            "displacement_um": 20.0 * np.sin(t)}


def test_a_mat_struct_is_named_and_its_fields_saved_as_variables_read(tmp_path):
    """It got "missing required column 'time_s'; found " with nothing found."""
    import scipy.io

    data = _mat_signals()
    scipy.io.savemat(tmp_path / "struct.mat", {"data": data})
    with pytest.raises(RecordingError, match=re.escape(
            "struct.mat: variable 'data' is a MATLAB struct with fields time_s, current_A, stress_MPa, displacement_um; "
            "gma-ffc reads each column as a variable of its own: save its fields as variables "
            "(in MATLAB, save(f, '-struct', 'data', '-v7'))")):
        read_recording(tmp_path / "struct.mat")
    scipy.io.savemat(tmp_path / "struct.mat", data)           # the fields as variables, as MATLAB's save -struct does
    np.testing.assert_array_equal(read_recording(tmp_path / "struct.mat").stress_MPa, data["stress_MPa"])


@pytest.mark.parametrize("value, words, fixed", [
    (lambda i: np.vstack([i, 2 * i]), "variable 'current_A' is a 2x100 matrix, not one vector; save one row or "
                                      "column of it as 'current_A' (in MATLAB, current_A = current_A(1, :) keeps the "
                                      "first row)", lambda v: v[0]),
    (lambda i: i + 0.5j, "variable 'current_A' is complex; save its real part (in MATLAB, current_A = real(current_A))",
     np.real),
    (lambda i: "0 0.1 0.2", "variable 'current_A' is text ('0 0.1 0.2'), not numbers", None),
    (lambda i: 1.5, "variable 'current_A' is a single value (1.5), not one per sample; save the recorded vector", None),
])
def test_a_mat_drive_that_is_not_one_vector_says_what_it_is_and_saved_as_advised_reads(tmp_path, value, words, fixed):
    """It got 'missing drive column: need current_A ...' although current_A was there."""
    import scipy.io

    data = _mat_signals()
    bad = value(data["current_A"])
    scipy.io.savemat(tmp_path / "odd.mat", {**data, "current_A": bad})
    with pytest.raises(RecordingError, match=re.escape(f"odd.mat: {words}")) as err:
        read_recording(tmp_path / "odd.mat")
    assert "missing" not in str(err.value)
    if fixed is not None:
        scipy.io.savemat(tmp_path / "odd.mat", {**data, "current_A": fixed(bad)})
        np.testing.assert_allclose(read_recording(tmp_path / "odd.mat").drive, data["current_A"])


def test_a_mat_stress_of_one_value_says_how_to_give_a_constant_stress_and_the_vector_reads(tmp_path):
    """It got 'no stress_MPa column' from simulate, and an MPI without a word from identify."""
    import scipy.io

    data = _mat_signals()
    scipy.io.savemat(tmp_path / "one.mat", {**data, "stress_MPa": -15.2})
    for require in (("time_s", "drive", "displacement_um"), ("time_s", "drive")):
        with pytest.raises(RecordingError, match=re.escape(
                "one.mat: variable 'stress_MPa' is a single value (-15.2), not one per sample; for a constant stress, "
                "save it as a vector as long as time_s (in MATLAB, stress_MPa = repmat(-15.2, size(time_s))), or, "
                "for simulate and invert, leave it out and pass --stress -15.2")):
            read_recording(tmp_path / "one.mat", require=require)
    scipy.io.savemat(tmp_path / "one.mat", {**data, "stress_MPa": np.full(data["time_s"].shape, -15.2)})  # repmat
    np.testing.assert_array_equal(read_recording(tmp_path / "one.mat").stress_MPa, -15.2)


def test_other_mat_variables_that_are_not_vectors_are_still_metadata_or_ignored(tmp_path):
    import scipy.io

    scipy.io.savemat(tmp_path / "extra.mat", {**_mat_signals(), "gain": 2.0, "note": "rig 2",
                                               "image": np.ones((3, 4)), "info": {"operator": "A"}})
    rec = read_recording(tmp_path / "extra.mat")
    assert rec.metadata == {"gain": 2.0, "note": "rig 2"} and "image" not in rec.columns
