"""The output side's own play operators (play_correction, stress_play) start from the core's
history (`gma_ffc.effects.base.PlayStart`), in batch runs and in steppers.

A play correction c (H_r[u] - u) on a pure Prandtl-Ishlinskii core is the same as moving weight c
from the core's r = 0 play to its play of threshold r. So the extended model must equal that
re-weighted core from any start. A minor loop never sweeps the wide play, so a start that
differs from the core's (they used to start relaxed) stays in the output for the whole run.
"""

from __future__ import annotations

import numpy as np
import pytest

from gma_ffc.extended import ExtendedModel
from gma_ffc.model import SDPIModel

STRESS = (-24.0, -11.3)
THRESHOLDS = np.array([0.0, 0.3, 0.6])
WEIGHTS = np.array([1.0, 0.8, 0.6])
C = 0.4           # moved from the r = 0 play to the r = 0.6 one


def _core(weights: np.ndarray, initial_state: str) -> SDPIModel:
    # one dead-zone at 0 of weight 1: the identity, so the core is the plays' weighted sum
    return SDPIModel(THRESHOLDS, weights, np.array([0.0]), np.array([[1.0], [0.0], [0.0]]),
                     stress_range_MPa=STRESS, drive_range=(0.0, 2.0), initial_state=initial_state)


def _pair(initial_state: str) -> tuple[ExtendedModel, SDPIModel]:
    ext = ExtendedModel(_core(WEIGHTS, initial_state),
                        {"static": {"stress_ref_MPa": -15.0},
                         "play_correction": {"thresholds": [0.6], "coefficients": [C]}})
    moved = _core(WEIGHTS + np.array([-C, 0.0, C]), initial_state)
    return ext, moved


def _minor_loops() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.arange(3000) * 1e-3
    u = 0.75 + 0.25 * np.sin(2 * np.pi * 3 * t)     # 0.5..1.0: never sweeps 2 x 0.6
    return t, u, np.full(t.size, -15.0)


@pytest.mark.parametrize("initial_state", ["descending", "relaxed"])
def test_a_play_correction_starts_where_the_core_does_from_rest(initial_state):
    ext, moved = _pair(initial_state)
    t, u, s = _minor_loops()
    want = moved.simulate(t, u, s, initial_drive=float(u[0]))
    np.testing.assert_allclose(ext.simulate(t, u, s, initial_drive=float(u[0])), want, atol=1e-10)
    fwd = ext.forward_stepper(1e-3, initial_drive=float(u[0]))
    np.testing.assert_allclose([fwd.step(float(a), float(b)) for a, b in zip(u, s)], want, atol=1e-10)
    fwd.reset(float(u[0]))                      # a reset starts the same way
    np.testing.assert_allclose([fwd.step(float(a), float(b)) for a, b in zip(u, s)], want, atol=1e-10)


def test_a_play_correction_starts_from_the_estimated_history():
    """Without a rest drive, the core's initial state is estimated from the drive (the same for
    both models: it depends on the thresholds and the drive), and the correction follows it."""
    ext, moved = _pair("descending")
    t, u, s = _minor_loops()
    np.testing.assert_allclose(ext.simulate(t, u, s), moved.simulate(t, u, s), atol=1e-10)


def test_the_inverse_stepper_undoes_the_forward_from_the_same_start():
    ext, _ = _pair("descending")
    t, u, s = _minor_loops()
    y = ext.simulate(t, u, s, initial_drive=float(u[0]))
    inv = ext.inverse_stepper(1e-3, initial_drive=float(u[0]))
    back = np.array([inv.step(float(r), float(b)) for r, b in zip(y, s)])
    np.testing.assert_allclose(back, u, atol=1e-8)


# ---- the monotone-stretch rule, bounded by the model's drive range ---------------------------

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from gma_ffc.initial_state import monotone_play_state, monotone_start_drive  # noqa: E402


@st.composite
def bank(draw):
    n = draw(st.integers(1, 12))
    half = draw(st.floats(0.1, 5.0))
    r = np.arange(n) * draw(st.floats(0.3, 1.2)) * half / n
    w = np.array([draw(st.floats(1e-3, 10.0)) for _ in range(n)])
    return r, w, -half, half


@settings(max_examples=300, deadline=None)
@given(b=bank(), d=st.sampled_from([1, -1]), where=st.floats(-0.5, 1.5), shift=st.floats(-3.0, 3.0))
def test_the_monotone_start_is_reachable_and_solved_exactly(b, d, where, shift):
    r, w, lo, hi = b
    v0 = lo + where * (hi - lo)                       # inside the range and beyond it
    p = monotone_play_state(r, v0, d, lo, hi)
    assert np.all(p >= v0 - r - 1e-12) and np.all(p <= v0 + r + 1e-12)        # eq. (2) at the first sample
    a, c = min(lo, v0), max(hi, v0)
    assert np.all(p >= np.minimum(a + r, c - r) - 1e-12) and np.all(p <= np.maximum(a + r, c - r) + 1e-12)
    z0 = float(np.dot(w, p)) + shift                  # any play sum, reachable or not
    v = monotone_start_drive(w, r, z0, d, lo, hi)
    assert abs(float(np.dot(w, monotone_play_state(r, v, d, lo, hi))) - z0) <= 1e-9 * max(1.0, abs(z0))


def test_a_run_from_the_bottom_of_the_range_starts_at_the_loop_corner_whatever_the_first_noise():
    """A recording that starts at zero current starts at the major loop's corner (every play at
    lo + r, where a sweep down to lo leaves it), whether noise makes the drive's first move look
    like a rise or a fall; before, a first 'rise' put every play at lo - r, below the loop."""
    r = np.linspace(0.0, 1.35, 10)
    up = monotone_play_state(r, -1.5, 1, -1.5, 1.5)
    down = monotone_play_state(r, -1.5, -1, -1.5, 1.5)
    assert np.allclose(up, -1.5 + r) and np.allclose(down, up)
