"""The model-fit monitor as a part of the controller (issue 30, docs/monitor.md).

It costs the loop nothing: it has no `on_tick`. The telemetry recorder packs each tick's row with
a hidden flags column (faulted, ramping), and hands every block of rows to the monitor's watch in
the telemetry writer's thread (`recorder.consumer`), which fills `predicted_um` and `residual_um`
before the rows are written (`model_watch.ModelWatch.on_block`). This part only follows the
manager's lifecycle:

* `on_start` (each run): a watch for the recorder's columns, its prediction at the inverse's
  start (the law's play state at the safe current), and the recorder's blocks to it;
* `prepare` (a reload, in the reloading thread): the new model's prediction brought to the present
  by replaying history, off the loop; `on_setup` hands it to the watch, which adopts it before
  the next block;
* `status_fields`: the monitor's state for the controller's status; `window` the last seconds as
  a recording for the service's background diagnosis, `start_state` the play state at its first
  sample (followed since the run started), so the diagnosis scores all of it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ..model import InverseStepper as SDPIInverseStepper
from .model_watch import ModelWatch, Prepared
from .tick import Broadcaster

if TYPE_CHECKING:
    from ..protocols import Model
    from .recorder import TelemetryRecorder
    from .setup import Setup



class ModelMonitor(Broadcaster):
    """Prediction beside the command and the model-fit monitor, for one controller's runs."""

    on_the_loop = False  # nothing on the loop: the recorder's blocks come to the watch in the writer's thread

    def __init__(self, monitor_cfg: dict[str, Any], period_s: float, recorder: TelemetryRecorder) -> None:
        self.cfg = monitor_cfg
        self.period_s = period_s
        self.recorder = recorder
        self.watch: ModelWatch | None = None
        self._prepared: tuple[Setup, Prepared | None] | None = None

    # ---- lifecycle (off the loop) ------------------------------------------------------------
    def on_start(self, setup: Setup) -> None:
        watch = ModelWatch(self.cfg, self.recorder.columns, self.recorder.columns, self.period_s)
        if self.recorder.telemetry is not None:
            watch.metadata = self.recorder.telemetry.metadata     # the run's start, stamped once known
        watch.start(setup.model, setup.safe_A, _play_state(setup))
        self.recorder.consumer = watch.on_block if watch.enabled else None
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
        """At the start and between two ticks after a reload: hand what `prepare` made to the watch."""
        pending, self._prepared = self._prepared, None
        if pending is not None and pending[0] is setup and self.watch is not None:
            self.watch.pending = pending[1]      # adopted before the next block
        self.cfg = setup.cfg.monitor           # the next run's window (monitor.enabled cannot change)

    # ---- reporting (any thread) -----------------------------------------------------------------
    def status_fields(self) -> dict[str, Any]:
        return {} if self.watch is None else {"monitor": self.watch.status()}

    def window(self, seconds: float) -> tuple[Any, Model]:
        """The last `seconds` of telemetry as a recording, and the model running now."""
        if self.watch is None:
            from ..errors import GmaError

            raise GmaError("the controller has not started: there is no telemetry to take")
        return self.watch.window(seconds)

    def start_state(self, recording: Any) -> dict[str, Any] | None:
        """The play state at the first sample of a `window` (`model_watch.ModelWatch.start_state`)."""
        return None if self.watch is None else self.watch.start_state(recording)


def _play_state(setup: Setup) -> Any:
    """The play state the law's inverse holds (just activated: the shared default start), for the
    prediction to start in the same one; None for a stepper without plays."""
    stepper = setup.law.stepper
    return stepper.play_state() if isinstance(stepper, SDPIInverseStepper) else None
