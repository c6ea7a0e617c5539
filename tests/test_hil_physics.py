"""The simulated GMA does what docs/hil_sim.md says: each effect measured from its own signature."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import curve_fit

from gma_ffc.errors import ConfigError, InputError
from hil_sim.plant import EFFECTS, GMAPlant, PlantConfig

CONFIG_DIR = Path(__file__).resolve().parents[1] / "hil_sim" / "configs"
PAPER_STRESSES = (-11.3, -15.2, -19.1, -24.0)


def sine_drive(freq_hz: float, periods: int, fs: float) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(int(round(periods * fs / freq_hz))) / fs
    return t, 1.5 * (1.0 - np.cos(2 * np.pi * freq_hz * t))


def last_period(cfg: PlantConfig, freq_hz: float, fs: float, stress: float = -11.3, seed: int = 0,
                periods: int = 3) -> dict[str, np.ndarray]:
    """Run a full-range sine and keep the last period (the first is the virgin curve)."""
    t, i = sine_drive(freq_hz, periods, fs)
    out = GMAPlant(cfg, seed=seed).run(t, i, load_mass_kg=cfg.mass_for_stress(stress))
    keep = t >= (periods - 1) / freq_hz - 1e-12
    phase = (2 * np.pi * freq_hz * t[keep]) % (2 * np.pi)
    return {"phase": phase, "i": i[keep], "x": out["displacement_um"][keep]}


def coercive_current(loop: dict[str, np.ndarray]) -> float:
    """Horizontal loop width at mid-stroke: current on the rising minus the falling branch."""
    x, i, phase = loop["x"], loop["i"], loop["phase"]
    rising = phase < np.pi
    mid = 0.5 * (x.max() + x.min())
    up = np.interp(mid, x[rising], i[rising])
    fall_order = np.argsort(x[~rising])
    down = np.interp(mid, x[~rising][fall_order], i[~rising][fall_order])
    return float(up - down)


def loop_area(loop: dict[str, np.ndarray]) -> float:
    x, i = loop["x"], loop["i"]
    return float(abs(np.sum(0.5 * (x[1:] + x[:-1]) * np.diff(i))))


# --- contract -----------------------------------------------------------------------------------

def test_plant_contract_and_measured_attributes() -> None:
    cfg = PlantConfig()
    plant = GMAPlant(cfg, seed=0)
    plant.reset()
    plant.set_load_mass(15.3)
    for _ in range(200):
        plant.step(2.0, 1 / 2000)
    values = [plant.displacement_um, plant.current_A, plant.stress_MPa, plant.force_N, plant.temperature_C]
    assert all(isinstance(v, float) and math.isfinite(v) for v in values)
    assert plant.current_A == pytest.approx(2.0)
    assert plant.displacement_um > 10.0                # tens of micrometres at 2 A
    assert plant.stress_MPa == pytest.approx(-15.2, abs=0.2)
    assert plant.temperature_C == pytest.approx(cfg.thermal.ambient_C)
    assert plant.time_s == pytest.approx(0.1)


def test_stress_follows_load_mass_as_on_the_paper_rig() -> None:
    cfg = PlantConfig()
    assert cfg.stress_for_mass(0.0) == pytest.approx(-11.3)
    assert cfg.stress_for_mass(50.0) == pytest.approx(-24.0, abs=0.1)   # the paper's 50 kg
    t = np.arange(4000) / 2000
    mass = np.where(t < 1.0, 0.0, 50.0)
    out = GMAPlant(cfg).run(t, np.zeros_like(t), load_mass_kg=mass)
    assert out["stress_MPa"][1000] == pytest.approx(cfg.stress_for_mass(0.0), abs=0.01)
    assert out["stress_MPa"][3000] == pytest.approx(cfg.stress_for_mass(50.0), abs=0.01)
    assert out["force_N"][3000] - out["force_N"][1000] == pytest.approx(50.0 * 9.80665, rel=1e-3)


# --- quasi-static hysteresis --------------------------------------------------------------------

def _stress_loops(cfg: PlantConfig) -> tuple[dict, dict, dict]:
    loops = {s: last_period(cfg, 3.0, 2000.0, stress=s) for s in PAPER_STRESSES}
    strokes = {s: float(lp["x"].max() - lp["x"].min()) for s, lp in loops.items()}
    widths = {s: coercive_current(lp) for s, lp in loops.items()}
    for s, lp in loops.items():
        rising = lp["phase"] < np.pi
        assert np.all(np.diff(lp["x"][rising]) >= -1e-9), f"rising branch not monotone at {s} MPa"
        assert np.all(np.diff(lp["x"][~rising]) <= 1e-9), f"falling branch not monotone at {s} MPa"
        assert lp["x"].min() >= 0.0                     # unipolar drive, no butterfly
        assert 10.0 < strokes[s] < 100.0                # tens of micrometres
    assert all(strokes[a] > strokes[b] for a, b in zip(PAPER_STRESSES, PAPER_STRESSES[1:]))
    assert max(widths.values()) / min(widths.values()) < 1.1   # 'coercive current' nearly constant
    assert min(widths.values()) > 0.1                  # and a real hysteresis
    return loops, strokes, widths


def test_default_rig_changes_with_stress_like_the_papers_and_saturates() -> None:
    """The paper's MPI misses by 0.82 um at -15.2 MPa and only 1.04 um at -19.1 MPa: a loop change
    of about a micrometre that grows less and less with compression. The default rig's loops must
    differ by that order (far above a 0.02 um sensor) and the change must flatten."""
    loops, strokes, _ = _stress_loops(PlantConfig())
    diff = {s: float(np.max(np.abs(loops[s]["x"] - loops[-11.3]["x"]))) for s in PAPER_STRESSES[1:]}
    assert 0.2 < diff[-15.2] < 2.0 and 0.2 < diff[-24.0] < 3.0
    early = diff[-15.2] / (15.2 - 11.3)             # um per MPa near the preload
    late = (diff[-24.0] - diff[-15.2]) / (24.0 - 15.2)
    assert late < 0.5 * early                       # saturating with compression


def test_strong_stress_rig_loses_tens_of_percent_of_stroke() -> None:
    cfg = PlantConfig.from_yaml(Path(__file__).parents[1] / "hil_sim" / "configs" / "strong_stress.yaml")
    _, strokes, _ = _stress_loops(cfg)
    assert strokes[-24.0] < 0.8 * strokes[-11.3]       # tens of percent across the range


def test_stress_dependent_width_option_changes_the_loop_width_strongly() -> None:
    cfg = PlantConfig()
    cfg.magnetics.stress_dependent_width = True
    low = coercive_current(last_period(cfg, 3.0, 2000.0, stress=-11.3))
    high = coercive_current(last_period(cfg, 3.0, 2000.0, stress=-24.0))
    assert high > 1.4 * low


def test_three_hz_is_rate_independent_within_sensor_accuracy_even_with_eddy_currents() -> None:
    cfg = PlantConfig().with_effects(["eddy", "noise"])
    one, three = last_period(cfg, 1.0, 2000.0, seed=1), last_period(cfg, 3.0, 2000.0, seed=2)
    grid = np.linspace(0.05, 2 * np.pi - 0.05, 400)
    diff = np.interp(grid, three["phase"], three["x"]) - np.interp(grid, one["phase"], one["x"])
    assert np.sqrt(np.mean(diff ** 2)) < 0.1           # the paper's sensor accuracy, 0.1 um


def test_eddy_currents_widen_the_loop_with_frequency() -> None:
    off, on = PlantConfig(), PlantConfig().with_effects(["eddy"])
    fs = 20000.0
    area_off = {f: loop_area(last_period(off, f, fs)) for f in (3.0, 100.0)}
    area_on = {f: loop_area(last_period(on, f, fs)) for f in (3.0, 30.0, 100.0)}
    assert area_off[100.0] == pytest.approx(area_off[3.0], rel=0.01)   # JA alone is rate-independent
    assert area_on[3.0] == pytest.approx(area_off[3.0], rel=0.03)      # negligible at 3 Hz
    assert area_on[3.0] < area_on[30.0] < area_on[100.0]
    assert area_on[100.0] > 1.3 * area_on[3.0]


# --- dynamics -----------------------------------------------------------------------------------

def ringing_frequency(cfg: PlantConfig, load_kg: float, fs: float = 40000.0) -> float:
    """Small current step after settling; frequency from the zero crossings of the ringing."""
    t = np.arange(int(1.0 * fs)) / fs
    i = np.where(t < 0.6, 1.0, 1.2)
    x = GMAPlant(cfg).run(t, i, load_mass_kg=load_kg)["displacement_um"]
    after = t >= 0.6
    ring = x[after] - x[after][-int(0.05 * fs):].mean()
    ts = t[after]
    sign = np.signbit(ring)
    idx = np.nonzero(sign[1:] != sign[:-1])[0][:12]
    crossings = ts[idx] - ring[idx] * (ts[idx + 1] - ts[idx]) / (ring[idx + 1] - ring[idx])
    return 1.0 / (2.0 * float(np.mean(np.diff(crossings))))


def test_resonance_matches_stiffness_and_mass_and_moves_with_load() -> None:
    cfg = PlantConfig().with_effects(["dynamics"])
    measured = {m: ringing_frequency(cfg, m) for m in (0.0, 50.0)}
    for m, f in measured.items():
        expected = math.sqrt(cfg.stiffness_N_per_um * 1e6 / (cfg.dynamics.moving_mass_kg + m)) / (2 * math.pi)
        assert f == pytest.approx(expected, rel=0.05)
    assert measured[50.0] < 0.3 * measured[0.0]


# --- slow effects -------------------------------------------------------------------------------

def test_thermal_drift_follows_its_time_constant_and_recovers_at_zero_current() -> None:
    cfg = PlantConfig().with_effects(["thermal", "noise"])
    fs = 10.0
    t = np.arange(int(600 * fs)) / fs
    i = np.where(t < 300.0, 2.0, 0.0)
    out = GMAPlant(cfg, seed=3).run(t, i)
    x = out["displacement_um"]
    heat = (t > 0.05) & (t < 300.0)

    def rise(tt: np.ndarray, x0: float, amp: float, tau: float) -> np.ndarray:
        return x0 + amp * (1.0 - np.exp(-tt / tau))

    (_, amp, tau), _ = curve_fit(rise, t[heat], x[heat], p0=(x[heat][0], 1.0, 20.0))
    assert tau == pytest.approx(cfg.thermal.time_constant_s, rel=0.05)
    expected_rise = 2.0 ** 2 * cfg.thermal.coil_resistance_ohm * cfg.thermal.thermal_resistance_K_per_W
    assert amp == pytest.approx(expected_rise * cfg.thermal.drift_um_per_K, rel=0.1)
    assert out["temperature_C"][t < 300.0].max() == pytest.approx(cfg.thermal.ambient_C + expected_rise, abs=0.5)
    cold = t > 300.1
    (_, amp_c, tau_c), _ = curve_fit(rise, t[cold] - 300.0, x[cold], p0=(x[cold][0], -1.0, 20.0))
    assert tau_c == pytest.approx(cfg.thermal.time_constant_s, rel=0.05)
    assert abs(x[-50:].mean() - x[(t > 300.0) & (t < 300.5)].mean()) > 0.9 * abs(amp_c)   # it recovered


def test_creep_follows_the_direction_of_the_last_step() -> None:
    cfg = PlantConfig().with_effects(["creep"])
    fs = 100.0
    t = np.arange(int(80 * fs)) / fs
    i = np.where(t < 40.0, 2.0, 1.0)
    x = GMAPlant(cfg).run(t, i)["displacement_um"]
    up = x[(t > 0.05) & (t < 40.0)]
    down = x[t >= 40.0]
    assert up[-1] - up[0] > 0.01 * up[0]                     # keeps rising after an up step
    assert np.all(np.diff(up) >= -1e-12)
    assert down[-1] - down[0] < -0.005 * down[0]             # keeps falling after a down step
    assert np.all(np.diff(down) <= 1e-12)
    static = GMAPlant(PlantConfig()).run(t, i)["displacement_um"]
    assert np.array_equal(static[(t > 0.05) & (t < 40.0)], np.full(up.size, static[10]))   # no creep: flat


@pytest.mark.parametrize("delay_ms, shift", [(1.0, 2), (2.5, 5)])
def test_delay_shifts_the_displacement_by_exactly_its_length(delay_ms: float, shift: int) -> None:
    cfg = PlantConfig().with_effects(["delay"])
    cfg.delay.delay_ms = delay_ms
    t, i = sine_drive(3.0, 2, 2000.0)
    delayed = GMAPlant(cfg).run(t, i)["displacement_um"]
    plain = GMAPlant(PlantConfig()).run(t, i)["displacement_um"]
    assert np.array_equal(delayed[shift:], plain[:-shift])
    assert not np.array_equal(delayed, plain)


def test_a_delay_between_samples_is_resolved_on_the_sub_step_grid() -> None:
    """1.2 ms at 2 kHz: with sub-steps (amplifier on) the output is the position exactly 1.2 ms ago."""
    cfg = PlantConfig().with_effects(["amplifier", "delay"])
    cfg.delay.delay_ms = 1.2
    sub = round(0.5e-3 / (cfg.numerics.max_substep_us * 1e-6))          # 20 sub-steps per sample
    t, i = sine_drive(3.0, 1, 2000.0)
    delayed = GMAPlant(cfg).run(t, i)["displacement_um"]
    fine_t = np.arange(t.size * sub) * (0.5e-3 / sub)
    fine = GMAPlant(PlantConfig().with_effects(["amplifier"])).run(fine_t, np.repeat(i, sub))["displacement_um"]
    lag = round(1.2e-3 / (0.5e-3 / sub))                                # 48 sub-steps
    k = np.arange(3, t.size)
    assert np.allclose(delayed[k], fine[sub * k + sub - 1 - lag], rtol=0, atol=1e-9)


def test_amplifier_is_a_first_order_current_loop() -> None:
    cfg = PlantConfig().with_effects(["amplifier"])
    fs = 200000.0
    t = np.arange(400) / fs
    cur = GMAPlant(cfg).run(t, np.full(t.size, 2.0))["current_A"]
    tau = 1.0 / (2 * math.pi * cfg.amplifier.bandwidth_hz)
    assert np.allclose(cur, 2.0 * (1 - np.exp(-(t + 1 / fs) / tau)), atol=1e-6)


# --- runs, seeds, configs -----------------------------------------------------------------------

def test_batch_run_equals_stepping_sample_for_sample_with_everything_on() -> None:
    cfg = PlantConfig().with_effects(EFFECTS)
    fs = 2000.0
    t, i = sine_drive(7.0, 6, fs)
    mass = np.where(t < 0.4, 0.0, 30.0)
    batch = GMAPlant(cfg, seed=11).run(t, i, load_mass_kg=mass)
    plant = GMAPlant(cfg, seed=11)
    plant.reset()
    stepped = np.empty((5, t.size))
    for k in range(t.size):
        plant.set_load_mass(mass[k])
        plant.step(i[k], 1 / fs)
        stepped[:, k] = (plant.displacement_um, plant.current_A, plant.stress_MPa, plant.force_N,
                         plant.temperature_C)
    for row, name in enumerate(("displacement_um", "current_A", "stress_MPa", "force_N", "temperature_C")):
        assert np.array_equal(batch[name], stepped[row]), name


def test_noise_is_seeded_and_deterministic() -> None:
    cfg = PlantConfig().with_effects(["noise"])
    t, i = sine_drive(3.0, 1, 2000.0)
    a = GMAPlant(cfg, seed=5).run(t, i)
    b = GMAPlant(cfg, seed=5).run(t, i)
    c = GMAPlant(cfg, seed=6).run(t, i)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert not np.array_equal(a["displacement_um"], c["displacement_um"])
    clean = GMAPlant(PlantConfig()).run(t, i)["displacement_um"]
    resid = a["displacement_um"] - clean
    assert 0.5 * cfg.noise.displacement_std_um < resid.std() < 2.0 * cfg.noise.displacement_std_um
    q = cfg.noise.displacement_quantum_um
    assert np.allclose(a["displacement_um"] / q, np.round(a["displacement_um"] / q), atol=1e-6)


def test_everything_off_is_clean_quasi_static_hysteresis() -> None:
    cfg = PlantConfig()
    assert cfg.enabled_effects == []
    t, i = sine_drive(3.0, 2, 2000.0)
    out = GMAPlant(cfg).run(t, i)
    assert np.array_equal(out["current_A"], i)
    assert np.all(out["temperature_C"] == cfg.thermal.ambient_C)
    # a full period later, at the same current and direction, the same displacement (closed loop)
    n = int(2000 / 3)
    again = GMAPlant(cfg).run(np.arange(3 * n) / 2000.0, np.tile(i[:n], 3))["displacement_um"]
    assert np.allclose(again[2 * n:], again[n:2 * n], atol=0.05)


def test_shipped_configs_load_and_bad_configs_name_the_key(tmp_path: Path) -> None:
    for path in sorted(CONFIG_DIR.glob("*.yaml")):
        PlantConfig.from_yaml(path)
    realistic = PlantConfig.from_yaml(CONFIG_DIR / "realistic.yaml")
    assert realistic.enabled_effects == list(EFFECTS)
    bad = tmp_path / "bad.yaml"
    bad.write_text("thermal:\n  time_constnt_s: 60\n")
    with pytest.raises(ConfigError, match="thermal.time_constnt_s"):
        PlantConfig.from_yaml(bad)
    bad.write_text("dynamics:\n  moving_mass_kg: -1\n")
    with pytest.raises(ConfigError, match="dynamics.moving_mass_kg"):
        PlantConfig.from_yaml(bad)
    bad.write_text("noise: {enabled: maybe}\n")
    with pytest.raises(ConfigError, match="noise.enabled"):
        PlantConfig.from_yaml(bad)
    bad.write_text("rig: [1, 2\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        PlantConfig.from_yaml(bad)
    with pytest.raises(InputError, match="load mass"):
        GMAPlant(cfg := PlantConfig()).set_load_mass(float("nan"))
    with pytest.raises(InputError, match="unknown effect"):
        cfg.with_effects(["magic"])


def test_current_decaying_to_subnormal_values_is_handled() -> None:
    """Regression: the amplifier/eddy lags decay the field into subnormal floats at rest."""
    cfg = PlantConfig().with_effects(["amplifier", "eddy"])
    t = np.arange(3000) / 1000.0
    out = GMAPlant(cfg).run(t, np.where(t < 0.1, 1.0, 0.0))
    assert np.all(np.isfinite(out["displacement_um"]))
    assert out["current_A"][-1] == 0.0


def test_commands_outside_the_supply_range_are_clamped() -> None:
    plant = GMAPlant(PlantConfig())
    plant.step(float("nan"), 1e-3)
    assert plant.current_A == 0.0
    plant.step(-5.0, 1e-3)
    assert plant.current_A == 0.0
    plant.step(99.0, 1e-3)
    assert plant.current_A == PlantConfig().amplifier.max_current_A
