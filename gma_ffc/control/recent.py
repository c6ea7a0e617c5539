"""The last seconds of telemetry rows, in memory, for a recording taken while the loop runs.

The telemetry writer's thread copies each block of rows into a preallocated ring (`push_block`,
in steps of at most half the margin). Another thread takes the last n rows (`last`) meanwhile: it
copies them and checks that the writer did not reach them (the ring holds `margin` rows more
than a snapshot may ask for; a copy that took longer is taken again).
"""

from __future__ import annotations

import numpy as np


class RecentRows:
    """A ring of the last `capacity` rows of `ncols` floats; `margin` rows are kept beyond any snapshot."""

    __slots__ = ("buf", "capacity", "margin", "head")

    def __init__(self, capacity: int, ncols: int, margin: int) -> None:
        if capacity < 1 or ncols < 1 or margin < 1:
            raise ValueError("capacity, ncols and margin must be at least 1")
        self.capacity = int(capacity) + int(margin)
        self.margin = int(margin)
        self.buf = np.full((self.capacity, ncols), np.nan)
        self.head = 0                      # rows pushed so far (the loop's only write besides the row)

    def push(self, row: np.ndarray) -> None:
        """Hot path: copy one row in."""
        self.buf[self.head % self.capacity] = row
        self.head += 1

    def push_block(self, rows: np.ndarray) -> None:
        """Copy rows in, oldest first, the head moved after each step of at most margin/2 rows (so
        a snapshot taken meanwhile sees any overwrite that could reach it)."""
        step = max(1, self.margin // 2)
        for start in range(0, len(rows), step):
            part = rows[start:start + step]
            idx = np.arange(self.head, self.head + len(part)) % self.capacity
            self.buf[idx] = part
            self.head += len(part)

    def clear(self) -> None:
        self.head = 0

    def last(self, n: int, tries: int = 5) -> np.ndarray:
        """A copy of the last `n` rows pushed (fewer if fewer were), oldest first."""
        n = min(int(n), self.capacity - self.margin)
        for _ in range(tries):
            head = self.head
            k = min(n, head)
            idx = np.arange(head - k, head) % self.capacity
            rows = self.buf[idx]
            if self.head - head < self.margin:     # the loop did not come round to what was copied
                return rows
        raise RuntimeError("the loop overwrote the rows while they were copied; try again when the machine is less busy")
