"""`gma-ffc run`: one controller in the foreground, supervised, reachable over the control socket.

Threads: the controller's fixed-rate loop runs in its own thread and is never disturbed by
service work; the main thread supervises it (systemd notifications, watchdog pings while the
loop makes progress, SIGHUP reloads, the status snapshot the control socket answers from). The
control socket itself is served by a child process (`control_plane`), so no client costs this
process anything; a third thread only carries out the `stop` and `reload` the owner sends
through it. Signal handlers only set flags. Whatever happens, the controller is asked to stop and its thread joined before
the process leaves, so its own exit path puts the amplifier at the safe current.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from .. import safe_files
from ..errors import FaultError, GmaError
from . import last_exit
from .control_plane import ControlPlane
from .control_socket import jsonable, refuse_if_running
from .diagnosis import check_state_dir
from .notify import Notifier
from .outputs import check_inputs_exist, check_outputs, inputs_of, outputs_of
from .paths import RuntimePaths, claim_lock, ensure_private_dir
from .status import faults_of, progress_count, status_line
from .watch import ModelOverride, ServiceWatch

log = logging.getLogger("gma_ffc.service")

ConfigLoader = Callable[[Path], Any]
ControllerFactory = Callable[[Any], Any]

SUPERVISE_PERIOD_S = 0.05
STATUS_PERIOD_S = 1.0      # systemd's STATUS= line, when it changes
PUBLISH_PERIOD_S = 0.5     # the control socket's status is at most this old (and fresh after a command)
JOIN_TIMEOUT_S = 10.0
# While the controller reconnects (its own bounded backoff, amplifier at the safe current) no
# ticks advance; the watchdog is still fed for this long, then stops so systemd restarts us.
RECONNECT_GRACE_S = 60.0


def _default_loader(path: Path) -> Any:
    from ..control.config import load_config

    return load_config(path)


def _default_factory(cfg: Any) -> Any:
    from ..control.manager import ControllerManager

    return ControllerManager(cfg)


@dataclass
class ReloadResult:
    """What the last reload did, reported in the status."""

    ok: bool
    message: str
    at_unix: float = field(default_factory=time.time)

    def as_dict(self) -> dict[str, Any]:
        return {"ok": self.ok, "message": self.message, "at_unix": self.at_unix}


class Service:
    """Run one controller until its duration ends, a stop is requested, or it fails."""

    def __init__(self, config_path: str | os.PathLike, *, duration_s: float | None = None,
                 stats_json: str | os.PathLike | None = None,
                 runtime: RuntimePaths | None = None, notifier: Notifier | None = None,
                 load_config: ConfigLoader = _default_loader,
                 make_controller: ControllerFactory = _default_factory,
                 install_signal_handlers: bool = True) -> None:
        self.config_path = Path(os.path.abspath(config_path))   # a telemetry file names its rig's config
        self.duration_s = duration_s
        self.stats_json = Path(stats_json) if stats_json else None
        self.runtime = runtime
        self.notifier = notifier or Notifier()
        self._load_config = load_config
        self._make_controller = make_controller
        self._install_signals = install_signal_handlers
        self._stop_event = threading.Event()
        self._reload_flag = threading.Event()
        self._reload_lock = threading.Lock()
        self._stop_reason: str | None = None
        self._last_reload: ReloadResult | None = None
        self._started_unix = time.time()
        self._ready = False
        self.controller: Any = None
        self.summary: Any = None
        self._error: BaseException | None = None
        self._plane: ControlPlane | None = None
        self._watch: ServiceWatch | None = None
        self._model_override = ModelOverride()
        self._exit_record: dict[str, Any] | None = None     # this run's start, once recorded

    # ---- requests from signals and the socket --------------------------------------------
    def request_stop(self, reason: str) -> None:
        """Ask the loop to stop (safe current first, which the controller does on exit)."""
        if self._stop_reason is None:
            self._stop_reason = reason
        if self.controller is not None:
            self.controller.request_stop(reason)
        self._stop_event.set()

    def reload(self, model: str | None = None) -> ReloadResult:
        """Re-read the config (and with it the model, or `model` instead: `gma-ffc reload --model`);
        refuse a bad one and keep the old."""
        with self._reload_lock:
            self.notifier.reloading()
            try:
                new_cfg = self._model_override.apply(self._load_config(self.config_path), model)
                self.controller.reload(new_cfg)
            except Exception as exc:  # any failure: the running config stays
                message = str(exc) if isinstance(exc, GmaError) else f"{type(exc).__name__}: {exc}"
                result = ReloadResult(False, f"reload refused, old config kept: {message}")
                log.error("%s", result.message)
            else:
                self._model_override.commit()
                if self._watch is not None:
                    self._watch.reconfigure(new_cfg)
                with_model = f" with model {new_cfg.model}" if self._model_override.path else ""
                result = ReloadResult(True, f"reloaded {self.config_path}{with_model}")
                log.info("%s", result.message)
            self._last_reload = result
            self.notifier.ready(status=result.message)
        self._publish()
        return result

    def status(self) -> dict[str, Any]:
        """The controller's snapshot plus what the service adds (pid, reloads, stop reason)."""
        snap = dict(self.controller.status()) if self.controller is not None else {}
        snap["service"] = {
            "pid": os.getpid(),
            "config": str(self.config_path),
            "started_unix": self._started_unix,
            "ready": self._ready,
            "stop_reason": self._stop_reason,
            "last_reload": self._last_reload.as_dict() if self._last_reload else None,
            "socket": str(self.runtime.socket) if self.runtime else None,
            "status_at_unix": time.time(),      # the socket answers from a snapshot up to 0.5 s old
            "model_override": self._model_override.status(),
        }
        if self._watch is not None:
            snap.update(self._watch.status())
        return snap

    def _publish(self, snapshot: dict[str, Any] | None = None) -> None:
        """Hand the control socket's process the status it answers from."""
        if self._plane is not None:
            self._plane.publish(self.status() if snapshot is None else snapshot)

    def handle_request(self, request: dict[str, Any]) -> dict[str, Any]:
        """The control socket's commands (`stop` and `reload` reach this process; the socket's
        own process answers `status` and `ping` itself)."""
        cmd = request.get("cmd")
        if cmd == "ping":
            return {"ok": True, "pid": os.getpid()}
        if cmd == "status":
            return {"ok": True, "status": self.status()}
        if cmd == "stop":
            self.request_stop(str(request.get("reason") or "stop requested over the socket"))
            self._publish()
            return {"ok": True, "pid": os.getpid()}
        if cmd == "reload":
            model = request.get("model")
            if model is not None and not (isinstance(model, str) and model):
                return {"ok": False, "error": f"reload: 'model' must be a model file's path, got {model!r}; "
                                              "the running model is kept"}
            result = self.reload(model)
            return {"ok": result.ok, "message": result.message,
                    **({} if result.ok else {"error": result.message})}
        return {"ok": False, "error": f"unknown command {cmd!r} (status, stop, reload, ping)"}

    # ---- the run ----------------------------------------------------------------------------
    def run(self) -> int:
        """Blocking; returns the exit code (0 stopped as asked, 1 the loop ended on a fault)."""
        if self.runtime is not None:      # the socket's process starts while the controller is built
            self._claim_runtime(self.runtime)
        try:
            cfg = self._load_config(self.config_path)
            self._check_outputs(cfg)
            self.controller = self._make_controller(cfg)
            self._claim_outputs()
        except BaseException:
            self._release_outputs()
            self._close_runtime()
            raise
        join_timeout_s = JOIN_TIMEOUT_S + _stop_ramp_s(cfg)
        previous_handlers: dict[int, Any] = {}
        self._watch = ServiceWatch(cfg, self.controller)
        try:
            self._watch.start()
            if self.runtime is not None:
                self._open_runtime(self.runtime)
            if self._install_signals:
                previous_handlers = self._install_handlers()
            thread = threading.Thread(target=self._run_controller, name="gma-ffc-loop", daemon=True)
            thread.start()
            self._supervise(thread)
        finally:
            self.request_stop(self._stop_reason or "service exiting")
            self.notifier.stopping(status=f"stopping: {self._stop_reason}")
            thread_alive = False
            with contextlib.suppress(NameError):
                thread.join(timeout=join_timeout_s)
                thread_alive = thread.is_alive()
            for signum, handler in previous_handlers.items():
                signal.signal(signum, handler)
            self._watch.close()          # the diagnosis child never outlives the service
            final = self.status()
            self._record_exit(final, thread_alive)
            self._close_runtime()
            if self.stats_json is not None:
                self._write_stats(final)
            self.notifier.close()
        if thread_alive:
            raise FaultError(f"the control loop did not stop within {join_timeout_s:g} s "
                             "(a driver call hung?); check the amplifier")
        if self._error is not None:
            if isinstance(self._error, GmaError):
                raise self._error
            raise FaultError(f"the control loop crashed: {type(self._error).__name__}: "
                             f"{self._error}") from self._error
        fault = _fault_from(final)
        if fault and not self._stop_requested_by_user():
            raise FaultError(f"the controller stopped on a fault: {fault}")
        return 0

    def _stop_requested_by_user(self) -> bool:
        return self._stop_reason not in (None, "service exiting", "control loop ended")

    def _run_controller(self) -> None:
        try:
            self.summary = self.controller.run(self._stop_event, self.duration_s)
        except BaseException as exc:  # reported by the main thread
            self._error = exc
            log.error("control loop crashed: %s", exc)

    def _supervise(self, thread: threading.Thread) -> None:
        """Notify READY once ticks advance, ping the watchdog only while they keep advancing,
        and publish the status snapshot the control socket answers from.

        `status()` costs a few hundred microseconds of the interpreter (percentiles over the
        loop's statistics), so it is taken fast only until READY, then every PUBLISH_PERIOD_S or
        at the watchdog interval, whichever is shorter, whatever clients ask; reloads and the
        loop's end are still seen within 50 ms.
        """
        interval = self.notifier.watchdog_interval_s
        poll_s = min(PUBLISH_PERIOD_S, interval) if interval else PUBLISH_PERIOD_S
        last_count = -1
        next_poll = 0.0
        reconnecting_since: float | None = None
        last_status_t = 0.0
        last_status_text = ""
        logged_event = 0
        while thread.is_alive():
            if self._reload_flag.is_set():
                self._reload_flag.clear()
                self.reload()
            now = time.monotonic()
            if now >= next_poll:
                snap = self.status()
                if self._watch is not None:      # may start or finish a background diagnosis
                    self._watch.poll(snap)
                    snap.update(self._watch.status())
                self._publish(snap)
                logged_event = _log_learning_events(snap, logged_event)
                count = progress_count(snap)
                progressed = last_count >= 0 and count > last_count
                last_count = count
                if snap.get("state") == "reconnecting":
                    reconnecting_since = now if reconnecting_since is None else reconnecting_since
                    alive = progressed or now - reconnecting_since < RECONNECT_GRACE_S
                else:
                    reconnecting_since = None
                    alive = progressed
                if not self._ready and count > 0:
                    self._ready = True
                    self._publish()                 # with ready: true, before READY=1 goes out
                    text = status_line(snap)
                    log.info("ready: %s", text)
                    self.notifier.ready(status=text)
                    last_status_t, last_status_text = now, text
                elif self._ready and alive and interval is not None:
                    self.notifier.watchdog()
                if self._ready and now - last_status_t >= STATUS_PERIOD_S:
                    text = status_line(snap)
                    if text != last_status_text:
                        self.notifier.status(text)
                        last_status_text = text
                    last_status_t = now
                next_poll = now + (poll_s if self._ready else SUPERVISE_PERIOD_S)
            thread.join(timeout=SUPERVISE_PERIOD_S)
        if self.controller is not None:
            _log_learning_events(self.controller.status(), logged_event)     # the last ones (e.g. not saved)
        if self._stop_reason is None:
            self._stop_reason = "control loop ended"

    # ---- runtime files and signals ------------------------------------------------------------
    def _claim_runtime(self, runtime: RuntimePaths) -> None:
        """The private directory and the socket (nobody else's controller answers there); the
        socket's process starts now and answers 'starting' until `_open_runtime`."""
        ensure_private_dir(runtime.directory)
        with claim_lock(runtime):
            refuse_if_running(runtime, _read_pid(runtime.pid_file))
            self._plane = ControlPlane(runtime.socket, self.handle_request).start(wait=False)

    def _open_runtime(self, runtime: RuntimePaths) -> None:
        assert self._plane is not None
        self._plane.wait_ready()
        self._publish()
        with safe_files.replace(runtime.pid_file, (runtime.directory,), safe_files.PID) as fh:
            fh.write(f"{os.getpid()}\n")
        self._exit_record = last_exit.started(str(self.config_path))
        self._write_exit_record(self._exit_record)

    def _record_exit(self, final: dict[str, Any], thread_alive: bool) -> None:
        """How this run ended, for `status` once nothing answers (only a run that recorded its start)."""
        if self._exit_record is None:
            return
        how = "crashed" if thread_alive or self._error is not None else "fault" if _fault_from(final) else "stopped"
        self._write_exit_record(last_exit.ended(str(self.config_path), self._exit_record["started_unix"],
                                                final, how, self._stop_reason))

    def _write_exit_record(self, record: dict[str, Any]) -> None:
        assert self.runtime is not None
        try:
            last_exit.write(self.runtime, record)
        except (OSError, GmaError) as exc:    # the run itself is not at stake: say so in the log
            log.error("cannot write the last-exit record %s: %s", last_exit.path_of(self.runtime), exc)

    def _close_runtime(self) -> None:
        if self._plane is not None:
            self._plane.close()
            self._plane = None
            if self.runtime is not None and _read_pid(self.runtime.pid_file) == os.getpid():
                with contextlib.suppress(FileNotFoundError):
                    self.runtime.pid_file.unlink()

    def _claim_outputs(self) -> None:
        """The telemetry file's lock, before the loop opens the driver: a second controller on the
        same rig is refused here (one line, exit 2) and never touches the amplifier."""
        claim = getattr(self.controller, "claim_outputs", None)
        if claim is not None:
            claim()

    def _release_outputs(self) -> None:
        release = getattr(self.controller, "release_outputs", None)
        if release is not None:
            release()

    def _check_outputs(self, cfg: Any) -> None:
        """Refuse, before anything starts, a file this run would write unsafely: through a link,
        outside the config's output_dirs, over a file that is not ours or one the run reads, into
        a folder that takes no new file, or two outputs on one file; and a state folder background
        diagnoses could not write in (one line naming what the user set, exit 2). A missing input
        is named first: it is the first thing to mend."""
        check_inputs_exist(inputs_of(cfg), str(self.config_path))
        check_outputs(outputs_of(cfg, str(self.config_path), self.stats_json), inputs_of(cfg))
        check_state_dir(getattr(cfg, "monitor", None), tuple(getattr(cfg, "output_dirs", ())))

    def _install_handlers(self) -> dict[int, Any]:
        def on_stop(signum: int, _frame: Any) -> None:
            self.request_stop(signal.Signals(signum).name)

        def on_hup(_signum: int, _frame: Any) -> None:
            self._reload_flag.set()

        previous: dict[int, Any] = {}
        for signum, handler in ((signal.SIGTERM, on_stop), (signal.SIGINT, on_stop),
                                (signal.SIGHUP, on_hup)):
            previous[signum] = signal.signal(signum, handler)
        return previous

    def _write_stats(self, final: dict[str, Any]) -> None:
        payload = {"status": final, "summary": self.summary}
        if self.stats_json is None:
            return
        with safe_files.replace(self.stats_json, (), safe_files.STATS) as fh:
            json.dump(payload, fh, indent=2, default=jsonable)
            fh.write("\n")


def _log_learning_events(status: dict[str, Any], logged: int) -> int:
    """Log each learning event once (a baseline, the reference beyond the limits, a back-off): the
    loop keeps them in its status and never logs itself. Returns the last event logged."""
    for event in (status.get("learning") or {}).get("events") or ():
        if event["seq"] > logged:
            at = f" at t={event['t_s']:.2f} s" if event.get("t_s") is not None else ""
            log.info("learning%s: %s", at, event["text"])
            logged = event["seq"]
    return logged


def _stop_ramp_s(cfg: Any) -> float:
    """The configured ramp to the safe current: the loop is given that long on top to finish."""
    try:
        return max(0.0, float(cfg.limits.get("stop_ramp_max_s", 0.0)))
    except (AttributeError, TypeError, ValueError):
        return 0.0


def _fault_from(status: dict[str, Any]) -> str | None:
    """The reason the loop stopped on its own, if it was a fault (with the controller's words)."""
    if str(status.get("state", "")).lower() in ("fault", "faulted", "failed", "error"):
        faults = faults_of(status)
        return "; ".join(faults) if faults else str(status.get("exit_reason") or status.get("state"))
    return None


def _read_pid(path: Path) -> int | None:
    try:
        return int(path.read_text().strip())
    except (OSError, ValueError):
        return None
