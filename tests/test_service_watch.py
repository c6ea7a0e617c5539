"""The service's side of the model-fit monitor (issue 30), alone: the model `reload --model`
adopts and how long it is kept, and the status screen's model-fit and diagnosis lines."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from gma_ffc.errors import ConfigError
from gma_ffc.service.status import format_table, status_line
from gma_ffc.service.watch import ModelOverride


@dataclass
class Cfg:
    model: str


def test_reload_model_is_kept_until_the_config_names_another(tmp_path):
    ext = tmp_path / "extended_model.yaml"
    ext.write_text("kind: extended\n")
    ov = ModelOverride()
    assert ov.apply(Cfg("/m/base.yaml"), str(ext)).model == str(ext.resolve())
    assert ov.path is None                       # nothing adopted until the reload went through
    ov.commit()
    assert ov.apply(Cfg("/m/base.yaml"), None).model == str(ext.resolve())     # a plain reload keeps it
    ov.commit()
    assert ov.apply(Cfg("/m/other.yaml"), None).model == "/m/other.yaml"      # the config's model changed: it wins
    ov.commit()
    assert ov.path is None and ov.status() is None
    with pytest.raises(ConfigError, match="not found"):
        ov.apply(Cfg("/m/base.yaml"), str(tmp_path / "missing.yaml"))


def test_a_refused_reload_adopts_nothing(tmp_path):
    ext = tmp_path / "e.yaml"
    ext.write_text("x")
    ov = ModelOverride()
    ov.apply(Cfg("/m/base.yaml"), str(ext))          # the controller then refuses it: no commit
    assert ov.apply(Cfg("/m/base.yaml"), None).model == "/m/base.yaml"


STATUS = {
    "state": "running", "started_unix_s": 1.7e9, "ticks": 5,
    "monitor": {"state": "drifting", "since_s": 84.2, "ratio": 6.3, "residual_rms_um": 0.91,
                "identification_rms_um": 0.095, "noise_floor_um": 0.071, "drive_unit": "A",
                "thresholds": {"drifting_above": 3.0, "ok_below": 2.0},
                "window": {"ticks": 7500, "of": 7500, "seconds": 30.0, "window_s": 30.0}, "tracking_rms_um": 0.93,
                "where": {"drive": {"range": [2.25, 2.625], "rms_um": 1.2, "share": 0.11},
                          "drive_rate_per_s": {"range": [9.49, 30.0], "rms_um": 1.1, "share": 0.3}}},
    "diagnosis": {"last": {"outcome": "effects_named", "effects": ["thermal_drift"], "rms_before_um": 1.64,
                           "rms_after_um": 0.106, "finished_unix": 1.7e9 + 120, "report": "/s/d/report.html",
                           "extended_model": "/s/d/extended_model.yaml"}},
}


def test_status_screen_names_the_drift_where_it_sits_and_how_to_adopt_the_fix():
    rows = dict(line.split("  ", 1) for line in format_table(STATUS).splitlines())
    rows = {k.strip(): v.strip() for k, v in rows.items()}
    assert rows["model fit"].startswith("DRIFTING since t=84.2 s") and "6.30x expected" in rows["model fit"]
    assert "at drive 2.25-2.62 A" in rows["residual largest"] and "9.49-30 A/s" in rows["residual largest"]
    assert rows["last diagnosis"].startswith("effects_named: thermal_drift (held-out RMS 1.64 -> 0.106 um)")
    assert rows["report"] == "/s/d/report.html"
    assert rows["adopt with"] == "gma-ffc reload --model /s/d/extended_model.yaml"
    assert "model drifting (6.3x)" in status_line(STATUS)


def test_status_screen_while_the_window_fills_and_without_displacement():
    unknown = {"state": "running", "monitor": {"state": "unknown",
                                                "window": {"ticks": 3000, "of": 7500, "seconds": 12.0, "window_s": 30.0}}}
    assert "unknown: 12 of 30 s" in format_table(unknown)
    off = {"state": "running", "monitor": {"state": "off", "reason": "the driver has no displacement channel"}}
    assert "off: the driver has no displacement channel" in format_table(off)


def test_monitor_state_dir_must_lie_in_output_dirs(tmp_path):
    from gma_ffc.control.config import validate_config

    base = {"rate_hz": 250.0, "clock": "simulated", "model": "m.yaml", "driver": {"kind": "sim"},
            "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 5.0, "offset_um": 10.0},
            "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0},
            "telemetry": {"path": None}, "output_dirs": [str(tmp_path / "out")]}
    with pytest.raises(ConfigError, match="monitor.state_dir"):
        validate_config({**base, "monitor": {"state_dir": str(tmp_path / "elsewhere")}})
    inside = validate_config({**base, "monitor": {"state_dir": str(tmp_path / "out")}})   # the folder itself is fine
    assert inside.monitor["state_dir"] == str(tmp_path / "out")
