"""The extended model's inverse is exact when sum terms depend on the core input, not only on y_c.

The plays of play_correction, stress_play and saturation and the saturation hinge are functions of this
sample's core input, which the inverse is solving for. Taking them at the previous sample's input
(the earlier scheme) is one fixed-point iteration per sample: where such a term's slope exceeds the
core's, the drive oscillates at the sample rate. The inverse now solves each sample's scalar
equation; these properties hold on random valid SDPI cores with random terms of both strengths.
"""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gma_ffc.extended import ExtendedModel
from gma_ffc.model import SDPIModel
from test_inverse import STRESS, drive_from_rng, sdpi_models

DT = 1e-3


def _sum_terms(rng: np.random.Generator, core: SDPIModel, strength: float) -> dict:
    """Sum-stage blocks that keep the whole model strictly increasing in the drive (so it has an
    exact inverse): play corrections with c_j <= 0 and stress plays with ds c_j <= 0 add slope in
    [0, |c|]; the saturation hinges steepen the curve beyond the range. `strength` scales them
    against the core's own slope; above about 1 the lagged scheme oscillated. Saturation's wide
    plays, c_j (H_rj - H_rj at the start) with c_j >= 0, add slope in [0, c] too."""
    n = int(rng.integers(1, 5))
    th = np.sort(rng.uniform(0.02, 1.0, n))
    slope = float(core.play_weights[0])          # the r = 0 play's weight: the least slope of the core's PI part
    wide = np.sort(rng.uniform(1.0, 3.0, 3))
    wide_coefficients = strength * slope * rng.dirichlet(np.ones(3))
    return {
        "static": {"offset_um": float(rng.uniform(-1, 1)), "gain": float(rng.uniform(0.5, 1.5)),
                   "stress_gain_per_MPa": float(rng.uniform(-0.01, 0.01)), "quadratic_per_um": 0.0,
                   "center_um": 0.0, "stress_ref_MPa": STRESS[1]},
        "play_correction": {"thresholds": th.tolist(),
                            "coefficients": (-strength * slope * rng.dirichlet(np.ones(n))).tolist()},
        "stress_play": {"thresholds": th[:1].tolist(), "coefficients_per_MPa": [float(rng.uniform(0, 0.05))]},
        "saturation": {"lo": -2.0, "hi": 3.0, "lin_lo": float(-rng.uniform(0, 1)), "quad_lo": float(-rng.uniform(0, 1)),
                       "lin_hi": float(rng.uniform(0, 1)), "quad_hi": float(rng.uniform(0, 1)),
                       "play_thresholds": wide.tolist(), "play_coefficients": wide_coefficients.tolist()},
        "creep": {"gain": float(rng.uniform(0, 0.05)), "tau_s": float(rng.uniform(0.005, 0.5))},
    }


def _model_and_drive(core: SDPIModel, seed: int, strength: float) -> tuple[ExtendedModel, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    m = ExtendedModel(core, _sum_terms(rng, core, strength))
    x, stress = drive_from_rng(rng, int(rng.integers(2, 20)))
    return m, x, stress


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(core=sdpi_models(), seed=st.integers(0, 2**32 - 1), strength=st.floats(0.0, 20.0))
def test_inverse_after_forward_returns_the_drive_whatever_the_play_terms_slope(core, seed, strength) -> None:
    m, x, stress = _model_and_drive(core, seed, strength)
    fwd = m.forward_stepper(DT, initial_drive=float(x[0]))
    y = np.array([fwd.step(float(a), float(s)) for a, s in zip(x, stress)])
    inv = m.inverse_stepper(DT, initial_drive=float(x[0]))
    x_back = np.array([inv.step(float(r), float(s)) for r, s in zip(y, stress)])
    assert np.max(np.abs(x_back - x)) <= 1e-8 * max(np.ptp(x), 1e-3)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(core=sdpi_models(), seed=st.integers(0, 2**32 - 1), strength=st.floats(0.0, 20.0))
def test_forward_after_inverse_returns_the_reference(core, seed, strength) -> None:
    m, x, stress = _model_and_drive(core, seed, strength)
    t = np.arange(x.size) * DT
    ref = m.simulate(t, x, stress, initial_drive=float(x[0]))         # a reference the model can reach
    smooth = ref[0] + np.cumsum(np.r_[0.0, np.diff(ref)] * 0.7)       # and a different one, also inside
    for r in (ref, smooth):
        inv = m.inverse_stepper(DT, initial_drive=float(x[0]))
        drive = np.array([inv.step(float(a), float(s)) for a, s in zip(r, stress)])
        y = m.simulate(t, drive, stress, initial_drive=float(x[0]))
        assert np.max(np.abs(y - r)) <= 1e-8 * max(np.ptp(r), 1e-3)


def test_a_strong_play_correction_no_longer_makes_the_drive_chatter() -> None:
    # a steep play correction on a flat core: the previous sample's play states made a fixed point
    # that overshot by more than it corrected, so the drive alternated every sample
    core = SDPIModel(np.array([0.0, 0.2]), np.array([1.0, 0.5]), np.array([0.0]), np.array([[2.0], [0.0], [0.0]]),
                     stress_range_MPa=STRESS, drive_range=(0.0, 2.0))
    m = ExtendedModel(core, {"static": {"stress_ref_MPa": -15.0},
                             "play_correction": {"thresholds": [0.3], "coefficients": [-6.0]}})
    t = np.arange(2000) * DT
    ref = 2.0 + 1.5 * (1 - np.cos(2 * np.pi * 2 * t))
    drive = m.invert(t, ref, np.full(t.size, -15.0))
    y = m.simulate(t, drive, np.full(t.size, -15.0), initial_drive=core.drive_range[0])
    assert np.max(np.abs(y - ref)) < 1e-9 * np.ptp(ref)
    # a 2 Hz drive has no sample-to-sample sign changes of its increments but at its two turns per period
    d = np.diff(drive)
    flips = int(np.sum(d[1:] * d[:-1] < -1e-18))
    assert flips <= 2 * 2 * t[-1] + 2, f"{flips} sign changes of the drive's increments in {t[-1]:.1f} s"
