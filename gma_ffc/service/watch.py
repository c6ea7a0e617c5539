"""What the service adds to the model-fit monitor (issue 30): the background diagnosis, the metrics
server, and the model a `gma-ffc reload --model` adopted. The runner calls `start`, `poll` (with
each status snapshot it takes), `status` and `close`; everything here runs in the service's
supervising thread or the metrics server's, never in the loop's.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from .diagnosis import BackgroundDiagnosis, Window
from .metrics import MetricsServer

log = logging.getLogger("gma_ffc.service")


class ServiceWatch:
    """The service's side of the model-fit monitor for one controller."""

    def __init__(self, cfg: Any, controller: Any) -> None:
        self.controller = controller
        self.part = _model_monitor(controller)
        self.diagnosis: BackgroundDiagnosis | None = None
        monitor = getattr(cfg, "monitor", None)
        if monitor and monitor.get("enabled") and self.part is not None:
            self.diagnosis = BackgroundDiagnosis(monitor, self._window, output_dirs=tuple(getattr(cfg, "output_dirs", ())),
                                                 drive_limits=drive_limits(cfg))
        metrics = getattr(cfg, "metrics", None)
        self.metrics = MetricsServer(self.last_snapshot, metrics["host"], metrics["port"]) if metrics else None
        self.metrics_address: tuple[str, int] | None = None
        self._last: dict[str, Any] = {}

    def _window(self, seconds: float) -> Window:
        """The last `seconds` of telemetry, the running model, and the play state at the first sample
        (None when not known: diagnose then estimates it and scores what the drive decides)."""
        assert self.part is not None
        recording, model = self.part.window(seconds)
        try:
            start = self.part.start_state(recording)
        except Exception as exc:   # noqa: BLE001 - the diagnosis still runs, on the state it estimates
            log.warning("background diagnosis: the play state at the window's start is not known (%s: %s)",
                        type(exc).__name__, exc)
            start = None
        return Window(recording, model, start)

    def start(self) -> None:
        if self.metrics is not None:
            self.metrics_address = self.metrics.start()

    def poll(self, snapshot: dict[str, Any]) -> None:
        """Each status snapshot the service takes: start or finish a diagnosis; keep it for metrics."""
        if self.diagnosis is not None:
            m = snapshot.get("monitor") or {}
            self.diagnosis.poll(str(m.get("state")), m.get("since_s"), m.get("t_s"))
        self._last = {**snapshot, **self.status()}
        if self.metrics is not None:
            self.metrics.publish()

    def last_snapshot(self) -> dict[str, Any]:
        """What a metrics scrape reads: the last snapshot the service took (the loop pays nothing)."""
        return self._last

    def reconfigure(self, cfg: Any) -> None:
        """A reload went through: the diagnosis follows the new monitor settings."""
        if self.diagnosis is not None and getattr(cfg, "monitor", None):
            self.diagnosis.cfg = cfg.monitor
            self.diagnosis.drive_limits = drive_limits(cfg)

    def status(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.diagnosis is not None:
            out["diagnosis"] = self.diagnosis.status()
        if self.metrics_address is not None:
            out["metrics"] = {"url": f"http://{self.metrics_address[0]}:{self.metrics_address[1]}/metrics"}
        return out

    def close(self) -> None:
        if self.diagnosis is not None:
            self.diagnosis.close()
        if self.metrics is not None:
            self.metrics.close()


def drive_limits(cfg: Any) -> tuple[float, float] | None:
    """The controller's current limits, which a diagnosis's advice keeps within (None: none known)."""
    limits = getattr(cfg, "limits", None) or {}
    try:
        return float(limits["current_min_A"]), float(limits["current_max_A"])
    except (KeyError, TypeError, ValueError):
        return None


def _model_monitor(controller: Any) -> Any:
    """The controller's model-fit monitor part (None for a controller without one: a test's fake)."""
    from ..control.model_monitor import ModelMonitor

    return next((b for b in getattr(controller, "broadcasters", ()) if isinstance(b, ModelMonitor)), None)


class ModelOverride:
    """The model `gma-ffc reload --model FILE` adopted, kept across later plain reloads for as long
    as the config file names the model it named then (an edit of its `model` key wins)."""

    def __init__(self) -> None:
        self.path: str | None = None
        self.config_model: str | None = None
        self._pending: tuple[str | None, str | None] | None = None

    def apply(self, cfg: Any, model: str | None) -> Any:
        """`cfg` with the model to run; `commit` once the reload went through."""
        if model is not None:
            path = Path(model).expanduser().resolve()
            if not path.is_file():
                raise ConfigError(f"model file {path} not found (reload --model takes a model file, e.g. "
                                  "DIR/extended_model.yaml from a diagnosis)")
            self._pending = (str(path), cfg.model)
        elif self.path is not None and self.config_model == cfg.model:
            self._pending = (self.path, self.config_model)
        else:
            self._pending = (None, None)
        chosen = self._pending[0]
        return cfg if chosen is None else dataclasses.replace(cfg, model=chosen)

    def commit(self) -> None:
        if self._pending is not None:
            self.path, self.config_model = self._pending
            self._pending = None

    def status(self) -> dict[str, Any] | None:
        if self.path is None:
            return None
        return {"model": self.path, "config_names": self.config_model,
                "how": "adopted with gma-ffc reload --model; a reload keeps it until the config's model key changes; "
                       "a restart runs the config's model"}
