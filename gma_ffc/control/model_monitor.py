"""The model-fit monitor as a part of the controller (issue 30, docs/monitor.md): a broadcaster.

The builder makes one for every controller and the manager ticks it before the telemetry
recorder, so the tick's `predicted_um` and `residual_um` are in the row the recorder packs. The
work is `model_watch.ModelWatch`'s; this part only follows the manager's lifecycle:

* `on_start` (each run): a watch for the recorder's columns, its prediction at the inverse's
  start (the law's play state at the safe current), and the recorder's rows into its ring;
* `on_tick` (hot path): the residual of this reading, then the prediction steps with the drive
  written. A fault tick wrote the safe current instead; a reading after a gap in the ticks
  (a reconnect, a stall) is not judged;
* `prepare` (a reload, in the reloading thread): the new model's prediction brought to the present
  by replaying history, off the loop; `on_setup` adopts it between two ticks;
* `status_fields`: the monitor's state for the controller's status; `window` the last seconds as
  a recording for the service's background diagnosis.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from ..model import InverseStepper as SDPIInverseStepper
from .model_watch import ModelWatch, Prepared
from .safety import RAMP
from .tick import Broadcaster, Tick

if TYPE_CHECKING:
    from ..protocols import Model
    from .recorder import TelemetryRecorder
    from .setup import Setup

# A reading more than this many periods after the last tick follows ticks the monitor did not see
# (a reconnect wrote the safe current outside them): it is not judged. Two periods: one late tick
# (an overrun) still is.
GAP_PERIODS = 2.5


class ModelMonitor(Broadcaster):
    """Prediction beside the command and the model-fit monitor, for one controller's runs."""

    def __init__(self, monitor_cfg: dict[str, Any], period_s: float, recorder: TelemetryRecorder) -> None:
        self.cfg = monitor_cfg
        self.period_s = period_s
        self.recorder = recorder
        self.watch: ModelWatch | None = None
        self._setup: Setup | None = None
        self._prepared: tuple[Setup, Prepared | None] | None = None
        self._last_t = -math.inf
        self._gap = GAP_PERIODS * period_s

    # ---- lifecycle (off the loop) ------------------------------------------------------------
    def on_start(self, setup: Setup) -> None:
        watch = ModelWatch(self.cfg, self.recorder.columns, self.recorder.columns, self.period_s)
        if self.recorder.telemetry is not None:
            watch.metadata = self.recorder.telemetry.metadata     # the run's start, stamped once known
        watch.start(setup.model, setup.safe_A, _play_state(setup))
        self.recorder.tap = watch.push if watch.enabled else None
        self._last_t = -math.inf
        self.watch = watch

    def prepare(self, setup: Setup) -> None:
        """A reload's model, its prediction replayed to the present (raises on monitor.enabled changing)."""
        if bool(setup.cfg.monitor["enabled"]) != bool(self.cfg["enabled"]):
            from ..errors import ConfigError

            raise ConfigError("config key 'monitor.enabled' changed: that needs a restart, not a reload "
                              "(the telemetry's columns follow it; the running configuration is kept)")
        watch = self.watch
        prepared = watch.prepare(setup.model, setup.cfg.model, setup.cfg.monitor) if watch is not None else None
        self._prepared = (setup, prepared)

    def on_setup(self, setup: Setup) -> None:
        """At the start and between two ticks after a reload: adopt what `prepare` made for it."""
        pending, self._prepared = self._prepared, None
        if pending is not None and pending[0] is setup and self.watch is not None:
            self.watch.adopt(pending[1])
        self._setup = setup
        self.cfg = setup.cfg.monitor           # the next run's window (monitor.enabled cannot change)

    # ---- hot path ----------------------------------------------------------------------------
    def on_tick(self, tick: Tick) -> None:
        watch, setup = self.watch, self._setup
        if watch is None or watch.prediction is None or setup is None:
            return
        if tick.faulted:               # the fault path wrote the safe current: seen, the reading not judged
            watch.interrupt(setup.safe_A, tick.stress_MPa)
            tick.predicted_um = tick.residual_um = math.nan
            return
        if tick.t - self._last_t > self._gap:
            watch.prediction.forget()
        self._last_t = tick.t
        watch.on_tick(tick.t, tick.displacement_um, tick.reference_um, tick.command_A, tick.stress_MPa,
                      tick.limited_by != RAMP)
        tick.predicted_um = watch.predicted_um
        tick.residual_um = watch.residual_um

    # ---- reporting (any thread) -----------------------------------------------------------------
    def status_fields(self) -> dict[str, Any]:
        return {} if self.watch is None else {"monitor": self.watch.status()}

    def window(self, seconds: float) -> tuple[Any, Model]:
        """The last `seconds` of telemetry as a recording, and the model running now."""
        if self.watch is None:
            from ..errors import GmaError

            raise GmaError("the controller has not started: there is no telemetry to take")
        return self.watch.window(seconds)


def _play_state(setup: Setup) -> Any:
    """The play state the law's inverse holds (just activated: the shared default start), for the
    prediction to start in the same one; None for a stepper without plays."""
    stepper = setup.law.stepper
    return stepper.play_state() if isinstance(stepper, SDPIInverseStepper) else None
