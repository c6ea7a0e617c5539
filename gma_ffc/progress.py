"""Progress for long work: a single updating line on a terminal, silence when piped."""

from __future__ import annotations

import sys
import time
from typing import IO


class Progress:
    """`with Progress("fitting", total=7) as p: p.advance()`; prints only when stderr is a TTY."""

    def __init__(self, label: str, total: int | None = None, stream: IO[str] | None = None,
                 enabled: bool | None = None) -> None:
        self.label = label
        self.total = total
        self.done = 0
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self._t0 = time.monotonic()
        self._last = 0.0

    def __enter__(self) -> "Progress":
        self._draw(force=True)
        return self

    def advance(self, n: int = 1, note: str = "") -> None:
        self.done += n
        self._draw(note=note)

    def _draw(self, note: str = "", force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if not force and now - self._last < 0.1 and (self.total is None or self.done < self.total):
            return
        self._last = now
        count = f"{self.done}/{self.total}" if self.total else f"{self.done}"
        text = f"\r{self.label}: {count} ({now - self._t0:.1f} s) {note}"
        self.stream.write(text[:120].ljust(80))
        self.stream.flush()

    def __exit__(self, *exc: object) -> None:
        if self.enabled:
            self._draw(force=True)
            self.stream.write("\n")
            self.stream.flush()
