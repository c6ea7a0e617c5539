"""Learning through the Modbus TCP emulator (real protocol, real time): a 2 s stall in the middle.

Learning must freeze, the output go to the safe current, come back within the slew limit, and
tracking return to its pre-stall level within 5 periods, because the learned correction was kept.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from gma_ffc.control.manager import ControllerManager
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
        ctrl = ControllerManager(cfg, model=model)
        result = {}
        stop = threading.Event()
        th = threading.Thread(target=lambda: result.setdefault("s", ctrl.run(stop, duration_s=60.0)))
        th.start()
        frozen_during_stall = None
        try:
            wait_ticks(ctrl, th, int(6.0 * RATE), limit_s=30.0)     # 15 periods: 4 of baseline, then learning
            learned_before = ctrl.setup.law.learner.learned_periods
            bench.rig.faults.set("silent")
            time.sleep(2.0)
            during = ctrl.status()
            frozen_during_stall = during["learning"]
            n_before_clear = len(bench.rig.history("setpoint"))
            ticks_at_clear = ctrl.stats.count
            bench.rig.faults.clear()
            # 10 periods of ticks after the link is back (counted, not timed: a busy machine misses deadlines)
            wait_ticks(ctrl, th, ticks_at_clear + int(10 * RATE / FREQ) + RATE, limit_s=40.0)
        finally:
            stop.set()
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
        # the learned correction was kept through the stall: the period after the link is back
        # applies the same correction, phase for phase, as the last period before it
        corr = rec.columns["correction_um"]
        phase = np.round((t * FREQ) % 1.0 * n).astype(int) % n
        last = {p: c for p, c in zip(phase[gap - n:gap + 1], corr[gap - n:gap + 1])}
        back = slice(gap + 1 + RATE // 5, gap + 1 + RATE // 5 + n)     # once the ramp is over
        kept = [abs(c - last[p]) for p, c in zip(phase[back], corr[back]) if p in last]
        span = np.ptp(corr[gap - n:gap + 1])
        assert len(kept) > n // 2 and np.median(kept) <= 0.25 * span + 1e-3, (np.median(kept), span)
        # and tracking is back at its pre-stall level within 5 periods. Real time on a shared
        # machine: the best 2-period window 5 to 8 periods after is judged, so one late burst of
        # ticks cannot fail it, while a lost correction (about 2x the error for several periods) does.
        before = np.sqrt(np.mean(err[gap - 3 * n:gap] ** 2))
        resumed = gap + 1 + 5 * n                                  # 5 periods after the link is back
        assert len(err) >= resumed + 5 * n
        after = min(np.sqrt(np.mean(err[a:a + 2 * n] ** 2)) for a in range(resumed, resumed + 3 * n + 1, n // 2))
        assert after <= 1.5 * before, (before, after)
        assert s["learning"]["learned_periods"] > learned_before
    finally:
        bench.emu.stop()


# ---- the emulator's random latency (issue 32: timing jitter over Modbus) --------------------------

def test_a_latency_the_emulator_cannot_have_is_refused():
    from gma_ffc.errors import FaultError
    from hil_sim.emulators.modbus import check_latency

    assert check_latency(None) is None and check_latency((0.001, 0.002)) == (0.001, 0.002)
    for bad in ((0.002, 0.001), (-0.001, 0.001), (0.0, 5.0), ("a", 1)):
        with pytest.raises(FaultError, match="latency"):
            check_latency(bad)


@pytest.mark.realtime
def test_the_modbus_emulator_holds_every_request_for_its_seeded_random_latency():
    from pymodbus.client import ModbusTcpClient

    from gma_ffc.registers import load_register_map
    from hil_sim.emulators import DEFAULT_MAP, EmulatedRig, ModbusEmulator, make_plant

    def session(seed):
        rig = EmulatedRig(make_plant(seed=0))
        with ModbusEmulator(rig, load_register_map(DEFAULT_MAP), latency_s=(1e-3, 2e-3), seed=seed) as emu:
            host, port = emu.host_port
            client = ModbusTcpClient(host, port=port, timeout=2, retries=0)
            client.connect()
            trips = []
            for _ in range(40):
                t0 = time.perf_counter()
                assert not client.read_input_registers(0, count=5, device_id=1).isError()
                trips.append(time.perf_counter() - t0)
            client.close()
            return np.array(emu.latencies_s), np.array(trips)

    lat, trips = session(7)
    assert len(lat) >= 40 and lat.min() >= 1e-3 and lat.max() <= 2e-3
    assert lat.max() - lat.min() > 0.5e-3                 # spread over the range, not one value
    assert np.median(trips) >= 1e-3                       # the client waits for it (no upper bound: busy machine)
    again, _ = session(7)
    assert np.array_equal(lat[:40], again[:40])           # seeded: a session can be run again


# ---- seeded sessions to the current floor, latency on (issue 32; the benchmark runs twenty) -----

@pytest.mark.realtime
def test_seeded_sessions_to_the_floor_through_modbus_with_latency_end_no_worse_than_feedforward(tmp_path):
    """A smaller `scripts/bench_learning.py --only sessions`: two of its seeded sessions (a sine
    from the current floor up, 1-2 ms latency on every request, 0 A floor, 50 A/s) through the
    Modbus TCP emulator. At 100 Hz, not the benchmark's 200 Hz: the loop keeps its deadlines
    on a busy machine. Feedforward is the run's own first periods (periods 2-4, before any
    correction), read from the telemetry, not from the learner's bookkeeping.

    Margins a busy machine keeps: a burst of late ticks costs a period 2-3x its RMS, so the end
    is judged on the median of the last 5 periods, worse-than-feedforward at 1.1x, and the
    median ratio at 0.6x (the benchmark's target, 0.4x, is met quiet and quoted there)."""
    from benchmarks.learning_rigs import draw_session, run_modbus_session

    ratios = []
    for seed in (0, 1):
        run = run_modbus_session(draw_session(seed), learning={"kind": "repetitive"}, periods=20, rate_hz=100.0,
                                 workdir=tmp_path)
        st = run.status["learning"]
        assert st["learned_periods"] >= 8, st
        feedforward = float(np.median(run.period_rms_um[1:4]))
        end = float(np.median(run.period_rms_um[-5:]))
        assert end <= 1.1 * feedforward, (seed, run.period_rms_um)          # never worse than feedforward
        ratios.append(end / feedforward)
        # the status shows the limited share and where the reference asks beyond the floor
        assert 0.0 < st["limited"]["share"] < 0.3 and "current_min" in st["limited"]["by"], st["limited"]
        assert any(s["limit"] == "current_min" for s in st["reference_beyond_limits"])
        assert not any(s["limit"] == "ramp" for s in st["reference_beyond_limits"])
    assert float(np.median(ratios)) <= 0.6, ratios
