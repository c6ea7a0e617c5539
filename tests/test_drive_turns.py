"""The drive's turns, however small, and how far it has moved since the last one (gma_ffc.drive)."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from gma_ffc.drive import moved_since_turn, turning_indices


def _brute_last_turn(u: np.ndarray, at: int) -> int:
    """The last sample before `at` after which the drive moves against its direction into it."""
    last, direction = 0, 0
    for k in range(1, at + 1):
        step = np.sign(u[k] - u[k - 1])
        if step != 0 and direction != 0 and step != direction:
            last = k - 1
        if step != 0:
            direction = step
    return last


@given(st.lists(st.integers(-3, 3), min_size=2, max_size=60), st.data())
def test_moved_since_turn_matches_walking_the_drive(steps, data):
    u = np.cumsum(np.asarray(steps, dtype=float))
    at = data.draw(st.integers(0, u.size - 1))
    assert moved_since_turn(u, turning_indices(u), at) == abs(u[at] - u[_brute_last_turn(u, at)])


def test_a_sine_turns_at_its_peaks():
    u = np.sin(2 * np.pi * np.arange(400) / 100)        # peaks at 25, 125, ...; troughs at 75, 175, ...
    assert turning_indices(u).tolist() == [25, 75, 125, 175, 225, 275, 325, 375]
