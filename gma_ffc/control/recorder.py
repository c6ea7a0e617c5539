"""The telemetry recorder: the run's recording, one row per tick (a broadcaster).

It owns the recording's schema (which columns, from the driver's channels and whether learning
is on), its metadata, and the packing of a `Tick` into a preallocated row. `telemetry.Telemetry`
is the writer: the ring buffer, the writer thread and the file. Columns follow
docs/recordings.md; `reference_um` is the reference for the tick's own instant, so
`reference_um - displacement_um` is the tracking error.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from .. import safe_files
from ..drivers.base import CURRENT, DISPLACEMENT, FORCE
from .prediction import FAULTED, RAMPING
from .safety import RAMP
from .telemetry import Telemetry, TelemetryLock
from .tick import Broadcaster, Tick

if TYPE_CHECKING:
    from .config import ControllerConfig
    from .setup import Setup

FIXED = ("time_s", "reference_um", "current_cmd_A", "current_A", "stress_MPa")
CORRECTION = "correction_um"
OUTSIDE = "outside_model"       # 1: drive beyond the identified range, 2: stress beyond it, 3: both
PREDICTED, RESIDUAL = "predicted_um", "residual_um"      # the model-fit monitor's (docs/monitor.md)


def columns(channels: Sequence[str], learning: bool, monitor: bool = False) -> list[str]:
    """The recording's columns for a driver with these channels (the monitor's prediction and
    residual right after the displacement they are about, when there is one to judge)."""
    cols = list(FIXED)
    if DISPLACEMENT in channels:
        cols += [DISPLACEMENT, PREDICTED, RESIDUAL] if monitor else [DISPLACEMENT]
    if FORCE in channels:
        cols.append(FORCE)
    if learning:
        cols.append(CORRECTION)
    cols.append(OUTSIDE)
    return cols


def _not_started(row: np.ndarray) -> None:
    raise RuntimeError("telemetry recorder: a tick before start()")


class TelemetryRecorder(Broadcaster):
    """Schema, metadata and row packing for one run; `telemetry` is the writer while it runs."""

    def __init__(self, cfg: ControllerConfig, simulated: bool) -> None:
        self.section = cfg.telemetry
        self.rate_hz = cfg.rate_hz
        self.output_dirs = cfg.output_dirs
        self.simulated = simulated
        self.monitor = bool(cfg.monitor["enabled"])
        self.writer_priority = 0 if simulated else max(0, cfg.scheduler["realtime_priority"] - 1)
        self.base_metadata = {"source": "gma-ffc controller", "sample_rate_hz": cfg.rate_hz,
                              "driver": cfg.driver["kind"], "config": cfg.source}
        self.telemetry: Telemetry | None = None
        self._claim: TelemetryLock | None = None     # the file's lock, taken before the driver opens
        self._closed = True
        self._row = np.zeros(len(FIXED) + 1)
        self._push = _not_started
        self._safe_A = 0.0
        self._disp = self._force = self._corr = -1
        self._flags = self._outside = -1
        self.columns: list[str] = []
        # With the monitor on: who gets each block of rows in the writer's thread, before it is
        # written (the model-fit monitor fills in its prediction); the block holds the file's
        # columns, then a hidden flags column (prediction.FAULTED | prediction.RAMPING).
        self.consumer: Callable[[np.ndarray], None] | None = None

    def claim(self) -> None:
        """Take the telemetry file's lock now, before the driver opens: a second controller on the
        same file is refused (ConfigError naming the holder) before it touches the amplifier."""
        path = self.section["path"]
        if path is None:
            return
        if self._claim is None:
            kind = safe_files.telemetry_kind(str(self.base_metadata["config"]))
            self._claim = TelemetryLock(path, self.output_dirs, (kind, int(self.section.get("keep_previous", 0))))
        self._claim.acquire()

    def release(self) -> None:
        """Give back a claim no run used (the run's writer releases its own at close)."""
        if self._claim is not None:
            self._claim.release()
            self._claim = None

    def start(self, channels: Sequence[str], setup: Setup, started_unix_s: float) -> None:
        """Open the recording (the writer refuses a file another controller holds)."""
        cols = columns(channels, setup.law.learner is not None, self.monitor)
        self.columns = cols
        metadata = {**self.base_metadata, "start_unix_s": started_unix_s,
                    "command_lead_s": setup.law.reference.lead_s, "model_kind": setup.model.kind,
                    "current_A_is": "measured (commanded where a reading is missing)"
                    if CURRENT in channels else "commanded"}
        predicted = PREDICTED in cols
        tel = Telemetry(self.section["path"], cols, metadata, capacity=int(self.section["buffer_s"] * self.rate_hz),
                        flush_interval_s=self.section["flush_interval_s"], block_when_full=self.simulated,
                        output_dirs=self.output_dirs, hidden=1 if predicted else 0,
                        consumer=self._consume if predicted else None, lock=self._claim)
        self._claim = None                    # the writer owns the lock now and releases it at close
        if self.writer_priority > 0:          # just below the loop (0 when the loop runs without SCHED_FIFO)
            tel.realtime_priority = self.writer_priority
        self.telemetry = tel
        self._push = tel.push
        self._closed = False
        self._row = np.zeros(len(cols) + (1 if predicted else 0))
        self._disp, self._force, self._corr = (cols.index(c) if c in cols else -1
                                               for c in (DISPLACEMENT, FORCE, CORRECTION))
        self._outside = cols.index(OUTSIDE)
        self._flags = len(cols) if predicted else -1
        if predicted:     # filled in the writer's thread
            self._row[cols.index(PREDICTED)] = self._row[cols.index(RESIDUAL)] = np.nan
        tel.start()

    def _consume(self, block: np.ndarray) -> None:
        consumer = self.consumer
        if consumer is not None:
            consumer(block)

    def on_setup(self, setup: Setup) -> None:
        self._safe_A = setup.safe_A        # the command a fault tick's row records

    def stamp_start(self, start_unix_s: float) -> None:
        """The wall-clock time of t = 0, known once the loop's first deadline is (before any row)."""
        if self.telemetry is not None:
            self.telemetry.metadata["start_unix_s"] = start_unix_s
            self.telemetry.metadata["unix_time_of_a_row"] = "start_unix_s + time_s"

    def on_tick(self, tick: Tick) -> None:
        row = self._row
        row[0] = tick.time_s
        row[1] = tick.reference_um
        row[2] = self._safe_A if tick.faulted else tick.command_A
        row[3] = tick.current_A
        row[4] = tick.stress_MPa
        if self._disp >= 0:
            row[self._disp] = tick.displacement_um
        if self._force >= 0:
            row[self._force] = tick.inputs.force_N
        if self._corr >= 0:
            row[self._corr] = tick.correction_um
        row[self._outside] = tick.outside_model
        if self._flags >= 0:
            row[self._flags] = FAULTED if tick.faulted else RAMPING if tick.limited_by == RAMP else 0
        self._push(row)

    def close(self) -> str:
        """Write what is left and close the file; returns the writer's error ('' when none)."""
        if self.telemetry is None or self._closed:
            return ""
        self._closed = True
        self.telemetry.close()
        return self.telemetry.error

    def status(self) -> dict[str, Any] | None:
        tel = self.telemetry
        if tel is None:
            return None
        return {"path": str(tel.path) if tel.path else None, "rows": tel.head, "rows_written": tel.rows_written,
                "dropped": tel.dropped, "error": tel.error or None}
