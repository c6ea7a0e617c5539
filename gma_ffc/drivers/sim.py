"""`sim` driver: the hil_sim plant stepped in-process, one period per written command.

The embedded default: no hardware, same controller code. ``read`` reports the plant's measured
values after the last step (load-cell force, coil current, displacement); ``write`` commands the
current and advances the plant by one period. The load mass may follow a schedule, so the
stress changes during a run as on the paper's rig.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..schema import Field, validate_section
from ..errors import ConfigError
from .base import CURRENT, DISPLACEMENT, FORCE, Driver, DriverError, Inputs


def _schedule(value: list, key: str) -> list[tuple[float, float]]:
    out = []
    for i, item in enumerate(value):
        if not (isinstance(item, (list, tuple)) and len(item) == 2 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in item)) or item[1] < 0:
            raise ConfigError(f"config key '{key}[{i}]' must be [time_s, load_mass_kg] with mass >= 0, got {item!r}")
        out.append((float(item[0]), float(item[1])))
    if any(b[0] <= a[0] for a, b in zip(out, out[1:])):
        raise ConfigError(f"config key '{key}' times must increase")
    return out


SCHEMA = {
    "kind": Field("str"),
    "plant_config": Field("str", None, nullable=True, help="a hil_sim plant YAML; defaults when empty"),
    "seed": Field("int", 0, min=0),
    "load_mass_kg": Field("float", 0.0, min=0.0),
    "load_schedule": Field("list", [], check=_schedule),
}


def _check_plant_config(path: Path, key: str) -> None:
    """Read the plant config now, at config load: a damaged one is one line and exit 2, not a
    fault when the driver opens (nothing to check without hil_sim; `open` says it is missing)."""
    try:
        from hil_sim.plant import PlantConfig
    except ImportError:
        return
    try:
        PlantConfig.from_yaml(path)
    except ConfigError as exc:
        raise ConfigError(f"config key '{key}': {exc}") from None


class SimDriver(Driver):
    """The simulated GMA rig (hil_sim.plant.GMAPlant) behind the driver interface."""

    kind = "sim"
    simulated_clock_ok = True

    def __init__(self, cfg: dict[str, Any], period_s: float, plant: Any = None) -> None:
        super().__init__(cfg, period_s)
        self.plant = plant
        self.channels = (FORCE, CURRENT, DISPLACEMENT)
        self.t = 0.0
        self._schedule = list(cfg.get("load_schedule", []))
        self._next = 0

    @classmethod
    def validate_config(cls, section: dict[str, Any], prefix: str, base_dir: Path | None) -> dict[str, Any]:
        out = validate_section(section, SCHEMA, prefix)
        if out["plant_config"] is not None:
            p = Path(out["plant_config"]).expanduser()
            if not p.is_absolute() and base_dir is not None:
                p = base_dir / p
            if not p.is_file():
                raise ConfigError(f"config key '{prefix}.plant_config': no such file {p}")
            _check_plant_config(p, f"{prefix}.plant_config")
            out["plant_config"] = str(p)
        return out

    def open(self) -> None:
        if self.plant is None:
            try:
                from hil_sim.plant import GMAPlant, PlantConfig
            except ImportError as exc:
                raise DriverError(f"the simulated plant is not available ({exc})") from None
            path = self.cfg.get("plant_config")
            pcfg = PlantConfig.from_yaml(path) if path else PlantConfig()
            self.plant = GMAPlant(pcfg, seed=self.cfg.get("seed", 0))
            # First step loads the JIT-compiled kernel: do it on a throwaway plant, not in tick 1.
            GMAPlant(pcfg, seed=0).step(0.0, self.period_s)
        self.plant.reset(self.cfg.get("load_mass_kg", 0.0))   # settles the stress for this load
        self.t = 0.0
        self._next = 0
        self._apply_schedule()

    def reconnect(self) -> None:
        """Nothing to reconnect: the plant keeps its state (a real rig would too)."""

    def _apply_schedule(self) -> None:
        sched = self._schedule
        while self._next < len(sched) and sched[self._next][0] <= self.t:
            self.plant.set_load_mass(sched[self._next][1])
            self._next += 1

    def read(self, inputs: Inputs) -> None:
        p = self.plant
        inputs.force_N = p.force_N
        inputs.current_A = p.current_A
        inputs.displacement_um = p.displacement_um

    def write(self, current_A: float) -> None:
        self.plant.step(current_A, self.period_s)
        self.last_written_A = current_A
        self.t += self.period_s
        if self._next < len(self._schedule):
            self._apply_schedule()

    def safe(self, current_A: float) -> None:
        # The plant is advanced by the command like any write: the safe current is what it sees last.
        self.write(current_A)

    def close(self) -> None:
        """The plant object stays for inspection after the run."""
