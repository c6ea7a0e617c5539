"""The controller watching its own model (issue 30, docs/monitor.md), off the loop.

The loop only packs its telemetry row (with a hidden flags column: faulted, ramping). The
telemetry writer's thread hands each block of rows to `on_block` before it writes them: each
row's reading is compared with the model's prediction (`prediction.predict_block`, one write
behind; NaN on rows not judged: a fault, a ramp, no valid stress, a gap in the ticks), the
prediction steps with the drives written, and the rows, with `predicted_um` and `residual_um`
filled in, go to the file and to a ring (`recent.RecentRows`). Off the loop too, `status` feeds
the rows kept since its last call to the fit monitor (`fit_monitor.FitMonitor`) as one block,
and the service takes the last `monitor.window_s` of the ring as a recording for a background
diagnosis.

A new model (a reload) is prepared in the reloading thread: its prediction is brought to the
present by replaying history through it (hysteresis, heating and creep states included): the
recording a background diagnosis fitted it on when the model comes from one (its folder holds
`window.csv`), then the retained rows after it; else the retained rows alone. The writer's thread
then adopts it before the next block, stepping only the rows kept since. Its monitor starts
afresh (`unknown`): the new model is judged on ticks it was not fitted on.

Beside the prediction, the writer's thread follows the plays of the model a diagnosis runs on
from the run's start (`play_memory.PlayMemory`), so `start_state` can say what state a window
starts in: diagnose then scores the window from its first sample (`--initial-state plays:FILE`).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..drive import drive_unit
from ..drivers.base import DISPLACEMENT
from ..protocols import Model
from .fit_monitor import OFF, FitMonitor, identification_error_um
from .play_memory import PlayMemory
from .prediction import RAMPING, Prediction, predict_block
from .recent import RecentRows

PREDICTED, RESIDUAL = "predicted_um", "residual_um"
COLUMNS = (PREDICTED, RESIDUAL)
# History kept beyond the window: a background diagnosis takes tens of seconds to a few minutes
# (scripts/bench_diagnose.py: ~9 s per recording, at nice 19 longer on a busy machine), and the
# replay that brings an adopted model to the present needs the rows since its recording ended.
EXTRA_HISTORY_S = 180.0
MAX_HISTORY_ROWS = 400_000      # ~35 MB of 11-column rows: a 5 kHz loop keeps 80 s, not 210
GAP_PERIODS = 2.5
CATCH_UP_MARGIN = 64            # the ring's least margin beyond a snapshot (recent.RecentRows)


@dataclass
class Prepared:
    """A model's prediction and monitor, brought to the present off the loop, waiting to be adopted."""

    model: Model
    prediction: Prediction
    fit: FitMonitor
    head: int               # rows of the ring it has seen
    replay: str             # how its state was brought to the present (for the status)


class ModelWatch:
    """Prediction beside the command, the fit monitor and the recent rows; see the module doc."""

    def __init__(self, monitor_cfg: dict[str, Any], channels: Sequence[str], columns: Sequence[str],
                 period_s: float) -> None:
        self.cfg = monitor_cfg
        self.period_s = period_s
        self.columns = list(columns)
        self.enabled = bool(monitor_cfg.get("enabled")) and DISPLACEMENT in channels
        self.off_reason = ("monitor.enabled is false" if not monitor_cfg.get("enabled") else
                           "the driver has no displacement channel: nothing to compare the model with")
        self.model: Model | None = None
        self.prediction: Prediction | None = None
        self.fit: FitMonitor | None = None
        self.replay = ""
        self.metadata: dict[str, Any] = {}
        self.plays: PlayMemory | None = None   # the diagnosed core's plays since the run started
        keep = min(int((monitor_cfg["window_s"] + EXTRA_HISTORY_S) / period_s), MAX_HISTORY_ROWS)
        self.rows = RecentRows(keep, len(self.columns), max(CATCH_UP_MARGIN, int(1.0 / period_s))) \
            if self.enabled else None
        self._col = {name: self.columns.index(name) for name in self.columns}
        self._fed = 0                     # rows of the ring the fit monitor has seen
        self._fed_drive = math.nan        # the command of the last row it saw (the next residual answers it)
        self.pending: Prepared | None = None   # a reload's prediction, adopted before the next block
        # A reading more than this long after the last judged one follows ticks the monitor did not
        # see (a reconnect wrote the safe current outside them): it is not judged. 2.5 periods: one
        # late tick (an overrun) still is.
        self.gap_s = GAP_PERIODS * period_s
        self._lock = threading.Lock()

    # ---- set-up (off the loop) -----------------------------------------------------------------
    def start(self, model: Model, drive: float, play_state: Any = None) -> None:
        """A run starts: the prediction at the inverse's start, a fresh monitor."""
        if not self.enabled:
            return
        self.model = model
        self.prediction = Prediction(model, self.period_s, drive, play_state)
        self.fit = self._fit_monitor(model)
        self.plays = PlayMemory.of(model, drive, play_state, self.cfg["window_s"] + EXTRA_HISTORY_S)
        self.replay = "started with the run, at the inverse's initial state"
        self._fed = self.rows.head if self.rows is not None else 0

    def _fit_monitor(self, model: Model) -> FitMonitor:
        return FitMonitor(max(16, int(round(self.cfg["window_s"] / self.period_s))), self.period_s,
                          identification_error_um(model), model.drive_range)

    def prepare(self, model: Model, model_path: str | None, monitor_cfg: dict[str, Any]) -> Prepared | None:
        """A reload's model, its prediction replayed up to the rows pushed so far (caller's thread)."""
        if bool(monitor_cfg.get("enabled")) != bool(self.cfg.get("enabled")):
            from ..errors import ConfigError

            raise ConfigError("config key 'monitor.enabled' changed: that needs a restart, not a reload "
                              "(the telemetry's columns follow it; the running configuration is kept)")
        if not self.enabled or self.rows is None:
            return None
        self.cfg = {**monitor_cfg, "enabled": True}         # the ring keeps the size the run started with
        head = self.rows.head
        retained = self.rows.last(head)
        history, how = self._history(model_path, retained)
        drive0 = float(history[0, self._col["current_cmd_A"]]) if len(history) else 0.0
        prediction = Prediction(model, self.period_s, drive0 if drive0 == drive0 else 0.0)
        self._replay(prediction, history)
        return Prepared(model, prediction, self._fit_monitor(model), head, how)

    def _history(self, model_path: str | None, retained: np.ndarray) -> tuple[np.ndarray, str]:
        """The rows to replay: the diagnosis' window, then the retained rows after it, when both
        are of this run and the retained rows reach back to its end; else the retained rows."""
        d, s, t = self._col["current_cmd_A"], self._col["stress_MPa"], self._col["time_s"]
        window = self._window_of(model_path)
        if window is not None and len(retained) and retained[0, t] <= window.time_s[-1] < retained[-1, t]:
            after = retained[retained[:, t] > window.time_s[-1]]
            fitted = np.column_stack([window.columns["current_cmd_A"], window.columns["stress_MPa"]])
            return self._as_history(np.vstack([fitted, after[:, [d, s]]])), \
                "replayed from the start of the recording it was fitted on"
        span = float(retained[-1, t] - retained[0, t]) if len(retained) else 0.0
        return self._as_history(retained[:, [d, s]]), f"replayed over the last {span:.3g} s of retained telemetry"

    def _window_of(self, model_path: str | None) -> Any:
        """The monitor window a background diagnosis fitted `model_path` on, if it is this run's."""
        window = Path(model_path).parent / "window.csv" if model_path else None
        if window is None or not window.is_file():
            return None
        from ..errors import RecordingError
        from ..recordings import read_recording

        try:
            rec = read_recording(window)
        except RecordingError:
            return None
        same_run = abs(float(rec.metadata.get("start_unix_s", math.nan)) - float(self.metadata.get("start_unix_s", math.inf))) < 1e-3
        usable = same_run and all(c in rec.columns for c in ("time_s", "current_cmd_A", "stress_MPa")) and len(rec.time_s)
        return rec if usable else None

    def _as_history(self, drive_stress: np.ndarray) -> np.ndarray:
        """Rows of the full column layout holding only drive and stress (what a replay reads)."""
        out = np.full((len(drive_stress), len(self.columns)), np.nan)
        out[:, self._col["current_cmd_A"]] = drive_stress[:, 0]
        out[:, self._col["stress_MPa"]] = drive_stress[:, 1]
        return out

    def _replay(self, prediction: Prediction, rows: np.ndarray) -> None:
        d, s = self._col["current_cmd_A"], self._col["stress_MPa"]
        ok = np.isfinite(rows[:, d]) & np.isfinite(rows[:, s])
        prediction.run(rows[ok, d], rows[ok, s])          # the blocks' own stepping, in one call

    def adopt(self, prepared: Prepared | None) -> None:
        """Before a block (the writer's thread): step the rows kept since `prepare`, then swap."""
        if prepared is None or self.rows is None:
            return
        missed = self.rows.head - prepared.head
        if missed > 0:
            self._replay(prepared.prediction, self.rows.last(missed))
        with self._lock:
            self.model, self.prediction, self.fit, self.replay = \
                prepared.model, prepared.prediction, prepared.fit, prepared.replay
            if self.plays is not None and not self.plays.follows(prepared.model):
                self.plays = None     # other plays: their state since the start is not known
            self._fed = self.rows.head            # the new model is judged on the ticks after it

    # ---- the telemetry writer's thread ---------------------------------------------------------
    def on_block(self, block: np.ndarray) -> None:
        """Rows the loop packed since the last block (the file's columns, then the flags): adopt a
        prepared model if one waits, fill each row's prediction and residual in place, and keep
        the rows in the ring."""
        if self.rows is None:
            return
        pending, self.pending = self.pending, None
        if pending is not None:
            self.adopt(pending)
        prediction, c = self.prediction, self._col
        if prediction is not None:
            flags = block[:, -1]
            predicted = predict_block(prediction, block[:, c["time_s"]], block[:, c["current_cmd_A"]],
                                      block[:, c["stress_MPa"]], flags, self.gap_s)
            block[:, c[PREDICTED]] = predicted
            residual = block[:, c[DISPLACEMENT]] - predicted
            residual[(flags.astype(np.int64) & RAMPING) != 0] = math.nan     # a ramp's readings are not judged
            block[:, c[RESIDUAL]] = residual
        if self.plays is not None:
            self.plays.advance(block[:, c["time_s"]], self._drive(block))
        self.rows.push_block(block[:, :len(self.columns)])

    # ---- reporting and snapshots (off the loop) ---------------------------------------------------
    def evaluate(self) -> None:
        """Feed the fit monitor the rows pushed since the last call (any thread but the loop's)."""
        with self._lock:
            if self.fit is None or self.rows is None:
                return
            head = self.rows.head
            new = self.rows.last(head - self._fed)
            self._fed = head
            if not len(new):
                return
            c = self._col
            cmd = new[:, c["current_cmd_A"]]
            answered = np.concatenate([[self._fed_drive], cmd[:-1]])      # the drive each residual answers
            self._fed_drive = float(cmd[-1])
            self.fit.feed(float(new[-1, c["time_s"]]), new[:, c[RESIDUAL]], answered,
                          new[:, c["reference_um"]] - new[:, c[DISPLACEMENT]])

    def status(self) -> dict[str, Any]:
        if self.fit is None or self.model is None:
            return {"state": OFF, "reason": self.off_reason}
        self.evaluate()
        out = self.fit.status()
        out["drive_unit"] = drive_unit(self.model.drive_name)
        out["prediction"] = self.replay
        return out

    def window(self, seconds: float) -> tuple[Any, Model]:
        """The last `seconds` of telemetry as a recording (rows without a finite displacement, drive
        or time left out), and the model running now."""
        from ..recordings import Recording

        if self.rows is None or self.model is None:
            raise RuntimeError("the model-fit monitor is off: there is no window to take")
        rows = self.rows.last(int(round(seconds / self.period_s)))
        keep = np.isfinite(rows[:, [self._col[c] for c in ("time_s", "current_A", DISPLACEMENT)]]).all(axis=1)
        rows = rows[keep]
        cols = {name: np.ascontiguousarray(rows[:, k]) for name, k in self._col.items()}
        meta = {**self.metadata, "source": "gma-ffc controller: the model-fit monitor's window",
                "rows_left_out": int((~keep).sum())}
        return Recording(cols, meta, "window.csv"), self.model

    def start_state(self, recording: Any) -> dict[str, Any] | None:
        """The play state at `recording`'s first sample (a window `window` took), for a diagnosis:
        the plays followed since the run started, brought to that row from the retained rows. None
        when it is not known (no plays, a reload to other plays, the history no longer reaching
        back to an anchor)."""
        memory = self.plays
        if memory is None or self.rows is None or not len(recording.time_s):
            return None
        retained = self.rows.last(self.rows.capacity - self.rows.margin)
        c = self._col
        t0 = float(recording.time_s[0])
        plays = memory.state_at(retained[:, c["time_s"]], self._drive(retained), t0)
        if plays is None:
            return None
        stress = recording.columns.get("stress_MPa")
        return {"plays": plays.tolist(), "time_s": t0, "drive": float(recording.drive[0]),
                "stress_MPa": float(stress[0]) if stress is not None else math.nan,
                "how": "followed along the drive since the run started at rest at the safe current"}

    def _drive(self, rows: np.ndarray) -> np.ndarray:
        """The drive the plays follow: the window's drive column (the measured current, which
        diagnose simulates on), the command where a reading is missing."""
        measured, command = rows[:, self._col["current_A"]], rows[:, self._col["current_cmd_A"]]
        return np.where(np.isfinite(measured), measured, command)
