"""The alternative rig (scripts/unseen/alt_plant.py) does what it claims, effect by effect.

The unseen-case benchmark is only worth something if each effect is really in the data with
its own signature, and absent when switched off. The diagnosis itself is not run here (that is
the benchmark's job).
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "unseen"))

from alt_plant import EFFECTS, AltGMAPlant, AltPlantConfig, delay_signal  # noqa: E402
import cases as case_gen  # noqa: E402
import signals as sg  # noqa: E402

from gma_ffc.recordings import read_recording  # noqa: E402

CLEAN = AltPlantConfig(noise=False)


def _sweep(freq: float = 3.0, periods: int = 4, rate: float = 2000.0, lo: float = 0.0, hi: float = 2.0):
    t = sg.time_axis(rate, periods / freq)
    return t, sg.cosine_sweep(t, freq, lo, hi)


def _last_period(t: np.ndarray, freq: float) -> np.ndarray:
    return t >= t[-1] - 1.0 / freq


def _loop_width_and_stroke(i: np.ndarray, x: np.ndarray) -> tuple[float, float]:
    """Current difference between the rising and falling branch at mid-stroke, and the stroke."""
    k = int(np.argmax(i))
    lo_x, hi_x = x.min(), x.max()
    mid = 0.5 * (lo_x + hi_x)
    rise_i, rise_x = i[: k + 1], x[: k + 1]
    fall_i, fall_x = i[k:][::-1], x[k:][::-1]
    i_up = np.interp(mid, np.maximum.accumulate(rise_x), rise_i)
    i_down = np.interp(mid, np.maximum.accumulate(fall_x), fall_i)
    return float(i_up - i_down), float(hi_x - lo_x)


def _loop(cfg: AltPlantConfig, stress: float, freq: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """Last of four periods, 600 samples per period at every frequency (same drive samples)."""
    t, i = _sweep(freq, rate=600.0 * freq)
    out = AltGMAPlant(cfg).run(t, i, cfg.mass_for_stress(stress))
    last = _last_period(t, freq)
    start = np.argmin(i[last])   # last period from its minimum: rise then fall
    return np.roll(i[last], -start), np.roll(out["displacement_um"][last], -start)


def test_stroke_falls_with_compression_while_loop_width_stays():
    w11, s11 = _loop_width_and_stroke(*_loop(CLEAN, -11.3))
    w24, s24 = _loop_width_and_stroke(*_loop(CLEAN, -24.0))
    assert 20.0 < s11 < 25.0 and 14.0 < s24 < 18.0           # stroke in its own range, not hil_sim's
    assert s24 < 0.8 * s11
    assert w11 > 0.15 and abs(w24 - w11) < 0.05 * w11        # coercive current ~ constant


def test_stress_dependent_play_widens_the_loop_with_compression():
    cfg = CLEAN.with_effect("stress_dependent_play", "clear")
    w11, _ = _loop_width_and_stroke(*_loop(cfg, -11.3))
    w24, _ = _loop_width_and_stroke(*_loop(cfg, -24.0))
    base11, _ = _loop_width_and_stroke(*_loop(CLEAN, -11.3))
    assert abs(w11 - base11) < 0.03 * base11                 # no change at the preload stress
    assert w24 > 1.3 * w11


def test_base_hysteresis_is_rate_independent_and_diffusion_makes_it_rate_dependent():
    slow_i, slow_x = _loop(CLEAN, -15.0, freq=1.0)
    fast_i, fast_x = _loop(CLEAN, -15.0, freq=50.0)
    assert np.allclose(slow_i, fast_i, rtol=0, atol=1e-9)
    assert np.max(np.abs(slow_x - fast_x)) < 1e-6             # same loop at 1 Hz and 50 Hz without the effect
    cfg = CLEAN.with_effect("rate_dependence", "clear")
    _, x_slow = _loop(cfg, -15.0, freq=1.0)
    _, x_fast = _loop(cfg, -15.0, freq=50.0)
    assert np.max(np.abs(x_slow - slow_x)) < 0.3              # quasi-static: hardly any effect
    assert np.max(np.abs(x_fast - fast_x)) > 2.0              # the diffusion lag changes fast loops
    w_base, _ = _loop_width_and_stroke(slow_i, slow_x)
    w_fast, _ = _loop_width_and_stroke(fast_i, x_fast)
    assert w_fast > 1.5 * w_base                              # ... and widens them
    # at DC the field has diffused in completely: same displacement as without the effect
    t = sg.time_axis(1000.0, 1.0)
    i = np.full(t.size, 1.2)
    a = AltGMAPlant(cfg).run(t, i)["displacement_um"]
    b = AltGMAPlant(CLEAN).run(t, i)["displacement_um"]
    assert a[0] < 0.9 * b[0] and abs(a[-1] - b[-1]) < 1e-6


@pytest.mark.parametrize("delay_ms, rate", [(0.4, 5000.0), (0.3, 5000.0)])
def test_delay_shifts_exactly_even_by_a_fraction_of_a_sample(delay_ms: float, rate: float):
    t = sg.time_axis(rate, 0.5)
    i = sg.band_limited_random(t, 1.0, 80.0, 0.1, 1.9, np.random.default_rng(3))
    base = AltGMAPlant(CLEAN).run(t, i)["displacement_um"]
    late = AltGMAPlant(replace(CLEAN, delay_ms=delay_ms)).run(t, i)["displacement_um"]
    shift = delay_ms * 1e-3 * rate                            # 2 and 1.5 samples
    n0, frac = int(np.floor(shift)), shift - np.floor(shift)
    expect = (1 - frac) * base[: base.size - n0] + frac * np.concatenate(([base[0]], base[: base.size - n0 - 1]))
    assert np.allclose(late[n0 + 1:], expect[1:], atol=1e-12)
    assert not np.allclose(late, base, atol=1e-3)
    assert np.array_equal(delay_signal(t, base, 0.0), base)


def _ringing_hz(cfg: AltPlantConfig, load_kg: float) -> float:
    rate = 50000.0
    t = sg.time_axis(rate, 0.06)
    i = np.where(t < 0.01, 0.8, 1.1)
    out = AltGMAPlant(cfg).run(t, i, load_kg)
    e = (out["true_displacement_um"] - out["free_strain_um"])[t > 0.0105]
    crossings = np.flatnonzero(np.diff(np.signbit(e)))
    # interpolated zero crossings, half a period apart
    tz = [(k + e[k] / (e[k] - e[k + 1])) / rate for k in crossings[:8]]
    return float(1.0 / (2.0 * np.mean(np.diff(tz))))


def test_resonance_at_the_expected_frequency_and_moves_with_load():
    cfg = CLEAN.with_effect("mechanical_dynamics", "clear")
    z = cfg.damping_ratio
    for load in (10.0, 60.0):
        f = _ringing_hz(cfg, load)
        assert f == pytest.approx(cfg.resonance_hz(load) * np.sqrt(1 - z * z), rel=0.02)
    assert cfg.resonance_hz(60.0) < 0.5 * cfg.resonance_hz(10.0)
    # off: no ringing at all, the displacement is the free strain
    t = sg.time_axis(5000.0, 0.05)
    out = AltGMAPlant(CLEAN).run(t, np.where(t < 0.01, 0.8, 1.1), 30.0)
    assert np.array_equal(out["true_displacement_um"], out["free_strain_um"])


def test_thermal_drift_has_two_time_constants_and_recovers_at_zero_current():
    cfg = replace(CLEAN.with_effect("thermal_drift", "clear"), spring_N_per_um=0.0)  # no stress feedback
    fast, slow = cfg.thermal_time_constants_s()
    assert slow > 5 * fast
    dt, amps = 0.05, 1.5
    t = np.arange(0, 900.0, dt)
    i = np.where(t < 600.0, amps, 0.0)
    on = AltGMAPlant(cfg).run(t, i)
    off = AltGMAPlant(replace(CLEAN, spring_N_per_um=0.0)).run(t, i)
    # coil/rod temperatures follow the analytic two-node solution under constant heating
    from alt_plant import _thermal_matrix
    a = _thermal_matrix(cfg)
    b = np.array([cfg.coil_resistance_ohm * amps ** 2 / cfg.coil_heat_capacity_J_per_K, 0.0])
    for tk in (10.0, 60.0, 300.0):
        rise = (scipy.linalg.expm(a * tk) - np.eye(2)) @ np.linalg.solve(a, b)
        k = int(round(tk / dt)) - 1
        assert on["true_coil_temperature_C"][k] - cfg.ambient_C == pytest.approx(rise[0], rel=0.01)
        assert on["true_rod_temperature_C"][k] - cfg.ambient_C == pytest.approx(rise[1], rel=0.01)
    # the drift is exactly rod + coil expansion and the stroke's temperature coefficient
    d_rod = on["true_rod_temperature_C"] - cfg.ambient_C
    d_coil = on["true_coil_temperature_C"] - cfg.ambient_C
    expect = (off["true_displacement_um"] * (1 - cfg.stroke_tempco_per_K * d_rod)
              + cfg.rod_expansion_um_per_K * d_rod + cfg.coil_expansion_um_per_K * d_coil)
    assert np.allclose(on["true_displacement_um"], expect, atol=1e-9)
    drift = on["true_displacement_um"] - off["true_displacement_um"]
    k600 = int(600.0 / dt) - 1
    assert drift[k600] > 1.0                                   # clear: micrometres of drift
    assert abs(drift[-1]) < 0.5 * drift[k600]                  # cools down at zero current
    assert np.array_equal(off["true_coil_temperature_C"], on["true_coil_temperature_C"])  # heating is always there


def test_creep_is_logarithmic_in_time_and_follows_the_step_direction():
    cfg = CLEAN.with_effect("creep", "clear")
    dt = 0.01
    t = np.arange(0, 400.0, dt)
    up = np.where(t < 1.0, 0.2, 1.6)
    on = AltGMAPlant(cfg).run(t, up)["true_displacement_um"]
    off = AltGMAPlant(CLEAN).run(t, up)["true_displacement_um"]
    assert np.allclose(off[t > 1.1], off[-1], rtol=0, atol=1e-9)  # no creep without the effect
    creep = on - off * (on[int(1.0 / dt) + 1] / off[int(1.0 / dt) + 1])
    at = {s: creep[int((1.0 + s) / dt)] for s in (1.0, 10.0, 100.0)}
    dec1, dec2 = at[10.0] - at[1.0], at[100.0] - at[10.0]
    assert dec1 > 0 and dec2 == pytest.approx(dec1, rel=0.15)   # equal rise per decade: log law
    step = off[-1] - off[int(0.5 / dt)]
    assert dec1 == pytest.approx(cfg.creep_per_decade * step, rel=0.25)
    down = np.where(t < 1.0, 1.6, 0.2)
    on_d = AltGMAPlant(cfg).run(t, down)["true_displacement_um"]
    assert on_d[int(100 / dt)] < on_d[int(2 / dt)]             # after a step down it creeps down


def test_saturation_flattens_the_curve_beyond_the_knee():
    cfg = replace(CLEAN, saturation_knee_A=1.2, saturation_softness_A=0.15)
    t = sg.time_axis(1000.0, 3.0)
    i = np.minimum(t, 2.0)
    on = AltGMAPlant(cfg).run(t, i)["true_displacement_um"]
    off = AltGMAPlant(CLEAN).run(t, i)["true_displacement_um"]
    below = t <= 1.2
    assert np.array_equal(on[below], off[below])
    k = lambda a: int(a * 1000)  # noqa: E731
    assert on[k(1.9)] - on[k(1.6)] < 0.2 * (off[k(1.9)] - off[k(1.6)])


def test_every_effect_switches_on_and_off():
    t = sg.time_axis(2000.0, 3.0)
    i = sg.band_limited_random(t, 0.5, 60.0, 0.05, 2.0, np.random.default_rng(1))
    base = AltGMAPlant(CLEAN).run(t, i, 40.0)["true_displacement_um"]
    for effect in EFFECTS:
        for level, floor in (("clear", 0.05), ("subtle", 0.005)):
            x = AltGMAPlant(CLEAN.with_effect(effect, level)).run(t, i, 40.0)["true_displacement_um"]
            assert np.sqrt(np.mean((x - base) ** 2)) > floor, (effect, level)
    with pytest.raises(ValueError, match="unknown effect"):
        CLEAN.with_effect("eddy", "clear")


def test_deterministic_by_seed_and_noise_only_on_the_measurement():
    cfg = AltPlantConfig()
    t = sg.time_axis(1000.0, 1.0)
    i = sg.triangle(t, 3.0, 0.0, 2.0)
    a = AltGMAPlant(cfg, seed=5).run(t, i, 20.0)
    b = AltGMAPlant(cfg, seed=5).run(t, i, 20.0)
    c = AltGMAPlant(cfg, seed=6).run(t, i, 20.0)
    for key in ("displacement_um", "current_A", "stress_MPa", "temperature_C"):
        assert np.array_equal(a[key], b[key])
        assert not np.array_equal(a[key], c[key])
    assert np.array_equal(a["true_displacement_um"], c["true_displacement_um"])
    noise = a["displacement_um"] - a["true_displacement_um"]
    assert 0.005 < np.std(noise) < 0.03
    assert np.allclose(a["displacement_um"] / cfg.displacement_lsb_um,
                       np.round(a["displacement_um"] / cfg.displacement_lsb_um), atol=1e-6)


def test_cases_are_concealed_readable_and_reproducible(tmp_path: Path):
    keys = ["creep-subtle", "null-3"]
    m1 = case_gen.generate(tmp_path / "a", seed=4, keys=keys)
    m2 = case_gen.generate(tmp_path / "b", seed=4, keys=keys)
    assert [c["id"] for c in m1["cases"]] == [c["id"] for c in m2["cases"]]
    truth = yaml.safe_load((tmp_path / "a" / "manifest.yaml").read_text())
    assert sorted(c["key"] for c in truth["cases"]) == sorted(keys)
    banned = list(EFFECTS) + ["clear", "subtle", "null", "creep", "delay", "thermal", "manifest"]
    for case in m1["cases"]:
        folder = tmp_path / "a" / case["id"]
        files = sorted(folder.rglob("*.csv"))
        assert len(files) == 4 + len(case["test_files"])
        for f in files:
            text = f.read_text()
            head = "\n".join(ln for ln in text.splitlines() if ln.startswith("#") or ln.startswith("time_s"))
            assert not any(word in head.lower() or word in f.name.lower() for word in banned)
            rec = read_recording(f)
            assert rec.stress_MPa is not None and np.all(rec.stress_MPa < -10.0)
        assert not any(p.name == "manifest.yaml" for p in folder.rglob("*"))
        assert (folder / "ident").is_dir() and (folder / "tests").is_dir()
    a_files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*.csv"))
    for rel in a_files:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes()
    with pytest.raises(ValueError, match="unknown case key"):
        case_gen.generate(tmp_path / "c", keys=["no-such-case"])
