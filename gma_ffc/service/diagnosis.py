"""Diagnosis in the background: when the model-fit monitor has been drifting for `trigger_s`, the
service writes the last `window_s` of telemetry as a recording in its state directory and runs
`gma-ffc diagnose` on it in a child process (nice 19, SCHED_OTHER, bound to the service: see
`diagnose_child`), one at a time and at most `max_per_hour`. The status names the outcome, the
effects and where the report is. The model-fit monitor knows the hysteresis state at the window's
first sample (it followed the plays since the run started): it is written beside the window as
initial_state.json and given to diagnose (`--initial-state plays:FILE`), so every sample of the
window is scored, however little of the drive range the run sweeps. Nothing here changes the
running model: `gma-ffc reload --model DIR/extended_model.yaml` adopts the extended model, after
the checks of any reload.

The service calls `poll` from its supervising thread (never the loop's) a few times a second; it
does nothing unless a child finished or a drift has lasted long enough. `close` kills the child.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

from .daemon import _last_error as last_error_line
from .status import summary_words

log = logging.getLogger("gma_ffc.service")

HOUR_S = 3600.0
KILL_GRACE_S = 2.0          # SIGTERM, then SIGKILL after this: diagnose writes nothing worth waiting for
# One thread each for the diagnosis' searches (GMA_FFC_CPUS: it also caps the BLAS threads it
# asks for), numpy's BLAS, OpenMP and numba in the child: on the two cores of a lab PC the
# diagnosis then never takes both, whatever its niceness.
SINGLE_THREAD = {"GMA_FFC_CPUS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                 "NUMBA_NUM_THREADS": "1", "MPLBACKEND": "Agg", "GMA_FFC_PROGRESS": "lines"}


@dataclass
class Window:
    """What the loop kept: the last seconds of telemetry as a recording, and the running model."""

    recording: Any        # gma_ffc.recordings.Recording
    model: Any            # the running model (an extended model is diagnosed through its base)
    start: dict[str, Any] | None = None   # the base's play state at the first sample, when known


def default_state_dir(environ: dict[str, str] | None = None) -> Path:
    """$STATE_DIRECTORY (systemd's StateDirectory=), else $XDG_STATE_HOME/gma-ffc, else
    ~/.local/state/gma-ffc; /var/lib/gma-ffc for root."""
    env = os.environ if environ is None else environ
    if env.get("STATE_DIRECTORY"):
        return Path(env["STATE_DIRECTORY"].split(":")[0])
    if env.get("XDG_STATE_HOME"):
        return Path(env["XDG_STATE_HOME"]) / "gma-ffc"
    if os.geteuid() == 0:
        return Path("/var/lib/gma-ffc")
    return Path.home() / ".local" / "state" / "gma-ffc"


def state_dir_for(monitor_cfg: dict[str, Any], output_dirs: Sequence[str] = ()) -> Path:
    """`monitor.state_dir`, else the default (`default_state_dir`), unless the config names output_dirs
    and the default lies outside them: then the first of them. Every background diagnosis of a
    config with output_dirs and no state_dir (the shipped config/sim.yaml's) failed, hours into the
    run, on "outside the directories the config names for output"."""
    from ..safe_files import OutputRefused, area_of

    if monitor_cfg.get("state_dir"):
        return Path(monitor_cfg["state_dir"])
    default = default_state_dir()
    if output_dirs:
        try:
            area_of(default / "diagnoses", output_dirs)      # as each diagnosis checks it
        except OutputRefused:
            return Path(output_dirs[0])
    return default


def check_state_dir(monitor_cfg: dict[str, Any] | None, output_dirs: Sequence[str] = ()) -> None:
    """With background diagnoses on, refuse at start a state folder they could not be written in
    (read-only, not this user's, a file in the way): it was found only when the first diagnosis
    started, maybe hours into the run. The probe is `atomic.check_folder_writable`'s."""
    from ..atomic import check_folder_writable
    from ..errors import ConfigError, InputError

    cfg = monitor_cfg or {}
    if not (cfg.get("enabled") and cfg.get("on_drift") == "diagnose" and cfg.get("max_per_hour", 0) > 0):
        return
    folder = state_dir_for(cfg, output_dirs)
    unset = "" if cfg.get("state_dir") else f" (not set: the default {folder})"
    try:
        check_folder_writable(folder / "diagnoses", f"config key 'monitor.state_dir'{unset}")
    except InputError as exc:
        raise ConfigError(f"{exc}; background diagnoses (monitor.on_drift: diagnose) are written in {folder}: set "
                          "monitor.state_dir to a folder this user may write, or monitor.on_drift: warn") from None


class BackgroundDiagnosis:
    """Starts, watches and reports the diagnosis child; see the module doc."""

    def __init__(self, monitor_cfg: dict[str, Any], take_window: Callable[[float], Window], *,
                 python: str = sys.executable, now: Callable[[], float] = time.time,
                 output_dirs: tuple[str, ...] = (), drive_limits: tuple[float, float] | None = None) -> None:
        self.cfg = monitor_cfg
        self.drive_limits = drive_limits        # the controller's: the advice asks for no drive beyond them
        self.output_dirs = output_dirs          # the config's: a diagnosis writes only inside them
        self.take_window = take_window
        self.python = python
        self.now = now
        self.state_dir = state_dir_for(monitor_cfg, output_dirs)
        self.child: subprocess.Popen | None = None
        self.started: list[float] = []          # wall-clock starts within the last hour
        self.diagnosed_episode: float | None = None
        self.current: dict[str, Any] | None = None
        self.last: dict[str, Any] | None = None
        self.note = ""

    # ---- the service's tick (a few times a second, off the loop) -------------------------------
    def poll(self, state: str, since_t: float | None, loop_t: float | None) -> None:
        if self.child is not None:
            if self.child.poll() is not None:
                self._finished(self.child.returncode)
            return
        if self.cfg.get("on_drift") != "diagnose" or state != "drifting" or since_t is None or loop_t is None:
            return
        if since_t == self.diagnosed_episode or loop_t - since_t < self.cfg["trigger_s"]:
            return
        now = self.now()
        self.started = [s for s in self.started if now - s < HOUR_S]
        if len(self.started) >= self.cfg["max_per_hour"]:
            nxt = min(self.started) + HOUR_S if self.started else None
            self.note = ("diagnosis off (monitor.max_per_hour: 0)" if nxt is None else
                         f"rate limit: {len(self.started)} diagnoses in the last hour (monitor.max_per_hour); "
                         f"next possible at {time.strftime('%H:%M:%S', time.localtime(nxt))}")
            return
        self.diagnosed_episode = since_t
        self._start(now)

    def _start(self, now: float) -> None:
        try:
            folder, argv = self._prepare(now)
        except Exception as exc:       # a full disk, a window that cannot be written: say so, keep running
            self.last = {"outcome": "failed", "error": f"could not write the recording: {type(exc).__name__}: {exc}",
                         "started_unix": now, "finished_unix": now}
            log.error("background diagnosis: %s", self.last["error"])
            return
        logf = open(folder / "diagnose.log", "ab")
        try:
            self.child = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=logf, stderr=logf, close_fds=True,
                                          start_new_session=True, env={**os.environ, **SINGLE_THREAD})
        finally:
            logf.close()
        self.started.append(now)
        self.current = {"folder": str(folder), "recording": str(folder / "window.csv"), "started_unix": now,
                        "pid": self.child.pid}
        self.note = ""
        log.warning("model drifting: background diagnosis started (pid %d) on %s", self.child.pid, folder / "window.csv")

    def _prepare(self, now: float) -> tuple[Path, list[str]]:
        """Write the window and the model into a new folder; the child's command line."""
        from ..modelio import save_model
        from ..recordings import write_recording

        if self.output_dirs:        # refused (the run goes on, the status says why) outside output_dirs
            from ..safe_files import area_of

            area_of(self.state_dir / "diagnoses", self.output_dirs)     # the folder each diagnosis gets one in
        window = self.take_window(self.cfg["window_s"])
        folder = _new_folder(self.state_dir / "diagnoses", now)
        write_recording(folder / "window.csv", window.recording)
        model = getattr(window.model, "base", window.model)
        save_model(model, folder / "model.yaml")
        argv = [self.python, "-m", "gma_ffc.service.diagnose_child", str(os.getpid()), "--", "diagnose",
                "--model", str(folder / "model.yaml"), str(folder / "window.csv"), "--out", str(folder)]
        if window.start is not None:        # known: diagnose scores the window from its first sample
            from ..known_state import write_play_state

            write_play_state(folder / "initial_state.json", window.start["plays"], time_s=window.start["time_s"],
                             drive=window.start["drive"], stress_MPa=window.start["stress_MPa"],
                             how=window.start["how"])
            argv += ["--initial-state", f"plays:{folder / 'initial_state.json'}"]
        if self.drive_limits is not None:
            argv += ["--drive-limits", *(repr(float(v)) for v in self.drive_limits)]
        return folder, argv

    def _finished(self, code: int) -> None:
        assert self.current is not None
        folder = Path(self.current["folder"])
        done = {**self.current, "finished_unix": self.now(), "exit_code": code}
        done.pop("pid", None)
        if code == 0:
            done.update(_read_outcome(folder))
        else:
            done.update(outcome="failed", error=last_error_line(folder / "diagnose.log", 0) or f"exit code {code}")
        self.last, self.current, self.child = done, None, None
        log.warning("background diagnosis finished: %s", summary_words(done))

    # ---- reporting and shutdown -----------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        return {"on_drift": self.cfg.get("on_drift"), "running": self.current, "last": self.last,
                "note": self.note, "state_dir": str(self.state_dir), "max_per_hour": self.cfg["max_per_hour"],
                "in_last_hour": len([s for s in self.started if self.now() - s < HOUR_S])}

    def close(self) -> None:
        """Kill the child (its whole session) and reap it: it never outlives the service."""
        child = self.child
        if child is None:
            return
        for sig, wait_s in ((signal.SIGTERM, KILL_GRACE_S), (signal.SIGKILL, 5.0)):
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(child.pid, sig)
            try:
                child.wait(timeout=wait_s)
                break
            except subprocess.TimeoutExpired:
                continue
        if self.current is not None:
            self.last = {**self.current, "outcome": "stopped", "error": "the service stopped before it finished",
                         "finished_unix": self.now()}
            self.last.pop("pid", None)
        self.child = self.current = None


def _read_outcome(folder: Path) -> dict[str, Any]:
    try:
        doc = json.loads((folder / "diagnosis.json").read_text())
    except (OSError, ValueError) as exc:
        return {"outcome": "failed", "error": f"diagnosis.json unreadable: {exc}"}
    extended = folder / str(doc.get("extended_model") or "extended_model.yaml")
    return {"outcome": doc.get("outcome"), "effects": list(doc.get("verdict") or []),
            "rms_before_um": doc.get("rms_before_um"), "rms_after_um": doc.get("rms_after_um"),
            "report": str(folder / "report.html"),
            "extended_model": str(extended) if extended.is_file() else None,
            "cannot_conclude": doc.get("cannot_conclude"),
            "scored": any((s.get("scored_share") or 0) > 0 for s in doc.get("initial_state") or [])}


def _new_folder(parent: Path, now: float) -> Path:
    """STATE/diagnoses/YYYYmmdd-HHMMSS (a suffix when one exists already), created 0750."""
    parent.mkdir(mode=0o750, parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(now))
    for k in range(1000):
        folder = parent / (stamp if k == 0 else f"{stamp}-{k}")
        try:
            folder.mkdir(mode=0o750)
            return folder
        except FileExistsError:
            continue
    raise FileExistsError(f"{parent}: no free folder name for {stamp}")
