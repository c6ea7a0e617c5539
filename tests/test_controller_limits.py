"""Property tests: no sequence of references or sensor values makes the controller command a
current outside its limits, or a step (through write) above the slew limit."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from gma_ffc.control.config import validate_config
from gma_ffc.control.manager import ControllerManager
from gma_ffc.control.reference import Playback
from gma_ffc.control.safety import Limiter
from gma_ffc.sil import cached_sdpi_and_mpi
from gma_ffc.drivers.base import CURRENT, DISPLACEMENT, FORCE, Driver

any_float = st.floats(allow_nan=True, allow_infinity=True, width=64)
physical = st.floats(-1e4, 1e4, allow_nan=False)


@given(lo=st.floats(-5, 0), span=st.floats(0.01, 10), slew=st.floats(0.1, 1e4), rate=st.floats(10, 1e4),
       targets=st.lists(any_float, min_size=1, max_size=200), initial=physical)
def test_limiter_never_leaves_the_box_nor_exceeds_the_slew(lo, span, slew, rate, targets, initial):
    hi = lo + span
    lim = Limiter(lo, hi, slew, 1.0 / rate, initial)
    prev = lim.last
    assert lo <= prev <= hi
    for t in targets:
        out = lim.apply(t)
        assert lo <= out <= hi
        assert abs(out - prev) <= slew / rate * (1 + 1e-12) + 1e-15
        prev = out


class ScriptedRig(Driver):
    """A driver whose sensor values come from a hypothesis-drawn script; records every command."""

    kind = "scripted"

    def __init__(self, forces):
        super().__init__({}, 1e-3)
        self.forces = forces
        self.channels = (FORCE, CURRENT, DISPLACEMENT)
        self.writes: list[float] = []
        self.safes: list[float] = []
        self.i = 0

    @classmethod
    def validate_config(cls, section, prefix, base_dir):
        return dict(section)

    def open(self):
        self.i = 0

    def read(self, inputs):
        inputs.force_N = self.forces[self.i % len(self.forces)]
        inputs.current_A = self.writes[-1] if self.writes else 0.0
        inputs.displacement_um = 0.0
        self.i += 1

    def write(self, current_A):
        self.writes.append(current_A)

    def safe(self, current_A):
        self.safes.append(current_A)

    def close(self):
        pass


@pytest.fixture(scope="module")
def model(request):
    return cached_sdpi_and_mpi(request.config.cache.mkdir("gma_ffc_sil_models"))[0]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(refs=st.lists(st.floats(-1e3, 1e3, allow_nan=False), min_size=2, max_size=60),
       forces=st.lists(st.one_of(st.floats(0, 2000), any_float), min_size=1, max_size=60),
       lo=st.floats(-1.0, 0.5), span=st.floats(0.05, 3.0), slew=st.floats(1.0, 5000.0))
# drawn in CI (2026-11-30): an absurd load-cell reading faults the run, whose row writes the safe
# current at once, a step beyond the slew limit by the fault table's design, not a stop's ramp
@example(refs=[0.0, 1.0], forces=[3079.0, 0.0, 3079.0], lo=0.0, span=1.0, slew=1.0)
def test_controller_commands_stay_inside_limits(model, refs, forces, lo, span, slew):
    hi = lo + span
    safe = min(max(0.0, lo), hi)
    cfg = validate_config({
        "rate_hz": 1000, "clock": "simulated", "model": "unused.yaml", "driver": {"kind": "sim"},
        "reference": {"kind": "sine", "frequency_hz": 3, "amplitude_um": 1},
        "limits": {"current_min_A": lo, "current_max_A": hi, "slew_A_per_s": slew, "safe_current_A": safe,
                   "stop_ramp_max_s": span / slew + 0.01},      # a ramp that fits (the config refuses one that cannot)
        "sensor": {"bad_ticks": 2}})
    rig = ScriptedRig(forces)
    ctrl = ControllerManager(cfg, model=model, driver=rig)
    ctrl.setup.law.reference = Playback(np.arange(len(refs)) * 1e-3, np.array(refs))
    summary = ctrl.run(duration_s=0.08)
    cmds = [safe] + rig.writes
    assert all(lo <= c <= hi for c in cmds + rig.safes)
    assert all(math.isfinite(c) for c in cmds)
    step = slew * 1e-3
    assert rig.safes and rig.safes[-1] == safe        # every run ends at the safe current
    if summary["state"] == "stopped":                  # a stop ramps: its final safe write within the slew
        ended = cmds + [rig.safes[-1]]                 # limit too (a fault's row may write it at once: the table)
        assert np.abs(np.diff(ended)).max(initial=0.0) <= step * (1 + 1e-9) + 1e-12
