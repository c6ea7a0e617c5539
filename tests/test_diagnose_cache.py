"""The fitter's caches hold a bounded number of bytes, whatever the recording's length."""

from __future__ import annotations

import threading

import numpy as np

from gma_ffc.diagnose.cache import BoundedCache, nbytes


def test_least_recently_used_entries_go_first_when_the_byte_budget_is_full():
    cache: BoundedCache[np.ndarray] = BoundedCache(max_entries=100, max_bytes=3 * 800)
    for k in range(3):
        cache.put(k, np.zeros(100))                  # 800 bytes each: exactly the budget
    assert cache.get(0) is not None                  # 0 is now the most recently used
    cache.put(3, np.zeros(100))
    assert cache.get(1) is None and cache.get(0) is not None and cache.get(3) is not None
    assert cache.bytes <= 3 * 800 and len(cache) == 3


def test_entry_limit_and_an_entry_larger_than_the_budget():
    cache: BoundedCache[np.ndarray] = BoundedCache(max_entries=2, max_bytes=10 ** 9)
    for k in range(5):
        cache.put(k, np.zeros(1))
    assert len(cache) == 2 and cache.get(4) is not None and cache.get(2) is None
    small: BoundedCache[np.ndarray] = BoundedCache(max_bytes=100)
    big = small.put("big", np.zeros(1000))           # kept alone: the caller is about to use it
    assert small.get("big") is big and len(small) == 1
    small.put("next", np.zeros(1))
    assert small.get("big") is None


def test_bytes_are_counted_through_tuples_and_lists_and_replaced_keys_are_not_counted_twice():
    value = [(np.zeros(10), np.zeros(5)), (np.zeros(2), np.zeros(3))]
    assert nbytes(value) == 8 * 20
    cache: BoundedCache[list] = BoundedCache()
    cache.put("a", value)
    cache.put("a", value)
    assert cache.bytes == 8 * 20


def test_compute_runs_once_per_key_and_threads_share_the_cache():
    cache: BoundedCache[np.ndarray] = BoundedCache(max_entries=8, max_bytes=8 * 8 * 64)
    calls: list[int] = []

    def compute(k: int) -> np.ndarray:
        calls.append(k)
        return np.full(8, float(k))

    assert cache.get_or_compute(1, lambda: compute(1))[0] == 1.0
    assert cache.get_or_compute(1, lambda: compute(1))[0] == 1.0
    assert calls == [1]

    errors: list[BaseException] = []

    def worker(seed: int) -> None:
        rng = np.random.default_rng(seed)
        try:
            for k in rng.integers(0, 32, 2000):
                assert cache.get_or_compute(int(k), lambda k=k: np.full(8, float(k)))[0] == float(k)
        except BaseException as e:            # noqa: BLE001  (reported below, in the main thread)
            errors.append(e)

    threads = [threading.Thread(target=worker, args=(s,)) for s in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == [] and len(cache) <= 8 and cache.bytes <= 8 * 8 * 64
