"""Stress-dependent play's signature: its gain must show where the drive is slow, at its holds or at
its turns alone (`SignatureCheck.gain_from_fast_parts(turns_alone=True)`, `drive.held`)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks.cases import case_recordings
from benchmarks.general import GENERAL_SIXTEENTH_SEED, general_cases
from gma_ffc.diagnose.engine import diagnose
from gma_ffc.drive import HOLD_S, held, holds
from gma_ffc.effects.base import SignatureCheck


@settings(max_examples=30, deadline=None)
@given(st.floats(0.1, 50.0), st.floats(0.05, 3.0), st.floats(-2.0, 2.0))
def test_a_sine_at_a_tenth_of_a_hertz_or_faster_never_holds(f_hz, amp, offset):
    """Its turning points pass within the hold band in well under HOLD_S."""
    t = np.arange(0.0, max(12.0 / f_hz, 1.0), 1.0 / (200.0 * f_hz))
    u = offset + amp * np.sin(2 * np.pi * f_hz * t)
    assert not held(t, u).any()


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(st.floats(-1.0, 1.0), st.floats(0.2, 3.0)), min_size=2, max_size=8))
def test_held_marks_exactly_the_levels_held_long_enough_and_holds_counts_them(levels):
    """A staircase of levels (each distinct from the last by more than the band): a level lasting
    HOLD_S or more is held throughout, a shorter one not at all."""
    fs = 100.0
    values, durations = [], []
    for value, seconds in levels:
        if values and abs(value - values[-1]) < 0.1:
            value = values[-1] + 0.5          # a step the band cannot take for the same level
        values.append(value)
        durations.append(seconds)
    u = np.concatenate([np.full(int(round(d * fs)), v) for v, d in zip(values, durations)])
    t = np.arange(u.size) / fs
    mask = held(t, u)
    starts = np.cumsum([0] + [int(round(d * fs)) for d in durations])
    long_enough = [t[b - 1] - t[a] >= HOLD_S for a, b in zip(starts[:-1], starts[1:])]
    for a, b, expected in zip(starts[:-1], starts[1:], long_enough):
        assert mask[a:b].all() == expected and mask[a:b].any() == expected
    assert holds(t, u, HOLD_S) == sum(long_enough)


class _Rows:
    """The part of a fitter the slow-part check reads: rates, holds, and held-out residuals that
    are those of `before` or of the effect's specs."""

    def __init__(self, rate, held_rows, r_before, r_after):
        self.rate_rows, self.held_rows = rate, held_rows
        self._r = {"before": r_before, "after": r_after}

    def test_residuals(self, specs):
        return self._r[specs]


def _check(fitter) -> SignatureCheck:
    result = type("Result", (), {"specs": "after"})()
    return SignatureCheck(fitter, None, "before", result, {}, 0.01, 0.8, 3.0)


def test_a_gain_at_the_turns_passes_though_the_holds_keep_their_error():
    """Holds (rate 0) are missed as before; where the drive moves, slow and fast alike gain 4x. With
    the holds the slowest 40 % are all holds and creep's check fails; the play's passes at the turns."""
    n = 4000
    rate = np.concatenate([np.zeros(1600), np.linspace(0.1, 50.0, 2400)])
    held_rows = rate == 0
    before = np.ones(n)
    after = np.where(held_rows, 1.0, 0.5)
    check = _check(_Rows(rate, held_rows, before, after))
    assert check.slow_ratio(holds=True) == 1.0
    assert check.gain_from_fast_parts("x") is not None
    assert check.slow_ratio(holds=False) == 0.25
    assert check.gain_from_fast_parts("x", turns_alone=True) is None


def test_a_gain_at_the_holds_alone_passes_as_before():
    """The other way round: the holds gain 4x and the turns nothing."""
    rate = np.concatenate([np.zeros(1600), np.linspace(0.1, 50.0, 2400)])
    held_rows = rate == 0
    after = np.where(held_rows, 0.5, 1.0)
    check = _check(_Rows(rate, held_rows, np.ones(rate.size), after))
    assert check.slow_ratio(holds=False) == 1.0
    assert check.gain_from_fast_parts("x", turns_alone=True) is None


def test_a_gain_only_where_the_drive_is_fast_fails_at_the_holds_and_the_turns():
    """A rate effect's leftover: the gain is on the fast samples alone, so holds and turns keep their error."""
    rate = np.concatenate([np.zeros(800), np.linspace(0.1, 50.0, 3200)])
    after = np.where(rate > np.percentile(rate, 60), 0.3, 1.0)
    check = _check(_Rows(rate, rate == 0, np.ones(rate.size), after))
    failure = check.gain_from_fast_parts("x", turns_alone=True)
    assert failure is not None and "of those where it moves" in failure.reason and "100% of before" in failure.reason


def test_too_few_turns_show_no_gain():
    """A step test's few moving rows: their slowest 40 % are fewer than a diagnosis scores at all
    (`min_samples`), so a gain there, however large, is not taken as the play's."""
    rate = np.concatenate([np.zeros(3000), np.linspace(0.1, 50.0, 900)])    # 360 slow moving rows
    held_rows = rate == 0
    after = np.where(held_rows, 1.0, 0.1)
    check = _check(_Rows(rate, held_rows, np.ones(rate.size), after))
    assert check.slow_ratio(holds=False) == 1.0
    assert check.gain_from_fast_parts("x", turns_alone=True) is not None


@pytest.mark.nightly
def test_a_width_law_that_gains_at_the_turns_is_named_though_the_steps_keep_their_error():
    """The sixteenth never-tuned draw's stress-dependent play (development since it was looked at):
    the plant's loops widen 2.2x from -11.4 to -24 MPa. The width law cuts the error where the drive
    turns round (to 61 %) and on the fast parts, but not on the steps' holds, where the core's minor
    loops miss (99 %). Refused before as another effect's leftover; named now."""
    case = {c.name: c for c in general_cases(GENERAL_SIXTEENTH_SEED, prefix="sixteenth")}[
        "sixteenth:stress_dependent_play@default"]
    model, ident, rec = case_recordings(case)
    dg = diagnose(model, [rec], identification=ident)
    assert dg.verdict == ["stress_dependent_play"]
    assert dg.rms_after_um < 0.75 * dg.rms_before_um     # 0.72 -> 0.47 um


def test_the_least_row_count_is_the_turns_alone():
    """A short recording's rows, all of them judged (holds and turns): the same check as before the
    turns were added, whatever their number (the diagnosis has already asked for `min_samples`)."""
    rate = np.concatenate([np.zeros(200), np.linspace(0.1, 50.0, 400)])    # 240 slow rows in all
    after = np.where(rate == 0, 0.5, 1.0)
    check = _check(_Rows(rate, rate == 0, np.ones(rate.size), after))
    assert check.slow_ratio() < 0.8
    assert check.gain_from_fast_parts("x") is None
