"""Learning feedforward's benchmark rigs (issue 32): references that reach the rig's limits, on the
simulated rig in-process and through the Modbus TCP emulator with random latency on every request.

Shared by scripts/bench_learning.py and tests/test_learning_emulator.py, so both judge the
learner on the same sessions. A session through the emulator runs in real time: the plant
advances with the wall clock, the latency is slept, and the controller's clock is the real one.

Seeds. `TUNING_SEEDS` are the sessions the defaults were chosen on; `HELD_OUT_SEEDS` and
`FRESH_SEEDS` draw from the same distribution and were never used to choose, and `HELD_OUT_RIG` is another
plant (every hil_sim effect on: dynamics, thermal drift, creep, amplifier bandwidth). The
benchmark quotes them apart.
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from gma_ffc.sil import RIG_EFFECTS

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "config" / "models" / "sim_sdpi.yaml"
REALISTIC = ROOT / "hil_sim" / "configs" / "realistic.yaml"
REGISTER_MAP = ROOT / "hil_sim" / "configs" / "devices" / "amplifier_int16.yaml"

TUNING_SEEDS = tuple(range(20))
HELD_OUT_SEEDS = tuple(range(1000, 1020))
# Through the real-time emulator 1000-1019 were seen once before the watch learned to follow the
# noise of a loaded machine (its false back-offs showed there); 3000-3019 were never run before
# the defaults and the watch were fixed.
FRESH_SEEDS = tuple(range(3000, 3020))
LATENCY_S = (1e-3, 2e-3)          # on every request, uniform: the 1-2 ms
MODBUS_RATE_HZ = 200.0            # two requests a tick, 1-2 ms each, plus ~0.5 ms of protocol work: 250 Hz overruns
FLOOR_A = 0.0
SLEW_A_PER_S = 50.0               # the rig


@dataclass(frozen=True)
class Session:
    """One tracking session: a sine whose bottom touches the current floor (0 um: the model's
    displacement at zero current), at a load, frequency and amplitude drawn from the seed."""

    seed: int
    frequency_hz: float
    amplitude_um: float
    stress_MPa: float
    plant: str = "default"            # "default" (+ RIG_EFFECTS) or "realistic" (every effect)
    latency_s: tuple[float, float] | None = LATENCY_S
    offset: float | None = None       # None: the amplitude, the bottom of the sine at 0 um

    @property
    def offset_um(self) -> float:
        return self.amplitude_um if self.offset is None else self.offset

    def describe(self) -> str:
        lo, hi = self.offset_um - self.amplitude_um, self.offset_um + self.amplitude_um
        return (f"seed {self.seed}: {self.frequency_hz:.2f} Hz, {lo:.0f}-{hi:.1f} um, "
                f"{self.stress_MPa:.1f} MPa, {self.plant} plant")


def draw_session(seed: int, plant: str = "default") -> Session:
    """The session of a seed: 2-4 Hz, 8-14 um amplitude (bottom at the floor), -11.3 to -19.1 MPa."""
    rng = np.random.default_rng(seed)
    return Session(seed, float(rng.uniform(2.0, 4.0)), float(rng.uniform(8.0, 14.0)),
                   float(rng.uniform(-19.1, -11.3)), plant)


HELD_OUT_RIG = tuple(draw_session(s, "realistic") for s in range(2000, 2005))


@dataclass
class SessionRun:
    """Per-period tracking RMS (um) and the controller's final status."""

    session: Session
    learning: bool
    period_rms_um: np.ndarray
    status: dict[str, Any]
    extra: dict[str, Any] = field(default_factory=dict)

    def window(self, first: int, last: int) -> float:
        """Mean per-period RMS over periods first..last (1-based, inclusive)."""
        return float(np.mean(self.period_rms_um[first - 1:last]))


def plant_config(session: Session) -> Any:
    from hil_sim.plant import PlantConfig

    if session.plant == "realistic":
        return PlantConfig.from_yaml(REALISTIC)
    return PlantConfig.from_dict(RIG_EFFECTS)


def period_rms(time_s: np.ndarray, err: np.ndarray, frequency_hz: float) -> np.ndarray:
    """RMS of `err` in each whole period (by time, so a period need not be a whole number of samples)."""
    k = np.floor(time_s * frequency_hz + 1e-9).astype(int)
    full = int(k.max())                                  # the last period is partial (stop ramp)
    return np.array([math.sqrt(float(np.mean(err[k == i] ** 2))) for i in range(full) if np.any(k == i)])


def run_modbus_session(session: Session, *, learning: dict | None, periods: int, model: Any = None,
                       rate_hz: float = MODBUS_RATE_HZ, limits: dict | None = None,
                       workdir: str | Path | None = None) -> SessionRun:
    """The real controller through the Modbus TCP emulator, in real time, for `periods` periods."""
    from gma_ffc.control.config import validate_config
    from gma_ffc.control.manager import ControllerManager
    from gma_ffc.modelio import load_model
    from gma_ffc.recordings import read_recording
    from gma_ffc.registers import load_register_map
    from hil_sim.emulators import EmulatedRig, ModbusEmulator
    from hil_sim.plant import GMAPlant

    pcfg = plant_config(session)
    plant = GMAPlant(pcfg, seed=session.seed)
    plant.reset(pcfg.mass_for_stress(session.stress_MPa))
    rig = EmulatedRig(plant, dt_s=1e-3, max_current_A=3.5)
    rmap = load_register_map(REGISTER_MAP)
    tmp = tempfile.TemporaryDirectory() if workdir is None else None
    folder = Path(workdir if workdir is not None else tmp.name)  # type: ignore[union-attr]
    tel = folder / f"modbus_{session.seed}_{'learn' if learning else 'ff'}.csv"
    emu = ModbusEmulator(rig, rmap, transport="tcp", port=0, seed=session.seed, latency_s=session.latency_s)
    try:
        host, port = emu.start()
        data = {
            "rate_hz": rate_hz, "model": str(MODEL),
            "driver": {"kind": "modbus", "devices": {"amp": {
                "transport": "tcp", "host": host, "port": port, "timeout_s": 0.2,
                "register_map": rmap.to_dict()}}},
            # lead: the displacement read answers the previous tick's command, and the command
            # reaches the device after the reads, about 1.5 ticks (what a user would configure);
            # the emulator's latency comes on top, uncovered, for the learner to cope with.
            "reference": {"kind": "sine", "frequency_hz": session.frequency_hz, "amplitude_um": session.amplitude_um,
                          "offset_um": session.offset_um, "lead_s": 1.5 / rate_hz},
            "limits": {"current_min_A": FLOOR_A, "current_max_A": 3.0, "slew_A_per_s": SLEW_A_PER_S,
                       **(limits or {})},
            "telemetry": {"path": str(tel), "flush_interval_s": 0.2},
        }
        if learning is not None:
            data["learning"] = dict(learning)
        ctrl = ControllerManager(validate_config(data), model=model if model is not None else load_model(MODEL))
        status = ctrl.run(duration_s=periods / session.frequency_hz)
        rec = read_recording(tel)
        err = rec.columns["reference_um"] - rec.displacement_um
        rms = period_rms(rec.time_s, err, session.frequency_hz)
        lat = np.asarray(emu.latencies_s)
        extra = {"latency_ms": (float(lat.min() * 1e3), float(lat.max() * 1e3)) if lat.size else None,
                 "floor_share": float(np.mean(rec.columns["current_cmd_A"] <= FLOOR_A + 1e-9))}
        return SessionRun(session, learning is not None, rms, status, extra)
    finally:
        emu.stop()
        if tmp is not None:
            tmp.cleanup()


def run_sim(session: Session, *, learning: dict | None, periods: int, limits: dict | None = None,
            rate_hz: float = 1000.0) -> SessionRun:
    """The same session on the simulated rig in-process (simulated clock, no protocol, no latency)."""
    from gma_ffc.sil import run_tracking

    pcfg = plant_config(session)
    run = run_tracking(MODEL, session.frequency_hz, periods, learning=learning, rate_hz=rate_hz,
                       amplitude_um=session.amplitude_um, offset_um=session.offset_um,
                       load_schedule=((0.0, pcfg.mass_for_stress(session.stress_MPa)),),
                       plant_effects=pcfg.to_dict() if session.plant != "default" else RIG_EFFECTS,
                       seed=session.seed, limits={"current_min_A": FLOOR_A, **(limits or {})})
    return SessionRun(session, learning is not None, run.period_rms_um, run.status)


def without_latency(session: Session) -> Session:
    return replace(session, latency_s=None)


# ---- the emulator's latency in simulated time ----------------------------------------------------
def latency_sim_driver(cfg: dict, period_s: float, latency_s: tuple[float, float], seed: int) -> Any:
    """The `sim` driver with the Modbus emulator's timing: each request waits a random latency
    (uniform in `latency_s`) before it acts. The tick's read samples the plant `l_r` after the
    deadline; its write takes effect `l_w` after that read, and the plant holds the previous
    command until then. Simulated time: no machine load, every seed repeats exactly, so settings
    can be compared that the real-time emulator (whose own deadline misses add jitter on a
    shared machine) cannot tell apart."""
    from gma_ffc.drivers.sim import SimDriver

    class LatencySimDriver(SimDriver):
        def open(self) -> None:
            super().open()
            self.rng = np.random.default_rng(seed)
            self.deadline = 0.0          # the current tick's nominal time
            self.plant_t = 0.0           # the instant the plant state is at
            self.held = 0.0              # the command the amplifier holds
            self.read_t = 0.0

        def _advance(self, to: float) -> None:
            if to > self.plant_t:
                self.plant.step(self.held, to - self.plant_t)
                self.plant_t = to

        def read(self, inputs: Any) -> None:
            self._advance(self.deadline + self.rng.uniform(*latency_s))
            self.read_t = self.plant_t
            super().read(inputs)

        def write(self, current_A: float) -> None:
            self._advance(max(self.read_t, self.deadline) + self.rng.uniform(*latency_s))
            self.held = current_A
            self.last_written_A = current_A
            self.deadline += self.period_s
            self.t = self.deadline

        def safe(self, current_A: float) -> None:
            self.write(current_A)

    return LatencySimDriver(cfg, period_s)


def run_latency_sim(session: Session, *, learning: dict | None, periods: int, rate_hz: float = MODBUS_RATE_HZ,
                    limits: dict | None = None, lead_s: float | None = None) -> SessionRun:
    """A session as `run_modbus_session` runs it (same reference, lead, limits and latency), with
    the latency in simulated time (`latency_sim_driver`). `lead_s`: the command lead a user set
    (default 1.5 ticks, as `run_modbus_session`)."""
    from gma_ffc.control.config import validate_config
    from gma_ffc.control.manager import ControllerManager
    from gma_ffc.control.scheduler import SimulatedClock
    from gma_ffc.modelio import load_model
    from gma_ffc.recordings import read_recording

    pcfg = plant_config(session)
    with tempfile.TemporaryDirectory() as tmp:
        plant_yaml = Path(tmp) / "plant.yaml"
        import yaml

        plant_yaml.write_text(yaml.safe_dump(pcfg.to_dict()))
        tel = Path(tmp) / "tel.csv"
        data = {
            "rate_hz": rate_hz, "clock": "simulated", "model": str(MODEL),
            "driver": {"kind": "sim", "plant_config": str(plant_yaml), "seed": session.seed,
                       "load_mass_kg": pcfg.mass_for_stress(session.stress_MPa)},
            "reference": {"kind": "sine", "frequency_hz": session.frequency_hz, "amplitude_um": session.amplitude_um,
                          "offset_um": session.offset_um, "lead_s": 1.5 / rate_hz if lead_s is None else lead_s},
            "limits": {"current_min_A": FLOOR_A, "current_max_A": 3.0, "slew_A_per_s": SLEW_A_PER_S, **(limits or {})},
            "telemetry": {"path": str(tel), "flush_interval_s": 0.5},
        }
        if learning is not None:
            data["learning"] = dict(learning)
        cfg = validate_config(data)
        driver = latency_sim_driver(cfg.driver, 1.0 / rate_hz, session.latency_s or (0.0, 0.0), session.seed)
        ctrl = ControllerManager(cfg, model=load_model(MODEL), driver=driver, clock=SimulatedClock())
        status = ctrl.run(duration_s=periods / session.frequency_hz)
        rec = read_recording(tel)
        err = rec.columns["reference_um"] - rec.displacement_um
        return SessionRun(session, learning is not None, period_rms(rec.time_s, err, session.frequency_hz), status)
