"""Reading and presenting the controller's status snapshot (one line for systemd, a table for people).

The controller's `status()` dict is the source; these helpers only read it, tolerating keys a
driver or controller version does not provide (shown as '-').
"""

from __future__ import annotations

import datetime as _dt
import math
import time
from typing import Any, Mapping

# Keys the controller may use for its tick counter, most specific first.
_TICK_KEYS = ("ticks", "tick", "tick_count", "n_ticks", "iterations")


def progress_count(status: Mapping[str, Any]) -> int:
    """The loop's tick counter: it grows while the control loop makes progress."""
    for key in _TICK_KEYS:
        value = status.get(key)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return int(value)
    return 0


def _get(status: Mapping[str, Any], *keys: str) -> Any:
    """First present key; dotted keys look inside nested dicts ('jitter_us.p99')."""
    for key in keys:
        node: Any = status
        for part in key.split("."):
            if not isinstance(node, Mapping) or part not in node:
                node = None
                break
            node = node[part]
        if node is not None:
            return node
    return None


def _num(value: Any, fmt: str, unit: str = "") -> str:
    if value is None:
        return "-"
    try:
        x = float(value)
    except (TypeError, ValueError):
        return str(value)
    if math.isnan(x):
        return "nan"
    return f"{x:{fmt}}{unit}"


def faults_of(status: Mapping[str, Any]) -> list[str]:
    """Active faults, with their messages when the controller gives them."""
    faults = _get(status, "fault_messages", "faults", "active_faults")
    if not faults:
        return []
    if isinstance(faults, Mapping):
        return [f"{k}: {v}" if v not in (None, True, "") else str(k) for k, v in faults.items()]
    if isinstance(faults, (list, tuple)):
        return [str(f) for f in faults]
    return [str(faults)]


def counts_words(counts: Any) -> str:
    """Faults raised since the start, by name ('comms_error 9, sensor_nan 1'; '' for none)."""
    if not isinstance(counts, Mapping):
        return ""
    return ", ".join(f"{name} {n}" for name, n in sorted(counts.items()) if n)


def since_start_clause(counts: Any) -> str:
    """'; faults since start (recovered ones too): comms_error 9' for a one-line summary ('' for none)."""
    counted = counts_words(counts)
    return f"; faults since start (recovered ones too): {counted}" if counted else ""


def fault_history_rows(status: Mapping[str, Any], now: float | None = None) -> list[tuple[str, str]]:
    """Faults since the start and the latest one that recovered: a comms fault that reconnected
    leaves no active fault, and the table said 'faults none' through 9 of them in 3 s."""
    counted = counts_words(status.get("fault_counts"))
    if not counted:
        return []
    rows = [("faults since start", counted)]
    listed = status.get("faults")
    active = set(status.get("fault_messages") or {}) | set(listed if isinstance(listed, list) else [])
    history = status.get("fault_history")
    recovered = [h for h in history if isinstance(h, Mapping) and h.get("fault") not in active] \
        if isinstance(history, list) else []
    if recovered:
        last = recovered[-1]
        at = last.get("at_unix_s")
        age = (f" {max(0.0, (time.time() if now is None else now) - at):.1f} s ago"
               if isinstance(at, (int, float)) else "")
        rows.append(("last recovered", f"{last.get('fault')}{age}: {last.get('message', '')}"))
    return rows


BEHIND_SHARE = 0.1
"""A loop whose ticks overran this often cannot keep its rate: a few overruns are a busy moment
(a reload, a flush), one tick in ten is the computer or the link too slow for the rate asked."""


def _behind(status: Mapping[str, Any]) -> str:
    """Words for a loop that cannot keep its rate ('' when it does): every overrun tick is a
    period the amplifier's command was late."""
    ticks, overruns = progress_count(status), _get(status, "overruns")
    if not isinstance(overruns, (int, float)) or ticks < 100 or overruns < BEHIND_SHARE * ticks:
        return ""
    return (f"; CANNOT KEEP IT: {100 * overruns / ticks:.0f} % of ticks overran (lower rate_hz, or a faster "
            "link or machine)")


def _measured_current(status: Mapping[str, Any]) -> str:
    """The amplifier's reading, or what stands in for it: with no reading (none configured, or a
    missing or absurd one this tick) the command is telemetry's current_A, and not called measured."""
    if status.get("current_measured") is False:
        return "measured - (no reading: telemetry's current_A is the command)"
    return "measured " + _num(_get(status, "current_A"), ".4f", " A")


SNAPSHOT_STALE_S = 2.0
"""The service publishes its snapshot every 0.5 s (docs/service.md): four intervals without one
mean its process is stopped (SIGSTOP), swapped out or starved, whatever the last snapshot said."""


def snapshot_age_s(status: Mapping[str, Any], now: float | None = None) -> float | None:
    """How old the snapshot is (`service.status_at_unix`), or None when it does not say."""
    at = (status.get("service") or {}).get("status_at_unix")
    if not isinstance(at, (int, float)):
        return None
    return max(0.0, (time.time() if now is None else now) - float(at))


def state_words(status: Mapping[str, Any], now: float | None = None) -> str:
    """The state as a person should read it: a 'running' the snapshot's age or the watchdog
    contradicts is not shown as plain 'running'."""
    state = str(_get(status, "state") or "-")
    if state != "running":
        return state
    age = snapshot_age_s(status, now)
    if age is not None and age > SNAPSHOT_STALE_S:
        return (f"NOT RESPONDING: its last snapshot is {age:.1f} s old (it said running); the process is stopped, "
                "swapped out or starved. 'gma-ffc stop' asks, then sends SIGTERM")
    if any(f.startswith("watchdog") for f in faults_of(status)):
        return "running, but STUCK: the loop makes no progress (see faults); the amplifier holds its last command"
    return state


def fields(status: Mapping[str, Any], now: float | None = None) -> list[tuple[str, str]]:
    """(label, value) rows for the human table."""
    svc = status.get("service") or {}
    rate = _get(status, "rate_hz", "achieved_rate_hz", "achieved_hz")
    target = _get(status, "target_rate_hz", "rate_target_hz", "configured_rate_hz")
    jit = {q: _get(status, f"jitter_us.{q}", f"period_jitter_us.{q}", f"jitter_{q}_us")
           for q in ("p50", "p99", "max")}
    rows = [
        ("state", state_words(status, now)),
        ("pid", str(svc.get("pid", "-"))),
        ("rate", _num(rate, ".1f", " Hz") + (f" (target {_num(target, 'g', ' Hz')})" if target else "")
         + _behind(status)),
        ("period jitter", "p50 " + _num(jit["p50"], ".1f", " us") + "  p99 "
         + _num(jit["p99"], ".1f", " us") + "  max " + _num(jit["max"], ".1f", " us")),
        ("overruns", _num(_get(status, "overruns"), ".0f")),
        ("ticks", str(progress_count(status))),
        ("exit reason", str(_get(status, "exit_reason") or "-")),
        ("stress", _num(_get(status, "stress_MPa", "last_stress_MPa"), ".2f", " MPa")),
        ("current", "command " + _num(_get(status, "current_cmd_A"), ".4f", " A") + ", " + _measured_current(status)),
        ("displacement", _num(_get(status, "displacement_um"), ".3f", " um")),
        ("reference", _num(_get(status, "reference_um", "last_reference_um"), ".3f", " um")),
        ("faults", ", ".join(faults_of(status)) or "none"),
    ]
    rows += fault_history_rows(status, now)
    learning = status.get("learning") or {}
    if learning.get("enabled"):
        trend = " ".join(f"{v:.3f}" for v in learning.get("rms_trend_um", [])[-5:]) or "-"
        state = f"FROZEN since t={learning.get('frozen_since_s', 0):.2f} s: {learning['frozen_reason']}" \
            if learning.get("frozen") else str(learning.get("stage", "learning"))
        rows.append(("learning", f"{state}; {learning.get('learned_periods', 0)} periods learned; "
                                 f"RMS per period (um, last 5): {trend}"))
        if learning.get("baseline_rms_um") is not None:
            rows.append(("learning vs ff", f"feedforward {learning['baseline_rms_um']:.3f} um, best "
                                           f"{learning.get('best_rms_um') or 0:.3f} um; gain {learning.get('gain')}, "
                                           f"{learning.get('backoffs', 0)} back-offs"))
        limited = learning.get("limited") or {}
        if limited.get("share"):
            where = ", ".join(f"{s['limit']} at phase {s['from']:.2f}-{s['to']:.2f}" for s in limited.get("where", []))
            rows.append(("learning limits", f"{100 * limited['share']:.1f} % of the last period limited: {where}"))
        if learning.get("last_event"):
            rows.append(("learning event", str(learning["last_event"])))
    elif "learning" in status:
        rows.append(("learning", "off"))
    socket_row = _socket_trouble(status.get("control_socket") or {})
    if socket_row:
        rows.append(("control socket", socket_row))
    rows += _telemetry_rows(status.get("telemetry") or {})
    rows += model_fit_rows(status)
    rows += diagnosis_rows(status.get("diagnosis") or {})
    reload = svc.get("last_reload")
    if reload:
        when = _dt.datetime.fromtimestamp(reload.get("at_unix", 0)).strftime("%H:%M:%S")
        rows.append(("last reload", f"{'ok' if reload.get('ok') else 'REFUSED'} at {when}: "
                                    f"{reload.get('message', '')}"))
    if svc.get("config"):
        rows.append(("config", str(svc["config"])))
    return rows


def _telemetry_rows(tel: Mapping[str, Any]) -> list[tuple[str, str]]:
    """A row only when telemetry is in trouble: a write that failed (a full disk) left the file behind
    the run, and the table said nothing of it until the stop."""
    if not tel.get("error") and not tel.get("dropped"):
        return []
    lost = f"{tel.get('dropped')} rows dropped (the writer fell behind); " if tel.get("dropped") else ""
    failed = f"{tel['error']}; " if tel.get("error") else ""
    return [("telemetry", f"{failed}{lost}{tel.get('rows_written', 0)} of {tel.get('rows', 0)} rows written "
                          f"to {tel.get('path')}")]


_SOCKET_TROUBLE = (("refused_uid", "connections from other users refused"), ("bad", "bad requests"),
                   ("too_long", "requests too long"), ("timed_out", "clients cut off at their deadline"),
                   ("evicted", "idle connections closed to make room"))


def _socket_trouble(counters: Mapping[str, Any]) -> str:
    """What clients have tried since the start, when anything went wrong ('' when nothing did)."""
    return ", ".join(f"{counters[key]} {words}" for key, words in _SOCKET_TROUBLE if counters.get(key))


def _clock(status: Mapping[str, Any], t: Any) -> str:
    """A loop time as the wall-clock time it happened at (the run's start plus t)."""
    start = status.get("started_unix_s")
    if not isinstance(t, (int, float)) or not isinstance(start, (int, float)):
        return ""
    return _dt.datetime.fromtimestamp(start + t).strftime("%H:%M:%S")


def model_fit_rows(status: Mapping[str, Any]) -> list[tuple[str, str]]:
    """The model-fit monitor (docs/monitor.md): state, since when, the ratio and its parts, where."""
    m = status.get("monitor")
    if not m:
        return []
    state = str(m.get("state", "-"))
    if state == "off":
        return [("model fit", f"off: {m.get('reason', 'no displacement channel')}")]
    window = m.get("window") or {}
    if state == "unknown":
        return [("model fit", f"unknown: {_num(window.get('seconds'), '.0f')} of {_num(window.get('window_s'), '.0f')} s "
                              "of residual so far (a whole window decides)")]
    since = f" since t={_num(m.get('since_s'), '.1f')} s ({_clock(status, m.get('since_s'))})"
    text = (f"{state.upper() if state == 'drifting' else state}{since}: residual {_num(m.get('residual_rms_um'), '.3g')} um RMS "
            f"= {_num(m.get('ratio'), '.2f')}x expected (identification {_num(m.get('identification_rms_um'), '.3g')} um, "
            f"noise floor {_num(m.get('noise_floor_um'), '.3g')} um, over {_num(window.get('seconds'), '.3g')} s; "
            f"drifting above {_num((m.get('thresholds') or {}).get('drifting_above'), 'g')}x)")
    rows = [("model fit", text)]
    if m.get("from_start"):
        rows.append(("", "since the first whole window: either these conditions are farther from the "
                         "identification's than the model fits (small loops, another load), or a change began "
                         "before the window was full (a coil heating from the start); the diagnosis tells which"))
    where = m.get("where") or {}
    parts = []
    du = m.get("drive_unit") or ""
    for key, what, unit in (("drive", "at drive", f" {du}"), ("drive_rate_per_s", "at drive rates", f" {du}/s")):
        band = where.get(key)
        if band:
            lo, hi = band["range"]
            hi_text = "up" if hi is None else f"{hi:.3g}"
            parts.append(f"{what} {lo:.3g}-{hi_text}{unit} ({band['rms_um']:.3g} um RMS, {100 * band['share']:.0f}% of ticks)")
    if parts:
        rows.append(("residual largest", "; ".join(parts)))
    if m.get("tracking_rms_um") is not None:
        rows.append(("tracking", f"{m['tracking_rms_um']:.3g} um RMS over the last window"))
    return rows


def diagnosis_rows(d: Mapping[str, Any]) -> list[tuple[str, str]]:
    """The background diagnosis: running, its outcome, the report, how to adopt the extended model."""
    rows: list[tuple[str, str]] = []
    if d.get("running"):
        run = d["running"]
        rows.append(("diagnosis", f"running since {_stamp(run.get('started_unix'))} on {run.get('recording')}"))
    last = d.get("last")
    if last:
        rows.append(("last diagnosis", f"{summary_words(last)} (finished {_stamp(last.get('finished_unix'))})"))
        if last.get("report"):
            rows.append(("report", str(last["report"])))
        if last.get("extended_model") and last.get("effects"):
            rows.append(("adopt with", f"gma-ffc reload --model {last['extended_model']}"))
    if d.get("note"):
        rows.append(("diagnosis note", str(d["note"])))
    return rows


def summary_words(d: Mapping[str, Any]) -> str:
    """A diagnosis' outcome in one line: for the status and the log."""
    outcome = d.get("outcome", "?")
    if outcome in ("failed", "stopped"):
        return f"{outcome}: {d.get('error', '')}"
    effects = ", ".join(d.get("effects") or []) or "no effect named"
    rms = ""
    if d.get("rms_before_um") is not None and d.get("rms_after_um") is not None and d.get("scored", True):
        rms = f" (held-out RMS {d['rms_before_um']:.3g} -> {d['rms_after_um']:.3g} um)"
    why = ""
    if outcome in ("inconclusive", "unexplained") and d.get("cannot_conclude"):
        why = f"; first of {len(d['cannot_conclude'])} reasons: {d['cannot_conclude'][0]}"     # the rest: the report
    return f"{outcome}: {effects}{rms}{why}"


def _stamp(unix: Any) -> str:
    return _dt.datetime.fromtimestamp(unix).strftime("%H:%M:%S") if isinstance(unix, (int, float)) else "-"


def format_table(status: Mapping[str, Any]) -> str:
    rows = fields(status)
    width = max(len(label) for label, _ in rows)
    return "\n".join(f"{label:<{width}}  {value}" for label, value in rows)


def status_line(status: Mapping[str, Any]) -> str:
    """One line for systemd's STATUS=: what `systemctl status` shows."""
    rate = _num(_get(status, "rate_hz", "achieved_rate_hz", "achieved_hz"), ".0f", " Hz")
    p99 = _num(_get(status, "jitter_us.p99", "period_jitter_us.p99", "jitter_p99_us"), ".0f", " us")
    stress = _num(_get(status, "stress_MPa", "last_stress_MPa"), ".1f", " MPa")
    faults = ", ".join(faults_of(status)) or "none"
    state = _get(status, "state") or "-"
    fit = _get(status, "monitor.state")
    fit_text = f", model {fit} ({_num(_get(status, 'monitor.ratio'), '.1f')}x)" if fit in ("ok", "drifting") else ""
    return (f"{state}: {rate}, jitter p99 {p99}, overruns "
            f"{_num(_get(status, 'overruns'), '.0f')}, stress {stress}, faults: {faults}{fit_text}")
