"""Telemetry: every tick as a row of a recording, written off the hot path.

The hot path copies one row into a preallocated ring (`push`, no allocation beyond Python
floats); a writer thread hands each block of new rows to a `consumer` if there is one (the
model-fit monitor, which fills its columns in place; the ring may hold `hidden` columns after the
file's for it), then appends the rows to a CSV recording (docs/recordings.md) and
flushes + fsyncs at least every `flush_interval_s` (<= 1 s), so a killed process loses at most
that much. Each flush writes whole lines in one call (the header with the first rows), so the
file is always a valid recording, at worst with a torn last line that readers report and skip.

With a real clock a full ring drops rows (counted in `dropped`, never blocking the loop); with
a simulated clock `push` waits for the writer instead, so fast runs lose nothing.

One file, one writer: a `TelemetryLock` (flock on FILE.lock, which names the holder's pid) is
taken before anything is truncated, and a second controller pointed at the same file is refused
with the other's pid. The controller takes it before it opens its driver (`claim`), so a refused
second controller never touches the amplifier; `start` takes it itself when nobody handed one in. Both files are opened by `gma_ffc.safe_files`: never through a
link, never outside `output_dirs`, and an existing file is truncated only if it is this rig's
telemetry (the same config). The header is written with the first rows, so it can carry the
wall-clock time of the first tick (`start_unix_s`; a row's unix time is start_unix_s + time_s).
"""

from __future__ import annotations

import fcntl
import io
import logging
import math
import os
import threading
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from .. import safe_files
from ..errors import ConfigError
from ..recordings import format_metadata

log = logging.getLogger(__name__)


def _cell(value: float) -> str:
    """One cell: the value, or nothing where there is none (a prediction before the model has one,
    a ramp's residual): an empty cell, never 'nan' or 'inf' text (docs/recordings.md)."""
    return "%.9g" % value if math.isfinite(value) else ""


def write_rows(out: io.StringIO, block: np.ndarray) -> None:
    """The rows of `block` as CSV lines (9 significant digits); a value that is not finite is an
    empty cell. In the writer's thread, in short steps: the loop can take the GIL between rows."""
    fmt = ",".join(["%.9g"] * block.shape[1]) + "\n"
    whole = np.isfinite(block).all(axis=1).tolist()
    write = out.write
    for values, finite in zip(block.tolist(), whole):
        write(fmt % tuple(values) if finite else ",".join(map(_cell, values)) + "\n")


class TelemetryLock:
    """The exclusive claim on one telemetry file: flock on FILE.lock, which names the holder's pid."""

    def __init__(self, path: str | os.PathLike, output_dirs: Sequence[str] = (),
                 keep: tuple[safe_files.Kind, int] | None = None) -> None:
        self.path = Path(path)
        self.output_dirs = tuple(output_dirs)
        self.keep = keep          # (the file's kind, how many earlier runs): moved aside once locked
        self.kept_as: str | None = None
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> None:
        """Take the lock (nothing if held already); ConfigError naming the holder if it is taken."""
        if self._fd is not None:
            return
        lock_path = self.path.with_name(self.path.name + ".lock")
        fd = safe_files.open_for_writing(lock_path, self.output_dirs, safe_files.TELEMETRY_LOCK, append=True)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "?"
            os.close(fd)
            # 'gma-ffc stop' alone reaches only a controller in the default runtime folder ("no controller
            # running" for one started with --runtime-dir or --no-socket); SIGTERM reaches any
            raise ConfigError(f"telemetry file {self.path} is being written by another controller (pid {holder}); "
                              f"stop it first ('kill {holder}' (SIGTERM) ramps its amplifier to the safe current "
                              "and ends it) or give this one another telemetry.path") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd
        if self.keep is not None:     # the run before, kept: only the lock's holder may move it
            try:
                self.kept_as = safe_files.keep_previous(self.path, self.output_dirs, *self.keep)
            except BaseException:
                self.release()
                raise
            if self.kept_as:
                log.info("telemetry: the previous run's %s is kept as %s", self.path, self.kept_as)

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)          # closing releases the flock
            self._fd = None


class Telemetry:
    """Ring buffer plus writer thread for one run's recording."""

    def __init__(self, path: str | os.PathLike | None, columns: Sequence[str], metadata: dict[str, Any],
                 capacity: int, flush_interval_s: float = 0.5, block_when_full: bool = False,
                 output_dirs: Sequence[str] = (), hidden: int = 0,
                 consumer: Callable[[np.ndarray], None] | None = None,
                 lock: TelemetryLock | None = None) -> None:
        self.path = Path(path) if path is not None else None
        self.output_dirs = tuple(output_dirs)
        self.columns = tuple(columns)
        self.metadata = metadata
        self.ncols = len(self.columns)
        self.capacity = max(16, int(capacity))
        self.buf = np.zeros((self.capacity, self.ncols + hidden))
        self.consumer = consumer
        self.flush_interval_s = flush_interval_s
        self.block_when_full = block_when_full
        self.realtime_priority = 0
        self.head = 0          # rows pushed (written by the hot path only)
        self.tail = 0          # rows written to disk (written by the writer only)
        self.dropped = 0
        self.rows_written = 0
        self.error = ""
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self._fh: int | None = None      # raw fd: each flush is one write() of whole lines
        self._lock = lock                # this file's lock, taken already (`claim`) or at start
        self._header_written = False
        self._keeps = False              # rows are kept: there is a file or a consumer, and a writer thread

    def start(self) -> None:
        if self.path is not None:
            self._open()
        elif self.consumer is None:
            return
        self._keeps = True
        self._thread = threading.Thread(target=self._run, name="gma-ffc-telemetry", daemon=True)
        self._thread.start()

    def _open(self) -> None:
        assert self.path is not None
        if self._lock is None:
            self._lock = TelemetryLock(self.path, self.output_dirs)
        self._lock.acquire()
        try:
            self._fh = safe_files.open_for_writing(self.path, self.output_dirs,
                                                   safe_files.telemetry_kind(str(self.metadata.get("config"))))
        except BaseException:
            self._unlock()
            raise

    def _unlock(self) -> None:
        if self._lock is not None:
            self._lock.release()

    def _header(self) -> str:
        return format_metadata(self.metadata) + ",".join(self.columns) + "\n"

    def _write_header(self) -> None:
        self._write_all(self._header().encode())
        self._header_written = True

    def push(self, row: np.ndarray) -> None:
        """Copy one row (the file's columns, then the hidden ones) into the ring; hot path."""
        if not self._keeps:
            self.head += 1
            return
        if self.head - self.tail >= self.capacity:
            if not self.block_when_full:
                self.dropped += 1
                return
            while self.head - self.tail >= self.capacity and self._thread is not None and self._thread.is_alive():
                self._wake.set()
                time.sleep(0.0005)
            if self.head - self.tail >= self.capacity:
                self.dropped += 1
                return
        self.buf[self.head % self.capacity] = row
        self.head += 1
        if self.block_when_full and self.head - self.tail == self.capacity // 2:
            self._wake.set()          # once as the ring passes half full (an Event.set a push costs ~1 us)

    def _run(self) -> None:
        if self.realtime_priority > 0:
            # Just below the loop: a writer preempted while holding the GIL would stall the loop.
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.realtime_priority))
            except (OSError, AttributeError):
                pass
        while not self._stop.is_set():
            self._wake.wait(self.flush_interval_s)
            self._wake.clear()
            self._drain()
        self._drain()

    def _drain(self) -> None:
        head, tail = self.head, self.tail
        if not self._keeps or head == tail:
            return
        idx = np.arange(tail, head) % self.capacity
        block = self.buf[idx]
        self.tail = head
        if self.consumer is not None:
            try:
                self.consumer(block)
            except Exception as exc:  # noqa: BLE001 - the rows are still written; the status says why
                self.error = f"model-fit monitor failed on a block of telemetry: {exc}"
                self.consumer = None
        if self._fh is None:
            return
        out = io.StringIO()
        if not self._header_written:     # in the first rows' write: the loop has stamped start_unix_s by then,
            out.write(self._header())    # and a file killed then holds rows under its header or nothing
        write_rows(out, block[:, :self.ncols])
        try:
            self._write_all(out.getvalue().encode())
            os.fsync(self._fh)
            self._header_written = True
            self.rows_written += len(block)
        except OSError as exc:   # disk full etc.: reported in status, the loop keeps control
            if not self.error:
                log.warning("telemetry write failed: %s (%s); the loop keeps control, rows are lost until "
                            "it can write", exc.strerror, self.path)
            self.error = f"telemetry write failed: {exc.strerror}"

    def _write_all(self, data: bytes) -> None:
        """One write() per flush, so a killed process leaves whole lines, but for the rare last
        line cut where a page of a long write ends (SIGKILL stops a write between pages); readers
        report that line and leave it out. The loop only repeats on a short write (disk nearly full)."""
        fd = self._fh
        assert fd is not None
        view = memoryview(data)
        while view:
            n = os.write(fd, view)
            view = view[n:]

    def close(self) -> None:
        """Write everything still in the ring and close the file."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
            self._thread = None
        self._drain()
        self._keeps = False
        if self._fh is not None:
            if not self._header_written:  # a run without a single tick still leaves a valid recording
                try:
                    self._write_header()
                except OSError as exc:
                    self.error = f"telemetry write failed: {exc.strerror}"
            os.close(self._fh)
            self._fh = None
        self._unlock()
