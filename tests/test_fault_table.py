"""Each row of the fault table exercised (issue 10): for every fault name, and every config choice
that selects a row, the fault is provoked in the loop (sim driver, simulated clock) and what the
row says is checked against what happened - how the output went safe (immediate: the first
command after the fault is the safe current in one step; ramp: within the slew limit each tick,
reaching the safe current within `limits.stop_ramp_max_s`; none: the run goes on), what followed
(stop, reconnect, continue), whether learning froze, and the state the run ended in. Plus: every
fault name the package raises has a row, so a fault added without an action fails here."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from gma_ffc.control import safety
from gma_ffc.control.manager import exit_state
from gma_ffc.drivers import DriverError
from gma_ffc.recordings import read_recording

from test_controller_faults import RATE, SLEW, make, models  # noqa: F401  (fixture reused)

SAFE = 0.0
STEP = SLEW / RATE          # the slew limit per tick
RAMP_MAX_S = 0.5            # limits.stop_ramp_max_s in these runs
LIMITS = {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": SLEW, "stop_ramp_max_s": RAMP_MAX_S}
BEYOND = {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 40.0, "offset_um": 40.0}


class Provoked:
    """Where in the driver's command log the fault was provoked (the tick's read)."""

    def __init__(self) -> None:
        self.mark: int | None = None


def _at(tick0, action):
    """An inject that runs `action(inputs, ctrl)` from tick `tick0` on, marking the first time."""
    def inject(tick, inputs, ctrl, driver, provoked):
        if tick >= tick0:
            if provoked.mark is None:
                provoked.mark = len(driver.log)
            action(tick, tick0, inputs, ctrl)
    return inject


def _raise_once(exc):
    def action(tick, tick0, inputs, ctrl):
        if tick == tick0:
            raise exc
    return action


def _force(value):
    def action(tick, tick0, inputs, ctrl):
        inputs.force_N = value
    return action


def _stuck(tick, tick0, inputs, ctrl):
    inputs.force_N = 600.0


def _current(value):
    def action(tick, tick0, inputs, ctrl):
        inputs.current_A = value        # the amplifier switched off: the coil carries nothing
    return action


def _slow_tick(tick, tick0, inputs, ctrl):
    if tick == tick0:
        ctrl.clock.advance(0.3)      # a tick that took 0.3 s against a 0.1 s watchdog


def _stop_at(tick0):
    """A stop requested during tick0 - 1's read: tick0 is the first tick that sees it."""
    def inject(tick, inputs, ctrl, driver, provoked):
        if tick == tick0 - 1:
            ctrl.request_stop("SIGTERM")
        elif tick == tick0:
            provoked.mark = len(driver.log)
    return inject


def _drift(tick, tick0, inputs, ctrl):
    inputs.force_N = 600.0 + 0.1 * (tick % 7)     # a live sensor's last digit before it sticks


def _stuck_after_drift(tick0):
    def inject(tick, inputs, ctrl, driver, provoked):
        if tick < tick0:
            _drift(tick, tick0, inputs, ctrl)
            return
        if provoked.mark is None:
            provoked.mark = len(driver.log)
        _stuck(tick, tick0, inputs, ctrl)
    return inject


# (fault name, config overrides selecting the row, how it is provoked)
CASES = [
    (safety.COMMS_TIMEOUT, {}, _at(500, _raise_once(DriverError("link down", "timeout")))),
    (safety.COMMS_TIMEOUT, {"comms": {"on_fault": "stop"}}, _at(500, _raise_once(DriverError("link down", "timeout")))),
    (safety.COMMS_ERROR, {}, _at(500, _raise_once(DriverError("link down", "comms")))),
    (safety.COMMS_ERROR, {"comms": {"on_fault": "stop"}}, _at(500, _raise_once(DriverError("link down", "comms")))),
    (safety.REGISTER_REFUSED, {}, _at(500, _raise_once(DriverError("force_N.address 99: no such register", "refused")))),
    (safety.EXCEPTION, {}, _at(400, _raise_once(RuntimeError("DAQ driver bug")))),
    (safety.WATCHDOG, {"watchdog_s": 0.1}, _at(400, _slow_tick)),
    (safety.SENSOR_NAN, {"sensor": {"bad_ticks": 5}}, _at(500, _force(math.nan))),
    (safety.SENSOR_ABSURD, {"sensor": {"bad_ticks": 5}}, _at(500, _force(1e7))),
    (safety.SENSOR_STALE, {"sensor": {"stale_ticks": 50}}, _stuck_after_drift(300)),
    (safety.CURRENT_NOT_FOLLOWING, {}, _at(500, _current(0.0))),     # at t = 0.5 s the sine is at its top
    (safety.STRESS_RANGE, {"stress": {"out_of_range": "clamp"}}, _at(400, _force(1500.0))),   # -39 MPa
    (safety.STRESS_RANGE, {"stress": {"out_of_range": "fault"}}, _at(400, _force(1500.0))),
    (safety.DRIVE_RANGE, {"limits": {**LIMITS, "current_max_A": 8.0, "beyond_model": "warn"}, "reference": BEYOND},
     None),
    (safety.DRIVE_RANGE, {"limits": {**LIMITS, "current_max_A": 8.0, "beyond_model": "clamp"}, "reference": BEYOND},
     None),
    (safety.DRIVE_RANGE, {"limits": {**LIMITS, "current_max_A": 8.0, "beyond_model": "fault"}, "reference": BEYOND},
     None),
    (safety.STOP, {}, _stop_at(700)),
]


def _case_id(case):
    name, over, _ = case
    choice = [f"{k}={v}" for sec in over.values() if isinstance(sec, dict)
              for k, v in sec.items() if k in ("on_fault", "out_of_range", "beyond_model")]
    return name + ("-" + "-".join(choice) if choice else "")


def _run(tmp_path, models, name, over, inject):  # noqa: F811
    over = {"limits": LIMITS, "learning": {"kind": "repetitive"}, **over}
    ctrl, driver, cfg = make(tmp_path, models, **over)
    provoked = Provoked()
    if inject is not None:
        driver.inject = lambda tick, inputs: inject(tick, inputs, ctrl, driver, provoked)
    learner = ctrl.setup.law.learner
    freezes, observed = [], []
    real_freeze, real_observe = learner.freeze, learner.observe

    def freeze(t, reason):
        freezes.append((len(driver.log), reason))
        real_freeze(t, reason)

    def observe(t, r, y, s, ok, why_not="", command_A=math.nan):
        observed.append((len(driver.log), ok))
        real_observe(t, r, y, s, ok, why_not, command_A)

    learner.freeze, learner.observe = freeze, observe
    summary = ctrl.run(duration_s=1.5)
    if inject is None:      # drive beyond the model: the first tick the law said so (one write per tick)
        outside = read_recording(cfg.telemetry["path"]).columns["outside_model"].astype(int) & 1
        provoked.mark = int(np.argmax(outside)) if outside.any() else None
    return ctrl, driver, cfg, summary, provoked.mark, freezes, observed


def test_the_cases_walk_every_row_and_every_configured_choice():
    covered = {(name, safety.fault_actions(_cfg(over))[name]) for name, over, _ in CASES}
    rows = {(name, action) for name, action in safety.FAULT_ACTIONS.items()}
    rows |= {(name, action) for name, (_, _, choices) in safety.CONFIGURED.items() for action in choices.values()}
    assert rows <= covered, rows - covered


def _cfg(over):
    from gma_ffc.control.config import validate_config

    return validate_config({"rate_hz": RATE, "model": "unused.yaml", "driver": {"kind": "sim"},
                            "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 12.0},
                            "limits": LIMITS, **over})


@pytest.mark.parametrize("case", CASES, ids=[_case_id(c) for c in CASES])
def test_each_row_of_the_fault_table_does_what_it_says(models, tmp_path, case):  # noqa: F811
    name, over, inject = case
    ctrl, driver, cfg, s, mark, freezes, observed = _run(tmp_path, models, name, over, inject)
    row = ctrl.setup.fault_table[name]
    assert row == safety.fault_actions(cfg)[name]
    assert mark is not None, "the fault was never provoked"
    if name != safety.STOP:       # a stop request is a row, not a fault the status reports
        assert name in [h["fault"] for h in s["fault_history"]], s["fault_history"]
    log = driver.log

    if row.output == "immediate":
        i = next(j for j in range(mark, len(log)) if log[j][0] == "safe")
        assert log[i] == ("safe", SAFE)
        # one step, ignoring the slew limit: the command before was well away from the safe current
        assert log[i - 1][0] == "write" and abs(log[i - 1][1] - SAFE) > STEP
        n_detect = {safety.SENSOR_NAN: 4, safety.SENSOR_ABSURD: 4, safety.SENSOR_STALE: 50,
                    safety.CURRENT_NOT_FOLLOWING: cfg.current_tracking["hold_s"] * RATE}.get(name, 0)
        assert i - mark <= n_detect + 1                  # the safe write came with the fault, nothing between
        if row.freeze_learning:
            assert [f for f in freezes if f[0] == i + 1 and name in f[1]], freezes   # frozen at the safe write
        if row.then == "reconnect":
            assert s["reconnects"] == 1 and name not in s["faults"] and s["state"] == "stopped"
            after = [c for k, c in log[i + 1:] if k == "write"]
            assert after and 0.0 < after[0] <= STEP + 1e-12           # resumes from the safe current
            assert np.abs(np.diff(after)).max() <= STEP + 1e-12
            assert s["ticks"] >= mark + 0.5 * RATE                     # and runs on (backoff took some)
        else:
            assert all(k == "safe" for k, _ in log[i:]), log[i:]        # stopped: no command after
            assert s["state"] == row.exit_state and name in s["faults"]
            assert s["exit_reason"]
    elif row.output == "ramp":
        after = np.array([log[mark - 1][1]] + [c for k, c in log[mark:] if k == "write"])
        assert after[0] > 3 * STEP                                     # it was driving: a real ramp
        assert np.abs(np.diff(after)).max() <= STEP + 1e-12            # within the slew limit each tick
        assert after[-1] == SAFE and len(after) - 1 <= RAMP_MAX_S * RATE + 1   # reached within stop_ramp_max_s
        assert log[-1] == ("safe", SAFE) and log[-2][0] == "write"     # no jump: the safe write changes nothing
        assert len(after) - 1 < 0.9 * (1.5 * RATE - mark)               # it stopped, well before the duration
        assert not [ok for n, ok in observed if n > mark and ok]        # learning froze for the ramp
        assert s["state"] == row.exit_state
        assert (name in s["faults"]) == (row.exit_state == "fault")
    else:   # none: a flag, the run goes on
        assert row.then == "continue" and not freezes
        assert s["ticks"] >= 0.95 * 1.5 * RATE and s["state"] == row.exit_state == "stopped"
        assert name in s["faults"] and s["outside_model"]["drive_ticks" if name == safety.DRIVE_RANGE
                                                           else "stress_ticks"] > 0


def test_a_reconnect_row_that_cannot_reconnect_ends_in_its_exit_state(models, tmp_path):  # noqa: F811
    def fail():
        raise DriverError("still down", "comms")

    inject = _at(500, _raise_once(DriverError("link down", "comms")))
    over = {"comms": {"on_fault": "reconnect", "max_attempts": 2, "backoff_initial_s": 0.01}}
    ctrl, driver, cfg = make(tmp_path, models, limits=LIMITS, **over)
    provoked = Provoked()
    driver.inject = lambda tick, inputs: inject(tick, inputs, ctrl, driver, provoked)
    driver.reconnect = fail
    s = ctrl.run(duration_s=1.5)
    row = ctrl.setup.fault_table[safety.COMMS_ERROR]
    assert row.then == "reconnect" and s["state"] == row.exit_state == "fault"
    assert "reconnect_failed" in s["faults"] and s["reconnects"] == 0
    assert driver.log[-1] == ("safe", SAFE) and all(k == "safe" for k, _ in driver.log[provoked.mark:])


def _raised_fault_names() -> set[str]:
    """Every fault name the package raises: the first argument of a `raise_fault`, `_execute` or
    `_envelope_fault` call or of a `TickFault`, when it is a `safety.NAME` or a literal; a
    `driver_fault(...)` there stands for every `safety.NAME` in that function's body."""
    import inspect

    from gma_ffc.control.faults import driver_fault

    by_driver = {getattr(safety, n.attr) for n in ast.walk(ast.parse(inspect.getsource(driver_fault)))
                 if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) and n.value.id == "safety"}
    names: set[str] = set()
    root = Path(safety.__file__).resolve().parents[1]
    for path in root.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if not (isinstance(node, ast.Call) and node.args):
                continue
            func = node.func
            if (isinstance(func, ast.Attribute) and func.attr in ("raise_fault", "_execute", "_envelope_fault")) \
                    or (isinstance(func, ast.Name) and func.id == "TickFault"):
                for arg in ast.walk(node.args[0]):
                    if isinstance(arg, ast.Name) and arg.id == "driver_fault":
                        names |= by_driver
                    elif isinstance(arg, ast.Attribute) and isinstance(arg.value, ast.Name) and arg.value.id == "safety":
                        names.add(getattr(safety, arg.attr))
                    elif isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                        names.add(arg.value)
    return names


def test_every_fault_name_has_a_row():
    """A fault added without an action fails here: loop faults need a row in FAULT_ACTIONS,
    faults raised on the way out are EXIT_FAULTS, and warnings are WARNINGS."""
    raised = _raised_fault_names()
    assert {safety.COMMS_ERROR, safety.WATCHDOG, safety.SAFE_WRITE_FAILED} <= raised   # the scan sees them
    known = set(safety.FAULT_ACTIONS) | safety.EXIT_FAULTS | safety.WARNINGS
    assert raised <= known, f"fault names with no row: {sorted(raised - known)}"
    # and every name safety defines is in exactly one of them
    limits = set(safety.LIMITS) | {safety.NOT_LIMITED}          # the limiter's words, not faults
    defined = {v for k, v in vars(safety).items() if k.isupper() and isinstance(v, str)} - limits
    assert defined == known
    assert not set(safety.FAULT_ACTIONS) & (safety.EXIT_FAULTS | safety.WARNINGS)
    assert not safety.EXIT_FAULTS & safety.WARNINGS
    # and should one slip through anyway, a run ending with it active ends in fault, never "stopped"
    table = safety.fault_actions(_cfg({}))
    assert exit_state(table, "a_fault_nobody_wrote_down") == "fault"
    assert exit_state(table, safety.REALTIME_REFUSED) == "stopped"


def test_a_row_that_makes_no_sense_is_refused():
    with pytest.raises(ValueError):
        safety.FaultAction("ramp", "reconnect", True, "fault")
    with pytest.raises(ValueError):
        safety.FaultAction("none", "stop", False, "stopped")
    with pytest.raises(ValueError):
        safety.FaultAction("immediate", "stop", True, "broken")
