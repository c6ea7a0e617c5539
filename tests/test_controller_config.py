"""Config validation: every error names the key and what is wrong; examples in config/ load;
drivers are found through the entry-point group."""

from __future__ import annotations

import re

from pathlib import Path

import pytest
import yaml

from gma_ffc.control.config import load_config, validate_config
from gma_ffc.drivers import available_drivers, driver_class
from gma_ffc.drivers.modbus import ModbusDriver
from gma_ffc.drivers.serial import SerialDriver
from gma_ffc.drivers.sim import SimDriver
from gma_ffc.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
BASE = {"rate_hz": 500, "model": "m.yaml", "driver": {"kind": "sim"},
        "reference": {"kind": "sine", "frequency_hz": 3, "amplitude_um": 10},
        "limits": {"current_min_A": 0, "current_max_A": 2, "slew_A_per_s": 100}}


def with_(path: str, value):
    data = yaml.safe_load(yaml.safe_dump(BASE))
    node = data
    keys = path.split(".")
    for k in keys[:-1]:
        node = node.setdefault(k, {})
    node[keys[-1]] = value
    return data


@pytest.mark.parametrize("name", ["sim", "modbus_tcp", "modbus_rtu", "serial"])
def test_example_configs_load(name):
    cfg = load_config(ROOT / "config" / f"{name}.yaml")
    assert cfg.rate_hz > 0 and cfg.driver["kind"] in ("sim", "modbus", "serial")
    # the shipped example model, resolved against the config's folder, so the example runs as is
    assert Path(cfg.model).is_absolute() and Path(cfg.model).is_file()


@pytest.mark.parametrize("path,value,message", [
    ("rate_hz", 0, r"'rate_hz' must be > 0"),
    ("rate_hz", "fast", r"'rate_hz' must be a number"),
    ("clock", "wall", r"'clock' must be one of real, simulated"),
    ("limits.current_max_A", -1, r"'limits.current_min_A' must be below 'limits.current_max_A'"),
    ("limits.safe_current_A", 5, r"'limits.safe_current_A' \(5.0\) must lie within"),
    ("limits.slew_A_per_s", 0, r"'limits.slew_A_per_s' must be > 0"),
    ("reference.kind", "square", r"'reference.kind' must be one of sine"),
    ("reference.frequency_hz", None, r"'reference.frequency_hz' must have a value"),
    ("stress.valid_range_MPa", [5, -5], r"'stress.valid_range_MPa' must have low < high"),
    ("stress.out_of_range", "ignore", r"'stress.out_of_range' must be one of clamp, fault"),
    ("sensor.bad_ticks", 0, r"'sensor.bad_ticks' must be >= 1"),
    ("telemetry.flush_interval_s", 5, r"'telemetry.flush_interval_s' must be <= 1"),
    ("driver.kind", "simm", r"no driver named 'simm'.*did you mean 'sim'"),
    ("driver", {"kind": "serial", "port": "/dev/ttyS0", "queries": {"force_N": "F?"}, "x": 1},
     r"'driver.x' is unknown"),
    ("driver.load_mass_kg", -3, r"'driver.load_mass_kg' must be >= 0"),
    ("driver.load_schedule", [[1, 5], [0.5, 2]], r"'driver.load_schedule' times must increase"),
    ("limits.stop_ramp_max_s", 0, r"'limits.stop_ramp_max_s' \(0 s\) is shorter than a stop's ramp"),
    # 7 mm typed in metres: every load-cell reading was absurd, found only once the rig ran (exit 1)
    ("stress.rod_diameter_mm", 0.007, r"'stress.rod_diameter_mm' \(0.007\) is under 1 mm.*in millimetres"),
    ("driver", {"kind": "serial", "port": "/dev/ttyS0", "queries": {"force_N": "F?"}, "timeout_s": 5},
     r"'driver.timeout_s' \(5 s\) must be below watchdog_s \(0.5 s\)"),
])
def test_bad_values_name_the_key(path, value, message):
    with pytest.raises(ConfigError, match=message):
        validate_config(with_(path, value))


@pytest.mark.parametrize("path,suggestion", [
    ("rate_hzz", "rate_hz"), ("limits.slew_A_per_sec", "limits.slew_A_per_s"),
    ("telemetry.pth", "telemetry.path"), ("reference.amplitude", "reference.amplitude_um"),
])
def test_unknown_keys_are_refused_with_a_did_you_mean(path, suggestion):
    with pytest.raises(ConfigError, match=rf"'{path}' is unknown \(did you mean '{suggestion}'\?\)"):
        validate_config(with_(path, 1))


def test_simulated_clock_is_refused_for_real_devices():
    data = with_("driver", {"kind": "serial", "port": "/dev/ttyS0", "queries": {"force_N": "MEAS:FORC?"}})
    data["clock"] = "simulated"
    with pytest.raises(ConfigError, match=r"'clock': 'simulated' .* use clock: real"):
        validate_config(data)


def test_missing_required_key():
    data = with_("limits", {"current_min_A": 0, "current_max_A": 1})
    with pytest.raises(ConfigError, match=r"'limits.slew_A_per_s' is required"):
        validate_config(data)


def test_file_errors_name_the_file_and_line(tmp_path):
    bad = tmp_path / "c.yaml"
    bad.write_text("rate_hz: 100\nlimits: [unclosed\n")
    with pytest.raises(ConfigError, match=r"c.yaml, line \d+: not valid YAML"):
        load_config(bad)
    with pytest.raises(ConfigError, match="no such config file"):
        load_config(tmp_path / "none.yaml")
    bad.write_text(yaml.safe_dump(with_("rate_hz", -5)))
    with pytest.raises(ConfigError, match=r"c.yaml: config key 'rate_hz'"):
        load_config(bad)


def test_a_tab_is_told_to_be_spaces_and_a_device_is_not_a_missing_file(tmp_path):
    """A tab gave PyYAML's "found character '\\t' that cannot start any token; is it a config file?";
    --config /dev/null said "not found". Each now says what it is; the tab replaced, the file reads."""
    from gma_ffc.control.config import check_config_file

    tabbed = tmp_path / "c.yaml"
    tabbed.write_text(yaml.safe_dump(BASE).replace("  ", "\t", 1))
    with pytest.raises(ConfigError, match=r"c.yaml, line \d+: a tab character; YAML indents with spaces only"):
        load_config(tabbed)
    tabbed.write_text(tabbed.read_text().replace("\t", "  "))          # as told
    assert load_config(tabbed).rate_hz == BASE["rate_hz"]
    with pytest.raises(ConfigError, match="/dev/null is not a regular file"):
        check_config_file(Path("/dev/null"))


def test_numbers_in_exponent_form_are_numbers(tmp_path):
    """YAML 1.1 reads 1e3 and 1.0e3 as strings: 'rate_hz must be a number, got '1.0e3'' told a user
    their number was not one."""
    f = tmp_path / "c.yaml"
    text = yaml.safe_dump(BASE).replace("rate_hz: 500", "rate_hz: 1.0e3").replace("slew_A_per_s: 100",
                                                                                  "slew_A_per_s: 5e2")
    f.write_text(text)
    cfg = load_config(f)
    assert cfg.rate_hz == 1000.0 and cfg.limits["slew_A_per_s"] == 500.0
    f.write_text(text.replace("rate_hz: 1.0e3", "rate_hz: 1e"))
    with pytest.raises(ConfigError, match="config key 'rate_hz' must be a number, got '1e'"):
        load_config(f)


def test_relative_paths_resolve_against_the_config_folder(tmp_path):
    f = tmp_path / "sub" / "c.yaml"
    f.parent.mkdir()
    f.write_text(yaml.safe_dump(with_("telemetry.path", "out/t.csv")))
    cfg = load_config(f)
    assert cfg.model == str(f.parent / "m.yaml") and cfg.telemetry["path"] == str(f.parent / "out/t.csv")


def test_playback_reference_file_is_checked(tmp_path):
    from gma_ffc.control.reference import build_reference

    cfg = validate_config(with_("reference", {"kind": "playback", "file": str(tmp_path / "nope.csv")}))
    with pytest.raises(ConfigError, match="reference.file"):
        build_reference(cfg.reference)
    (tmp_path / "ref.csv").write_text("time_s,reference_um\n0,0\n0.5,5\n1.0,0\n")
    ref = build_reference(validate_config(with_("reference", {"kind": "playback", "file": str(tmp_path / "ref.csv"),
                                                              "loop": True})).reference)
    assert ref.value(0.25) == pytest.approx(2.5) and ref.value(1.25) == pytest.approx(2.5)


def test_drivers_come_from_the_entry_point_group():
    eps = available_drivers()
    assert {"sim", "modbus", "serial"} <= set(eps)
    assert driver_class("sim") is SimDriver
    assert driver_class("modbus") is ModbusDriver
    assert driver_class("serial") is SerialDriver


def test_stress_source_must_match_the_driver_channels(tmp_path):
    from gma_ffc.control.manager import ControllerManager

    cfg = validate_config(with_("stress.source", "stress"))
    with pytest.raises(ConfigError, match=r"'stress.source' is 'stress' but driver 'sim' provides no 'stress_MPa'"):
        ControllerManager(cfg, model=object())


def test_a_stop_ramp_cut_short_is_refused_and_the_advised_time_is_accepted():
    """A stop ramps within the slew limit for at most stop_ramp_max_s, then writes the safe current:
    with 3 A to cover at 1 A/s in 0.5 s, that write was a 1.18 A step where 0.005 A a tick is allowed
    (a new user's sweep, 2026-11-30). Refused, with a time that fits; that time is accepted."""
    slow = {"current_min_A": 0, "current_max_A": 3, "slew_A_per_s": 1.0, "stop_ramp_max_s": 0.5}
    with pytest.raises(ConfigError, match=r"3 A at 1 A/s takes 3 s.*Set limits.stop_ramp_max_s to ([0-9.]+) or more") as e:
        validate_config(with_("limits", slow))
    advised = float(re.search(r"stop_ramp_max_s to ([0-9.]+) or more", str(e.value)).group(1))
    cfg = validate_config(with_("limits", {**slow, "stop_ramp_max_s": advised}))
    assert cfg.limits["stop_ramp_max_s"] * slow["slew_A_per_s"] >= 3.0


def test_a_stop_ramp_too_long_for_a_milliampere_limit_says_to_check_the_limit_first():
    """`current_max_A: 3000` (3 A typed in mA) was told only to set stop_ramp_max_s to 6.1; done, the
    run was refused as a unit slip. The message names the limit to correct first; corrected, it loads."""
    slip = {"current_min_A": 0, "current_max_A": 3000, "slew_A_per_s": 500.0}
    with pytest.raises(ConfigError, match=r"If limits.current_max_A \(3000 A\) is not the coil's limit in "
                                          r"amperes.*correct it first\. Set limits.stop_ramp_max_s to 6.1"):
        validate_config(with_("limits", slip))
    assert validate_config(with_("limits", {**slip, "current_max_A": 3.0})).limits["current_max_A"] == 3.0
    with pytest.raises(ConfigError, match=r"If limits.current_min_A \(-3000 A\)"):
        validate_config(with_("limits", {**slip, "current_min_A": -3000, "current_max_A": 3}))
    with pytest.raises(ConfigError) as err:                 # a slow slew on a 3 A coil: no word of milliamperes
        validate_config(with_("limits", {**slip, "current_max_A": 3.0, "slew_A_per_s": 0.5}))
    assert "milliamperes" not in str(err.value) and "Set limits.stop_ramp_max_s to 6.1" in str(err.value)


def test_every_modbus_device_timeout_is_held_below_the_watchdog():
    cfg = yaml.safe_load((ROOT / "config" / "modbus_tcp.yaml").read_text())
    next(iter(cfg["driver"]["devices"].values()))["timeout_s"] = 5.0
    with pytest.raises(ConfigError, match=r"'driver.devices.amp.timeout_s' \(5 s\) must be below watchdog_s"):
        validate_config(cfg, base_dir=ROOT / "config")


def test_a_monitor_window_too_short_to_diagnose_is_refused_and_the_advised_one_or_warn_is_accepted():
    import re

    short = {"window_s": 0.5, "trigger_s": 0.0}
    with pytest.raises(ConfigError, match=r"too short for the background diagnosis.*make it ([0-9.]+) s or more") as e:
        validate_config(with_("monitor", short))
    advised = float(re.search(r"make it ([0-9.]+) s or more", str(e.value)).group(1))
    assert validate_config(with_("monitor", {**short, "window_s": advised})).monitor["window_s"] == advised
    assert validate_config(with_("monitor", {**short, "on_drift": "warn"})).monitor["on_drift"] == "warn"


def test_the_window_check_needs_what_diagnose_needs():
    """The service's config holds its own copy of diagnose's least sample count, so that loading a
    config never imports the diagnosis; the copy must follow the diagnosis's default."""
    import inspect

    from gma_ffc.control.config import DIAGNOSIS_MIN_SAMPLES
    from gma_ffc.diagnose.selection import EffectSelector

    assert inspect.signature(EffectSelector).parameters["min_samples"].default == DIAGNOSIS_MIN_SAMPLES
