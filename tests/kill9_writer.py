"""kill -9 at random moments while the controller writes telemetry and saves its learned correction
and a model file (issue 33), and what each kill left behind.

Run by tests/test_kill9.py as `python kill9_writer.py WORK KILLS SEED`: it loads the model, warms
every compiled path up with a short run, builds the controller once, then forks KILLS writers one
after another, each a copy of that controller. Each writer runs it (simulated clock, flat out,
learning on, telemetry flushed every 10 ms) while a second thread
saves the learned correction (`save_learned`) and a model file (`save_model`, as `identify` does)
over and over; it is killed with SIGKILL after a random delay. After each kill this process
checks the files through the same code users run: `gma-ffc simulate` on the telemetry (a torn
last line is reported, not fatal), the controller's own loader on the learned file, `load_model`
on the model file. One JSON line per kill on stdout.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import random
import signal
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "config" / "models" / "sim_sdpi.yaml"
RATE_HZ = 1000
KILL_AFTER_S = (0.03, 0.3)       # from the fork: through many flushes and saves


def make_config(work: Path):
    from gma_ffc.control.config import validate_config

    return validate_config({
        "rate_hz": RATE_HZ, "clock": "simulated", "model": str(MODEL),
        "driver": {"kind": "sim", "load_mass_kg": 15.3},
        "reference": {"kind": "sine", "frequency_hz": 20.0, "amplitude_um": 5.0, "offset_um": 6.0},
        "limits": {"current_min_A": 0.0, "current_max_A": 2.0, "slew_A_per_s": 200.0},
        "telemetry": {"path": str(work / "tel.csv"), "flush_interval_s": 0.01, "buffer_s": 0.2},
        "learning": {"kind": "repetitive", "file": str(work / "learned.yaml")},
        "output_dirs": [str(work)],
    }, source=str(work / "rig.yaml"))


def writer(ctrl, cfg, model, work: Path) -> None:
    """The forked child: the controller's loop plus a thread saving both files, until killed."""
    from gma_ffc.control.learned_file import save_learned
    from gma_ffc.modelio import save_model

    def save_forever() -> None:
        while True:
            if ctrl.setup.law.learner is not None:
                save_learned(ctrl.setup.law.learner, cfg.learning.file, cfg.output_dirs)
            save_model(model, work / "model.yaml")

    threading.Thread(target=save_forever, daemon=True).start()
    ctrl.run(duration_s=None)


def _time_column(tel: Path) -> np.ndarray:
    """The telemetry's time column as it reads back. A kill just after the first flush can leave one
    whole row: a recording too short to simulate (simulate refuses it in one line), not a torn file."""
    import numpy as np

    from gma_ffc.errors import RecordingError
    from gma_ffc.recordings import read_recording

    try:
        return read_recording(tel).time_s
    except RecordingError as exc:
        if "needs at least two samples, has 1" not in str(exc):
            raise
    rows = [line for line in tel.read_text().splitlines() if line and not line.startswith("#")]
    return np.array([float(rows[1].split(",")[0])])      # rows[0] is the header


def check(cfg, model, work: Path) -> dict:
    """What one kill left: each file read back by the code that reads it in use."""
    import numpy as np

    from gma_ffc.cli import main
    from gma_ffc.control.builder import make_learner
    from gma_ffc.control.reference import build_reference
    from gma_ffc.errors import GmaError
    from gma_ffc.modelio import load_model
    from gma_ffc.recordings import read_recording

    out: dict = {"temporaries_left": len([p for p in work.iterdir() if p.name.endswith(".tmp")])}
    tel = work / "tel.csv"
    data = tel.read_bytes() if tel.exists() else b""
    out["telemetry_bytes"] = len(data)
    out["torn"] = bool(data) and not data.endswith(b"\n")
    if data:                             # the header goes out with the first rows: a file has rows or is empty
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            out["simulate_exit"] = main(["simulate", "--model", str(MODEL), str(tel), "-o", str(work / "sim.csv"),
                                         "--initial-state", "relaxed"])
        out["torn_reported"] = "is incomplete" in err.getvalue()
        out["simulate_error"] = err.getvalue().strip()[-300:] if out["simulate_exit"] else ""
        time_s = _time_column(tel)
        steps = np.diff(time_s)
        out["rows"] = len(time_s)
        out["contiguous_from_0"] = bool(time_s[0] == 0.0 and np.all(np.abs(steps - 1.0 / RATE_HZ) < 1e-6))
    else:
        out["rows"] = 0                  # killed before the first flush: nothing to read back yet
    learned = Path(cfg.learning.file)
    out["learned_saved"] = learned.exists()
    if learned.exists():
        try:
            make_learner(cfg, model, build_reference(cfg.reference, model.preview_s))
            out["learned_whole"] = True
        except GmaError as exc:
            out["learned_whole"] = False
            out["learned_error"] = str(exc)
    out["model_saved"] = (work / "model.yaml").exists()
    if out["model_saved"]:
        try:
            load_model(work / "model.yaml")
            out["model_whole"] = True
        except GmaError as exc:
            out["model_whole"] = False
            out["model_error"] = str(exc)
    return out


def main(argv: list[str]) -> int:
    work, kills, seed = Path(argv[0]), int(argv[1]), int(argv[2])
    started = time.monotonic()
    from gma_ffc.control.manager import ControllerManager as Controller
    from gma_ffc.modelio import load_model

    model = load_model(MODEL)
    warm = work / "warm-up"
    warm.mkdir()
    Controller(make_config(warm), model=model).run(duration_s=0.05)    # every compiled path, once
    cfg = make_config(work)
    ctrl = Controller(cfg, model=model)  # each child runs its own copy of this one
    rng = random.Random(seed)
    for i in range(kills):
        delay = rng.uniform(*KILL_AFTER_S)
        pid = os.fork()
        if pid == 0:
            try:
                writer(ctrl, cfg, model, work)
            finally:
                os._exit(0)
        time.sleep(delay)
        os.kill(pid, signal.SIGKILL)
        _, status = os.waitpid(pid, 0)
        result = {"kill": i, "after_s": round(delay, 3), "killed": os.WIFSIGNALED(status), **check(cfg, model, work),
                  "elapsed_s": round(time.monotonic() - started, 2)}
        print(json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
