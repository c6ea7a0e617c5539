"""In-process fault handling with the sim driver: injected exceptions, bad sensor values, model
range, stop requests and the watchdog. For each: the last command is the safe current, the status
names the fault, and telemetry has every tick up to it."""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

from gma_ffc.control.config import validate_config
from gma_ffc.control.manager import ControllerManager
from gma_ffc.control.law import start_stepper
from gma_ffc.control.scheduler import SimulatedClock
from gma_ffc.sil import cached_sdpi_and_mpi
from gma_ffc.drivers import DriverError
from gma_ffc.drivers.sim import SimDriver
from gma_ffc.recordings import read_recording

SLEW = 200.0
RATE = 1000.0


@pytest.fixture(scope="module")
def models(request):
    return cached_sdpi_and_mpi(request.config.cache.mkdir("gma_ffc_sil_models"))


class LoggingSim(SimDriver):
    """The sim driver, remembering every command and how it was sent; faults injected per tick."""

    def __init__(self, cfg, period_s, inject=None):
        super().__init__(cfg, period_s)
        self.log: list[tuple[str, float]] = []
        self.inject = inject or (lambda tick, inputs: None)
        self.tick = 0

    def read(self, inputs):
        super().read(inputs)
        self.tick += 1
        self.inject(self.tick, inputs)

    def write(self, current_A):
        self.log.append(("write", current_A))
        super().write(current_A)

    def safe(self, current_A):
        self.log.append(("safe", current_A))
        SimDriver.write(self, current_A)


def make(tmp_path, models, inject=None, clock="simulated", **over):
    data = {"rate_hz": RATE, "clock": clock, "model": "unused.yaml",
            "driver": {"kind": "sim", "load_mass_kg": 15.0},
            "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 12.0, "offset_um": 15.0},
            "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": SLEW},
            "telemetry": {"path": str(tmp_path / "run.csv")}}
    data.update(over)
    cfg = validate_config(data)
    driver = LoggingSim(cfg.driver, cfg.period_s, inject)
    return ControllerManager(cfg, model=models[0], driver=driver), driver, cfg


def check_common(ctrl, driver, cfg, summary, fault):
    assert summary["state"] == "fault" and fault in summary["faults"], summary["fault_messages"]
    assert fault in summary["fault_messages"] and summary["fault_messages"][fault]
    assert driver.log[-1] == ("safe", 0.0)
    assert any(cmd > 0.5 for kind, cmd in driver.log if kind == "write")   # it was driving
    rec = read_recording(cfg.telemetry["path"])
    assert len(rec) == ctrl.recorder.telemetry.head and ctrl.recorder.telemetry.dropped == 0
    return rec


def test_exception_in_read_goes_to_safe_current_at_once(models, tmp_path):
    def inject(tick, inputs):
        if tick == 400:
            raise RuntimeError("DAQ driver bug")

    ctrl, driver, cfg = make(tmp_path, models, inject)
    s = ctrl.run(duration_s=2.0)
    rec = check_common(ctrl, driver, cfg, s, "exception")
    assert "RuntimeError: DAQ driver bug" in s["fault_messages"]["exception"]
    assert len(rec) == 399 == s["ticks"]      # every complete tick before the fault


def test_exception_in_model_step_is_caught(models, tmp_path):
    ctrl, driver, cfg = make(tmp_path, models)

    class Boom:
        def __init__(self, inner):
            self.inner, self.n = inner, 0

        def step(self, r, s):
            self.n += 1
            if self.n == 300:
                raise FloatingPointError("overflow in the inverse")
            return self.inner.step(r, s)

        def reset(self, u):
            self.inner.reset(u)

    ctrl.setup.law.stepper = Boom(ctrl.setup.law.stepper)
    s = ctrl.run(duration_s=1.0)
    rec = check_common(ctrl, driver, cfg, s, "exception")
    assert rec.columns["current_cmd_A"][-1] == 0.0     # the fault tick is logged with the safe command


@pytest.mark.parametrize("value,fault", [(math.nan, "sensor_nan"), (1e7, "sensor_absurd"),
                                         (-20000.0, "sensor_absurd")])
def test_bad_load_cell_for_n_ticks_faults(models, tmp_path, value, fault):
    def inject(tick, inputs):
        if tick >= 500:
            inputs.force_N = value

    ctrl, driver, cfg = make(tmp_path, models, inject, sensor={"bad_ticks": 5})
    s = ctrl.run(duration_s=2.0)
    rec = check_common(ctrl, driver, cfg, s, fault)
    # four bad readings are ridden out on the last good stress; the fifth faults
    assert s["ticks"] == 499 + 4
    assert np.all(np.isfinite(rec.stress_MPa)) and rec.stress_MPa[-1] == rec.stress_MPa[-6]


def test_a_single_glitch_is_ridden_out(models, tmp_path):
    def inject(tick, inputs):
        if tick in (300, 301):
            inputs.force_N = math.nan

    ctrl, driver, cfg = make(tmp_path, models, inject, sensor={"bad_ticks": 3})
    s = ctrl.run(duration_s=0.6)
    assert s["state"] == "stopped" and s["faults"] == []


def test_stuck_load_cell_faults(models, tmp_path):
    def inject(tick, inputs):
        inputs.force_N = 600.0 + 0.1 * (tick % 7) if tick < 300 else 600.0

    ctrl, driver, cfg = make(tmp_path, models, inject, sensor={"stale_ticks": 50})
    s = ctrl.run(duration_s=2.0)
    check_common(ctrl, driver, cfg, s, "sensor_stale")
    assert 300 + 45 <= s["ticks"] <= 300 + 50


def test_stress_outside_model_range_is_clamped_and_reported(models, tmp_path):
    ctrl, driver, cfg = make(tmp_path, models, driver={"kind": "sim", "load_mass_kg": 80.0})
    s = ctrl.run(duration_s=0.5)
    assert s["state"] == "stopped" and s["stress_clamped_ticks"] > 400
    assert "stress_out_of_model_range" in s["faults"]
    assert "clamped" in s["fault_messages"]["stress_out_of_model_range"]
    # never silent (issue 10): a status flag and a telemetry column too, not only a fault message
    assert s["outside_model"]["stress_ticks"] == s["stress_clamped_ticks"]
    outside = read_recording(cfg.telemetry["path"]).columns["outside_model"].astype(int)
    assert np.count_nonzero(outside & 2) >= s["stress_clamped_ticks"]


def test_stress_outside_model_range_can_fault_with_a_ramp(models, tmp_path):
    def inject(tick, inputs):
        if tick >= 400:
            inputs.force_N = 1500.0      # -39 MPa, beyond the identified -24 MPa

    ctrl, driver, cfg = make(tmp_path, models, inject, stress={"out_of_range": "fault"})
    s = ctrl.run(duration_s=2.0)
    assert s["state"] == "fault" and "stress_out_of_model_range" in s["faults"]
    writes = np.array([c for k, c in driver.log if k == "write"])
    assert writes[-1] == 0.0 and np.abs(np.diff(writes)).max() <= SLEW / RATE + 1e-12   # ramped, no jump


def test_stop_request_ramps_to_safe_within_the_slew_limit(models, tmp_path):
    ctrl, driver, cfg = make(tmp_path, models)

    def inject(tick, inputs):
        if tick == 700:
            ctrl.request_stop("SIGTERM")

    driver.inject = inject
    s = ctrl.run(duration_s=5.0)
    assert s["state"] == "stopped" and s["exit_reason"] == "SIGTERM" and s["faults"] == []
    writes = np.array([c for k, c in driver.log if k == "write"])
    assert writes[-1] == 0.0 and writes[698] > 0.5
    assert np.abs(np.diff(writes)).max() <= SLEW / RATE + 1e-12
    assert driver.log[-1] == ("safe", 0.0)
    assert s["ticks"] < 700 + 3.0 / (SLEW / RATE)


def test_stop_event_stops_the_loop(models, tmp_path):
    ev = threading.Event()
    ctrl, driver, cfg = make(tmp_path, models, lambda tick, inputs: ev.set() if tick == 100 else None)
    s = ctrl.run(ev)
    assert s["state"] == "stopped" and s["exit_reason"] == "stop requested" and driver.log[-1] == ("safe", 0.0)


def test_comms_error_reconnects_and_resumes_from_safe(models, tmp_path):
    def inject(tick, inputs):
        if tick == 500:
            raise DriverError("link down", "timeout")

    ctrl, driver, cfg = make(tmp_path, models, inject)
    s = ctrl.run(duration_s=1.0)
    assert s["state"] == "stopped" and s["reconnects"] == 1 and s["faults"] == []
    assert [h["fault"] for h in s["fault_history"]] == ["comms_timeout"]
    i = driver.log.index(("safe", 0.0))
    assert driver.log[i - 1][1] > 0.5                      # it was driving: the safe write jumped
    after = [c for k, c in driver.log[i + 1:] if k == "write"]
    assert 0.0 < after[0] <= SLEW / RATE + 1e-12           # resumes from the safe current
    assert np.abs(np.diff(after)).max() <= SLEW / RATE + 1e-12


def test_a_failed_safe_write_is_cleared_once_the_safe_current_is_written_after_a_reconnect(models, tmp_path):
    """The link drops and the first safe write fails too; after the reconnect the safe current is
    written, so safe_write_failed is no longer active (it stayed listed until the run ended),
    and it stays in the history and the counts."""
    seen = {}

    def inject(tick, inputs):
        if tick == 500:
            driver.safe = failing_once
            raise DriverError("link down", "timeout")
        if tick == 600:
            seen["active"] = dict(ctrl.faults.active)

    def failing_once(current_A):
        del driver.safe                       # the next safe write goes through
        raise DriverError("write setpoint: connection lost", "comms")

    ctrl, driver, cfg = make(tmp_path, models, inject)
    s = ctrl.run(duration_s=1.0)
    assert s["reconnects"] == 1 and seen["active"] == {}, seen
    assert s["state"] == "stopped" and s["faults"] == []
    assert s["fault_counts"]["safe_write_failed"] == 1
    assert "safe_write_failed" in [h["fault"] for h in s["fault_history"]]
    i = driver.log.index(("safe", 0.0))               # the safe write after the reconnect
    after = [c for k, c in driver.log[i + 1:] if k == "write"]
    assert 0.0 < after[0] <= SLEW / RATE + 1e-12       # and the loop resumes from it


def test_a_link_that_comes_back_and_fails_every_write_gives_up_after_max_attempts(models, tmp_path):
    """A device that answers each reconnect and refuses every write (a setpoint it cannot encode)
    was reconnected forever, the coil going between the safe current and the first command."""
    def refuse(current_A):
        driver.log.append(("refused", current_A))
        raise DriverError("write setpoint: illegal data value", "comms")

    def inject(tick, inputs):
        if tick == 300:
            driver.write = refuse

    ctrl, driver, cfg = make(tmp_path, models, inject, comms={"max_attempts": 3, "backoff_initial_s": 0.01})
    s = ctrl.run(duration_s=5.0)
    assert s["state"] == "fault" and "reconnect_failed" in s["faults"], s["fault_messages"]
    assert "3 reconnects in a row that failed again before a command got through" in \
        s["fault_messages"]["reconnect_failed"]
    assert "illegal data value" in s["fault_messages"]["reconnect_failed"]
    assert s["reconnects"] == 3 and driver.log[-1] == ("safe", 0.0)
    assert sum(kind == "refused" for kind, _ in driver.log) == 4


def test_comms_error_with_stop_policy_stops(models, tmp_path):
    def inject(tick, inputs):
        if tick == 200:
            raise DriverError("link down", "comms")

    ctrl, driver, cfg = make(tmp_path, models, inject, comms={"on_fault": "stop"})
    s = ctrl.run(duration_s=1.0)
    check_common(ctrl, driver, cfg, s, "comms_error")


def test_watchdog_trips_on_a_stalled_tick(models, tmp_path):
    import time

    def inject(tick, inputs):
        if tick == 30:
            time.sleep(0.3)

    ctrl, driver, cfg = make(tmp_path, models, inject, clock="real", rate_hz=200.0, watchdog_s=0.1)
    s = ctrl.run(duration_s=2.0)
    assert s["state"] == "fault" and "watchdog" in s["faults"]
    assert driver.log[-1] == ("safe", 0.0)
    assert s["ticks"] <= 31


class StallingClock(SimulatedClock):
    """Simulated time in which the whole process stops for `stall_s` while the loop sleeps
    before deadline number `at` (what SIGSTOP/SIGCONT does: no tick runs, the command is held)."""

    def __init__(self, at, stall_s):
        super().__init__()
        self.at, self.stall_s, self.sleeps = at, stall_s, 0

    def sleep_until(self, deadline):
        self.sleeps += 1
        super().sleep_until(deadline)
        if self.sleeps == self.at:
            self.advance(self.stall_s)


def test_a_whole_process_stall_longer_than_the_watchdog_goes_safe_and_names_it(models, tmp_path):
    """A 2 s stall between two ticks (watchdog 0.5 s) is the watchdog fault: the safe current at
    once, the run ends in 'fault', and the message gives the stall's length (2 s plus the tick
    before it) and when it ended.
    It used to pass unnoticed: no fault, only missed deadlines, the command held 2 s."""
    ctrl, driver, cfg = make(tmp_path, models)
    ctrl = ControllerManager(cfg, model=models[0], driver=driver, clock=StallingClock(at=500, stall_s=2.0))
    s = ctrl.run(duration_s=4.0)
    check_common(ctrl, driver, cfg, s, "watchdog")
    message = s["fault_messages"]["watchdog"]
    assert "stalled for 2.001 s, until t=2.499 s" in message and "(a period and watchdog_s: 0.501 s)" in message, message
    assert s["ticks"] < 510 and s["exit_reason"].startswith("watchdog")


def test_a_gap_shorter_than_the_watchdog_or_a_reconnect_is_not_a_stall(models, tmp_path):
    """A 0.4 s stall (under watchdog_s) and a reconnect whose backoff (1 s) is longer than
    watchdog_s (the watchdog is paused while the amplifier is safe) both run on."""
    def inject(tick, inputs):
        if tick == 700:
            raise DriverError("link down", "timeout")

    ctrl, driver, cfg = make(tmp_path, models, inject, comms={"backoff_initial_s": 1.0})
    ctrl = ControllerManager(cfg, model=models[0], driver=driver, clock=StallingClock(at=300, stall_s=0.4))
    s = ctrl.run(duration_s=2.0)
    assert s["state"] == "stopped" and s["reconnects"] == 1 and "watchdog" not in s["fault_counts"]


def test_a_slow_loop_is_not_a_stall_its_period_is_not_counted_against_the_watchdog(models, tmp_path):
    """At 1 Hz two ticks are a second apart when all is well, and the default watchdog is 0.5 s: a
    run was faulted "stalled for 1.000 s" after its first tick (a new user's sweep, 2026-11-30).
    A stall is now a period and watchdog_s without a tick; a real one is still found (above)."""
    ctrl, driver, cfg = make(tmp_path, models, rate_hz=1.0)
    s = ctrl.run(duration_s=6.0)
    assert s["state"] == "stopped" and "watchdog" not in s["fault_counts"], s["fault_messages"]
    ctrl, driver, cfg = make(tmp_path, models, rate_hz=1.0)
    ctrl = ControllerManager(cfg, model=models[0], driver=driver, clock=StallingClock(at=3, stall_s=2.0))
    s = ctrl.run(duration_s=8.0)
    assert "watchdog" in s["fault_counts"] and "stalled for 3.000 s" in s["fault_messages"]["watchdog"]


def test_driver_that_cannot_open_faults_without_output(models, tmp_path):
    ctrl, driver, cfg = make(tmp_path, models, comms={"on_fault": "stop"})

    def fail():
        raise DriverError("no such device", "comms")

    driver.open = fail
    s = ctrl.run(duration_s=1.0)
    assert s["state"] == "fault" and "comms_error" in s["faults"] and driver.log == []
    assert not (tmp_path / "run.csv").exists()


CHILD = r'''
import sys, threading, time
from gma_ffc.control.config import validate_config
from gma_ffc.control.manager import ControllerManager
from gma_ffc.control.scheduler import SimulatedClock
from gma_ffc.modelio import load_model
cfg = validate_config({"rate_hz": 500, "model": sys.argv[1], "driver": {"kind": "sim", "load_mass_kg": 15.0},
                       "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 12.0, "offset_um": 15.0},
                       "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": 500.0},
                       "telemetry": {"path": sys.argv[2], "flush_interval_s": 0.5}})
ctrl = ControllerManager(cfg)
threading.Thread(target=ctrl.run, daemon=True).start()
while ctrl.stats.count == 0:
    time.sleep(0.001)
print("running", flush=True)
time.sleep(60)
'''


def test_killed_process_loses_at_most_a_second_of_telemetry(models, tmp_path):
    import signal
    import subprocess
    import sys
    import time

    from gma_ffc.modelio import save_model

    save_model(models[0], tmp_path / "model.yaml")
    out = tmp_path / "killed.csv"
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(tmp_path / "model.yaml"), str(out)],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "running"
        t_run = time.monotonic()
        time.sleep(2.0)
        elapsed = time.monotonic() - t_run
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait(timeout=10)
    rec = read_recording(out)                 # whole lines only: a valid recording
    assert rec.time_s[-1] >= elapsed - 1.0 - 0.2
    assert len(rec) >= (elapsed - 1.0 - 0.2) * 500 * 0.9


def test_a_first_glitch_of_the_load_cell_leaves_telemetry_that_simulate_and_diagnose_read(models, tmp_path, capsys):
    """The load cell's first two readings missing (a transmitter settling; bad_ticks 3 rides them out):
    the controller held the safe current, and its telemetry's first rows had no stress. simulate and
    diagnose refused the whole run's telemetry ("'stress_MPa' is nan or empty ... put the stress at
    that time in the cell"). Those leading rows are left out, with a note; the rest is read."""
    from gma_ffc.cli import main
    from gma_ffc.modelio import save_model

    def inject(tick, inputs):
        if tick <= 2:
            inputs.force_N = math.nan

    ctrl, driver, cfg = make(tmp_path, models, inject, sensor={"bad_ticks": 3})
    s = ctrl.run(duration_s=0.6)
    assert s["ok"], s["fault_messages"]
    rec = read_recording(cfg.telemetry["path"])
    assert rec.file_rows[0] == 2 and np.all(np.isfinite(rec.stress_MPa)) and rec.time_s.size == s["ticks"] - 2
    assert "the first 2 rows (lines 11-12) have no stress" in rec.notes[0], rec.notes
    save_model(models[0], tmp_path / "model.yaml")
    assert main(["simulate", "--model", str(tmp_path / "model.yaml"), cfg.telemetry["path"],
                 "-o", str(tmp_path / "predicted.csv")]) == 0
    assert "have no stress" in capsys.readouterr().err


def test_a_dropped_displacement_reading_leaves_telemetry_that_simulate_and_diagnose_read(models, tmp_path, capsys):
    """One displacement reading the sensor did not give (tick 300): its telemetry cell was empty, and
    simulate and diagnose refused the whole run ("'displacement_um' is nan or empty"). The row is left
    out, with a note naming its line, as the model-fit monitor's window already does; the rest is read,
    and a later bad cell is still named at its own line in the file."""
    from gma_ffc.cli import main
    from gma_ffc.modelio import save_model

    def inject(tick, inputs):
        if tick == 300:
            inputs.displacement_um = math.nan

    ctrl, driver, cfg = make(tmp_path, models, inject)
    s = ctrl.run(duration_s=0.6)
    assert s["ok"], s["fault_messages"]
    rec = read_recording(cfg.telemetry["path"])
    assert rec.time_s.size == s["ticks"] - 1 and np.all(np.isfinite(rec.columns["displacement_um"]))
    assert "1 row has no displacement" in rec.notes[0] and "first at line 310" in rec.notes[0], rec.notes
    save_model(models[0], tmp_path / "model.yaml")
    assert main(["simulate", "--model", str(tmp_path / "model.yaml"), cfg.telemetry["path"],
                 "-o", str(tmp_path / "predicted.csv")]) == 0
    lines = open(cfg.telemetry["path"]).read().splitlines()
    lines[399] = lines[399].replace(lines[399].split(",")[0], "0", 1)       # time going back at line 400
    (tmp_path / "back.csv").write_text("\n".join(lines) + "\n")
    from gma_ffc.errors import RecordingError
    with pytest.raises(RecordingError, match=r"back.csv, line 400: time does not increase"):
        read_recording(tmp_path / "back.csv")


def test_a_telemetry_write_that_fails_shows_in_the_status_while_the_run_goes_on(models, tmp_path, monkeypatch):
    """A full disk: the writer kept `telemetry write failed` to itself until the stop, and the status
    table of a running controller said "faults none" with the file far behind the run. The status
    carries the error and the table a telemetry row, while the loop keeps control."""
    import errno

    from gma_ffc.control.telemetry import Telemetry
    from gma_ffc.service.status import format_table

    ctrl, driver, cfg = make(tmp_path, models)
    wrote = Telemetry._write_all

    def full(tel, data):            # the disk fills after the first block
        if tel.rows_written:
            raise OSError(errno.ENOSPC, "No space left on device")
        wrote(tel, data)
    monkeypatch.setattr(Telemetry, "_write_all", full)
    stop = threading.Event()
    runner = threading.Thread(target=ctrl.run, args=(stop, 60.0))
    runner.start()
    try:
        deadline = time.monotonic() + 30.0
        while not (ctrl.status().get("telemetry") or {}).get("error") and time.monotonic() < deadline:
            time.sleep(0.01)
        status = ctrl.status()
    finally:
        stop.set()
        runner.join(30.0)
    assert status["state"] == "running" and status["telemetry"]["error"] == "telemetry write failed: No space left on device"
    row = next(line for line in format_table(status).splitlines() if line.startswith("telemetry"))
    assert "No space left on device" in row and f"rows written to {cfg.telemetry['path']}" in row, row


class SwitchingOffSim(LoggingSim):
    """A driver whose safe() switches the output off (Modbus `disable_on_safe`): the coil carries 0 A."""

    switches_off_on_safe = True

    def safe(self, current_A):
        self.log.append(("safe", current_A))
        SimDriver.write(self, 0.0)


def plays_through(plays, model, path):
    """The forward plays (model units) after the coil carried each current of `path` in turn."""
    p = np.array(plays, dtype=float)
    for x in path:
        p = np.clip(p, x - model.input_offset - model.play_thresholds, x - model.input_offset + model.play_thresholds)
    return p


@pytest.mark.parametrize("driver_class, path, forgets", [(SwitchingOffSim, (1.2, 0.0, 1.2), False),
                                                          (LoggingSim, (1.2, 1.2), True)])
def test_a_reconnect_carries_the_inverse_memory_through_the_currents_the_coil_carried(models, tmp_path,
                                                                                     driver_class, path, forgets):
    """With a non-zero safe current the inverse resumes with the coil's path in its memory. Where
    the output stays on, the default start (used before) forgot the run before the fault. Where
    safe() switches the output off, the coil went to 0 A and back: on this model that wipes the
    plays as the default start assumes, and the memory carried must agree with it."""
    seen = {}

    def inject(tick, inputs):
        if tick == 500:
            seen["before"] = ctrl.setup.law.stepper.play_state().copy()
            raise DriverError("link down", "timeout")
        if tick == 501:
            seen["after"] = ctrl.setup.law.stepper.play_state().copy()
            seen["how"] = ctrl.setup.law.initial_state

    cfg = validate_config({"rate_hz": RATE, "clock": "simulated", "model": "unused.yaml",
                           "driver": {"kind": "sim", "load_mass_kg": 15.0},
                           "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 12.0, "offset_um": 15.0},
                           "limits": {"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": SLEW,
                                      "safe_current_A": 1.2},
                           "telemetry": {"path": str(tmp_path / "run.csv")}})
    driver = driver_class(cfg.driver, cfg.period_s, inject)
    ctrl = ControllerManager(cfg, model=models[0], driver=driver)
    s = ctrl.run(duration_s=1.0)
    assert s["state"] == "stopped" and s["reconnects"] == 1, s["fault_messages"]
    model = models[0]
    expected = plays_through(seen["before"], model, path)
    np.testing.assert_allclose(seen["after"], expected, atol=1e-9)
    assert " -> ".join(f"{x:.4g}" for x in path) in seen["how"] and "reconnect" in seen["how"]
    default = model.inverse_stepper(cfg.period_s)
    start_stepper(default, model, 1.2)
    assert (np.abs(default.play_state() - expected).max() > 0.05) == forgets


def test_a_reconnect_after_a_failed_safe_write_takes_the_default_start(models, tmp_path):
    """The safe write failed: what the coil carried until the link came back is not known."""
    seen = {}

    def inject(tick, inputs):
        if tick == 500:
            driver.safe = failing_once
            raise DriverError("link down", "timeout")
        if tick == 501:
            seen["how"] = ctrl.setup.law.initial_state

    def failing_once(current_A):
        del driver.safe
        raise DriverError("write setpoint: connection lost", "comms")

    ctrl, driver, cfg = make(tmp_path, models, inject)
    s = ctrl.run(duration_s=1.0)
    assert s["reconnects"] == 1 and "continued" not in seen["how"] and "safe current" in seen["how"], seen
