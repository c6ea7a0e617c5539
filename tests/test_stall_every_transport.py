"""A 2 s stall on any transport is a transient inside the reconnect policy, not the end of the
service (issue 10): the controller goes safe, names the comms fault, reconnects, resumes from
the safe current within the slew limit and tracks again. The watchdog stays for a loop that
truly hangs (tests/test_controller_faults.py)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from gma_ffc.control.manager import ControllerManager
from gma_ffc.recordings import read_recording
from gma_ffc.sil import cached_sdpi_and_mpi
from test_drivers_modbus import STRONG, Bench, wait_ticks
from test_drivers_serial import amplifier, serial_cfg  # noqa: F401  (fixture)

SLEW = 50.0


def run_with_stall(ctrl, rig, rate, stall_s=2.0):
    result = {}
    th = threading.Thread(target=lambda: result.setdefault("s", ctrl.run(duration_s=6.0)))
    th.start()
    try:
        wait_ticks(ctrl, th, int(1.5 * rate), limit_s=30.0)
        rig.faults.set("silent")
        time.sleep(stall_s)
        rig.faults.clear()
    finally:
        th.join(timeout=60.0)
    assert not th.is_alive()
    return result["s"]


def check_recovered(s, path, rate):
    assert s["state"] == "stopped" and s["reconnects"] >= 1, (s["fault_messages"], s["fault_history"])
    assert {"comms_timeout", "comms_error"} & {h["fault"] for h in s["fault_history"]}
    assert "watchdog" not in {h["fault"] for h in s["fault_history"]}
    rec = read_recording(path)
    t, cmd = rec.time_s, rec.columns["current_cmd_A"]
    gap = int(np.argmax(np.diff(t)))
    assert t[gap + 1] - t[gap] > 1.5                               # the stall is in the recording
    ramp = cmd[gap + 1:gap + 1 + int(rate)]
    assert ramp[0] <= SLEW / rate + 1e-6 and np.abs(np.diff(ramp)).max() <= SLEW / rate + 1e-6
    assert t[-1] - t[gap + 1] > 1.0                                # and it ran on afterwards


@pytest.mark.realtime
@pytest.mark.parametrize("transport,rate", [("tcp", 200), ("rtu", 100)])
def test_two_second_stall_on_modbus_recovers(request, tmp_path, transport, rate):
    model = cached_sdpi_and_mpi(request.config.cache.mkdir("gma_ffc_sil_models"), STRONG)[0]
    bench = Bench(transport, "amplifier_int16.yaml")
    try:
        cfg = bench.cfg(tmp_path, f"stall_{transport}", rate,
                        limits={"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": SLEW},
                        comms={"on_fault": "reconnect", "backoff_initial_s": 0.1, "backoff_max_s": 0.5,
                               "max_attempts": 0})
        s = run_with_stall(ControllerManager(cfg, model=model), bench.rig, rate)
        check_recovered(s, cfg.telemetry["path"], rate)
    finally:
        bench.emu.stop()


@pytest.mark.realtime
def test_two_second_stall_on_serial_recovers(request, tmp_path, amplifier):
    model = cached_sdpi_and_mpi(request.config.cache.mkdir("gma_ffc_sil_models"), STRONG)[0]
    rig, port = amplifier()
    cfg = serial_cfg(tmp_path, "stall_serial", port, rate_hz=100,
                     limits={"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": SLEW},
                     comms={"on_fault": "reconnect", "backoff_initial_s": 0.1, "backoff_max_s": 0.5,
                            "max_attempts": 0})
    s = run_with_stall(ControllerManager(cfg, model=model), rig, 100)
    check_recovered(s, cfg.telemetry["path"], 100)
