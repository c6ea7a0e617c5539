"""A least-recently-used cache bounded in entries and in bytes, safe to share between threads.

The fitter caches core runs, regressors and anchor designs by spec. Each entry is one or more
arrays as long as the recordings, so a count limit alone lets memory grow with the recording: 64
core runs of an hour at 1 kHz are 3.7 GB. A byte budget keeps the cache's memory the same for
any length (a long recording keeps fewer entries and re-runs the core more often; a re-run costs
what the first run did, and the results are the same either way).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Any, Callable, Generic, Hashable, TypeVar

import numpy as np

V = TypeVar("V")


def nbytes(value: Any) -> int:
    """The array memory an entry holds: arrays, and tuples, lists and dicts of them."""
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if isinstance(value, (tuple, list)):
        return sum(nbytes(v) for v in value)
    if isinstance(value, dict):
        return sum(nbytes(v) for v in value.values())
    return 0


class BoundedCache(Generic[V]):
    """key -> value, computed once and kept while it is among the most recently used entries
    within `max_entries` and `max_bytes` (the newest entry is always kept, whatever its size).
    Two threads asking for the same missing key may both compute it; both get an equal value."""

    def __init__(self, max_entries: int = 64, max_bytes: int = 128 * 2 ** 20) -> None:
        self.max_entries = int(max_entries)
        self.max_bytes = int(max_bytes)
        self._items: OrderedDict[Hashable, tuple[V, int]] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._items)

    @property
    def bytes(self) -> int:
        return self._bytes

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self._bytes = 0

    def get(self, key: Hashable) -> V | None:
        with self._lock:
            hit = self._items.get(key)
            if hit is None:
                return None
            self._items.move_to_end(key)
            return hit[0]

    def put(self, key: Hashable, value: V) -> V:
        size = nbytes(value)
        with self._lock:
            old = self._items.pop(key, None)
            if old is not None:
                self._bytes -= old[1]
            self._items[key] = (value, size)
            self._bytes += size
            while len(self._items) > 1 and (len(self._items) > self.max_entries or self._bytes > self.max_bytes):
                _, (_, dropped) = self._items.popitem(last=False)
                self._bytes -= dropped
        return value

    def get_or_compute(self, key: Hashable, compute: Callable[[], V]) -> V:
        hit = self.get(key)
        return hit if hit is not None else self.put(key, compute())
