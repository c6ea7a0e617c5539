"""Prometheus metrics (issue 30): the text format a scraper reads, from a status snapshot handed to
the metrics process. The scrape while a real loop runs is in tests/test_model_watch_service.py."""

from __future__ import annotations

import re
import time
import urllib.request
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families

from gma_ffc.errors import ConfigError
from gma_ffc.service.metrics import MetricsServer

ROOT = Path(__file__).resolve().parents[1]

STATUS = {
    "state": "running", "ticks": 12000, "achieved_rate_hz": 999.8, "target_rate_hz": 1000.0, "overruns": 3,
    "jitter_p50_us": 4.1, "jitter_p99_us": 31.0, "jitter_max_us": 240.0,
    "compute_p50_us": 22.0, "compute_p99_us": 51.0, "compute_max_us": 300.0,
    "faults": ["drive_out_of_model_range"], "fault_counts": {"comms_timeout": 2, "drive_out_of_model_range": 1},
    "monitor": {"state": "drifting", "ratio": 4.2, "residual_rms_um": 0.84, "noise_floor_um": 0.05,
                "identification_rms_um": 0.1, "tracking_rms_um": 0.9},
    "learning": {"enabled": True, "rms_trend_um": [0.5, 0.31, 0.2], "learned_periods": 40, "frozen": False},
}


def scrape(port):
    """One scrape, once the child has the first snapshot (it is handed over a pipe)."""
    end = time.monotonic() + 20
    while True:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as reply:
            assert reply.headers["Content-Type"].startswith("text/plain")
            text = reply.read().decode()
        if "gma_ffc_controller_state" in text or time.monotonic() > end:
            break
        time.sleep(0.05)
    return {s.name: s.value for f in text_string_to_metric_families(text) for s in f.samples
            if not s.labels}, {(s.name, tuple(sorted(s.labels.items()))): s.value
                               for f in text_string_to_metric_families(text) for s in f.samples if s.labels}


def test_every_figure_of_the_issue_is_served_in_base_units():
    server = MetricsServer(lambda: STATUS, "127.0.0.1", 0)
    host, port = server.start()
    try:
        plain, labelled = scrape(port)
    finally:
        server.close()
    assert host == "127.0.0.1"
    assert plain["gma_ffc_ticks_total"] == 12000 and plain["gma_ffc_overruns_total"] == 3
    assert labelled[("gma_ffc_period_jitter_seconds", (("quantile", "0.5"),))] == pytest.approx(4.1e-6)
    assert labelled[("gma_ffc_period_jitter_seconds", (("quantile", "0.99"),))] == pytest.approx(31e-6)
    assert labelled[("gma_ffc_faults_total", (("kind", "comms_timeout"),))] == 2
    assert labelled[("gma_ffc_fault_active", (("kind", "drive_out_of_model_range"),))] == 1
    assert plain["gma_ffc_tracking_rms_meters"] == pytest.approx(0.9e-6)
    # every name docs/monitor.md lists is served (three were served without their model_ prefix,
    # and the Grafana panel drew nothing for them: a new user's sweep, 2026-11-30)
    documented = set(re.findall(r"gma_ffc_[a-z_]+", (ROOT / "docs" / "monitor.md").read_text()))
    served = {name for name, _ in labelled} | set(plain)
    served |= {n[: -len(s)] for n in served for s in ("_total", "_created") if n.endswith(s)}
    assert documented <= served | {n + "_total" for n in served}, sorted(documented - served)
    assert plain["gma_ffc_model_residual_ratio"] == pytest.approx(4.2)
    assert labelled[("gma_ffc_model_fit_state", (("state", "drifting"),))] == 1
    assert labelled[("gma_ffc_model_fit_state", (("state", "ok"),))] == 0
    assert plain["gma_ffc_learning_period_rms_meters"] == pytest.approx(0.2e-6)
    assert labelled[("gma_ffc_controller_state", (("state", "running"),))] == 1


def test_a_taken_port_is_one_clear_error():
    first = MetricsServer(lambda: STATUS, "127.0.0.1", 0)
    _, port = first.start()
    try:
        with pytest.raises(ConfigError, match="metrics.port"):
            MetricsServer(lambda: STATUS, "127.0.0.1", port).start()
    finally:
        first.close()


@pytest.mark.parametrize("host", ["nohost.invalid", "192.0.2.1"])
def test_an_address_the_machine_does_not_have_names_metrics_host_not_the_port(host):
    """A host that does not resolve, or no interface holds, was refused with "choose another
    metrics.port", which cannot help (a new user's sweep, 2026-11-30)."""
    with pytest.raises(ConfigError, match=r"choose an address of this machine for metrics.host") as e:
        MetricsServer(lambda: STATUS, host, 0).start()
    assert "metrics.port" not in str(e.value)


def test_missing_sections_are_left_out_not_faked():
    server = MetricsServer(lambda: {"state": "starting", "ticks": 0}, "127.0.0.1", 0)
    _, port = server.start()
    try:
        plain, labelled = scrape(port)
    finally:
        server.close()
    assert "gma_ffc_model_residual_ratio" not in plain and "gma_ffc_rate_hertz" not in plain
    assert labelled[("gma_ffc_controller_state", (("state", "starting"),))] == 1


def test_the_server_process_leaves_with_the_service():
    server = MetricsServer(lambda: STATUS, "127.0.0.1", 0)
    server.start()
    child = server.child
    server.close()
    assert child.poll() is not None
