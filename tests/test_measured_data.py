"""The measured recording the tests use is there in every checkout, and is the one in ../shared."""

from __future__ import annotations

from pathlib import Path

import pytest

import measured


@pytest.mark.skipif(not measured.SHARED_PIEZO.exists(),
                    reason="no ../shared beside this checkout: nothing to compare the vendored copy with")
def test_the_vendored_piezo_recording_is_byte_for_byte_shared_s():
    assert measured.vendored_piezo_bytes() == measured.SHARED_PIEZO.read_bytes()


def test_without_shared_the_tests_read_the_vendored_copy(tmp_path, monkeypatch):
    monkeypatch.setattr(measured, "SHARED_PIEZO", tmp_path / "nowhere" / "piezo_150V_1Hz.csv")
    path = measured.piezo_csv(tmp_path)
    assert path.parent == tmp_path and path.read_bytes() == measured.vendored_piezo_bytes()
    assert path.read_text().splitlines()[3] == "time_s,voltage_V,displacement_um"


def test_with_neither_copy_the_measured_data_tests_fail_rather_than_skip(tmp_path, monkeypatch):
    monkeypatch.setattr(measured, "SHARED_PIEZO", tmp_path / "nowhere" / "a.csv")
    monkeypatch.setattr(measured, "VENDORED_PIEZO", tmp_path / "nowhere" / "a.csv.xz")
    with pytest.raises(FileNotFoundError, match="neither"):
        measured.piezo_csv(tmp_path)


def test_every_test_finds_the_measured_recording_through_the_fixture():
    """A test that looks for ../shared itself could skip when it is missing: only measured.py may."""
    for path in Path(__file__).parent.glob("*.py"):
        if path.name not in ("measured.py", Path(__file__).name):
            assert '"shared" / "data"' not in path.read_text(), f"{path.name}: use the piezo_csv fixture"
