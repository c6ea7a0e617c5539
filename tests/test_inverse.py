"""Numerical truth of the analytic inverse: derived, then proved on random valid parameters.

Inverse after forward returns the drive, and forward after inverse returns the reference, to
rounding, for random SDPI parameters that satisfy Proposition 3.1, random drive histories with
minor loops, stress changing during the run, and non-zero initial play states.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gma_ffc.constrained_weights import slopes_to_weights
from gma_ffc.inverse import deadzone_inverse, deadzone_inverse_into, play_inverse
from gma_ffc.model import SDPIModel

STRESS = (-24.0, -11.3)


def sdpi_from_rng(rng: np.random.Generator, n_h: int, l: int) -> SDPIModel:
    """Random SDPI satisfying Proposition 3.1 by construction: play weights w_0 > 0, w_i >= 0,
    and every piece's slope a convex quadratic in stress with a positive minimum."""
    r_h = np.r_[0.0, np.cumsum(rng.uniform(0.02, 0.4, n_h - 1))]
    w_h = np.r_[rng.uniform(0.2, 5.0), rng.uniform(0.0, 3.0, n_h - 1) * (rng.random(n_h - 1) < 0.8)]
    r_pos = np.cumsum(rng.uniform(0.2, 3.0, l))
    r_neg = -np.cumsum(rng.uniform(0.2, 3.0, l))[::-1]
    r_s = np.r_[r_neg, 0.0, r_pos]
    m = 2 * l + 1
    vmin = rng.uniform(0.05, 3.0, m)           # slope at its minimum
    curv = rng.uniform(0.0, 0.01, m)           # >= 0: convex in stress
    s_at = rng.uniform(*STRESS, m)             # where the minimum is
    # slope_k(s) = vmin + curv (s - s_at)^2 = c0 + c1 s + c2 s^2
    slope_coeffs = np.vstack([vmin + curv * s_at**2, -2 * curv * s_at, curv])
    coeffs = slopes_to_weights(slope_coeffs)
    offset = [rng.uniform(-5, 30), rng.uniform(-0.5, 0.5), rng.uniform(-0.01, 0.01)]
    return SDPIModel(r_h, w_h, r_s, coeffs, output_coeffs=offset, input_offset=rng.uniform(-1, 2),
                     stress_range_MPa=STRESS, drive_range=(-3.0, 4.0))


def drive_from_rng(rng: np.random.Generator, n_turns: int) -> tuple[np.ndarray, np.ndarray]:
    """A drive through n_turns random turning points (major and minor loops) and a stress path."""
    turns = rng.uniform(-3.0, 4.0, n_turns)
    pieces = [np.linspace(a, b, rng.integers(2, 40), endpoint=False) for a, b in zip(turns[:-1], turns[1:])]
    x = np.concatenate(pieces + [turns[-1:]])
    stress = np.clip(rng.uniform(*STRESS) + np.cumsum(rng.normal(0, 0.4, x.size)), *STRESS)
    return x, stress


@st.composite
def sdpi_models(draw: st.DrawFn) -> SDPIModel:
    n_h = draw(st.integers(1, 12))
    l = draw(st.integers(0, 4))
    model = sdpi_from_rng(np.random.default_rng(draw(st.integers(0, 2**32 - 1))), n_h, l)
    assert model.invertibility_violations() == []
    return model


@st.composite
def histories(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A drive through random turning points, a stress path, a prehistory."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    x, stress = drive_from_rng(rng, draw(st.integers(2, 25)))
    prehistory = rng.uniform(-3.0, 4.0, rng.integers(1, 8)) if draw(st.booleans()) else None
    return x, stress, prehistory


def _initial_play_state(model: SDPIModel, prehistory: np.ndarray | None) -> np.ndarray | None:
    """Non-zero initial states: whatever an earlier drive history left in the plays."""
    if prehistory is None:
        return None
    stepper = model.forward_stepper(initial_drive=float(prehistory[0]))
    for v in prehistory:
        stepper.step(float(v), -15.0)
    return stepper._state[: model.n_play].copy()


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(model=sdpi_models(), hist=histories())
def test_inverse_after_forward_returns_the_drive(model: SDPIModel, hist) -> None:
    x, stress, prehistory = hist
    y0 = _initial_play_state(model, prehistory)
    y = model.simulate(None, x, stress, initial_drive=x[0], initial_play_state=y0)
    x_back = model.invert(None, y, stress, initial_drive=x[0], initial_play_state=y0)
    span = max(np.ptp(x), 1e-3)
    assert np.max(np.abs(x_back - x)) <= 1e-9 * span


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(model=sdpi_models(), hist=histories())
def test_forward_after_inverse_returns_the_reference(model: SDPIModel, hist) -> None:
    x, stress, prehistory = hist
    # Use the drive path as a reference shape scaled into displacement units.
    ref = 10.0 * x
    y0 = _initial_play_state(model, prehistory)
    drive = model.invert(None, ref, stress, initial_drive=0.5, initial_play_state=y0)
    y = model.simulate(None, drive, stress, initial_drive=0.5, initial_play_state=y0)
    assert np.max(np.abs(y - ref)) <= 1e-9 * np.ptp(ref)


@settings(max_examples=60, deadline=None)
@given(model=sdpi_models(), hist=histories())
def test_steppers_equal_batch_sample_for_sample(model: SDPIModel, hist) -> None:
    x, stress, _ = hist
    y = model.simulate(None, x, stress, initial_drive=1.0)
    fwd = model.forward_stepper(1e-3, initial_drive=1.0)
    assert np.array_equal([fwd.step(a, s) for a, s in zip(x, stress)], y)
    inv = model.inverse_stepper(1e-3, initial_drive=1.0)
    x_inv = model.invert(None, y, stress, initial_drive=1.0)
    assert np.array_equal([inv.step(a, s) for a, s in zip(y, stress)], x_inv)


def test_kernel_dead_zone_inverse_equals_the_papers_sums() -> None:
    rng = np.random.default_rng(0)
    for l in range(0, 5):
        r = np.r_[-np.cumsum(rng.uniform(0.1, 2, l))[::-1], 0, np.cumsum(rng.uniform(0.1, 2, l))]
        w = slopes_to_weights(rng.uniform(0.1, 3, 2 * l + 1))
        r_ref, w_ref = deadzone_inverse(r, w)
        r_k, w_k = np.empty_like(r), np.empty_like(w)
        deadzone_inverse_into(r, w, r_k, w_k)
        np.testing.assert_allclose(r_k, r_ref, rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(w_k, w_ref, rtol=1e-13, atol=1e-13)


def _superposition(z: np.ndarray, r: np.ndarray, w: np.ndarray) -> np.ndarray:
    out = np.zeros_like(z)
    for rj, wj in zip(r, w):
        out += wj * (np.maximum(z - rj, 0) if rj > 0 else np.minimum(z - rj, 0) if rj < 0 else z)
    return out


def test_paper_sign_typo_in_19_and_22_would_break_the_inverse() -> None:
    """(12)/(14) carry a minus sign; (19)/(22) print none. Only the minus inverts."""
    r = np.array([-2.0, -1.0, 0.0, 1.0, 2.0])
    w = np.array([0.3, 0.2, 1.0, 0.4, 0.5])
    z = np.linspace(-4, 4, 801)
    y = _superposition(z, r, w)
    r_inv, w_inv = deadzone_inverse(r, w)
    np.testing.assert_allclose(_superposition(y, r_inv, w_inv), z, atol=1e-12)
    typo = w_inv.copy()
    typo[np.arange(5) != 2] *= -1.0  # the paper's (19)/(22) without the minus
    assert np.max(np.abs(_superposition(y, r_inv, typo) - z)) > 0.1


def test_play_inverse_matches_equations_8_and_9() -> None:
    r = np.array([0.0, 0.5, 1.0, 1.5])
    w = np.array([2.0, 1.0, 0.5, 0.25])
    r_inv, w_inv = play_inverse(r, w)
    # (8): r'_i = sum_{j<=i} w_j (r_i - r_j), worked by hand
    np.testing.assert_allclose(r_inv, [0.0, 1.0, 2.5, 4.25])
    # (9): w'_0 = 1/w_0, w'_i = -w_i / ((w_0+..+w_i)(w_0+..+w_{i-1}))
    np.testing.assert_allclose(w_inv, [0.5, -1 / (3 * 2), -0.5 / (3.5 * 3), -0.25 / (3.75 * 3.5)])


def test_invertibility_check_names_the_constraint_and_the_stress() -> None:
    r_s = np.array([-1.0, 0.0, 1.0])
    # positive-side slope w_0 + w_1 = 1 + (-1.2 - 0.05 (s + 20)) dips below zero as s rises
    coeffs = np.array([[0.2, 1.0, -1.2 - 0.05 * 20], [0.0, 0.0, -0.05], [0.0, 0.0, 0.0]])
    model = SDPIModel(np.array([0.0]), np.array([1.0]), r_s, coeffs, stress_range_MPa=STRESS)
    bad = model.invertibility_violations()
    assert [v.constraint for v in bad] == ["sum w_s0..w_s1"]
    assert bad[0].stress_MPa == pytest.approx(-11.3)
    assert bad[0].value == pytest.approx(1.0 - 1.2 - 0.05 * (-11.3 + 20))
    assert "short by" in str(bad[0])


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), log_k=st.floats(-9.0, 9.0))
def test_moving_scale_from_the_plays_to_the_dead_zones_changes_neither_output_nor_verdict(seed, log_k):
    """Data fix only the product of play and dead-zone weights: plays k w with dead-zone thresholds
    k r_s and weights c / k give the same output. The check must agree: it held w_h0 to a billionth
    of a dead-zone weight, so a fit that moved the scale (a butterfly loop: w_h0 1.7e-9 of plays
    summing to 4.5e-8, a central dead-zone weight of 15) was refused as violating Proposition 3.1."""
    rng = np.random.default_rng(seed)
    model = sdpi_from_rng(rng, int(rng.integers(2, 12)), int(rng.integers(0, 4)))
    k = 10.0 ** log_k
    moved = SDPIModel(model.play_thresholds, k * model.play_weights, k * model.deadzone_thresholds,
                      model.deadzone_coeffs / k, output_coeffs=model.output_coeffs, input_offset=model.input_offset,
                      stress_range_MPa=STRESS, drive_range=(-3.0, 4.0))
    x = rng.uniform(-3.0, 4.0, 40)
    s = rng.uniform(*STRESS, 40)
    scale = max(float(np.ptp(model.simulate(None, x, s))), 1e-9)
    assert np.max(np.abs(moved.simulate(None, x, s) - model.simulate(None, x, s))) <= 1e-9 * scale
    assert model.invertibility_violations() == [] and moved.invertibility_violations() == []
