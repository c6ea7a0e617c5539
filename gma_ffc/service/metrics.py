"""The loop's figures in Prometheus text format, where labs look (config `metrics:`, docs/monitor.md).

A scrape reads the service's status snapshot, the one `gma-ffc status` shows, and turns it into
metric families. The HTTP server is prometheus_client's, in a process of its own
(`python -m gma_ffc.service.metrics`): the service hands it each snapshot it takes (twice a
second) down a pipe, and scrapes never touch the loop's process. Served from a thread of the
loop's process, scrapes at 10 Hz raised the loop's p99 period jitter at 1 kHz from 33 us to
860 us on a busy machine: a server thread preempted while it holds the interpreter lock stalls the
loop (scripts/bench_monitor.py). Bound to 127.0.0.1 unless the config says otherwise. Units are
Prometheus' base units: seconds and metres (Grafana shows them as us and um).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import logging
import os
import socket
import subprocess
import sys
from typing import Any, Callable, Iterator, Mapping

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector, CollectorRegistry

from ..errors import ConfigError

log = logging.getLogger("gma_ffc.service")

US, UM = 1e-6, 1e-6
CONTROLLER_STATES = ("starting", "running", "reconnecting", "stopping", "stopped", "fault", "idle")
FIT_STATES = ("ok", "drifting", "off", "unknown")


class StatusCollector(Collector):
    """Metric families from one status snapshot per scrape."""

    def __init__(self, status: Callable[[], Mapping[str, Any]]) -> None:
        self.status = status

    def collect(self) -> Iterator[Metric]:
        s = self.status()
        if not s:               # before the service's first snapshot: nothing known, nothing faked
            return
        yield from _loop(s)
        yield from _faults(s)
        yield from _model_fit(s.get("monitor") or {})
        yield from _learning(s.get("learning") or {})


def _gauge(name: str, doc: str, value: Any) -> Iterator[Metric]:
    if isinstance(value, (int, float)) and not isinstance(value, bool) and value == value:
        yield GaugeMetricFamily(name, doc, value=float(value))


def _states(name: str, doc: str, states: tuple[str, ...], current: Any) -> Metric:
    g = GaugeMetricFamily(name, doc, labels=["state"])
    for state in states:
        g.add_metric([state], 1.0 if state == current else 0.0)
    return g


def _quantiles(name: str, doc: str, s: Mapping[str, Any], prefix: str) -> Metric:
    g = GaugeMetricFamily(name, doc, labels=["quantile"])
    for q, key in (("0.5", "p50"), ("0.99", "p99"), ("1", "max")):
        v = s.get(f"{prefix}_{key}_us")
        if isinstance(v, (int, float)):
            g.add_metric([q], v * US)
    return g


def _loop(s: Mapping[str, Any]) -> Iterator[Metric]:
    yield _states("gma_ffc_controller_state", "the controller's lifecycle state (1 for the current one)",
                  CONTROLLER_STATES, s.get("state"))
    yield CounterMetricFamily("gma_ffc_ticks", "control ticks run", value=float(s.get("ticks") or 0))
    yield from _gauge("gma_ffc_rate_hertz", "achieved loop rate", s.get("achieved_rate_hz"))
    yield from _gauge("gma_ffc_target_rate_hertz", "configured loop rate", s.get("target_rate_hz"))
    yield _quantiles("gma_ffc_period_jitter_seconds", "period jitter over the run (quantile 1: the largest)", s, "jitter")
    yield _quantiles("gma_ffc_compute_seconds", "compute time per tick over the run", s, "compute")
    yield CounterMetricFamily("gma_ffc_overruns", "ticks that missed their deadline", value=float(s.get("overruns") or 0))


def _faults(s: Mapping[str, Any]) -> Iterator[Metric]:
    counts = CounterMetricFamily("gma_ffc_faults", "faults raised, by kind", labels=["kind"])
    for kind, n in sorted((s.get("fault_counts") or {}).items()):
        counts.add_metric([str(kind)], float(n))
    yield counts
    active = GaugeMetricFamily("gma_ffc_fault_active", "faults active now, by kind", labels=["kind"])
    for kind in s.get("faults") or []:
        active.add_metric([str(kind)], 1.0)
    yield active


def _model_fit(m: Mapping[str, Any]) -> Iterator[Metric]:
    if not m:
        return
    yield _states("gma_ffc_model_fit_state", "the model-fit monitor's state (1 for the current one)",
                  FIT_STATES, m.get("state"))
    yield from _gauge("gma_ffc_model_residual_ratio", "residual RMS over what a fitting model leaves", m.get("ratio"))
    # the names docs/monitor.md and its Grafana panel give: the monitor's own figures under model_
    for key, name, doc in (("residual_rms_um", "model_residual_rms", "residual RMS over the monitor's window"),
                           ("noise_floor_um", "model_noise_floor", "noise floor estimated from the residual"),
                           ("identification_rms_um", "model_identification_rms",
                            "the model's identification error (its reference)"),
                           ("tracking_rms_um", "tracking_rms", "tracking error RMS over the monitor's last whole window")):
        value = m.get(key)
        yield from _gauge(f"gma_ffc_{name}_meters", doc, None if value is None else value * UM)


def _learning(learning: Mapping[str, Any]) -> Iterator[Metric]:
    if not learning.get("enabled"):
        return
    trend = learning.get("rms_trend_um") or []
    if trend:
        yield from _gauge("gma_ffc_learning_period_rms_meters", "tracking RMS of the last learned period",
                          trend[-1] * UM)
    yield CounterMetricFamily("gma_ffc_learning_periods", "periods learned",
                              value=float(learning.get("learned_periods") or 0))
    yield from _gauge("gma_ffc_learning_frozen", "1 while learning is frozen", 1.0 if learning.get("frozen") else 0.0)


class MetricsServer:
    """The metrics child: started with `start`, fed snapshots with `publish`, stopped with `close`."""

    def __init__(self, status: Callable[[], Mapping[str, Any]], host: str, port: int,
                 python: str = sys.executable) -> None:
        self.status = status
        self.host, self.port = host, port
        self.python = python
        self.child: subprocess.Popen | None = None

    def start(self) -> tuple[str, int]:
        """Start the child and return where it serves; ConfigError when it cannot bind."""
        self.child = subprocess.Popen([self.python, "-m", "gma_ffc.service.metrics", str(os.getpid()), self.host,
                                       str(self.port)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, close_fds=True)
        assert self.child.stdout is not None and self.child.stdin is not None
        first = self.child.stdout.readline().decode().strip()
        if not first.startswith("serving "):
            self.close()
            key, _, why = first.partition(" ")
            advice = ("choose an address of this machine for metrics.host (127.0.0.1, or 0.0.0.0 for every interface)"
                      if key == "host" else "choose another metrics.port (0: any free port)")
            raise ConfigError(f"config key 'metrics': cannot serve on {self.host}:{self.port} "
                              f"({why or first or 'no answer'}); {advice}")
        host, port = first.split()[1].rsplit(":", 1)
        fcntl.fcntl(self.child.stdin.fileno(), fcntl.F_SETFL, os.O_NONBLOCK)   # a stuck child never blocks the service
        log.info("metrics at http://%s:%s/metrics", host, port)
        self.publish()
        return host, int(port)

    def publish(self) -> None:
        """Hand the child the latest snapshot (dropped when its pipe is full: the next one follows)."""
        child = self.child
        if child is None or child.stdin is None:
            return
        from .control_socket import jsonable as _jsonable

        line = json.dumps(self.status(), default=_jsonable).encode() + b"\n"
        with contextlib.suppress(BlockingIOError, BrokenPipeError):
            os.write(child.stdin.fileno(), line)

    def close(self) -> None:
        child, self.child = self.child, None
        if child is None:
            return
        with contextlib.suppress(OSError):
            if child.stdin is not None:
                child.stdin.close()       # the child leaves when its input ends
        try:
            child.wait(timeout=5)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
        if child.stdout is not None:
            child.stdout.close()


def serve(parent_pid: int, host: str, port: int) -> int:
    """The child: serve the last snapshot read from stdin until stdin ends (or the parent dies)."""
    from prometheus_client import start_http_server

    from .diagnose_child import bind_to_parent

    bind_to_parent(parent_pid)
    latest: list[dict[str, Any]] = [{}]             # swapped whole: a scrape reads one snapshot
    registry = CollectorRegistry(auto_describe=False)
    registry.register(StatusCollector(lambda: latest[0]))
    try:
        server, _thread = start_http_server(port, addr=host, registry=registry)
    except OSError as exc:     # which key to change: an address no interface has, or a port in use
        host_fault = isinstance(exc, socket.gaierror) or exc.errno == errno.EADDRNOTAVAIL
        print(f"{'host' if host_fault else 'port'} {exc.strerror}", flush=True)
        return 1
    bound_host, bound_port = server.server_address[:2]
    print(f"serving {bound_host!s}:{bound_port}", flush=True)
    for line in sys.stdin.buffer:
        with contextlib.suppress(ValueError):
            snapshot = json.loads(line)
            if isinstance(snapshot, dict):
                latest[0] = snapshot
    server.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(serve(int(sys.argv[1]), sys.argv[2], int(sys.argv[3])))
