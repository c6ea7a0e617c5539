"""The simulated giant magnetostrictive actuator (contract: docs/ARCHITECTURE.md, physics: docs/hil_sim.md).

A physically richer plant than the SDPI model it is used to test: Jiles-Atherton magnetisation
with a stress-dependent (Sablik-Jiles) effective field and quadratic magnetostriction, plus
switchable eddy currents, rod/load dynamics, Joule heating, creep, transport delay, amplifier
bandwidth and sensor noise. It deliberately shares no code with `gma_ffc.model`/`operators`,
so judging the model against it is not judging the model against itself.

    cfg = PlantConfig.from_yaml("hil_sim/configs/realistic.yaml")   # or PlantConfig()
    plant = GMAPlant(cfg, seed=0)
    plant.set_load_mass(15.3)
    plant.step(1.2, 1 / 2000)          # no allocation; measured values as attributes
    plant.displacement_um, plant.current_A, plant.stress_MPa, plant.force_N, plant.temperature_C
    out = plant.run(t, i_cmd, load_mass_kg=m)   # batch, same kernel, same numbers
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from gma_ffc.errors import ConfigError, InputError
from gma_ffc.yamlfile import read_yaml

from . import kernels as K

EFFECTS = ("eddy", "dynamics", "thermal", "creep", "delay", "amplifier", "noise")
"""Switchable physics, in the order the CLI lists them."""

G = K.G


@dataclass
class RigConfig:
    """Geometry and preload of the paper's rig (phi 7 mm rod, -11.3 MPa unloaded)."""

    rod_diameter_mm: float = 7.0
    rod_length_mm: float = 80.0
    preload_stress_MPa: float = -11.3       # stress from the preload spring alone (compression < 0)
    preload_spring_N_per_um: float = 0.2    # disc-spring stiffness: stress grows a little with stroke

    @property
    def rod_area_m2(self) -> float:
        return math.pi * (self.rod_diameter_mm * 1e-3) ** 2 / 4.0

    @property
    def preload_N(self) -> float:
        return -self.preload_stress_MPa * 1e6 * self.rod_area_m2


@dataclass
class MagneticsConfig:
    """Jiles-Atherton parameters of Terfenol-D and the coil."""

    coil_field_A_per_m_per_A: float = 15000.0   # n = N/L of the solenoid
    saturation_magnetisation_A_per_m: float = 7.65e5
    anhysteretic_shape_A_per_m: float = 7000.0   # JA 'a'
    pinning_A_per_m: float = 2500.0              # JA 'k': sets the loop width ("coercive current")
    reversibility: float = 0.2                   # JA 'c'
    interdomain_coupling: float = 0.0            # JA 'alpha'
    saturation_magnetostriction_ppm: float = 1200.0   # 3/2 lambda_s
    stress_coupling: float = 0.9                 # multiplier on the Sablik-Jiles magnetoelastic field
    stress_saturation_MPa: float = 6.0           # S: stress enters as S*tanh(sigma/S); 0 = linear
    stress_dependent_width: bool = False         # option: pinning (loop width) follows stress
    width_change_per_MPa: float = 0.12           # relative pinning change per MPa of extra compression
    width_reference_MPa: float = -11.3


@dataclass
class EddyConfig:
    enabled: bool = False
    time_constant_ms: float = 0.1     # lag of the rod field behind the coil field


@dataclass
class DynamicsConfig:
    enabled: bool = False
    youngs_modulus_GPa: float = 30.0  # Terfenol-D E^H (18-55 GPa, Delta-E effect); typical mid value
    moving_mass_kg: float = 1.5       # output rod, head, platform, a third of the rod
    damping_ratio: float = 0.05


@dataclass
class ThermalConfig:
    enabled: bool = False
    coil_resistance_ohm: float = 2.0
    thermal_resistance_K_per_W: float = 2.5
    time_constant_s: float = 60.0
    ambient_C: float = 22.0
    drift_um_per_K: float = 0.2       # net differential expansion rod vs housing


@dataclass
class CreepConfig:
    enabled: bool = False
    time_constants_s: list = field(default_factory=lambda: [0.3, 3.0, 30.0])
    gains: list = field(default_factory=lambda: [0.01, 0.01, 0.01])   # fractions of the stroke


@dataclass
class DelayConfig:
    enabled: bool = False
    delay_ms: float = 1.0             # sensor + acquisition latency on the displacement


@dataclass
class AmplifierConfig:
    enabled: bool = False
    bandwidth_hz: float = 1000.0      # current-loop -3 dB bandwidth (first order)
    min_current_A: float = 0.0        # unipolar supply
    max_current_A: float = 4.0


@dataclass
class NoiseConfig:
    enabled: bool = False
    displacement_std_um: float = 0.02
    displacement_quantum_um: float = 0.01
    current_std_A: float = 0.001
    current_quantum_A: float = 0.0003
    force_std_N: float = 0.5
    force_quantum_N: float = 0.1
    temperature_std_C: float = 0.05
    temperature_quantum_C: float = 0.01


@dataclass
class NumericsConfig:
    max_substep_us: float = 25.0
    max_field_step_A_per_m: float = 50.0


_SECTIONS: dict[str, type] = {
    "rig": RigConfig, "magnetics": MagneticsConfig, "eddy": EddyConfig, "dynamics": DynamicsConfig,
    "thermal": ThermalConfig, "creep": CreepConfig, "delay": DelayConfig,
    "amplifier": AmplifierConfig, "noise": NoiseConfig, "numerics": NumericsConfig,
}


@dataclass
class PlantConfig:
    """Every parameter of the simulated actuator. Defaults: clean quasi-static hysteresis, no effects."""

    rig: RigConfig = field(default_factory=RigConfig)
    magnetics: MagneticsConfig = field(default_factory=MagneticsConfig)
    eddy: EddyConfig = field(default_factory=EddyConfig)
    dynamics: DynamicsConfig = field(default_factory=DynamicsConfig)
    thermal: ThermalConfig = field(default_factory=ThermalConfig)
    creep: CreepConfig = field(default_factory=CreepConfig)
    delay: DelayConfig = field(default_factory=DelayConfig)
    amplifier: AmplifierConfig = field(default_factory=AmplifierConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    numerics: NumericsConfig = field(default_factory=NumericsConfig)

    # -- building ---------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None, source: str = "plant config") -> "PlantConfig":
        """Build from nested sections; unknown or mistyped keys raise ConfigError naming them."""
        cfg = cls()
        if data is None:
            return cfg
        if not isinstance(data, Mapping):
            raise ConfigError(f"{source}: expected a mapping of sections ({', '.join(_SECTIONS)})")
        for name, values in data.items():
            if name not in _SECTIONS:
                raise ConfigError(f"{source}: unknown section '{name}' (known: {', '.join(_SECTIONS)})")
            if values is None:
                continue
            if not isinstance(values, Mapping):
                raise ConfigError(f"{source}: section '{name}' must be a mapping of key: value")
            section = getattr(cfg, name)
            known = {f.name: f for f in dataclasses.fields(section)}
            for key, value in values.items():
                if key not in known:
                    raise ConfigError(
                        f"{source}: unknown key '{name}.{key}' (known: {', '.join(known)})")
                setattr(section, key, _coerce(value, getattr(section, key), f"{source}: '{name}.{key}'"))
        cfg.validate(source)
        return cfg

    @classmethod
    def from_yaml(cls, path: str | Path) -> "PlantConfig":
        return cls.from_dict(read_yaml(path, "plant config", ConfigError), str(path))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def with_effects(self, effects: Iterable[str]) -> "PlantConfig":
        """A copy with exactly these effects switched on (and every other one off)."""
        wanted = set(effects)
        unknown = wanted - set(EFFECTS)
        if unknown:
            raise InputError(f"unknown effect(s) {', '.join(sorted(unknown))}; choose from {', '.join(EFFECTS)}")
        cfg = copy.deepcopy(self)
        for name in EFFECTS:
            getattr(cfg, name).enabled = name in wanted
        return cfg

    @property
    def enabled_effects(self) -> list[str]:
        return [name for name in EFFECTS if getattr(self, name).enabled]

    def validate(self, source: str = "plant config") -> None:
        """Physical sanity: positive sizes, time constants, masses; ConfigError naming the key."""
        def positive(section: str, key: str) -> None:
            v = getattr(getattr(self, section), key)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"{source}: '{section}.{key}' must be a positive number, got {v!r}")

        for sec, key in [("rig", "rod_diameter_mm"), ("rig", "rod_length_mm"),
                         ("magnetics", "coil_field_A_per_m_per_A"),
                         ("magnetics", "saturation_magnetisation_A_per_m"),
                         ("magnetics", "anhysteretic_shape_A_per_m"), ("magnetics", "pinning_A_per_m"),
                         ("magnetics", "saturation_magnetostriction_ppm"),
                         ("eddy", "time_constant_ms"), ("dynamics", "youngs_modulus_GPa"),
                         ("dynamics", "moving_mass_kg"), ("thermal", "coil_resistance_ohm"),
                         ("thermal", "thermal_resistance_K_per_W"), ("thermal", "time_constant_s"),
                         ("delay", "delay_ms"), ("amplifier", "bandwidth_hz"),
                         ("numerics", "max_substep_us"), ("numerics", "max_field_step_A_per_m")]:
            positive(sec, key)
        if self.rig.preload_stress_MPa > 0:
            raise ConfigError(f"{source}: 'rig.preload_stress_MPa' is compression, so negative "
                              f"(e.g. -11.3), got {self.rig.preload_stress_MPa}")
        if not 0.0 <= self.magnetics.reversibility < 1.0:
            raise ConfigError(f"{source}: 'magnetics.reversibility' must be in [0, 1), "
                              f"got {self.magnetics.reversibility}")
        if not 0.0 <= self.dynamics.damping_ratio < 1.0:
            raise ConfigError(f"{source}: 'dynamics.damping_ratio' must be in [0, 1), "
                              f"got {self.dynamics.damping_ratio}")
        if self.amplifier.max_current_A <= self.amplifier.min_current_A:
            raise ConfigError(f"{source}: 'amplifier.max_current_A' must exceed 'amplifier.min_current_A'")
        if self.delay.delay_ms * 1e-3 > 0.5:
            raise ConfigError(f"{source}: 'delay.delay_ms' above 500 ms is not a transport delay "
                              f"this simulator keeps history for")
        for key in ("time_constants_s", "gains"):
            v = getattr(self.creep, key)
            if not (isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) for x in v)):
                raise ConfigError(f"{source}: 'creep.{key}' must be a list of three numbers, got {v!r}")
        if min(self.creep.time_constants_s) <= 0:
            raise ConfigError(f"{source}: 'creep.time_constants_s' must be positive")
        for key in [f.name for f in dataclasses.fields(NoiseConfig) if f.name != "enabled"]:
            v = getattr(self.noise, key)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"{source}: 'noise.{key}' must be zero or positive, got {v!r}")

    # -- derived quantities used by tests and docs --------------------------------------------
    def stress_for_mass(self, load_mass_kg: float, displacement_um: float = 0.0) -> float:
        """Static rod stress in MPa (compression negative) for a load mass."""
        force = self.rig.preload_N + load_mass_kg * G + self.rig.preload_spring_N_per_um * displacement_um
        return -force / self.rig.rod_area_m2 * 1e-6

    def mass_for_stress(self, stress_MPa: float) -> float:
        """Load mass that gives this static stress at zero stroke (inverse of stress_for_mass)."""
        return (-stress_MPa * 1e6 * self.rig.rod_area_m2 - self.rig.preload_N) / G

    @property
    def stiffness_N_per_um(self) -> float:
        """Rod stiffness E*A/L plus the preload spring, acting on the load."""
        rod = self.dynamics.youngs_modulus_GPa * 1e9 * self.rig.rod_area_m2 / (self.rig.rod_length_mm * 1e-3)
        return rod * 1e-6 + self.rig.preload_spring_N_per_um

    def resonance_hz(self, load_mass_kg: float) -> float:
        """Undamped natural frequency sqrt(k/m)/2pi with the load on the moving mass."""
        m = self.dynamics.moving_mass_kg + load_mass_kg
        return math.sqrt(self.stiffness_N_per_um * 1e6 / m) / (2 * math.pi)

    def parameter_vector(self) -> np.ndarray:
        """Flatten into the kernel's parameter layout (hil_sim.kernels.P_*)."""
        p = np.zeros(K.N_PARAMS)
        mg, rig = self.magnetics, self.rig
        p[K.P_ON_EDDY] = float(self.eddy.enabled)
        p[K.P_ON_DYN] = float(self.dynamics.enabled)
        p[K.P_ON_THERMAL] = float(self.thermal.enabled)
        p[K.P_ON_CREEP] = float(self.creep.enabled)
        p[K.P_ON_DELAY] = float(self.delay.enabled)
        p[K.P_ON_AMP] = float(self.amplifier.enabled)
        p[K.P_ON_NOISE] = float(self.noise.enabled)
        p[K.P_ON_WIDTH] = float(mg.stress_dependent_width)
        p[K.P_TURNS_PER_M] = mg.coil_field_A_per_m_per_A
        p[K.P_MS] = mg.saturation_magnetisation_A_per_m
        p[K.P_A] = mg.anhysteretic_shape_A_per_m
        p[K.P_K] = mg.pinning_A_per_m
        p[K.P_C] = mg.reversibility
        p[K.P_ALPHA] = mg.interdomain_coupling
        p[K.P_LAMBDA_SAT] = mg.saturation_magnetostriction_ppm * 1e-6
        p[K.P_STRESS_COUPLING] = mg.stress_coupling
        p[K.P_STRESS_SAT] = mg.stress_saturation_MPa
        p[K.P_K_STRESS] = mg.width_change_per_MPa
        p[K.P_SIGMA_REF] = mg.width_reference_MPa
        p[K.P_ROD_LEN_UM] = rig.rod_length_mm * 1e3
        p[K.P_ROD_AREA] = rig.rod_area_m2
        p[K.P_PRELOAD_N] = rig.preload_N
        p[K.P_SPRING_N_PER_UM] = rig.preload_spring_N_per_um
        p[K.P_STIFF_N_PER_UM] = self.stiffness_N_per_um
        p[K.P_MOVING_MASS] = self.dynamics.moving_mass_kg
        p[K.P_ZETA] = self.dynamics.damping_ratio
        p[K.P_TAU_EDDY] = self.eddy.time_constant_ms * 1e-3
        p[K.P_TAU_AMP] = 1.0 / (2 * math.pi * self.amplifier.bandwidth_hz)
        p[K.P_I_MIN] = self.amplifier.min_current_A
        p[K.P_I_MAX] = self.amplifier.max_current_A
        p[K.P_R_COIL] = self.thermal.coil_resistance_ohm
        p[K.P_R_TH] = self.thermal.thermal_resistance_K_per_W
        p[K.P_TAU_TH] = self.thermal.time_constant_s
        p[K.P_T_AMB] = self.thermal.ambient_C
        p[K.P_DRIFT_UM_PER_K] = self.thermal.drift_um_per_K
        p[K.P_CREEP_TAU0:K.P_CREEP_TAU2 + 1] = self.creep.time_constants_s
        p[K.P_CREEP_G0:K.P_CREEP_G2 + 1] = self.creep.gains
        p[K.P_DELAY_S] = self.delay.delay_ms * 1e-3
        nz = self.noise
        p[K.P_NOISE_X], p[K.P_QUANT_X] = nz.displacement_std_um, nz.displacement_quantum_um
        p[K.P_NOISE_I], p[K.P_QUANT_I] = nz.current_std_A, nz.current_quantum_A
        p[K.P_NOISE_F], p[K.P_QUANT_F] = nz.force_std_N, nz.force_quantum_N
        p[K.P_NOISE_T], p[K.P_QUANT_T] = nz.temperature_std_C, nz.temperature_quantum_C
        p[K.P_DT_SUB] = self.numerics.max_substep_us * 1e-6
        p[K.P_DH_MAX] = self.numerics.max_field_step_A_per_m
        return p


def _coerce(value: Any, default: Any, where: str) -> Any:
    """Check a YAML value against the type of its default; say what was expected."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{where} must be true or false, got {value!r}")
        return value
    if isinstance(default, (int, float)):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"{where} must be a number, got {value!r}")
        return float(value)
    if isinstance(default, list):
        if not isinstance(value, list):
            raise ConfigError(f"{where} must be a list, got {value!r}")
        return [float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v for v in value]
    return value


class GMAPlant:
    """The simulated actuator: real-time `step()` and batch `run()` share one numba kernel."""

    def __init__(self, cfg: PlantConfig | None = None, seed: int = 0) -> None:
        self.cfg = cfg if cfg is not None else PlantConfig()
        self.cfg.validate()
        self.seed = int(seed)
        self._p = self.cfg.parameter_vector()
        self._state = np.zeros(K.N_STATE)
        self._rng = np.zeros(1, dtype=np.uint64)
        self._hist = np.zeros((2, K.DELAY_BUFFER))
        self._load_mass = 0.0
        self.reset()

    def reset(self, load_mass_kg: float | None = None) -> None:
        """Back to the demagnetised rod at rest, ambient temperature, and the seed's noise stream."""
        if load_mass_kg is not None:
            self._load_mass = self._check_mass(load_mass_kg)
        s = self._state
        s[:] = 0.0
        s[K.S_DIR] = 1.0
        s[K.S_TEMP] = self.cfg.thermal.ambient_C
        s[K.S_MASS] = self._load_mass
        s[K.S_T] = 0.0
        self._hist[:] = 0.0
        s[K.S_COUNT] = 1.0      # the delay history starts with the rest position at t = 0
        self._rng[0] = np.uint64(self.seed & 0xFFFFFFFFFFFFFFFF) * np.uint64(0x9E3779B1) + np.uint64(12345)
        self._settle()

    def _settle(self) -> None:
        """Static force/stress for the current load, and measurements without advancing time."""
        s = self._state
        force = self._p[K.P_PRELOAD_N] + s[K.S_MASS] * G + self._p[K.P_SPRING_N_PER_UM] * s[K.S_X]
        s[K.S_FORCE] = force
        s[K.S_SIGMA] = -force / self._p[K.P_ROD_AREA] * 1e-6
        s[K.S_XOUT] = s[K.S_X]
        s[K.S_MEAS_X] = s[K.S_X]
        s[K.S_MEAS_I] = s[K.S_I]
        s[K.S_MEAS_F] = force
        s[K.S_MEAS_SIGMA] = s[K.S_SIGMA]
        s[K.S_MEAS_T] = s[K.S_TEMP]

    @staticmethod
    def _check_mass(kg: float) -> float:
        kg = float(kg)
        if not (math.isfinite(kg) and 0.0 <= kg <= 1000.0):
            raise InputError(f"load mass must be between 0 and 1000 kg, got {kg}")
        return kg

    def set_load_mass(self, kg: float) -> None:
        """Change the load; the stress follows from the next step on (preload + m*g)."""
        self._load_mass = self._check_mass(kg)
        self._state[K.S_MASS] = self._load_mass

    @property
    def load_mass_kg(self) -> float:
        return self._load_mass

    def step(self, current_cmd_A: float, dt_s: float) -> None:
        """Advance dt_s with the command held; then read the sensors. Allocates nothing."""
        K.step_kernel(self._state, self._p, self._rng, self._hist, float(current_cmd_A), float(dt_s))

    # measured values after the last step (noise and quantisation applied when enabled)
    @property
    def displacement_um(self) -> float:
        return float(self._state[K.S_MEAS_X])

    @property
    def current_A(self) -> float:
        return float(self._state[K.S_MEAS_I])

    @property
    def stress_MPa(self) -> float:
        return float(self._state[K.S_MEAS_SIGMA])

    @property
    def force_N(self) -> float:
        return float(self._state[K.S_MEAS_F])

    @property
    def temperature_C(self) -> float:
        return float(self._state[K.S_MEAS_T])

    @property
    def time_s(self) -> float:
        """Plant time since reset."""
        return float(self._state[K.S_T])

    def true_state(self) -> dict[str, float]:
        """Noise-free internal values (for tests and plots, never for a diagnosis)."""
        s = self._state
        return {"current_A": s[K.S_I], "field_A_per_m": s[K.S_H], "magnetisation_A_per_m": s[K.S_M],
                "magnetostriction_um": s[K.S_XMS], "free_stroke_um": s[K.S_XFREE],
                "position_um": s[K.S_X], "displacement_um": s[K.S_XOUT], "temperature_C": s[K.S_TEMP],
                "force_N": s[K.S_FORCE], "stress_MPa": s[K.S_SIGMA]}

    def run(self, time_s: np.ndarray, current_cmd_A: np.ndarray,
            load_mass_kg: float | np.ndarray | None = None, reset: bool = True) -> dict[str, np.ndarray]:
        """Batch run from a fresh reset (unless reset=False); equal to stepping sample for sample.

        Sample i is `step(current_cmd_A[i], time_s[i] - time_s[i-1])`, the first with
        dt = time_s[1] - time_s[0]. Returns time_s, current_cmd_A and the measured
        displacement_um, current_A, stress_MPa, force_N, temperature_C.
        """
        t = np.ascontiguousarray(time_s, dtype=float)
        cmd = np.ascontiguousarray(current_cmd_A, dtype=float)
        if t.ndim != 1 or cmd.shape != t.shape:
            raise InputError(f"time_s and current_cmd_A must be 1-D and equally long "
                             f"({t.shape} vs {cmd.shape})")
        if t.size > 1 and not (np.diff(t) > 0).all():
            raise InputError("time_s must be strictly increasing")
        if not np.isfinite(t).all():
            raise InputError("time_s contains NaN or infinite values")
        if load_mass_kg is None:
            mass = np.full(t.shape, self._load_mass)
        else:
            mass = np.ascontiguousarray(np.broadcast_to(np.asarray(load_mass_kg, dtype=float), t.shape))
            if not (np.isfinite(mass).all() and (mass >= 0).all() and (mass <= 1000).all()):
                raise InputError("load_mass_kg must be between 0 and 1000 kg")
        if reset:
            self.reset(float(mass[0]) if mass.size else None)
        out = np.empty((5, t.size))
        if t.size:
            K.run_kernel(self._state, self._p, self._rng, self._hist, t, cmd, mass, out)
            self._load_mass = float(mass[-1])
        return {"time_s": t.copy(), "current_cmd_A": cmd.copy(), "displacement_um": out[0],
                "current_A": out[1], "stress_MPa": out[2], "force_N": out[3], "temperature_C": out[4]}
