"""The setup: everything a reload swaps at a tick boundary, as one record.

The builder makes one from a config and a model; the runner holds the current one and replaces
it whole between two ticks. What a reload cannot change (rate, clock, driver, telemetry,
scheduler, metrics server: `RESTART_KEYS`) lives outside it, with the runner.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..protocols import Model
from .config import ControllerConfig
from .current_tracking import CurrentTracker
from .envelope import StressRange
from .law import FeedforwardController
from .reference import Reference
from .safety import FaultAction, Limiter, SensorMonitor

# `metrics`: the server is bound once, at the service's start (service/watch.py); a reload that
# said "reloaded" kept serving the old address.
RESTART_KEYS = ("rate_hz", "clock", "driver", "telemetry", "scheduler", "metrics")


@dataclass(eq=False)
class Setup:
    """One configuration's parts, built and checked before the loop sees them."""

    cfg: ControllerConfig
    model: Model
    law: FeedforwardController       # the controller: reference (with lead), inverse, learner, drive range
    reference_now: Reference         # the reference for the tick's own instant (telemetry, learning)
    limiter: Limiter                 # current and slew limits
    monitor: SensorMonitor           # load cell -> stress, plausibility
    tracking: CurrentTracker         # the measured current against the command (where the driver reads it)
    stress_range: StressRange        # the model's identified stress range and its policy
    fault_table: dict[str, FaultAction]   # safety.FAULT_ACTIONS resolved for this config
    safe_A: float                    # limits.safe_current_A
