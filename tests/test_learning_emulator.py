"""Learning through the Modbus TCP emulator (real protocol, real time): a 2 s stall in the middle.

Learning must freeze, the output go to the safe current, come back within the slew limit, and
tracking return to its pre-stall level within 5 periods, because the learned correction was kept.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from gma_ffc.control.controller import Controller
from gma_ffc.recordings import read_recording
from test_drivers_modbus import STRONG, Bench, wait_ticks  # noqa: F401  (fixtures reused)
from gma_ffc.sil import cached_sdpi_and_mpi

RATE = 250
FREQ = 2.5                       # 100 samples a period at 250 Hz
SLEW = 50.0


@pytest.mark.realtime
def test_two_second_stall_freezes_learning_goes_safe_and_tracking_returns(tmp_path, request):
    model = cached_sdpi_and_mpi(request.config.cache.mkdir("gma_ffc_sil_models"), STRONG)[0]
    bench = Bench("tcp", "amplifier_int16.yaml", stress=-15.2, noise=True)
    try:
        cfg = bench.cfg(tmp_path, "learn_stall", RATE,
                        reference={"kind": "sine", "frequency_hz": FREQ, "amplitude_um": 12.0, "offset_um": 15.0,
                                   "lead_s": 1.5 / RATE},
                        limits={"current_min_A": 0.0, "current_max_A": 3.0, "slew_A_per_s": SLEW},
                        comms={"on_fault": "reconnect", "backoff_initial_s": 0.1, "backoff_max_s": 0.5,
                               "max_attempts": 0},
                        learning={"kind": "repetitive"})
        ctrl = Controller(cfg, model=model)
        result = {}
        th = threading.Thread(target=lambda: result.setdefault("s", ctrl.run(duration_s=14.0)))
        th.start()
        frozen_during_stall = None
        try:
            wait_ticks(ctrl, th, int(6.0 * RATE), limit_s=30.0)     # 15 periods of learning
            learned_before = ctrl.learner.learned_periods
            bench.rig.faults.set("silent")
            time.sleep(2.0)
            during = ctrl.status()
            frozen_during_stall = during["learning"]
            n_before_clear = len(bench.rig.history("setpoint"))
            bench.rig.faults.clear()
        finally:
            th.join(timeout=40.0)
        assert not th.is_alive()
        s = result["s"]
        assert s["state"] == "stopped" and s["reconnects"] >= 1, s["fault_messages"]
        assert learned_before >= 8
        assert frozen_during_stall["frozen"] and "comms" in frozen_during_stall["frozen_reason"]
        assert {"comms_timeout", "comms_error"} & {h["fault"] for h in during["fault_history"]}
        first_back = bench.rig.history("setpoint")[n_before_clear].value
        assert first_back <= SLEW / RATE + 1e-6          # the device hears the safe current or one slew step first
        rec = read_recording(cfg.telemetry["path"])
        t, cmd = rec.time_s, rec.columns["current_cmd_A"]
        err = rec.columns["reference_um"] - rec.displacement_um
        gap = int(np.argmax(np.diff(t)))
        assert t[gap + 1] - t[gap] > 1.5                          # the stall is in the recording
        ramp = cmd[gap + 1:gap + 1 + RATE]
        assert ramp[0] <= SLEW / RATE + 1e-6                      # resumes from the safe current ...
        assert np.abs(np.diff(ramp)).max() <= SLEW / RATE + 1e-6  # ... within the slew limit
        n = int(RATE / FREQ)
        before = np.sqrt(np.mean(err[gap - 3 * n:gap] ** 2))
        resumed = gap + 1 + 5 * n                                  # 5 periods after the link is back
        after = np.sqrt(np.mean(err[resumed:resumed + 2 * n] ** 2))
        assert len(err) >= resumed + 2 * n
        assert after <= 1.5 * before, (before, after)
        assert s["learning"]["learned_periods"] > learned_before
    finally:
        bench.emu.stop()
