"""Progress for long work: one updating line on a terminal, a plain line per stage when piped.

On a terminal the line shows the stage, the fraction done and the elapsed time, and never runs
past 79 columns (a wrapped line leaves debris when it is redrawn). Piped or redirected it stays
quiet, as the CLI contract says (docs/cli.md); with GMA_FFC_PROGRESS=lines in the environment
every new stage is then one plain line on stderr instead, so a service log or a batch job shows
where the time went.
"""

from __future__ import annotations

import os
import sys
import time
from typing import IO

WIDTH = 79


class Progress:
    """`with Progress("fitting", total=7) as p: p.advance(note="stage")`."""

    def __init__(self, label: str, total: int | None = None, stream: IO[str] | None = None,
                 enabled: bool | None = None) -> None:
        self.label = label
        self.total = total
        self.done = 0
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty() if enabled is None else enabled
        self.lines = not self.tty and os.environ.get("GMA_FFC_PROGRESS") == "lines"
        self._t0 = time.monotonic()
        self._last = 0.0
        self._note = ""

    def __enter__(self) -> "Progress":
        self._draw(force=True)
        return self

    def advance(self, n: int = 1, note: str = "") -> None:
        self.done += n
        if note and note != self._note:
            self._note = note
            if self.lines:
                self._line(f"{self.label}: {note} ({self._count()}, {self._elapsed()})\n")
        self._draw()

    def _count(self) -> str:
        if self.total:
            return f"{min(self.done, self.total)}/{self.total}, {100 * min(self.done, self.total) / self.total:.0f} %"
        return f"step {self.done}"

    def _elapsed(self) -> str:
        return f"{time.monotonic() - self._t0:.1f} s"

    def _draw(self, force: bool = False) -> None:
        if not self.tty:
            return
        now = time.monotonic()
        if not force and now - self._last < 0.1 and (self.total is None or self.done < self.total):
            return
        self._last = now
        text = f"{self.label}: [{self._count()}] {self._elapsed()}  {self._note}"
        if len(text) > WIDTH:
            text = text[: WIDTH - 3] + "..."
        self._line("\r" + text + "\x1b[K")        # clear what a longer previous line left behind

    def _line(self, text: str) -> None:
        self.stream.write(text)
        self.stream.flush()

    def __exit__(self, *exc: object) -> None:
        if self.tty:
            self._draw(force=True)
            self._line("\n")
        elif self.lines:
            self._line(f"{self.label}: done ({self._elapsed()})\n")
