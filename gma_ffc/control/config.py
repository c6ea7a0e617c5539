"""Controller configuration: load a YAML file, validate every key, fill defaults.

Errors are `ConfigError`s that name the dotted key and say what is wrong; unknown keys are
refused with a did-you-mean. The driver section is validated by the driver plugin itself
(`Driver.validate_config`), so a lab's own driver gets the same checks.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping


from ..errors import ConfigError
from ..schema import Field, pair, validate_section
from ..yamlfile import read_yaml
from .current_tracking import MIN_HOLD_TICKS
from .envelope import BEYOND_POLICIES, STRESS_POLICIES
from .learning import LearningConfig, reference_period_s

DEFAULT_ROD_DIAMETER_MM = 7.0
# A GMA's Terfenol-D rod is millimetres to tens of millimetres across (the paper's 7 mm); under 1 mm is
# a unit slip (7 mm typed in metres, centimetres or inches), which made every load-cell reading look
# absurd only once the rig ran, after the amplifier was opened.
MIN_ROD_DIAMETER_MM = 1.0


def _rod_diameter(value: float, key: str) -> float:
    if value < MIN_ROD_DIAMETER_MM:
        raise ConfigError(f"config key '{key}' ({value:g}) is under {MIN_ROD_DIAMETER_MM:g} mm, thinner than any "
                          f"GMA's rod: give the diameter in millimetres (0.007 m is 7 mm)")
    return value

TOP = {
    "rate_hz": Field("float", 1000.0, min=0.0, min_exclusive=True, max=100_000.0),
    "clock": Field("choice", "real", choices=("real", "simulated")),
    "model": Field("str", help="path to a model file (from `gma-ffc identify`)"),
    "driver": Field("map", help="the driver section, with 'kind' (sim, modbus, serial or a plugin)"),
    "reference": Field("map", help="the reference section, with 'kind' (sine, triangle, multisine, playback)"),
    "stress": Field("map", {}),
    "limits": Field("map", help="current and slew limits are required"),
    "sensor": Field("map", {}),
    "current_tracking": Field("map", {}, help="the measured coil current against the command (docs/controller.md)"),
    "comms": Field("map", {}),
    "telemetry": Field("map", {}),
    "scheduler": Field("map", {}),
    "watchdog_s": Field("float", 0.5, min=0.0, min_exclusive=True),
    "learning": Field("map", {}, help="learning feedforward (off by default): {kind: repetitive}"),
    "output_dirs": Field("list", [], help="the only folders the controller writes into (telemetry, learned "
                                          "correction, background diagnoses); default: the folders those paths name"),
    "monitor": Field("map", {}, help="the model-fit monitor (docs/monitor.md)"),
    "metrics": Field("map", None, nullable=True, help="serve Prometheus metrics (docs/monitor.md): {port: 9464}"),
}

STRESS = {
    "rod_diameter_mm": Field("float", DEFAULT_ROD_DIAMETER_MM, min=0.0, min_exclusive=True, check=_rod_diameter),
    "source": Field("choice", "force", choices=("force", "stress")),
    "out_of_range": Field("choice", "clamp", choices=STRESS_POLICIES),
    "valid_range_MPa": Field("list", [-80.0, 10.0], check=pair),
}

LIMITS = {
    "current_min_A": Field("float"),
    "current_max_A": Field("float"),
    "slew_A_per_s": Field("float", min=0.0, min_exclusive=True),
    "safe_current_A": Field("float", 0.0),
    "stop_ramp_max_s": Field("float", 2.0, min=0.0),
    "beyond_model": Field("choice", "warn", choices=BEYOND_POLICIES,
                          help="a command outside the drive range the model was identified on: warn (flag it "
                               "in status and telemetry), clamp (to that range) or fault (ramp to safe, stop)"),
}

SENSOR = {
    "bad_ticks": Field("int", 3, min=1),
    "stale_ticks": Field("int", 0, min=0, help="0 disables the stuck-sensor check"),
    # The load cell's rated capacity, from its datasheet. By default none: the plausible stress
    # range (stress.valid_range_MPa) on the configured rod already bounds the force. Set, it holds
    # whatever the rod diameter says, so a wrong diameter cannot make an overload look plausible.
    "force_limit_N": Field("float", None, min=0.0, min_exclusive=True, nullable=True,
                           help="the load cell's rated capacity (N); only with stress.source: force"),
}

# Current tracking (control/current_tracking.py): the measured coil current against the command
# through the amplifier's lag; on wherever the driver reads the current.
AUTO = "auto"
TRACKING_RANGE_DIVISOR = 10     # tolerance_A auto: a tenth of the current range
DEFAULT_LAG_S = 1.0 / (2.0 * math.pi * 1000.0)
DEFAULT_HOLD_S = 0.05


def _tolerance(value: Any, key: str) -> Any:
    if value == AUTO:
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ConfigError(f"config key '{key}' must be a current in A above 0 (e.g. 0.3), '{AUTO}' (a tenth of the "
                          f"current range) or null (no current tracking), got {value!r}")
    return float(value)


CURRENT_TRACKING = {
    # auto: a tenth of the current range (limits.current_max_A - current_min_A: 0.3 A
    # for 0-3 A). Far above what a healthy amplifier's reading strays by (an int16 register's 0.1 mA, a
    # 12-bit ADC's 0.02 % of range, the simulated rig's 1 mA noise and 0.3 mA quantum), far below what
    # an amplifier switched off leaves missing (the whole command, most of the range on a stroke).
    "tolerance_A": Field("any", AUTO, nullable=True, check=_tolerance,
                         help="how far the measured current may stray from the expected one (A); auto: a tenth "
                              "of the current range; null: no current tracking"),
    # a first-order 1 kHz current loop, 1/(2 pi 1 kHz) = 0.16 ms: hil_sim's amplifier (bandwidth_hz: 1000),
    # and a usual linear current amplifier's; at the shipped rates (200-1000 Hz) it settles within a tick
    "lag_s": Field("float", DEFAULT_LAG_S, min=0.0, max=10.0,
                   help="the amplifier's current-loop time constant (s): 1 / (2 pi bandwidth)"),
    # outlasts the lag's own transient (5 lags: 0.8 ms) and a reading a tick or two late on a busy
    # link (10 ms at 200 Hz, the slowest shipped rate) five times over; still short against anyone
    # switching an amplifier back on. At least two ticks (at rates under 40 Hz, two periods).
    "hold_s": Field("float", DEFAULT_HOLD_S, min=0.0, min_exclusive=True,
                    help="how long the departure must last before the fault (s)"),
}

COMMS = {
    "on_fault": Field("choice", "reconnect", choices=("reconnect", "stop")),
    "backoff_initial_s": Field("float", 0.1, min=0.0, min_exclusive=True),
    "backoff_max_s": Field("float", 2.0, min=0.0, min_exclusive=True),
    "max_attempts": Field("int", 5, min=0, help="0 retries forever"),
    "safe_retry_s": Field("float", 1.0, min=0.0, max=30.0,
                          help="how long to keep retrying the safe-current write on a failing link"),
}

TELEMETRY = {
    "path": Field("str", None, nullable=True),
    "flush_interval_s": Field("float", 0.5, min=0.01, max=1.0),
    "buffer_s": Field("float", 4.0, min=0.1),
    # 3: a service that fails and restarts keeps the run that failed, and two before it; at 1 kHz a
    # day's telemetry is about 7 GB, so more is the lab's choice, not a default
    "keep_previous": Field("int", 3, min=0, max=100,
                           help="earlier runs' telemetry kept beside the new one, as NAME.1.csv (the last) to "
                                "NAME.N.csv; 0: a new run overwrites the last"),
}

SCHEDULER = {
    "spin_us": Field("float", 300.0, min=0.0, max=100_000.0),
    "realtime_priority": Field("int", 0, min=0, max=99,
                               help="SCHED_FIFO priority of the loop thread (0 = normal scheduling)"),
    "gil_switch_interval_us": Field("float", 100.0, min=10.0, max=5000.0,
                                    help="how soon the loop gets the GIL back from other threads"),
    "loop_cpu": Field("int", None, min=-1, nullable=True,
                      help="with realtime_priority > 0: the CPU the loop thread runs on, which a background "
                           "diagnosis never uses (null: the last CPU allowed, when there are two or more; -1: no pinning)"),
}

# The model-fit monitor (gma_ffc/control/fit_monitor.py, docs/monitor.md).
MONITOR = {
    "enabled": Field("bool", True, help="predict the displacement beside the command and watch the residual"),
    # 30 s: ten periods of a 0.3 Hz reference, and long enough for the background diagnosis to see
    # a heating time constant's first part; a drift shows within a fraction of it (the mean square
    # passes 9x the expected one long before the window has turned over).
    "window_s": Field("float", 30.0, min=0.5, max=600.0, help="the residual's RMS is taken over this much"),
    "trigger_s": Field("float", 10.0, min=0.0, help="drifting this long starts a background diagnosis"),
    "on_drift": Field("choice", "diagnose", choices=("warn", "diagnose"),
                      help="warn (status and log only) or diagnose (also run gma-ffc diagnose in the background)"),
    "max_per_hour": Field("int", 2, min=0, max=60, help="background diagnoses at most this often (0: never)"),
    "state_dir": Field("str", None, nullable=True,
                       help="where diagnoses are written (default: $STATE_DIRECTORY, else $XDG_STATE_HOME/gma-ffc, "
                            "else /var/lib/gma-ffc for root, ~/.local/state/gma-ffc for others; the first of "
                            "output_dirs when the config names them and that default lies outside)"),
}

# Prometheus metrics (gma_ffc/service/metrics.py). Loopback by default: the figures say what the
# rig is doing, which is nobody else's business unless the lab says so.
METRICS = {
    "host": Field("str", "127.0.0.1", help="address to serve on (0.0.0.0: every interface)"),
    "port": Field("int", 9464, min=0, max=65535, help="0: any free port (the status says which)"),
}

REFERENCE_KINDS = ("sine", "triangle", "multisine", "playback")


def _component(value: Any, key: str) -> dict[str, float]:
    return validate_section(value, {
        "frequency_hz": Field("float", min=0.0, min_exclusive=True),
        "amplitude_um": Field("float", min=0.0),
        "phase_deg": Field("float", 0.0),
    }, key)


def _components(value: list, key: str) -> list[dict[str, float]]:
    if not value:
        raise ConfigError(f"config key '{key}' must list at least one component")
    return [_component(v, f"{key}[{i}]") for i, v in enumerate(value)]


REFERENCE = {
    "sine": {
        "kind": Field("choice", choices=REFERENCE_KINDS),
        "frequency_hz": Field("float", min=0.0, min_exclusive=True),
        "amplitude_um": Field("float", min=0.0),
        "offset_um": Field("float", 0.0),
        "phase_deg": Field("float", -90.0),
        "lead_s": Field("float", 0.0, min=0.0),
    },
    "triangle": {
        "kind": Field("choice", choices=REFERENCE_KINDS),
        "frequency_hz": Field("float", min=0.0, min_exclusive=True),
        "amplitude_um": Field("float", min=0.0),
        "offset_um": Field("float", 0.0),
        "lead_s": Field("float", 0.0, min=0.0),
    },
    "multisine": {
        "kind": Field("choice", choices=REFERENCE_KINDS),
        "components": Field("list", check=_components),
        "offset_um": Field("float", 0.0),
        "lead_s": Field("float", 0.0, min=0.0),
    },
    "playback": {
        "kind": Field("choice", choices=REFERENCE_KINDS),
        "file": Field("str", help="a recording with time_s and reference_um"),
        "loop": Field("bool", False),
        "lead_s": Field("float", 0.0, min=0.0),
    },
}


@dataclass
class ControllerConfig:
    """A validated configuration: plain dicts per section, defaults filled in."""

    rate_hz: float
    clock: str
    model: str
    driver: dict[str, Any]
    reference: dict[str, Any]
    stress: dict[str, Any]
    limits: dict[str, Any]
    sensor: dict[str, Any]
    current_tracking: dict[str, Any]      # tolerance_A resolved (None: off), hold_s at least two ticks
    comms: dict[str, Any]
    telemetry: dict[str, Any]
    scheduler: dict[str, Any]
    watchdog_s: float
    learning: LearningConfig = field(default_factory=LearningConfig)
    output_dirs: tuple[str, ...] = ()      # empty: each output's own folder (gma_ffc.safe_files)
    monitor: dict[str, Any] = field(default_factory=lambda: validate_section({}, MONITOR, "monitor"))
    metrics: dict[str, Any] | None = None
    source: str = "<memory>"
    raw: dict[str, Any] = field(default_factory=dict, repr=False)
    learned_setting: str = "learning.file"   # what named learning.file: the key, or run's --learned

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def rod_area_mm2(self) -> float:
        return math.pi * (self.stress["rod_diameter_mm"] / 2.0) ** 2


def _resolve(path: str, base: Path | None) -> str:
    p = Path(os.path.expanduser(path))
    if not p.is_absolute() and base is not None:
        p = base / p
    return str(p)


def _resolve_file(key: str, path: str, base: Path | None, example: str) -> str:
    """An output file's path, resolved; a folder (an existing one, or a path ending in '/') is
    refused here with a file name to give, before any check on where it may be written."""
    resolved = _resolve(path, base)
    if path.endswith(("/", os.sep)) or os.path.isdir(resolved):
        name = path.rstrip("/" + os.sep) or "."
        raise ConfigError(f"config key '{key}': {resolved} is a folder, not a file; name a file in it, "
                          f"e.g. {name}/{example}")
    return resolved


def validate_config(data: Any, source: str = "<memory>", base_dir: str | Path | None = None) -> ControllerConfig:
    """Validate a parsed config mapping; relative file paths resolve against `base_dir`."""
    top = validate_section(data, TOP, "")
    base = Path(base_dir) if base_dir is not None else None
    reference = _reference(top["reference"], base)         # sections in this order: the first error is reported
    limits = _limits(top["limits"], top["rate_hz"])
    driver = _driver(top["driver"], top["clock"], base)
    _limits_fit_the_setpoint(limits, driver)
    _calls_within_the_watchdog(driver, top["watchdog_s"])
    stress, sensor = _sensing(top["stress"], top["sensor"])
    tracking = _current_tracking(top["current_tracking"], limits, top["rate_hz"])
    comms = _comms(top["comms"])
    telemetry = validate_section(top["telemetry"], TELEMETRY, "telemetry")
    if telemetry["path"] is not None:
        telemetry["path"] = _resolve_file("telemetry.path", telemetry["path"], base, "run.csv")
    learning = _learning(top["learning"], reference, base)
    monitor = _monitor_section(top["monitor"], top["rate_hz"], base)
    output_dirs = _output_dirs(top["output_dirs"], base, {"telemetry.path": telemetry["path"],
                                                          "learning.file": learning.file,
                                                          "monitor.state_dir": _diagnoses_of(monitor["state_dir"])})
    return ControllerConfig(rate_hz=top["rate_hz"], clock=top["clock"], model=_resolve(top["model"], base),
                            driver=driver, reference=reference, stress=stress, limits=limits, sensor=sensor,
                            current_tracking=tracking, comms=comms, telemetry=telemetry,
                            scheduler=validate_section(top["scheduler"], SCHEDULER, "scheduler"),
                            watchdog_s=top["watchdog_s"], learning=learning, output_dirs=output_dirs,
                            monitor=monitor,
                            metrics=None if top["metrics"] is None else validate_section(top["metrics"], METRICS, "metrics"),
                            source=source, raw=dict(data))


def _reference(raw: dict[str, Any], base: Path | None) -> dict[str, Any]:
    kind = raw.get("kind")
    if kind is None:
        raise ConfigError(f"config key 'reference.kind' is required: one of {', '.join(REFERENCE_KINDS)}")
    if kind not in REFERENCE:
        validate_section({"kind": kind}, {"kind": Field("choice", choices=REFERENCE_KINDS)}, "reference")
    reference = validate_section(raw, REFERENCE[kind], "reference")
    if kind == "playback":
        reference["file"] = _resolve(reference["file"], base)
    return reference


def _limits(raw: dict[str, Any], rate_hz: float) -> dict[str, Any]:
    limits = validate_section(raw, LIMITS, "limits")
    if not limits["current_min_A"] < limits["current_max_A"]:
        raise ConfigError("config key 'limits.current_min_A' must be below 'limits.current_max_A' "
                          f"({limits['current_min_A']} >= {limits['current_max_A']})")
    if not limits["current_min_A"] <= limits["safe_current_A"] <= limits["current_max_A"]:
        raise ConfigError(f"config key 'limits.safe_current_A' ({limits['safe_current_A']}) must lie within "
                          f"[limits.current_min_A, limits.current_max_A]")
    _stop_ramp_fits(limits, rate_hz)
    return limits


def _stop_ramp_fits(limits: dict[str, Any], rate_hz: float, since: Mapping[str, Any] | None = None) -> None:
    """A stop ramps to the safe current within the slew limit and ends after `stop_ramp_max_s`,
    writing the safe current then. From the limit farthest from the safe current the ramp must fit
    in that time (with one tick to spare, its last step), or that write is a step beyond the slew limit.
    On a reload (`since`: the running limits) the command may still stand anywhere the running
    limits allowed, as new, narrower limits are reached at the new slew: the ramp must fit from there too."""
    safe, slew = limits["safe_current_A"], limits["slew_A_per_s"]
    ends = [limits] if since is None else [limits, since]
    farthest = max(max(end["current_max_A"] - safe, safe - end["current_min_A"]) for end in ends)
    need_s = farthest / slew + 1.0 / rate_hz
    if limits["stop_ramp_max_s"] < need_s:
        enough = math.ceil(need_s * 10.0) / 10.0
        start = "" if since is None else ", from where the running limits may have left the command"
        raise ConfigError(
            f"config key 'limits.stop_ramp_max_s' ({limits['stop_ramp_max_s']:g} s) is shorter than a stop's ramp "
            f"to the safe current at the slew limit{start}: {farthest:g} A at {slew:g} A/s takes {need_s:.3g} s, "
            f"and cutting it short would write the safe current in one step beyond the slew limit. "
            f"{_far_limit_first(limits, farthest)}Set limits.stop_ramp_max_s to {enough:g} or more, or raise "
            f"limits.slew_A_per_s")


# A lab GMA's coil amplifier gives a few amperes to a few tens (the paper's rig 3 A): a current limit
# this large is most likely milliamperes typed as amperes, worth naming before a longer stop ramp.
LIKELY_MILLIAMPERES_A = 100.0


def _far_limit_first(limits: Mapping[str, Any], farthest: float) -> str:
    """The limit that makes the ramp long, to check before lengthening the ramp: `current_max_A: 3000`
    (milliamperes typed as amperes) was told only to set stop_ramp_max_s to 6.1, and then refused as
    a unit slip once the model was read. '' for a limit below LIKELY_MILLIAMPERES_A, and when the
    farthest end is the running limits' (a reload)."""
    safe = limits["safe_current_A"]
    spans = {"current_max_A": limits["current_max_A"] - safe, "current_min_A": safe - limits["current_min_A"]}
    for key, span in spans.items():
        if span == farthest and abs(limits[key]) >= LIKELY_MILLIAMPERES_A:
            return (f"If limits.{key} ({limits[key]:g} A) is not the coil's limit in amperes (milliamperes "
                    "typed as amperes are 1000x), correct it first. ")
    return ""


def stop_ramp_fits_after_reload(running: Mapping[str, Any], new: Mapping[str, Any], rate_hz: float) -> None:
    """ConfigError if a stop after reloading limits `new` over `running` could not ramp to the safe
    current within the new slew limit in the new `stop_ramp_max_s` (`_stop_ramp_fits`)."""
    _stop_ramp_fits(dict(new), rate_hz, since=running)


def _calls_within_the_watchdog(driver: Mapping[str, Any], watchdog_s: float, key: str = "driver") -> None:
    """A driver call may block for its comms timeout (`timeout_s`, the driver's or each device's), and
    the safe current can only be written once it returns: a timeout as long as the watchdog would
    hold the command unwatched past it."""
    for name, value in driver.items():
        where = f"{key}.{name}"
        if isinstance(value, Mapping):
            _calls_within_the_watchdog(value, watchdog_s, where)
        elif name == "timeout_s" and isinstance(value, (int, float)) and value >= watchdog_s:
            raise ConfigError(
                f"config key '{where}' ({value:g} s) must be below watchdog_s ({watchdog_s:g} s): a call that "
                f"blocks that long holds the last command, unwatched, until it returns. Set {where} below "
                f"{watchdog_s:g} s (a few periods is usual), or raise watchdog_s")


def _driver(raw: dict[str, Any], clock: str, base: Path | None) -> dict[str, Any]:
    """The driver section, validated by the driver plugin itself."""
    from ..drivers import driver_class

    if "kind" not in raw:
        raise ConfigError("config key 'driver.kind' is required (sim, modbus, serial or a plugin's name)")
    cls = driver_class(raw["kind"], key="driver.kind")
    if clock == "simulated" and not getattr(cls, "simulated_clock_ok", False):
        raise ConfigError(f"config key 'clock': 'simulated' never sleeps, which only suits a simulated rig; "
                          f"driver '{raw['kind']}' talks to real devices: use clock: real")
    return cls.validate_config(raw, "driver", base)


def _limits_fit_the_setpoint(limits: dict[str, Any], driver: dict[str, Any]) -> None:
    """Every current the limits allow must be one the driver can send: a setpoint register that
    cannot encode current_max_A would fail each write, a comms fault the loop would retry forever."""
    from ..drivers import driver_class

    carried = getattr(driver_class(driver["kind"]), "setpoint_range_A", lambda cfg: None)(driver)
    if carried is None:
        return
    lo, hi, what = carried
    for key in ("current_min_A", "current_max_A", "safe_current_A"):
        if not lo <= limits[key] <= hi:
            raise ConfigError(f"config key 'limits.{key}' ({limits[key]:g} A) is beyond what {what} can carry "
                              f"({lo:g} to {hi:g} A): bring the limit within that, or change the channel's "
                              "type or scale to match the amplifier")


def _sensing(stress_raw: dict[str, Any], sensor_raw: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """The `stress` and `sensor` sections, which must agree on what the sensor reads."""
    stress = validate_section(stress_raw, STRESS, "stress")
    sensor = validate_section(sensor_raw, SENSOR, "sensor")
    if sensor["force_limit_N"] is not None and stress["source"] != "force":
        raise ConfigError("config key 'sensor.force_limit_N' bounds a load cell's reading, but stress.source is "
                          f"{stress['source']!r}: remove it, or read the load cell (stress.source: force)")
    return stress, sensor


def _current_tracking(raw: Any, limits: dict[str, Any], rate_hz: float) -> dict[str, Any]:
    """The `current_tracking` section, its defaults resolved: tolerance_A 'auto' from the current
    range, and the hold at least MIN_HOLD_TICKS ticks (a hold set shorter is refused)."""
    tracking = validate_section(raw, CURRENT_TRACKING, "current_tracking")
    if tracking["tolerance_A"] == AUTO:
        tracking["tolerance_A"] = (limits["current_max_A"] - limits["current_min_A"]) / TRACKING_RANGE_DIVISOR
    least = MIN_HOLD_TICKS / rate_hz
    if tracking["hold_s"] < least:
        if isinstance(raw, Mapping) and "hold_s" in raw:
            raise ConfigError(f"config key 'current_tracking.hold_s' ({tracking['hold_s']:g} s) must hold at least "
                              f"{MIN_HOLD_TICKS} ticks at rate_hz {rate_hz:g}, so that one late reading cannot trip "
                              f"it: make it {least:g} s or more")
        tracking["hold_s"] = least
    return tracking


def _comms(raw: dict[str, Any]) -> dict[str, Any]:
    comms = validate_section(raw, COMMS, "comms")
    if comms["backoff_max_s"] < comms["backoff_initial_s"]:
        raise ConfigError("config key 'comms.backoff_max_s' must be >= 'comms.backoff_initial_s'")
    return comms


def _learning(raw: Any, reference: dict[str, Any], base: Path | None) -> LearningConfig:
    learning = LearningConfig.from_mapping(raw or None)
    if learning.enabled and learning.period_s is None and reference_period_s(reference) is None \
            and not (reference["kind"] == "playback" and reference["loop"]):
        raise ConfigError("config key 'learning.period_s' is required: the reference is not periodic, so the "
                          "learner cannot take its period from it")
    if learning.enabled and learning.period_s is not None:
        _period_holds_whole_cycles(float(learning.period_s), reference)
    if learning.file is not None:
        learning = LearningConfig(**{**learning.to_dict(),
                                     "file": _resolve_file("learning.file", learning.file, base, "learned.yaml")})
    return learning


CYCLES_TOLERANCE = 1e-6     # relative: a period given to six digits still counts whole cycles


def _period_holds_whole_cycles(period_s: float, reference: dict[str, Any]) -> None:
    """A learning period must hold whole cycles of every component of a sine, triangle or multisine
    reference: learning repeats the last period's error, and a reference that does not repeat in it
    made learning 15-20 % worse than the feedforward alone, with no back-off (a new user's sweep,
    2026-11-30: a 0.5 s period on a 3 Hz sine; 1/3 s on 3 Hz + 3.7 Hz)."""
    kind = reference["kind"]
    freqs = ([float(reference["frequency_hz"])] if kind in ("sine", "triangle") else
             [float(c["frequency_hz"]) for c in reference["components"]] if kind == "multisine" else [])
    for f in freqs:
        cycles = period_s * f
        if round(cycles) < 1 or abs(cycles - round(cycles)) > CYCLES_TOLERANCE * max(cycles, 1.0):
            raise ConfigError(
                f"config key 'learning.period_s' ({period_s:g} s) holds {cycles:.4g} cycles of the reference's "
                f"{f:g} Hz: learning repeats each period's error, and this reference does not repeat in it. "
                f"{_common_period_advice(freqs, reference_period_s(reference) is not None)}")


def _common_period_advice(freqs: list[float], own_period: bool) -> str:
    """The shortest time in which every frequency completes whole cycles (frequencies read to a
    thousandth of a hertz), as advice; or that there is none a learner could use. `own_period`: the
    learner takes the reference's period itself when the key is left out."""
    from fractions import Fraction

    periods = [1 / Fraction(f).limit_denominator(1000) for f in freqs]
    common = Fraction(math.lcm(*(q.numerator for q in periods)), math.gcd(*(q.denominator for q in periods)))
    if common > 600:         # ten minutes: a period no learner sees often enough to learn from
        return "Its components share no period under 10 minutes: give them harmonic frequencies"
    return (f"Set learning.period_s to {float(common):.9g} s (or a whole multiple)"
            + (", or leave it out: the learner then takes the reference's own" if own_period else ""))


def _output_dirs(named: list, base: Path | None, outputs: dict[str, str | None]) -> tuple[str, ...]:
    """The folders the config names for output, resolved; every output path must lie in one."""
    from ..safe_files import OutputRefused, area_of

    dirs = []
    for i, d in enumerate(named):
        if not isinstance(d, str) or not d:
            raise ConfigError(f"config key 'output_dirs[{i}]' must be a folder path, got {d!r}")
        dirs.append(_resolve(d, base))
    for key, path in outputs.items():
        if path is not None and dirs:
            try:
                area_of(path, dirs)
            except OutputRefused as exc:
                raise ConfigError(f"config key '{key}': {exc}") from None
    return tuple(dirs)


DIAGNOSIS_MIN_SAMPLES = 400
"""What `gma-ffc diagnose` needs at least (`EffectSelector(min_samples=400)`): a window shorter than
that made every background diagnosis 'too little data (83 samples)' (a new user's sweep, 2026-11-30).
A copy, so that loading a config never imports the diagnosis; tests/test_controller_config.py holds
it to the diagnosis's default."""


def _monitor_section(raw: Any, rate_hz: float, base: Path | None) -> dict[str, Any]:
    monitor = validate_section(raw, MONITOR, "monitor")
    if monitor["window_s"] * rate_hz < 16:
        raise ConfigError(f"config key 'monitor.window_s' ({monitor['window_s']:g} s) must hold at least 16 ticks "
                          f"at {rate_hz:g} Hz: make it at least {16 / rate_hz:g} s")
    ticks = monitor["window_s"] * rate_hz
    chosen = isinstance(raw, Mapping) and "window_s" in raw       # a default window at a slow rate is not refused
    if chosen and monitor["on_drift"] == "diagnose" and monitor["max_per_hour"] > 0 and ticks < DIAGNOSIS_MIN_SAMPLES:
        enough = math.ceil(10.0 * DIAGNOSIS_MIN_SAMPLES / rate_hz) / 10.0
        raise ConfigError(f"config key 'monitor.window_s' ({monitor['window_s']:g} s, {ticks:.0f} ticks at {rate_hz:g} Hz) "
                          f"is too short for the background diagnosis it starts, which needs {DIAGNOSIS_MIN_SAMPLES} "
                          f"samples at least: make it {enough:g} s or more, or set monitor.on_drift: warn")
    if monitor["state_dir"] is not None:
        monitor["state_dir"] = _resolve(monitor["state_dir"], base)
    return monitor


def _diagnoses_of(state_dir: str | None) -> str | None:
    """Where background diagnoses write inside `monitor.state_dir` (what output_dirs must hold)."""
    return None if state_dir is None else str(Path(state_dir) / "diagnoses")


def check_config_file(path: Path) -> None:
    """`--config` must name a file: a folder is said to be one, with a config in it to give."""
    if path.is_dir():
        configs = [c.name for c in sorted(path.iterdir()) if _looks_like_config(c)]
        hint = (f"give a config file in it, e.g. --config {path / configs[0]} (configs there: "
                f"{', '.join(configs[:5])}{', ...' if len(configs) > 5 else ''})" if configs
                else "give a controller config's YAML file (none in that folder looks like one)")
        raise ConfigError(f"config file {path} is a folder, not a file; {hint}")
    if path.exists() and not path.is_file():      # /dev/null, a FIFO: there, but no file to read
        raise ConfigError(f"config file {path} is not a regular file; give a controller config's YAML file")
    if not path.is_file():
        raise ConfigError(f"config file {path} not found")


def _looks_like_config(path: Path) -> bool:
    """A YAML file holding a controller config's required keys (a model file does not)."""
    if path.suffix not in (".yaml", ".yml") or not path.is_file():
        return False
    try:
        data = read_yaml(path, "config file", ConfigError)
    except ConfigError:
        return False
    return isinstance(data, Mapping) and {"model", "driver"} <= set(data)


def load_config(path: str | os.PathLike) -> ControllerConfig:
    """Read and validate a YAML config file; relative paths inside resolve against its folder."""
    p = Path(path)
    data = read_yaml(p, "config file", ConfigError)
    if not isinstance(data, Mapping):
        raise ConfigError(f"{p}: the config must be a mapping of keys to values")
    try:
        # the source as an absolute path: telemetry records it, and a later run from another folder
        # must still know that file as its own (`safe_files.telemetry_kind`)
        return validate_config(data, source=os.path.abspath(p), base_dir=p.parent)
    except ConfigError as exc:
        raise ConfigError(f"{p}: {exc}") from None
