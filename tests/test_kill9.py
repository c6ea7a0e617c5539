"""kill -9 at a random moment, 50 times, while the controller writes telemetry and saves its
learned correction and a model file (issue 33; tests/kill9_writer.py does the killing). After
every kill the telemetry reads back with `gma-ffc simulate` (a torn last line reported, not
fatal), and the learned file and the model file are whole."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gma_ffc.cli import main
from gma_ffc.recordings import read_recording

HERE = Path(__file__).parent
MODEL = HERE.parent / "config" / "models" / "sim_sdpi.yaml"
KILLS = 50


# real time: the kills land 0.03-0.3 s into each run by the wall clock, so on a busy machine more of
# them land before the first write, and the share read back (asserted: at least half) falls
@pytest.mark.realtime
@pytest.mark.slow
def test_kill_9_fifty_times_leaves_every_file_readable(tmp_path, capsys):
    res = subprocess.run([sys.executable, str(HERE / "kill9_writer.py"), str(tmp_path), str(KILLS), "33"],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    kills = [json.loads(line) for line in res.stdout.splitlines()]
    assert len(kills) == KILLS and all(k["killed"] for k in kills)
    for k in kills:
        if k["telemetry_bytes"] and k["rows"] == 1:      # killed after the first row: whole, too short to simulate
            assert k["simulate_exit"] == 2 and "at least two samples" in k["simulate_error"], k
            assert k["contiguous_from_0"], k
        elif k["telemetry_bytes"]:
            assert k["simulate_exit"] == 0, k
            assert k["rows"] > 0 and k["contiguous_from_0"], k
            assert k["torn_reported"] == k["torn"], k
        if k["learned_saved"]:
            assert k["learned_whole"], k
        if k["model_saved"]:
            assert k["model_whole"], k
    read_back = sum(1 for k in kills if k["telemetry_bytes"])
    saved = sum(1 for k in kills if k["learned_saved"] and k["model_saved"])
    assert read_back >= KILLS // 2 and saved >= KILLS // 2        # the kills did land among the writes
    with capsys.disabled():
        print(f"\nkill -9 x{KILLS}: telemetry read back {read_back} times ({sum(k['torn'] for k in kills)} with a torn "
              f"last line, reported), median {np.median([k['rows'] for k in kills]):.0f} rows; learned and model "
              f"files whole every time they existed ({saved}); killed mid-save (temporaries left): "
              f"{kills[-1]['temporaries_left']}")


@pytest.mark.parametrize("cut", [3, 10])
def test_a_torn_last_line_is_reported_and_left_out(tmp_path, capsys, cut):
    """Deterministic: a telemetry file cut inside its last line (as a kill between two pages of a
    write leaves it) reads back without that line, and simulate says so on stderr."""
    rows = "\n".join(f"{k * 0.001:.9g},{0.1 * k:.9g},-15.2,{1.5 * k:.9g}" for k in range(50))
    text = "# source: gma-ffc controller\n# config: rig.yaml\ntime_s,current_A,stress_MPa,displacement_um\n" + rows + "\n"
    path = tmp_path / "tel.csv"
    path.write_bytes(text.encode()[:-cut])
    rec = read_recording(path)
    assert len(rec) == 49 and rec.notes and "line 53" in rec.notes[0] and "incomplete" in rec.notes[0]
    assert main(["simulate", "--model", str(MODEL), str(path), "-o", str(tmp_path / "p.csv"),
                 "--initial-state", "relaxed"]) == 0
    err = capsys.readouterr().err
    assert err.count("note:") == 1 and "tel.csv: the last line (line 53) is incomplete" in err


def test_a_csv_without_its_final_newline_keeps_its_last_row(tmp_path):
    """A spreadsheet export often lacks the final newline: a whole last row is data, kept."""
    path = tmp_path / "export.csv"
    path.write_text("time_s,current_A,displacement_um\n0,0,0\n0.001,0.1,0.2\n0.002,0.2,0.4")
    rec = read_recording(path)
    assert len(rec) == 3 and rec.notes == []
