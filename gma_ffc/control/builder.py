"""The builder: a validated config (and optionally a model, driver or clock) into the controller's parts.

`build` makes everything a run needs; `build_setup` the part a reload swaps (the law with its
inverse, learner and drive range, the limits, the sensor monitor, the model's stress range, the
resolved fault table), and `build_reload` checks a new config against the running one first.
Everything here runs before the loop sees it, in the caller's thread: model loading, plugin
construction and the JIT warm-up all happen here, and any error leaves the running parts alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..drivers import Driver, DriverProtocol, Inputs, driver_class
from ..drivers.base import DISPLACEMENT, FORCE, INSTANCE_MEMBERS, STRESS, missing_members
from ..errors import ConfigError, ModelError
from ..model_reach import reach_exceeded
from ..protocols import Model
from . import safety
from .config import ControllerConfig, stop_ramp_fits_after_reload
from .current_tracking import CurrentTracker
from .envelope import DriveRange, StressRange
from .faults import FaultLog
from .hardware import DriverSupervisor
from .law import FeedforwardController
from .learned_file import load_learned, model_fingerprint
from .learning import RepetitiveLearner, model_gain_table, reference_period_s
from .model_monitor import ModelMonitor
from .recorder import TelemetryRecorder
from .reference import Reference, build_reference
from .scheduler import Clock, MonotonicClock, SimulatedClock, TickStats
from .setup import RESTART_KEYS, Setup
from .state_broadcaster import StateBroadcaster
from .tick import Broadcaster, Tick
from .watchdog import Watchdog


@dataclass(eq=False)
class Parts:
    """What the runner is built from: the first setup, and what a reload cannot change."""

    cfg: ControllerConfig
    clock: Clock
    setup: Setup
    tick: Tick
    stats: TickStats
    faults: FaultLog
    hardware: DriverSupervisor
    recorder: TelemetryRecorder
    state: StateBroadcaster
    watchdog: Watchdog
    plugins: list[Broadcaster]       # parts the config plugs in, ticked before the recorder (their columns)


def build(cfg: ControllerConfig, *, model: Model | None = None, driver: DriverProtocol | None = None,
          clock: Any = None) -> Parts:
    """All the parts of a controller for `cfg`; `model`, `driver`, `clock` replace the configured ones."""
    model = model if model is not None else load_model(cfg)
    clock = clock if clock is not None else build_clock(cfg)
    drv = build_driver(cfg, driver)
    setup = build_setup(cfg, model)
    stats = TickStats(cfg.period_s)
    faults = FaultLog(stats)
    hardware = DriverSupervisor(drv, clock.simulated, cfg.comms, faults)
    recorder = TelemetryRecorder(cfg, clock.simulated)
    tick = Tick(Inputs())
    state = StateBroadcaster(cfg.rate_hz, tick, stats, faults, hardware, recorder)
    # the heartbeat is stamped at each tick's start, so a period passes between two even when all is
    # well: no progress means none for a period and watchdog_s beyond it (at 1 Hz, 0.5 s alone tripped)
    watchdog = Watchdog(cfg.period_s + cfg.watchdog_s, clock, faults, cfg.scheduler["realtime_priority"])
    plugins: list[Broadcaster] = [ModelMonitor(cfg.monitor, cfg.period_s, recorder)]   # its status says when it is off
    return Parts(cfg, clock, setup, tick, stats, faults, hardware, recorder, state, watchdog, plugins)


def load_model(cfg: ControllerConfig) -> Model:
    from ..modelio import load_model as load

    return load(cfg.model)


def build_clock(cfg: ControllerConfig) -> Clock:
    """The configured clock. The real one spins at most half a period: a loop that never sleeps at
    SCHED_FIFO would hit the kernel's RT throttling (50 ms stalls per second) and starve the rest."""
    if cfg.clock == "simulated":
        return SimulatedClock()
    return MonotonicClock(min(cfg.scheduler["spin_us"] * 1e-6, 0.5 * cfg.period_s))


def build_driver(cfg: ControllerConfig, driver: DriverProtocol | None = None) -> DriverProtocol:
    """The configured driver plugin (or `driver`), checked against the contract and the stress source."""
    drv = driver if driver is not None else driver_class(cfg.driver["kind"])(cfg.driver, cfg.period_s)
    if not isinstance(drv, Driver) and missing_members(drv, INSTANCE_MEMBERS):
        raise ConfigError(f"driver '{cfg.driver['kind']}' lacks the driver contract's "
                          f"{', '.join(missing_members(drv, INSTANCE_MEMBERS))}")
    want = FORCE if cfg.stress["source"] == "force" else STRESS
    if drv.channels and want not in drv.channels:
        raise ConfigError(f"config key 'stress.source' is {cfg.stress['source']!r} but driver "
                          f"'{cfg.driver['kind']}' provides no '{want}' channel (it has: "
                          f"{', '.join(drv.channels)})")
    if cfg.learning.enabled and drv.channels and DISPLACEMENT not in drv.channels:
        # learning corrects the measured error: without the reading it froze for the whole run
        raise ConfigError(f"config key 'learning' is on, but driver '{cfg.driver['kind']}' provides no "
                          f"'{DISPLACEMENT}' channel (it has: {', '.join(drv.channels)}): learning needs the "
                          "measured displacement. Add the sensor's channel to the driver, or remove the learning section")
    return drv


def build_setup(cfg: ControllerConfig, model: Model) -> Setup:
    """The reloadable parts for `cfg` and `model`, with the model's inverse compiled and warmed up.

    The command uses the reference `lead` ahead (configured latency + the model's delay preview);
    telemetry records the reference for *now*, so the tracking error is y(t) - r(t).
    """
    lim = cfg.limits
    _drives_a_current(cfg, model)
    _limits_near_the_model(cfg, model)
    reference = build_reference(cfg.reference, model.preview_s)
    _reference_within_reach(cfg, model, reference)
    stress_range = StressRange.of_model(model, cfg.stress["out_of_range"])
    warm_up(model, cfg.period_s, stress_range)
    law = FeedforwardController(model, reference, model.inverse_stepper(cfg.period_s, initial_drive=lim["safe_current_A"]),
                                make_learner(cfg, model, reference), DriveRange.of_model(model, lim["beyond_model"]))
    limiter = safety.Limiter(lim["current_min_A"], lim["current_max_A"], lim["slew_A_per_s"], cfg.period_s,
                             lim["safe_current_A"])
    monitor = safety.SensorMonitor(cfg.stress["source"], cfg.rod_area_mm2, tuple(cfg.stress["valid_range_MPa"]),
                                   cfg.sensor["force_limit_N"], cfg.sensor["bad_ticks"], cfg.sensor["stale_ticks"])
    ct = cfg.current_tracking
    tracking = CurrentTracker(ct["tolerance_A"], ct["lag_s"], ct["hold_s"], cfg.period_s)
    return Setup(cfg, model, law, build_reference({**cfg.reference, "lead_s": 0.0}), limiter, monitor, tracking,
                 stress_range, safety.fault_actions(cfg), float(lim["safe_current_A"]))


# A current limit this many times the largest current the model was identified on lies far beyond
# anything the model knows (its inverse there is a guess), and is most likely a unit slip: milliamperes
# typed as amperes are 1000x. An amplifier limit a little above the model's range (x1.5, x3) is usual.
LIMIT_BEYOND_MODEL_FACTOR = 10.0


def _limits_near_the_model(cfg: ControllerConfig, model: Model) -> None:
    """ConfigError for a current limit over LIMIT_BEYOND_MODEL_FACTOR times the model's largest
    identified current (a user's `current_max_A: 3000` for 3 A, accepted, let the command reach 6.8 A)."""
    lo, hi = (float(v) for v in model.drive_range)
    extent = max(abs(lo), abs(hi))
    if not math.isfinite(extent) or extent <= 0.0:
        return
    for key in ("current_max_A", "current_min_A"):
        value = float(cfg.limits[key])
        if abs(value) > LIMIT_BEYOND_MODEL_FACTOR * extent:
            raise ConfigError(
                f"config key 'limits.{key}' ({value:g} A) is {abs(value) / extent:.0f}x the largest current the "
                f"model was identified on ({extent:.3g} A, {cfg.model}): check its unit (amperes, not milliamperes) "
                f"and set it to the coil's limit, at most {LIMIT_BEYOND_MODEL_FACTOR * extent:.3g} A for this "
                "model; to drive further, identify a model over the wider current first")


REFERENCE_KEYS = {"sine": "reference.amplitude_um and offset_um", "triangle": "reference.amplitude_um and offset_um",
                  "multisine": "reference.components' amplitude_um and reference.offset_um",
                  "playback": "the reference_um column of reference.file"}


def _reference_within_reach(cfg: ControllerConfig, model: Model, reference: Reference) -> None:
    """ConfigError for a reference over REFERENCE_BEYOND_REACH_FACTOR times the model's reach."""
    peak = reference.peak_um()
    reach = reach_exceeded(model, peak)
    if reach is None:
        return
    raise ConfigError(
        f"config key 'reference' asks for up to {peak:g} um, {peak / reach:.0f}x the most the model gives over its "
        f"identified drive range ({reach:.3g} um, {cfg.model}): check the unit of "
        f"{REFERENCE_KEYS.get(cfg.reference['kind'], 'the reference')} (micrometres, not nanometres) and keep "
        f"the reference within about {reach:.3g} um; no drive the model knows reaches it")


def _drives_a_current(cfg: ControllerConfig, model: Model) -> None:
    """Every driver writes a current setpoint (`current_setpoint_A`), so the model's inverse must give
    amperes: a model identified on a voltage drive gives volts, which the amplifier would take as
    amperes (a new user's sweep ran one on Modbus, 2026-11-30)."""
    name = getattr(model, "drive_name", "current_A")
    if name != "current_A":
        raise ModelError(f"{cfg.model}: the model's drive is {name}, but the controller commands a current "
                         "(current_A) through its driver, and would send the model's volts as amperes. Use a "
                         "model identified from recordings with a current_A column")


def build_reload(running: ControllerConfig, cfg: ControllerConfig, model: Model | None = None) -> Setup:
    """The setup a reload to `cfg` swaps in; ConfigError (the running one kept) for a key that
    needs a restart, or any error building it."""
    for key in RESTART_KEYS:
        if getattr(cfg, key) != getattr(running, key):
            raise ConfigError(f"config key '{key}' changed: that needs a restart, not a reload "
                              f"(the running configuration is kept)")
    stop_ramp_fits_after_reload(running.limits, cfg.limits, cfg.rate_hz)
    setup = build_setup(cfg, model if model is not None else load_model(cfg))
    if setup.law.learner is not None:
        setup.law.learner.last_event = "reset: configuration reloaded"
    return setup


def warm_up(model: Model, period_s: float, stress_range: StressRange) -> None:
    """Call a throwaway stepper once so JIT compilation / cache loading happens before tick 1."""
    model.inverse_stepper(period_s, initial_drive=0.0).step(0.0, stress_range.operating_point())


def make_learner(cfg: ControllerConfig, model: Model, reference: Reference) -> RepetitiveLearner | None:
    """The repetitive learner the config asks for (None when learning is off), with the saved
    correction of an earlier run when `learning.file` holds one learned for this model."""
    lc = cfg.learning
    if not lc.enabled:
        return None
    period = lc.period_s or reference_period_s(cfg.reference) or getattr(reference, "duration", None)
    if not period:
        raise ConfigError("config key 'learning.period_s' is required: the reference is not periodic")
    learner = RepetitiveLearner(lc, cfg.rate_hz, period, model_gain_table(model), model_fingerprint(model))
    if lc.file is not None:
        load_learned(learner, lc.file)
    return learner
