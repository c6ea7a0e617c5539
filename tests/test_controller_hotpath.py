"""The hot path allocates nothing that grows with the run, and the references are what they say."""

from __future__ import annotations

import fnmatch
import math
import threading
import tracemalloc

import numpy as np
import pytest

from gma_ffc.control.config import validate_config
from gma_ffc.control.manager import ControllerManager
from gma_ffc.drivers.sim import SimDriver
from gma_ffc.control.reference import MultiSine, Sine, Triangle
from gma_ffc.sil import cached_sdpi_and_mpi


@pytest.fixture(scope="module")
def model(request):
    return cached_sdpi_and_mpi(request.config.cache.mkdir("gma_ffc_sil_models"))[0]


def test_memory_does_not_grow_with_the_number_of_ticks(model):
    """Ten times the ticks retain no more memory: nothing per tick is kept (stats, telemetry and
    faults live in buffers sized at start)."""
    cfg = validate_config({"rate_hz": 1000, "clock": "simulated", "model": "unused.yaml",
                           "driver": {"kind": "sim", "load_mass_kg": 10.0},
                           "reference": {"kind": "multisine", "offset_um": 15.0,
                                         "components": [{"frequency_hz": 3, "amplitude_um": 8},
                                                        {"frequency_hz": 7, "amplitude_um": 2}]},
                           "limits": {"current_min_A": 0, "current_max_A": 3, "slew_A_per_s": 500},
                           "telemetry": {"path": None}})
    ctrl = ControllerManager(cfg, model=model)
    ctrl.run(duration_s=0.05)                 # first run: anything lazily created
    tracemalloc.start()
    try:
        ctrl.run(duration_s=0.5)
        short = tracemalloc.get_traced_memory()[0]
        ctrl.run(duration_s=5.0)
        long = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert ctrl.stats.count > 5000
    assert long - short < 8 * 1024, (short, long)


class Quiet(SimDriver):
    """The sim driver without its plant: a device that answers at once, its displacement
    flickering in the last digit like a live sensor's (between two constants: the driver itself
    allocates nothing), its current the last command's."""

    odd = False

    def open(self):
        pass

    def read(self, inputs):
        self.odd = not self.odd
        last = self.last_written_A          # its current follows the command (the current tracking's check)
        inputs.force_N, inputs.current_A = 600.0, (last if last == last else 0.0)
        inputs.displacement_um = 10.001 if self.odd else 10.0

    def write(self, current_A):
        self.last_written_A = current_A


@pytest.mark.parametrize("learning, floor_A", [(False, 0.0), (True, 0.0), (True, 0.5)],
                         ids=["feedforward", "learning", "learning at the floor"])
def test_ticks_and_their_broadcasts_keep_nothing(model, learning, floor_A):
    """Ticks as the loop runs them (read, stress, law, limits, write, the learner's observation,
    telemetry row, status values), driven by hand so nothing but the tick is traced: ten
    thousand more of them retain no more memory than a thousand (counters replace their ints,
    buffers were sized at start). A 0.5 A floor cuts the bottom ~16 % of every period: the
    learner hears each cut (issue 32) and keeps nothing for it either."""
    cfg = validate_config({"rate_hz": 1000, "clock": "simulated", "model": "unused.yaml", "driver": {"kind": "sim"},
                           "reference": {"kind": "sine", "frequency_hz": 3, "amplitude_um": 8, "offset_um": 15},
                           "limits": {"current_min_A": floor_A, "current_max_A": 3, "slew_A_per_s": 500,
                                      "safe_current_A": floor_A},
                           "telemetry": {"path": None},      # the writer thread only for the monitor's blocks
                           "learning": {"kind": "repetitive"} if learning else {}})
    ctrl = ControllerManager(cfg, model=model, driver=Quiet({}, 1e-3))
    ctrl.recorder.start(ctrl.driver.channels, ctrl.setup, 0.0)
    for b in ctrl.broadcasters:          # the plugged-in parts too (the model-fit monitor's prediction and ring)
        b.on_start(ctrl.setup)
    ctrl._start_schedule()
    ctrl._has_current = True        # as `_start_and_loop` finds it: the current tracking runs in the ticks too

    def ticks(first, n):
        for k in range(first, first + n):
            t = k * 1e-3
            ctrl._tick(t, t)
            for b in ctrl.broadcasters:
                if b.on_the_loop:
                    b.on_tick(ctrl.tick)

    ticks(0, 1000)                       # a learner's first periods set up what it keeps
    # the monitor's writer thread allocates its blocks meanwhile: only what the loop's thread keeps
    # counts (frames under threading's bootstrap are another thread's; tracemalloc's own are the
    # snapshots', which grow with the number of traces)
    others = [tracemalloc.Filter(False, name, all_frames=True) for name in (threading.__file__, tracemalloc.__file__)]
    for name in (threading.__file__, tracemalloc.__file__):
        fnmatch.fnmatch("", name)                    # the filters' patterns compiled before tracing starts

    def loop_thread_bytes():
        return sum(stat.size for stat in tracemalloc.take_snapshot().filter_traces(others).statistics("filename"))

    tracemalloc.start(64)
    try:
        ticks(1000, 1000)
        short = loop_thread_bytes()
        ticks(2000, 10_000)
        long = loop_thread_bytes()
    finally:
        tracemalloc.stop()
        ctrl.recorder.close()
    assert long - short < 1024, (short, long)
    watch = next(b for b in ctrl.broadcasters if not b.on_the_loop).watch       # the model-fit monitor, off the loop
    kept = watch.rows.last(1000)          # its writer-thread work ran on those ticks' rows
    assert np.isfinite(kept[:, watch.columns.index("residual_um")]).mean() > 0.9
    learner = ctrl.setup.law.learner
    assert (learner is not None) == learning and (learner is None or learner.learned_periods > 20)
    if learner is not None:
        assert (learner.status()["limited"]["share"] > 0.05) == (floor_A > 0)   # the floor was touched, and heard


def test_sine_leads_by_the_configured_latency():
    plain, led = Sine(3.0, 10.0, 5.0), Sine(3.0, 10.0, 5.0, lead_s=0.01)
    for t in np.linspace(0, 1, 17):
        assert led.value(t) == pytest.approx(plain.value(t + 0.01))
    assert plain.value(0.0) == pytest.approx(-5.0)       # default phase starts at the minimum


def test_triangle_shape():
    tri = Triangle(2.0, 4.0, 1.0)
    assert tri.value(0.0) == pytest.approx(-3.0) and tri.value(0.25) == pytest.approx(5.0)
    assert tri.value(0.125) == pytest.approx(1.0) and tri.value(0.5) == pytest.approx(-3.0)


def test_multisine_is_the_sum_of_its_components():
    ms = MultiSine([{"frequency_hz": 1.0, "amplitude_um": 2.0, "phase_deg": 0.0},
                    {"frequency_hz": 5.0, "amplitude_um": 1.0, "phase_deg": 90.0}], offset_um=3.0)
    t = 0.13
    expect = 3.0 + 2.0 * math.sin(2 * math.pi * t) + math.sin(2 * math.pi * 5 * t + math.pi / 2)
    assert ms.value(t) == pytest.approx(expect)


def test_tick_stats_percentiles_and_skipped_deadlines():
    from gma_ffc.control.scheduler import TickStats

    st = TickStats(1e-3)
    t = 0.0
    for i in range(1, 1001):
        st.record(t, i * 1e-7)            # compute 0.1 .. 100 us, uniformly
        t += 1e-3
        if i == 500:
            t += 2e-3                     # two deadlines skipped: an overrun, not jitter
        if i == 700:
            t += 30e-6                    # one tick 30 us late
    s = st.summary()
    assert s["ticks"] == 1000
    assert s["compute_p50_us"] == pytest.approx(50.0, abs=0.2)
    assert s["compute_p99_us"] == pytest.approx(99.0, abs=0.2)
    assert s["compute_max_us"] == pytest.approx(100.0)
    assert s["jitter_max_us"] == pytest.approx(30.0, abs=1e-6)
    assert s["jitter_p50_us"] <= 0.1 and s["jitter_p99_us"] <= 0.1      # only 2 of 999 intervals jitter
    assert s["achieved_rate_hz"] == pytest.approx(999 / (999e-3 + 2e-3 + 30e-6))
