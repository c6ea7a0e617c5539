"""The extended model is a first-class model: steppers equal batch, inverse undoes forward, files round-trip."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gma_ffc.extended import ExtendedModel
from gma_ffc.errors import ModelError
from gma_ffc.identify import SDPIIdentifier
from gma_ffc.modelio import load_model, save_model
from gma_ffc.recordings import Recording

FS = 1000.0


def _loop_recording(stress: float, seed: int) -> Recording:
    """A synthetic rate-independent hysteresis (two plays and a curved output) at one stress."""
    t = np.arange(int(2.0 * FS)) / FS
    u = 1.0 - np.cos(2 * np.pi * 3 * t)
    plays = []
    for r in (0.05, 0.2):
        y, out = u[0], np.empty_like(u)
        for k, v in enumerate(u):
            y = min(max(y, v - r), v + r)
            out[k] = y
        plays.append(out)
    gain = 10.0 * (1 + 0.02 * (stress + 15))
    x = gain * (0.5 * u + 0.3 * plays[0] + 0.2 * plays[1]) + 1.5 * u ** 2
    x = x + np.random.default_rng(seed).normal(0, 0.01, t.size)
    return Recording({"time_s": t, "current_A": u, "stress_MPa": np.full(t.size, stress), "displacement_um": x},
                     {}, f"loop_{stress}.csv")


@pytest.fixture(scope="module")
def base():
    return SDPIIdentifier(n_play=6, n_deadzone=5).fit([_loop_recording(s, i) for i, s in
                                                       enumerate((-12.0, -16.0, -20.0))]).model_


def _all_blocks(base) -> ExtendedModel:
    return ExtendedModel(base, {
        "eddy_lag": {"tau_s": 0.004},
        "delay": {"delay_s": 0.0025},
        "static": {"offset_um": 0.3, "gain": 1.05, "stress_gain_per_MPa": 0.002, "quadratic_per_um": 0.001,
                   "center_um": 10.0, "stress_ref_MPa": -16.0},
        "play_correction": {"thresholds": [0.1, 0.3], "coefficients": [0.5, -0.2]},
        "stress_play": {"thresholds": [0.2], "coefficients_per_MPa": [0.05]},
        "stress_width": {"coef_per_MPa": 0.04, "eps": 0.3},
        "loop_width": {"kappa_per_MPa": 0.03, "stress_ref_MPa": -16.0},
        "saturation": {"lo": 0.0, "hi": 1.8, "lin_lo": 0.0, "quad_lo": 0.0, "lin_hi": -1.0, "quad_hi": -2.0},
        "creep": {"gain": 0.03, "tau_s": 0.2},
        "dynamics": {"f_ref_hz": 60.0, "zeta": 0.2, "beta_per_MPa": 0.05, "stress_ref_MPa": -12.0},
        "thermal": {"gain_um_per_A2": 0.4, "tau_s": 3.0, "fast_gain_um_per_A2": -0.2, "fast_tau_s": 0.4},
    }, ["rate_dependence", "time_delay"])


def _drive(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.arange(n) / FS
    u = 1.0 - np.cos(2 * np.pi * 4 * t) * np.exp(-0.1 * t)
    s = -13.0 - 6.0 * (t > t[-1] / 2)
    return t, u, s


def test_forward_stepper_equals_batch(base):
    m = _all_blocks(base)
    t, u, s = _drive(1500)
    batch = m.simulate(t, u, s, initial_drive=float(u[0]))     # the stepper's start: relaxed-from u[0]
    fwd = m.forward_stepper(1 / FS, initial_drive=float(u[0]))
    steps = np.array([fwd.step(float(a), float(b)) for a, b in zip(u, s)])
    np.testing.assert_allclose(steps, batch, rtol=1e-9, atol=1e-9)
    # the blocks matter: the extended prediction is not the base's
    assert np.max(np.abs(batch - base.simulate(t, u, s))) > 0.5
    fwd.reset(float(u[0]))
    again = np.array([fwd.step(float(a), float(b)) for a, b in zip(u, s)])
    np.testing.assert_allclose(again, batch, rtol=1e-9, atol=1e-9)


def test_invert_then_simulate_recovers_the_reference(base):
    # every block is inverted exactly (the loop width by the widened core's own inverse, the play
    # terms and saturation solved with the core's inverse each sample) but the delay, by preview,
    # and the heating, from the previous sample's drive
    m = _all_blocks(base)
    t = np.arange(3000) / FS
    ref = 8.0 + 6.0 * np.sin(2 * np.pi * 2 * t) ** 2
    s = np.full(t.size, -15.0)
    drive = m.invert(t, ref, s)
    x0 = base.drive_range[0]      # invert assumes the actuator at rest there, as the core's own inverse does
    y = m.simulate(t, drive, s, initial_drive=x0)
    # the delay is compensated by preview: the output follows the reference once the preview has passed
    settled = slice(200, t.size - 10)
    err = y[settled] - ref[settled]
    assert np.sqrt(np.mean(err ** 2)) < 0.02 * np.ptp(ref)
    assert m.preview_s == pytest.approx(0.0025)
    # without the blocks in the inverse the error is far larger: the test can fail
    plain = m.simulate(t, base.invert(t, ref, s), s, initial_drive=x0)
    assert np.sqrt(np.mean((plain[settled] - ref[settled]) ** 2)) > 5 * np.sqrt(np.mean(err ** 2))


def test_inverse_stepper_matches_batch_invert(base):
    blocks = {k: v for k, v in _all_blocks(base).blocks().items() if v and k != "delay"}
    m = ExtendedModel(base, blocks)
    t = np.arange(800) / FS
    ref = 5.0 + 4.0 * np.sin(2 * np.pi * 3 * t)
    batch = m.invert(t, ref, np.full(t.size, -14.0))
    inv = m.inverse_stepper(1 / FS, initial_drive=0.0)
    steps = np.array([inv.step(float(r), -14.0) for r in ref])
    np.testing.assert_allclose(steps, batch, rtol=1e-12, atol=1e-12)


def test_file_round_trip_and_registration(base, tmp_path):
    m = _all_blocks(base)
    path = tmp_path / "ext.yaml"
    save_model(m, path)
    loaded = load_model(path)
    assert loaded.kind == "extended" and isinstance(loaded, ExtendedModel)
    t, u, s = _drive(600)
    np.testing.assert_allclose(loaded.simulate(t, u, s), m.simulate(t, u, s), rtol=1e-12, atol=1e-12)
    assert set(loaded.to_dict()["inverted"]) == {k for k, v in m.blocks().items() if v}
    assert loaded.stress_range_MPa == base.stress_range_MPa


@pytest.mark.parametrize("block, bad, words", [
    ("eddy_lag", {"tau_s": -1.0}, "eddy_lag.tau_s"),
    ("dynamics", {"f_ref_hz": 50.0, "zeta": math.nan}, "dynamics.zeta"),
    ("flux_capacitor", {"x": 1}, "unknown block"),
    ("stress_play", {"thresholds": [0.1, 0.2], "coefficients_per_MPa": [1.0]}, "stress_play"),
    ("stress_width", {"coef_per_MPa": 0.1, "eps": 0.0}, "stress_width.eps"),
    ("stress_width", {"coef_per_MPa": "wide", "eps": 0.3}, "stress_width.coef_per_MPa"),
])
def test_damaged_files_are_refused_with_the_key(base, block, bad, words):
    d = ExtendedModel(base, {}).to_dict()
    d["blocks"][block] = bad
    with pytest.raises(ModelError, match=words.replace(".", r"\.")):
        ExtendedModel.from_dict(d)


def test_missing_base_is_refused(base):
    d = ExtendedModel(base, {}).to_dict()
    del d["base"]
    with pytest.raises(ModelError, match="base"):
        ExtendedModel.from_dict(d)


def test_stress_width_widens_the_core_loop_with_stress_and_is_inverted(base):
    """The loop-width block: no effect at the reference stress, a wider loop beyond it; the inverse
    (one sample behind on the widened core) still tracks the reference."""
    static = {"offset_um": 0.0, "gain": 1.0, "stress_gain_per_MPa": 0.0, "quadratic_per_um": 0.0,
              "center_um": 0.0, "stress_ref_MPa": -16.0}
    m = ExtendedModel(base, {"static": static, "stress_width": {"coef_per_MPa": -0.08, "eps": 0.3}})   # wider under more compression
    t = np.arange(1000) / FS
    u = 1.0 - np.cos(2 * np.pi * 2 * t)
    at_ref = m.simulate(t, u, np.full(t.size, -16.0))
    np.testing.assert_allclose(at_ref, base.simulate(t, u, np.full(t.size, -16.0)), atol=1e-9)
    s = np.full(t.size, -20.0)
    y, yb = m.simulate(t, u, s), base.simulate(t, u, s)

    def width(x: np.ndarray) -> float:      # rising minus falling branch at mid drive, second cycle
        k = np.arange(500, 1000)
        mid = np.abs(u[k] - 1.0) < 0.05
        rising = np.gradient(u)[k] > 0
        return float(np.mean(x[k][mid & ~rising]) - np.mean(x[k][mid & rising]))

    assert width(y) > width(yb) * 1.1
    ref = 4.0 + 3.0 * np.sin(2 * np.pi * 2 * t) ** 2
    drive = m.invert(t, ref, s)
    x0 = base.drive_range[0]
    out = m.simulate(t, drive, s, initial_drive=x0)
    plain = m.simulate(t, base.invert(t, ref, s), s, initial_drive=x0)
    settled = slice(100, None)
    err = np.sqrt(np.mean((out[settled] - ref[settled]) ** 2))
    assert err < 0.5 * np.sqrt(np.mean((plain[settled] - ref[settled]) ** 2))
