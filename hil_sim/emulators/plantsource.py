"""Build the plant the emulators expose: hil_sim.plant.GMAPlant, or a tiny stand-in while the
real plant is not importable (it is developed in parallel; the stand-in only keeps the protocol
layer testable and says so)."""

from __future__ import annotations

import math
import sys
from os import PathLike
from pathlib import Path

from gma_ffc.errors import ConfigError


class StandInPlant:
    """Minimal GMA-like plant: first-order current loop, one play operator, linear spring.

    Not physics; just enough dynamics that 'the measured current follows the setpoint' and
    'displacement and force respond' can be checked through the protocols.
    """

    def __init__(self, tau_s: float = 2e-3, gain_um_per_A: float = 20.0, play_A: float = 0.1,
                 preload_N: float = 435.0, stiffness_N_per_um: float = 2.0) -> None:
        self.tau_s = tau_s
        self.gain = gain_um_per_A
        self.play = play_A
        self.preload_N = preload_N
        self.stiffness = stiffness_N_per_um
        self.reset()

    def reset(self) -> None:
        self.current_A = 0.0
        self._play_out = 0.0
        self.displacement_um = 0.0
        self.force_N = -self.preload_N

    def step(self, current_cmd_A: float, dt_s: float) -> None:
        alpha = 1.0 - math.exp(-dt_s / self.tau_s)
        self.current_A += alpha * (current_cmd_A - self.current_A)
        x = self.current_A
        self._play_out = min(max(self._play_out, x - self.play), x + self.play)
        self.displacement_um = self.gain * self._play_out
        self.force_N = -(self.preload_N + self.stiffness * self.displacement_um)


def make_plant(config_path: str | PathLike | None = None, seed: int = 0, *, allow_stand_in: bool = True,
               sensor_noise: bool = False):
    """The real plant from hil_sim.plant (config YAML or defaults); the stand-in if it is missing.
    `sensor_noise`: the defaults with the sensors' noise on (a config says for itself)."""
    try:
        from hil_sim import plant as plant_module
    except ImportError:
        if config_path is not None or not allow_stand_in:
            raise ConfigError(
                "--plant-config: hil_sim.plant is not available in this checkout, so a plant config cannot be used"
            ) from None
        print("note: hil_sim.plant not available; using the emulators' stand-in plant", file=sys.stderr)
        return StandInPlant()
    cfg = plant_module.PlantConfig.from_yaml(Path(config_path)) if config_path else plant_module.PlantConfig()
    if sensor_noise and not config_path:
        cfg.noise.enabled = True
    plant = plant_module.GMAPlant(cfg, seed=seed)
    plant.step(0.0, 1e-3)  # JIT-compile (or load the cache) now, not inside the first request
    plant.reset()
    return plant
