"""numba's kernel cache on a read-only install: numba itself gives up with "no locator available"
at import; gma_ffc points it at a private per-user directory instead, and only there."""

from __future__ import annotations

import os
import stat
import subprocess
import sys

import pytest

import gma_ffc


@pytest.fixture
def nowhere_writable(monkeypatch, tmp_path):
    """The package folder and ~/.cache read-only; the temp dir is tmp_path."""
    real = gma_ffc._writable
    monkeypatch.setenv("NUMBA_CACHE_DIR", "")                  # unset, and restored after the test
    monkeypatch.setattr(gma_ffc, "_writable", lambda p: str(p).startswith(str(tmp_path)) and real(p))
    monkeypatch.setattr("tempfile.gettempdir", lambda: str(tmp_path))
    monkeypatch.setitem(sys.modules, "numba", None)          # as if numba were not imported yet
    return tmp_path


def test_a_private_directory_when_nothing_else_is_writable(nowhere_writable):
    gma_ffc._numba_cache_dir()
    private = os.environ["NUMBA_CACHE_DIR"]
    assert os.path.dirname(private) == str(nowhere_writable)
    assert stat.S_IMODE(os.stat(private).st_mode) == 0o700


def test_never_a_directory_others_can_write(nowhere_writable):
    d = nowhere_writable / f"gma-ffc-numba-{os.getuid()}"
    d.mkdir(mode=0o777)
    os.chmod(d, 0o777)
    gma_ffc._numba_cache_dir()
    assert not os.environ["NUMBA_CACHE_DIR"]


def test_the_users_choice_wins(nowhere_writable, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", "/somewhere/else")
    gma_ffc._numba_cache_dir()
    assert os.environ["NUMBA_CACHE_DIR"] == "/somewhere/else"


def test_a_writable_install_keeps_numbas_own_place(monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", "")
    monkeypatch.setattr(gma_ffc, "_writable", lambda p: True)
    gma_ffc._numba_cache_dir()
    assert not os.environ["NUMBA_CACHE_DIR"]


def test_no_warning_reaches_the_user(tmp_path):
    """A fresh process with an empty cache compiles and says nothing on stderr (run twice:
    compiling, then loading)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"), PYTHONWARNINGS="default")
    code = ("import numpy as np; from gma_ffc.modelio import load_model; from pathlib import Path; "
            f"m = load_model(Path({str(gma_ffc.__file__)!r}).parents[1] / 'config/models/sim_sdpi.yaml'); "
            "m.simulate(np.arange(3.0), np.zeros(3), -15.0, initial_state='estimate', measured_um=np.zeros(3))")
    for _ in range(2):
        run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
        assert run.returncode == 0, run.stderr
        assert run.stderr == ""
