"""The output band the unknown initial state leaves (gma_ffc.state_band), on random models and
histories: the true output always lies inside it, its ends are outputs real histories give, and it
collapses exactly once every play is determined (moved monotonically by 2r, or driven to an end
of the range)."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gma_ffc.initial_state import settled_index
from gma_ffc.state_band import admissible_corners, history_range, output_band
from test_inverse import sdpi_models

LO, HI = -3.0, 4.0           # sdpi_models' drive range
STRESS = (-24.0, -11.3)


def _drive(rng: np.random.Generator, n_turns: int, lo: float = LO, hi: float = HI) -> np.ndarray:
    turns = rng.uniform(lo, hi, n_turns)
    pieces = [np.linspace(a, b, int(rng.integers(2, 30)), endpoint=False) for a, b in zip(turns[:-1], turns[1:])]
    return np.concatenate(pieces + [turns[-1:]])


def _stress(rng: np.random.Generator, n: int) -> np.ndarray:
    return np.clip(rng.uniform(*STRESS) + np.cumsum(rng.normal(0, 0.4, n)), *STRESS)


def _true_start(model, rng: np.random.Generator, x0: float) -> np.ndarray:
    """The plays a real history inside the drive range leaves at x0: from an end of the range
    (where every play is determined), through random turning points, to x0."""
    pre = np.r_[rng.choice([LO, HI]), rng.uniform(LO, HI, int(rng.integers(0, 8))), x0]
    stepper = model.forward_stepper(initial_drive=float(pre[0]))
    stepper.reset(float(pre[0]), admissible_corners(model, np.array([pre[0], LO, HI]))[0])
    for v in pre:
        stepper.step(float(v), -15.0)
    return stepper._state[: model.n_play].copy()


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(model=sdpi_models(), seed=st.integers(0, 2**32 - 1), n_turns=st.integers(1, 20))
def test_the_true_output_always_lies_inside_the_band(model, seed, n_turns):
    rng = np.random.default_rng(seed)
    x = _drive(rng, max(n_turns, 2))
    s = _stress(rng, x.size)
    truth = model.simulate(None, x, s, initial_play_state=_true_start(model, rng, float(x[0])))
    band = output_band(model, x, s)
    tol = 1e-9 * max(1.0, float(np.max(np.abs(band.upper))))
    assert np.all(band.lower - tol <= truth) and np.all(truth <= band.upper + tol)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(model=sdpi_models(), seed=st.integers(0, 2**32 - 1))
def test_the_bands_ends_are_outputs_of_real_histories(model, seed):
    """Not a loose bound: a drive that came up to the first value (or down to it) from an end of
    the range gives each end of the band exactly."""
    rng = np.random.default_rng(seed)
    x = _drive(rng, int(rng.integers(2, 10)))
    s = _stress(rng, x.size)
    band = output_band(model, x, s)
    ends = []
    for came_from in (LO, HI):
        run = np.r_[came_from, x]              # the end of the range, then straight to x[0]
        ss = np.r_[s[0], s]
        low, _ = admissible_corners(model, run)   # at an end, the box is one state
        ends.append(model.simulate(None, run, ss, initial_play_state=low)[1:])
    lower, upper = np.minimum(*ends), np.maximum(*ends)
    scale = max(1.0, float(np.max(np.abs(upper))))
    assert np.allclose(lower, band.lower, rtol=0, atol=1e-9 * scale)
    assert np.allclose(upper, band.upper, rtol=0, atol=1e-9 * scale)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(model=sdpi_models(), seed=st.integers(0, 2**32 - 1), n_turns=st.integers(2, 20))
def test_the_band_collapses_once_every_play_is_determined(model, seed, n_turns):
    rng = np.random.default_rng(seed)
    x = _drive(rng, n_turns)
    s = _stress(rng, x.size)
    width = output_band(model, x, s).width
    assert np.all(width >= 0.0)
    assert np.all(width[settled_index(model, x):] == 0.0)          # moved by 2 r_max: exactly zero
    at_end = np.flatnonzero((x - model.input_offset <= history_range(model, x)[0])
                            | (x - model.input_offset >= history_range(model, x)[1]))
    if at_end.size:                                                  # driven to an end of the range
        assert np.all(width[at_end[0]:] == 0.0)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(model=sdpi_models(), seed=st.integers(0, 2**32 - 1))
def test_a_run_started_from_any_state_lies_inside_the_band_that_holds_it(model, seed):
    """The state diagnose runs from (an estimate, a relaxed start) may lie outside the box a
    history inside the range leaves: the band widened to hold it holds that run too."""
    rng = np.random.default_rng(seed)
    x = _drive(rng, int(rng.integers(2, 12)))
    s = _stress(rng, x.size)
    v0 = float(x[0]) - model.input_offset
    state = v0 + rng.uniform(-1.0, 1.0, model.n_play) * model.play_thresholds
    run = model.simulate(None, x, s, initial_play_state=state)
    band = output_band(model, x, s, also=state)
    tol = 1e-9 * max(1.0, float(np.max(np.abs(band.upper))))
    assert np.all(band.lower - tol <= run) and np.all(run <= band.upper + tol)
    plain = output_band(model, x, s)
    assert np.all(band.width >= plain.width - tol)


def test_a_recording_that_starts_at_an_end_of_the_range_is_known_from_its_first_sample():
    from test_inverse import sdpi_from_rng
    model = sdpi_from_rng(np.random.default_rng(3), 8, 2)
    t = np.linspace(0.0, 1.0, 400)
    x = LO + (HI - LO) * 0.5 * (1 - np.cos(2 * np.pi * 3 * t)) * t    # amplitude grows from the minimum
    band = output_band(model, x, np.full(x.size, -15.0))
    assert np.all(band.width == 0.0)
    mid = 0.5 * (LO + HI) + 0.5 * (HI - LO) * t * np.sin(2 * np.pi * 3 * t)   # grows from the middle
    width = output_band(model, mid, np.full(x.size, -15.0)).width
    assert width[0] > 0.0 and width[-1] < width[0]
