"""A second simulated GMA, written independently of hil_sim and of gma_ffc's model.

Why it exists: `gma-ffc diagnose` is proven on hil_sim (Jiles-Atherton, first-order eddy lag,
exponential creep, ...). To see whether it generalises, it must also be judged on a rig whose
physics and numbers it has never seen. This plant shares no code, no parameter values and no
effect laws with hil_sim, and it is not a Prandtl-Ishlinskii model:

* hysteresis: a Preisach model of relays (centre c, half-width r) with a bell-shaped density in
  c and in r; drive 0..2 A, stroke 23 um at -11.3 MPa falling to 16 um at -24 MPa, curve shape
  (exponent of the magnetisation-to-strain map) changing with stress, loop width (relay
  half-widths, the "coercive current") independent of stress;
* rate_dependence: magnetic diffusion into a conducting rod (radial finite volumes, implicit),
  one relay population per radial shell - a distributed lag, not a first-order one;
* mechanical_dynamics: rod + load as an exactly discretised 2nd-order system; the resonance
  moves with the load mass and the load cell sees the inertial force (the magnetics see the
  static stress only: the Delta-E coupling of dynamic stress into strain is left out);
* thermal_drift: two thermal nodes (coil and rod), so the drift has two time constants;
  rod expansion, coil-former expansion and a stroke temperature coefficient;
* creep: a logarithmic creep law (a Prony series of relaxations with log-spaced time
  constants, equal weight per decade);
* time_delay: a fractional-sample acquisition delay of the displacement channel;
* stress_dependent_play: relay half-widths grow with compression;
* saturation: the field is soft-clipped above a knee current.

Units: A, um, MPa (compression negative), s, degC. Noise and quantisation are seeded.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from numba import njit

G = 9.80665
EFFECTS = ("rate_dependence", "mechanical_dynamics", "thermal_drift", "creep", "time_delay",
           "stress_dependent_play", "saturation")
N_SHELLS = 6          # radial finite volumes when diffusion is on
CREEP_PER_DECADE = 4  # Prony terms per decade of the creep law


@dataclass(frozen=True)
class AltPlantConfig:
    """Every parameter of the alternative rig; an effect is off when its switch value is 0."""

    # rig geometry and loading
    rod_diameter_mm: float = 8.0
    preload_MPa: float = -11.3
    spring_N_per_um: float = 0.35          # preload spring, adds stress as the rod extends
    ambient_C: float = 22.0
    # Preisach hysteresis
    centre_lo_A: float = 0.0
    centre_hi_A: float = 1.6
    centre_peak_A: float = 0.8
    centre_spread_A: float = 0.55
    half_width_A: float = 0.16             # most probable relay half-width (coercive current)
    half_width_spread_A: float = 0.07
    n_centres: int = 28
    n_widths: int = 10
    stroke_um: float = 23.0                # at the preload stress
    stroke_loss_per_MPa: float = 0.024     # fraction of stroke lost per MPa more compression
    shape_exponent: float = 1.3           # strain ~ magnetisation ** exponent
    shape_exponent_per_MPa: float = 0.02
    # rate_dependence (magnetic diffusion time mu*sigma*R^2; 0 = off)
    diffusion_time_ms: float = 0.0
    # mechanical_dynamics (off: the displacement follows the free strain at once)
    dynamics: bool = False
    rod_stiffness_N_per_um: float = 30.0
    moving_mass_kg: float = 0.9
    damping_ratio: float = 0.08
    # thermal (temperatures are always simulated; thermal_drift is their effect on displacement)
    coil_resistance_ohm: float = 2.4
    coil_heat_capacity_J_per_K: float = 20.0
    rod_heat_capacity_J_per_K: float = 60.0
    coil_to_rod_W_per_K: float = 0.8
    coil_to_ambient_W_per_K: float = 0.5
    rod_to_ambient_W_per_K: float = 0.4
    rod_expansion_um_per_K: float = 0.0
    coil_expansion_um_per_K: float = 0.0
    stroke_tempco_per_K: float = 0.0
    # creep (fraction of a displacement change added per decade of time; 0 = off)
    creep_per_decade: float = 0.0
    creep_tau_min_s: float = 0.2
    creep_tau_max_s: float = 500.0
    # time_delay (displacement acquisition delay; 0 = off)
    delay_ms: float = 0.0
    # stress_dependent_play (relative growth of relay half-widths per MPa of extra compression)
    play_growth_per_MPa: float = 0.0
    # saturation (knee of the soft clip of the field; 0 = off)
    saturation_knee_A: float = 0.0
    saturation_softness_A: float = 0.15
    # sensors
    noise: bool = True
    displacement_noise_um: float = 0.012
    displacement_lsb_um: float = 0.005
    current_noise_A: float = 0.0008
    current_lsb_A: float = 0.0005
    stress_noise_MPa: float = 0.03
    temperature_noise_C: float = 0.05
    temperature_lsb_C: float = 0.1

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if isinstance(value, bool):
                continue
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"AltPlantConfig.{name} must be a finite number, got {value!r}")
        if self.damping_ratio <= 0 or self.damping_ratio >= 1:
            raise ValueError("AltPlantConfig.damping_ratio must be in (0, 1) (underdamped rod)")
        if self.preload_MPa >= 0:
            raise ValueError("AltPlantConfig.preload_MPa must be negative (compression)")

    @property
    def rod_area_m2(self) -> float:
        return math.pi * (0.5e-3 * self.rod_diameter_mm) ** 2

    def stress_for_mass(self, load_kg: float) -> float:
        """Static stress (MPa) with this load mass on top, rod at rest."""
        return self.preload_MPa - load_kg * G / self.rod_area_m2 * 1e-6

    def mass_for_stress(self, stress_MPa: float) -> float:
        return (self.preload_MPa - stress_MPa) * 1e6 * self.rod_area_m2 / G

    def resonance_hz(self, load_kg: float) -> float:
        """Undamped resonance of rod + load."""
        k = self.rod_stiffness_N_per_um * 1e6
        return math.sqrt(k / (self.moving_mass_kg + load_kg)) / (2 * math.pi)

    def thermal_time_constants_s(self) -> tuple[float, float]:
        """The two time constants of the coil-rod thermal network (fast, slow)."""
        a = _thermal_matrix(self)
        lam = np.sort(np.linalg.eigvals(a).real)
        return float(-1.0 / lam[0]), float(-1.0 / lam[1])

    def with_effect(self, effect: str, level: str = "clear") -> "AltPlantConfig":
        """A copy with one effect of the diagnose vocabulary switched on ('clear' or 'subtle')."""
        if effect not in EFFECTS:
            raise ValueError(f"unknown effect {effect!r}; one of {', '.join(EFFECTS)}")
        if level not in ("clear", "subtle"):
            raise ValueError("level must be 'clear' or 'subtle'")
        return replace(self, **EFFECT_SETTINGS[effect][level])


EFFECT_SETTINGS: dict[str, dict[str, dict[str, Any]]] = {
    "rate_dependence": {"clear": {"diffusion_time_ms": 12.0}, "subtle": {"diffusion_time_ms": 4.0}},
    "mechanical_dynamics": {
        "clear": {"dynamics": True, "damping_ratio": 0.12},
        "subtle": {"dynamics": True, "damping_ratio": 0.25, "rod_stiffness_N_per_um": 60.0}},
    "thermal_drift": {
        "clear": {"rod_expansion_um_per_K": 1.5, "coil_expansion_um_per_K": -0.3, "stroke_tempco_per_K": 0.006},
        "subtle": {"rod_expansion_um_per_K": 0.45, "coil_expansion_um_per_K": -0.08, "stroke_tempco_per_K": 0.002}},
    "creep": {"clear": {"creep_per_decade": 0.03}, "subtle": {"creep_per_decade": 0.01}},
    "time_delay": {"clear": {"delay_ms": 0.6}, "subtle": {"delay_ms": 0.17}},
    "stress_dependent_play": {"clear": {"play_growth_per_MPa": 0.06}, "subtle": {"play_growth_per_MPa": 0.02}},
    "saturation": {
        "clear": {"saturation_knee_A": 1.45, "saturation_softness_A": 0.12},
        "subtle": {"saturation_knee_A": 1.6, "saturation_softness_A": 0.25}},
}


def _thermal_matrix(cfg: AltPlantConfig) -> np.ndarray:
    cc, cr = cfg.coil_heat_capacity_J_per_K, cfg.rod_heat_capacity_J_per_K
    gcr, gca, gra = cfg.coil_to_rod_W_per_K, cfg.coil_to_ambient_W_per_K, cfg.rod_to_ambient_W_per_K
    return np.array([[-(gcr + gca) / cc, gcr / cc], [gcr / cr, -(gcr + gra) / cr]])


def _relays(cfg: AltPlantConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Relay centres, half-widths and normalised weights on a grid (bell density in both)."""
    c = np.linspace(cfg.centre_lo_A, cfg.centre_hi_A, cfg.n_centres)
    r = np.linspace(0.02, cfg.half_width_A + 3.5 * cfg.half_width_spread_A, cfg.n_widths)
    cc, rr = np.meshgrid(c, r, indexing="ij")
    w = (np.exp(-0.5 * ((cc - cfg.centre_peak_A) / cfg.centre_spread_A) ** 2)
         * np.exp(-0.5 * ((rr - cfg.half_width_A) / cfg.half_width_spread_A) ** 2))
    w = w.ravel()
    return cc.ravel().copy(), rr.ravel().copy(), w / w.sum()


def _shell_weights(n: int) -> np.ndarray:
    edges = np.linspace(0.0, 1.0, n + 1)
    return np.diff(edges ** 2)  # area fractions, sum 1


# parameter vector layout for the kernel
_P = ("preload_N", "g_load", "spring_N_per_m", "area_m2", "stroke_um", "stroke_loss", "expo0", "expo_per",
      "tau_diff_s", "dyn", "k_N_per_m", "m_kg", "zeta", "r_coil", "cc", "cr", "gcr", "gca", "gra",
      "beta_rod", "beta_coil", "tempco", "creep_w", "play_growth", "knee", "soft")


def _param_vector(cfg: AltPlantConfig) -> np.ndarray:
    area = cfg.rod_area_m2
    vals = {
        "preload_N": -cfg.preload_MPa * 1e6 * area, "g_load": G, "spring_N_per_m": cfg.spring_N_per_um * 1e6,
        "area_m2": area, "stroke_um": cfg.stroke_um, "stroke_loss": cfg.stroke_loss_per_MPa,
        "expo0": cfg.shape_exponent, "expo_per": cfg.shape_exponent_per_MPa,
        "tau_diff_s": cfg.diffusion_time_ms * 1e-3, "dyn": 1.0 if cfg.dynamics else 0.0,
        "k_N_per_m": cfg.rod_stiffness_N_per_um * 1e6, "m_kg": cfg.moving_mass_kg, "zeta": cfg.damping_ratio,
        "r_coil": cfg.coil_resistance_ohm, "cc": cfg.coil_heat_capacity_J_per_K, "cr": cfg.rod_heat_capacity_J_per_K,
        "gcr": cfg.coil_to_rod_W_per_K, "gca": cfg.coil_to_ambient_W_per_K, "gra": cfg.rod_to_ambient_W_per_K,
        "beta_rod": cfg.rod_expansion_um_per_K, "beta_coil": cfg.coil_expansion_um_per_K,
        "tempco": cfg.stroke_tempco_per_K, "creep_w": cfg.creep_per_decade / CREEP_PER_DECADE,
        "play_growth": cfg.play_growth_per_MPa, "knee": cfg.saturation_knee_A, "soft": cfg.saturation_softness_A,
    }
    return np.array([vals[name] for name in _P], dtype=float)


@njit(cache=True)
def _diffuse(h: np.ndarray, surface: float, dt: float, tau: float, area: np.ndarray,
             a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> None:
    """One implicit-Euler step of radial field diffusion dH/dt = (1/tau) (1/rho) d(rho dH/drho)/drho."""
    n = h.size
    step = 1.0 / n
    for j in range(n):
        g_in = (j / n) / step if j > 0 else 0.0
        g_out = ((j + 1) / n) / step if j < n - 1 else 2.0 / step
        diag = area[j] / dt
        a[j] = -g_in / tau
        c[j] = -g_out / tau if j < n - 1 else 0.0
        b[j] = diag + (g_in + g_out) / tau
        d[j] = diag * h[j] + (g_out / tau * surface if j == n - 1 else 0.0)
    for j in range(1, n):  # Thomas algorithm
        f = a[j] / b[j - 1]
        b[j] -= f * c[j - 1]
        d[j] -= f * d[j - 1]
    h[n - 1] = d[n - 1] / b[n - 1]
    for j in range(n - 2, -1, -1):
        h[j] = (d[j] - c[j] * h[j + 1]) / b[j]


@njit(cache=True)
def _simulate(p: np.ndarray, centres: np.ndarray, widths: np.ndarray, weights: np.ndarray,
              shell_w: np.ndarray, creep_tau: np.ndarray, ambient: float,
              drive: np.ndarray, dt_arr: np.ndarray, load: np.ndarray,
              x_out: np.ndarray, stress_out: np.ndarray, tcoil_out: np.ndarray, trod_out: np.ndarray,
              free_out: np.ndarray) -> None:
    """Integrate the rig sample by sample: sample k holds drive[k] for dt_arr[k] (zero-order hold)."""
    preload, g_load, k_spring, area = p[0], p[1], p[2], p[3]
    stroke0, stroke_loss, expo0, expo_per = p[4], p[5], p[6], p[7]
    tau_diff, dyn, k_rod, m_rod, zeta = p[8], p[9], p[10], p[11], p[12]
    r_coil, cc, cr, gcr, gca, gra = p[13], p[14], p[15], p[16], p[17], p[18]
    beta_rod, beta_coil, tempco, creep_w, play_growth, knee, soft = p[19], p[20], p[21], p[22], p[23], p[24], p[25]

    n_sh = shell_w.size if tau_diff > 0.0 else 1
    nr = centres.size
    state = np.zeros((n_sh, nr), dtype=np.uint8)   # relays start down: drive came down to zero
    field = np.zeros(n_sh)
    area_sh = np.empty(n_sh)
    for j in range(n_sh):
        area_sh[j] = 0.5 * ((j + 1.0) ** 2 - j ** 2) / n_sh ** 2
    ta, tb, tc, td = np.zeros(n_sh), np.zeros(n_sh), np.zeros(n_sh), np.zeros(n_sh)
    z = np.zeros(creep_tau.size)
    t_coil, t_rod = 0.0, 0.0       # rises above ambient
    x, v, acc = 0.0, 0.0, 0.0
    for k in range(drive.size):
        i_now = drive[k]
        dt = dt_arr[k]
        m_load = load[k]
        static = preload + m_load * g_load + k_spring * x * 1e-6
        sigma = -(static + (m_load * acc * 1e-6 if dyn > 0.0 else 0.0)) / area * 1e-6   # what the load cell sees
        comp = (static - preload) / area * 1e-6   # MPa of static compression beyond the preload
        # field in the rod
        if tau_diff > 0.0:
            n_sub = int(math.ceil(dt / (tau_diff / 60.0)))
            if n_sub < 1:
                n_sub = 1
            for _ in range(n_sub):
                _diffuse(field, i_now, dt / n_sub, tau_diff, area_sh, ta, tb, tc, td)
        else:
            field[0] = i_now
        # Preisach relays per shell
        fw = 1.0 + play_growth * comp
        if fw < 0.2:
            fw = 0.2
        expo = expo0 + expo_per * comp
        stroke = stroke0 * (1.0 - stroke_loss * comp)
        strain = 0.0
        for j in range(n_sh):
            h = field[j]
            if knee > 0.0 and h > knee:
                h = knee + soft * math.tanh((h - knee) / soft)
            m = 0.0
            for q in range(nr):
                half = widths[q] * fw
                if h >= centres[q] + half:
                    state[j, q] = 1
                elif h <= centres[q] - half:
                    state[j, q] = 0
                if state[j, q] == 1:
                    m += weights[q]
            if m > 1.0:
                m = 1.0
            sw = shell_w[j] if n_sh > 1 else 1.0
            strain += sw * m ** expo
        # two-node thermal network (coil heated by I^2 R)
        power = r_coil * i_now * i_now
        d_coil = (power - gcr * (t_coil - t_rod) - gca * t_coil) / cc
        d_rod = (gcr * (t_coil - t_rod) - gra * t_rod) / cr
        t_coil += dt * d_coil
        t_rod += dt * d_rod
        x_hys = stroke * strain * (1.0 - tempco * t_rod)
        # logarithmic creep: Prony series, equal weight per decade
        creep = 0.0
        for q in range(z.size):
            z[q] += (x_hys - z[q]) * (1.0 - math.exp(-dt / creep_tau[q]))
            creep += z[q]
        x_free = x_hys + creep_w * creep + beta_rod * t_rod + beta_coil * t_coil
        # rod + load: exact zero-order-hold solution of m x'' + c x' + k x = k x_free
        if dyn > 0.0:
            mt = m_rod + m_load
            wn = math.sqrt(k_rod / mt)
            wd = wn * math.sqrt(1.0 - zeta * zeta)
            e0 = x - x_free
            ca = e0
            cb = (v + zeta * wn * e0) / wd
            dec = math.exp(-zeta * wn * dt)
            cs, sn = math.cos(wd * dt), math.sin(wd * dt)
            e1 = dec * (ca * cs + cb * sn)
            v = dec * (-zeta * wn * (ca * cs + cb * sn) + wd * (-ca * sn + cb * cs))
            x = x_free + e1
            acc = -wn * wn * e1 - 2.0 * zeta * wn * v
        else:
            x = x_free
        x_out[k] = x
        free_out[k] = x_free
        stress_out[k] = sigma
        tcoil_out[k] = ambient + t_coil
        trod_out[k] = ambient + t_rod


class AltGMAPlant:
    """The alternative rig. `run` simulates one experiment from rest and returns measured columns."""

    def __init__(self, cfg: AltPlantConfig | None = None, seed: int = 0) -> None:
        self.cfg = cfg or AltPlantConfig()
        self.seed = int(seed)
        self._p = _param_vector(self.cfg)
        self._centres, self._widths, self._weights = _relays(self.cfg)
        self._shell_w = _shell_weights(N_SHELLS)
        decades = math.log10(self.cfg.creep_tau_max_s / self.cfg.creep_tau_min_s)
        n_tau = max(1, int(round(decades * CREEP_PER_DECADE)) + 1)
        self._creep_tau = (np.logspace(math.log10(self.cfg.creep_tau_min_s), math.log10(self.cfg.creep_tau_max_s), n_tau)
                           if self.cfg.creep_per_decade > 0 else np.zeros(0))

    def run(self, time_s: np.ndarray, current_A: np.ndarray, load_mass_kg: float | np.ndarray = 0.0) -> dict[str, np.ndarray]:
        """Simulate from rest (demagnetised, ambient temperature, relaxed) and measure.

        Returns measured columns (`time_s`, `current_A`, `stress_MPa`, `displacement_um`,
        `temperature_C`: the coil's) and, for tests only, noise-free `true_*` values
        (`true_displacement_um` is after the delay) and `free_strain_um` (before the rod dynamics
        and the delay).
        """
        t = np.ascontiguousarray(time_s, dtype=float)
        i_cmd = np.ascontiguousarray(current_A, dtype=float)
        if t.ndim != 1 or t.size < 2 or i_cmd.shape != t.shape:
            raise ValueError("time_s and current_A must be 1-D arrays of equal length >= 2")
        if np.any(np.diff(t) <= 0):
            raise ValueError("time_s must be strictly increasing")
        load = np.broadcast_to(np.asarray(load_mass_kg, dtype=float), t.shape).copy()
        dt = np.concatenate(([t[1] - t[0]], np.diff(t)))
        n = t.size
        x, stress, tcoil, trod, free = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        _simulate(self._p, self._centres, self._widths, self._weights, self._shell_w, self._creep_tau,
                  self.cfg.ambient_C, i_cmd, dt, load, x, stress, tcoil, trod, free)
        x_true = delay_signal(t, x, self.cfg.delay_ms * 1e-3)
        out = {"time_s": t.copy(), "true_displacement_um": x_true, "free_strain_um": free,
               "true_stress_MPa": stress, "true_coil_temperature_C": tcoil, "true_rod_temperature_C": trod}
        if self.cfg.noise:
            rng = np.random.default_rng(self.seed)
            c = self.cfg
            out["displacement_um"] = _quantise(x_true + rng.normal(0.0, c.displacement_noise_um, n), c.displacement_lsb_um)
            out["current_A"] = _quantise(i_cmd + rng.normal(0.0, c.current_noise_A, n), c.current_lsb_A)
            out["stress_MPa"] = stress + rng.normal(0.0, c.stress_noise_MPa, n)
            out["temperature_C"] = _quantise(tcoil + rng.normal(0.0, c.temperature_noise_C, n), c.temperature_lsb_C)
        else:
            out.update(displacement_um=x_true.copy(), current_A=i_cmd.copy(), stress_MPa=stress.copy(),
                       temperature_C=tcoil.copy())
        return out


def delay_signal(t: np.ndarray, y: np.ndarray, delay_s: float) -> np.ndarray:
    """y(t - delay) by linear interpolation between samples; before the start, the first value."""
    if delay_s <= 0.0:
        return y.copy()
    return np.interp(t - delay_s, t, y, left=y[0])


def _quantise(y: np.ndarray, lsb: float) -> np.ndarray:
    return np.round(y / lsb) * lsb if lsb > 0 else y
