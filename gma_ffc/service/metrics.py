"""The loop's figures in Prometheus text format, where labs look (config `metrics:`, docs/monitor.md).

A scrape reads the service's status snapshot, the one `gma-ffc status` shows, and turns it into
metric families: the loop pays nothing for metrics, whether anyone scrapes or not. The HTTP
server is prometheus_client's, in a thread of its own, bound to 127.0.0.1 unless the config
says otherwise. Units are Prometheus' base units: seconds and metres (Grafana shows them as us
and um).
"""

from __future__ import annotations

import logging
import threading
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
    for key, doc in (("residual_rms_um", "residual RMS over the monitor's window"),
                     ("noise_floor_um", "noise floor estimated from the residual"),
                     ("identification_rms_um", "the model's identification error (its reference)"),
                     ("tracking_rms_um", "tracking error RMS over the monitor's last whole window")):
        value = m.get(key)
        yield from _gauge(f"gma_ffc_{key[:-3]}_meters", doc, None if value is None else value * UM)


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
    """prometheus_client's HTTP server on (host, port) with only the status collector."""

    def __init__(self, status: Callable[[], Mapping[str, Any]], host: str, port: int) -> None:
        self.registry = CollectorRegistry(auto_describe=False)
        self.registry.register(StatusCollector(status))
        self.host, self.port = host, port
        self._server: Any = None
        self._thread: threading.Thread | None = None

    def start(self) -> tuple[str, int]:
        from prometheus_client import start_http_server

        try:
            self._server, self._thread = start_http_server(self.port, addr=self.host, registry=self.registry)
        except OSError as exc:
            raise ConfigError(f"config key 'metrics': cannot serve on {self.host}:{self.port} ({exc.strerror}); "
                              "choose another metrics.port") from None
        host, port = self._server.server_address[:2]
        log.info("metrics at http://%s:%d/metrics", host, port)
        return host, port

    def close(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
