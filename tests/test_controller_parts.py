"""The controller's parts alone (issue 34): the inverse's play state and the reload hand-over, the
limiter naming the limit that bound, the law's one call into the learner, the load cell's force
limit, and a broadcaster plugged into the loop without touching it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from gma_ffc.control import safety
from gma_ffc.control.config import validate_config
from gma_ffc.control.envelope import DriveRange
from gma_ffc.control.law import FeedforwardController, carried_play_state
from gma_ffc.control.learning import RAMPING
from gma_ffc.control.manager import ControllerManager
from gma_ffc.control.reference import Sine
from gma_ffc.control.tick import Broadcaster
from gma_ffc.errors import ConfigError
from gma_ffc.inverse import play_forward_state, play_inverse_initial_state
from gma_ffc.model import SDPIModel
from gma_ffc.modelio import load_model

from test_controller_faults import make, models  # noqa: F401  (fixture reused)

MODEL = Path(__file__).resolve().parents[1] / "config" / "models" / "sim_sdpi.yaml"


# ---- the inverse's play state, and the hand-over on a reload --------------------------------------
@given(w=st.lists(st.floats(0.01, 10.0), min_size=1, max_size=12), data=st.data())
def test_play_forward_state_undoes_the_inverse_initial_state(w, data):
    y0 = np.array(data.draw(st.lists(st.floats(-100, 100), min_size=len(w), max_size=len(w))))
    q = play_inverse_initial_state(np.array(w), y0)
    np.testing.assert_allclose(play_forward_state(np.array(w), q), y0, rtol=1e-9, atol=1e-9 * (1 + np.abs(y0).max()))


def sweep(n: int = 1500) -> np.ndarray:
    t = np.arange(n) * 1e-3
    return 20.0 + 12.0 * np.sin(2 * np.pi * 3 * t - np.pi / 2) + 2.0 * np.sin(2 * np.pi * 11 * t)


def test_a_running_inverse_knows_the_forward_plays_it_stands_for():
    """(10) holds at every sample: the plays read out of the inverse are those of a forward model
    driven by the inverse's own output, to rounding, along a run with minor loops."""
    model = load_model(MODEL)
    inv, fwd = model.inverse_stepper(1e-3), model.forward_stepper(1e-3)
    ref = sweep()
    start = model.invert_initial_state(ref[:1], -15.0)[0]
    inv.reset(0.0, start)
    fwd.reset(0.0, start)
    worst = 0.0
    for r in ref:
        fwd.step(inv.step(float(r), -15.0), -15.0)
        worst = max(worst, float(np.abs(inv.play_state() - fwd._state[: model.n_play]).max()))
    assert worst < 1e-9


def law_on(model: SDPIModel, ref: Sine) -> FeedforwardController:
    law = FeedforwardController(model, ref, model.inverse_stepper(1e-3))
    law.activate(0.0)
    return law


def test_taking_over_from_the_same_model_continues_every_output():
    model = load_model(MODEL)
    ref = Sine(3.0, 12.0, 20.0)
    old, twin = law_on(model, ref), law_on(model, ref)
    for k in range(417):                      # to the middle of a falling branch
        twin.update(k * 1e-3, -15.0)
        u = old.update(k * 1e-3, -15.0)
    new = FeedforwardController(load_model(MODEL), ref, load_model(MODEL).inverse_stepper(1e-3))
    new.take_over(old, u)
    for k in range(417, 1200):
        assert new.update(k * 1e-3, -15.0) == pytest.approx(twin.update(k * 1e-3, -15.0), abs=1e-12)


def test_a_carried_state_is_a_play_state_for_other_thresholds():
    """To a model with other thresholds (and offset) the carried plays keep |x - p(r)| <= r."""
    model = load_model(MODEL)
    law = law_on(model, Sine(3.0, 12.0, 20.0))
    for k in range(700):
        u = law.update(k * 1e-3, -15.0)
    d = model.to_dict()
    d["play_thresholds"] = list(np.asarray(model.play_thresholds) * 1.37)
    d["input_offset"] = model.input_offset + 0.2
    other = SDPIModel.from_dict(d)
    plays = carried_play_state(model, law.stepper, other)
    assert plays is not None and plays.shape == (other.n_play,)
    x = u - other.input_offset
    assert np.all(np.abs(x - plays) <= np.asarray(other.play_thresholds) + 1e-9)
    assert carried_play_state(model, object(), other) is None        # not an SDPI stepper: nothing carried


@settings(max_examples=40, deadline=None)
@given(ticks=st.integers(1, 900), safe=st.floats(0.0, 3.0), off=st.booleans())
def test_a_resumed_inverse_holds_the_plays_of_a_forward_model_driven_along_the_coils_path(ticks, safe, off):
    """`resume` after a reconnect: the inverse's plays are those of a forward model driven by the
    law's commands up to the fault, then by the safe current (and 0 A while the output was off)."""
    model = load_model(MODEL)
    law = law_on(model, Sine(3.0, 12.0, 20.0))
    fwd = model.forward_stepper(1e-3)
    fwd.reset(0.0, law.stepper.play_state())
    for k in range(ticks):
        fwd.step(law.update(k * 1e-3, -15.0), -15.0)
    law.deactivate(ticks * 1e-3, "comms_timeout", freeze_learning=True)
    path = (safe, 0.0) if off else (safe,)
    law.resume(safe, path)
    for x in path + (safe,):
        fwd.step(x, -15.0)
    assert law.active and "reconnect" in law.initial_state
    np.testing.assert_allclose(law.stepper.play_state(), fwd._state[: model.n_play], atol=1e-9)


# ---- the limiter says which limit bound ----------------------------------------------------------
@given(lo=st.floats(-5, 0), span=st.floats(0.01, 10), slew=st.floats(0.1, 1e4), rate=st.floats(10, 1e4),
       targets=st.lists(st.floats(-1e3, 1e3), min_size=1, max_size=100), initial=st.floats(-1e3, 1e3))
@example(lo=0.0, span=1.0, slew=1.0, rate=75.0, targets=[0.0, 0.25], initial=0.25)   # a step one rounding over
def test_the_limiter_names_the_limit_that_changed_the_command(lo, span, slew, rate, targets, initial):
    hi = lo + span
    lim = safety.Limiter(lo, hi, slew, 1.0 / rate, initial)
    for target in targets:
        prev = lim.last
        out = lim.apply(target)
        bound = lim.clipped
        assert (bound == safety.NOT_LIMITED) == (out == target)
        if bound in (safety.SLEW, safety.RAMP):      # RAMP: the slew limit on the way from a safe-current write
            assert abs(min(max(target, lo), hi) - prev) > lim.max_step
            assert abs(out - prev) == pytest.approx(lim.max_step, rel=1e-9, abs=1e-12) or out in (lo, hi)
        elif bound == safety.CURRENT_MAX:
            assert out == hi and target > hi
        elif bound == safety.CURRENT_MIN:
            assert out == lo and target < lo


# ---- the law's one call into the learner ---------------------------------------------------------
class Ear:
    """A learner that only listens: records what the law tells it."""

    def __init__(self):
        self.heard: list[tuple] = []

    def correction(self, t):
        return 0.0

    def limited(self, t, limit, push):
        self.heard.append(("limited", limit, math.copysign(1.0, push)))

    def observe(self, t, r, y, stress, ok, why_not="", command_A=math.nan):
        self.heard.append((ok, why_not))

    def freeze(self, t, reason):
        self.heard.append((False, "frozen: " + reason))


def test_the_learner_learns_from_the_laws_ticks_and_hears_where_a_limit_cut_them():
    model = load_model(MODEL)
    ear = Ear()
    law = FeedforwardController(model, Sine(3.0, 12.0, 20.0), model.inverse_stepper(1e-3), ear)  # type: ignore[arg-type]
    law.activate(0.0)
    t = 0.0
    for limit, cut in ((safety.NOT_LIMITED, 0.0), (safety.CURRENT_MIN, 0.1), (safety.CURRENT_MAX, -0.1),
                       (safety.SLEW, -0.05), (safety.RAMP, 0.05), (safety.NOT_LIMITED, -0.2)):
        t += 1e-3
        raw = law.update(t, -15.0)
        law.observe(t, 1.0, 1.0, -15.0, limit, raw + cut)
    law.observe(t + 1e-3, 1.0, 1.0, -15.0, safety.RAMP, 0.0)           # the runner's safe current (stopping)
    law.observe(t + 2e-3, 1.0, 1.0, math.nan, safety.NOT_LIMITED, 0.0)  # no stress yet
    law.deactivate(t, "comms_error: at the safe current")
    learned = (True, "")
    assert ear.heard == [learned,
                         ("limited", safety.CURRENT_MIN, 1.0), learned,
                         ("limited", safety.CURRENT_MAX, -1.0), learned,
                         ("limited", safety.SLEW, -1.0), learned,
                         ("limited", safety.RAMP, 1.0), (False, RAMPING),          # a transient: frozen
                         ("limited", safety.MODEL_RANGE, -1.0), learned,   # a cut the runner did not name: the law's clamp
                         (False, "stopping"), (False, "no valid stress yet"),
                         (False, "frozen: comms_error: at the safe current")]
    assert not law.active


def test_the_drive_range_policy_lives_in_one_place():
    rng = DriveRange(0.0, 3.0, "clamp")
    assert rng.clamp and rng.message(3.5).endswith(": clamped to the range's edge 3 (limits.beyond_model: clamp)")
    with pytest.raises(ValueError):
        DriveRange(0.0, 3.0, "ignore")
    model = load_model(MODEL)
    padded = DriveRange.of_model(model, "warn")
    lo, hi = model.drive_range
    assert padded.lo == pytest.approx(lo - 0.01 * (hi - lo)) and padded.hi == pytest.approx(hi + 0.01 * (hi - lo))


def test_the_drive_range_message_says_what_was_written_and_which_range_it_checks():
    """Reference to the 0 A floor: status said '-0.03282 outside [-0.03245, 3.032]: commanded
    anyway' for a command clipped to 0 A, and called the widened range the identified one (a new
    user's sweep, 2026-11-30; the model file says drive_range [-0.0024, 3.0024])."""
    model = load_model(MODEL)
    lo, hi = model.drive_range
    warn = DriveRange.of_model(model, "warn")
    clipped = warn.message(-0.03282, 0.0, 3.0)
    assert clipped.startswith(f"the inverse asks for -0.03282, outside [{warn.lo:.5g}, {warn.hi:.5g}] (the model's "
                              f"identified drive_range [{lo:.5g}, {hi:.5g}] widened by 1 % of its span at each end): ")
    assert clipped.endswith(": clipped to 0 A by limits.current_min_A (limits.beyond_model: warn)")
    assert "commanded anyway" not in clipped and "drive_range [-0.0024, 3.0024]" in clipped   # the file's words
    assert warn.message(-0.04, -1.0, 3.0).endswith(": commanded anyway (limits.beyond_model: warn)")
    assert warn.message(3.5, 0.0, 3.2).endswith(": clipped to 3.2 A by limits.current_max_A (limits.beyond_model: warn)")
    clamp = DriveRange.of_model(model, "clamp").message(-0.04, 0.0, 3.0)
    assert clamp.endswith(f": clipped to 0 A by limits.current_min_A (clamped to the range's edge {warn.lo:.4g} "
                          "first) (limits.beyond_model: clamp)")
    assert "(the drive range the model was identified on)" in DriveRange(0.0, 3.0).message(3.5)


# ---- the load cell's force limit -----------------------------------------------------------------
AREA = math.pi * 3.5 ** 2          # the 7 mm rod


def test_by_default_the_plausible_force_is_the_plausible_stress_on_the_rod():
    """No separate force limit unless one is configured: the valid stress range already bounds
    the force (a 5000 N default could never trip before it: 80 MPa on this rod is 3079 N)."""
    cfg = validate_config({"rate_hz": 1000, "model": "m.yaml", "driver": {"kind": "sim"},
                           "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 1.0},
                           "limits": {"current_min_A": 0, "current_max_A": 3, "slew_A_per_s": 500}})
    assert cfg.sensor["force_limit_N"] is None
    mon = safety.SensorMonitor("force", AREA, (-80.0, 10.0), None, 1, 0)
    assert mon.plausible_raw() == pytest.approx((-10.0 * AREA, 80.0 * AREA))
    assert mon.update(1500.0, math.nan) == "" and mon.stress == pytest.approx(-1500.0 / AREA)
    assert mon.update(80.0 * AREA + 1.0, math.nan) == safety.SENSOR_ABSURD
    loose = safety.SensorMonitor("force", AREA, (-80.0, 10.0), 5000.0, 1, 0)
    assert loose.plausible_raw() == mon.plausible_raw()        # a looser limit changes nothing


def test_a_force_limit_below_the_stress_range_trips_the_sensor_fault(models, tmp_path):  # noqa: F811
    """A 1000 N load cell reading 1500 N: -39 MPa is a plausible stress on the configured rod, but
    beyond the cell's rating, so it is absurd (a wrong rod diameter cannot hide an overload)."""
    def inject(tick, inputs):
        if tick >= 400:
            inputs.force_N = 1500.0

    ctrl, driver, cfg = make(tmp_path, models, inject, sensor={"bad_ticks": 3, "force_limit_N": 1000.0})
    s = ctrl.run(duration_s=1.0)
    assert s["state"] == "fault" and "sensor_absurd" in s["faults"], s["fault_messages"]
    assert "-384.8 .. 1000 N" in s["fault_messages"]["sensor_absurd"]
    assert s["ticks"] == 399 + 2 and driver.log[-1] == ("safe", 0.0)


def test_a_force_limit_without_a_load_cell_is_refused():
    with pytest.raises(ConfigError, match="sensor.force_limit_N.*stress.source is 'stress'"):
        validate_config({"rate_hz": 1000, "model": "m.yaml", "driver": {"kind": "sim"},
                         "reference": {"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 1.0},
                         "limits": {"current_min_A": 0, "current_max_A": 3, "slew_A_per_s": 500},
                         "stress": {"source": "stress"}, "sensor": {"force_limit_N": 1000.0}})


# ---- a broadcaster plugged in ----------------------------------------------------------------------
class Counter(Broadcaster):
    """What a later part (a model-fit monitor) needs: every tick's data, and each new setup."""

    def __init__(self):
        self.ticks = 0
        self.faulted = 0
        self.setups: list = []
        self.last_command = math.nan

    def on_setup(self, setup):
        self.setups.append(setup.model)

    def on_tick(self, tick):
        self.ticks += 1
        self.faulted += tick.faulted
        self.last_command = tick.command_A


def test_a_plugged_broadcaster_sees_every_tick_and_every_setup(models, tmp_path):  # noqa: F811
    def inject(tick, inputs):
        if tick == 300:
            inputs.force_N = math.nan            # a read that worked, with a bad value: a fault tick with a row

    ctrl, driver, cfg = make(tmp_path, models, inject, sensor={"bad_ticks": 1})
    counter = Counter()
    ctrl.attach(counter)
    ctrl.reload(cfg, model=models[1])
    s = ctrl.run(duration_s=1.0)
    assert counter.setups == [models[0], models[1]]
    assert counter.ticks == ctrl.recorder.telemetry.head == s["ticks"] + 1    # the fault tick has its row too
    assert counter.faulted == 1 and counter.last_command > 0.5     # the command the fault found
    assert ctrl.tick.command_A == 0.0 == s["current_cmd_A"]        # then the safe current was written


# ---- the law's lifecycle across runs ---------------------------------------------------------------
def test_every_run_starts_the_law_from_the_safe_current(models):  # noqa: F811
    """A run ends at the safe current, so the next starts the inverse there afresh (deactivate at
    the end, activate at the start): on a rig that reads the same, it commands the same."""
    from test_controller_hotpath import Quiet

    class Logged(Quiet):
        def write(self, current_A):
            self.writes.append(current_A)
            super().write(current_A)        # the current it reads follows

    cfg = validate_config({"rate_hz": 1000, "clock": "simulated", "model": "unused.yaml", "driver": {"kind": "sim"},
                           "reference": {"kind": "sine", "frequency_hz": 3, "amplitude_um": 8, "offset_um": 15},
                           "limits": {"current_min_A": 0, "current_max_A": 3, "slew_A_per_s": 500},
                           "telemetry": {"path": None}})
    rig = Logged({}, 1e-3)
    ctrl = ControllerManager(cfg, model=models[0], driver=rig)
    runs = []
    for _ in range(2):
        rig.writes, rig.odd = [], False
        ctrl.run(duration_s=0.25)
        assert not ctrl.setup.law.active
        runs.append(rig.writes)
    assert len(runs[0]) == len(runs[1]) > 250
    np.testing.assert_allclose(runs[1], runs[0], rtol=0, atol=1e-9)     # to the rounding of t


def test_a_drive_below_the_model_and_the_current_floor_is_reported_as_clipped_in_the_run(models, tmp_path):  # noqa: F811
    """The runner passes its current limits to the message: the status said 'commanded anyway'."""
    ctrl, _, _ = make(tmp_path, models, reference={"kind": "sine", "frequency_hz": 3.0, "amplitude_um": 12.0,
                                                   "offset_um": 6.0})      # troughs at -6 um: below 0 A
    s = ctrl.run(duration_s=0.5)
    messages = [h["message"] for h in s["fault_history"] if h["fault"] == "drive_out_of_model_range"]
    assert messages and all(m.endswith("clipped to 0 A by limits.current_min_A (limits.beyond_model: warn)")
                            for m in messages), messages


def test_an_absurd_load_cell_reading_says_where_the_range_comes_from_and_the_sign_slip():
    """A Modbus load cell scaled -0.1 N/count (compression read negative) faulted with 'outside the
    plausible -384.8 .. 3079 N (last value -434.7)', and -434.7 N looks plausible to anyone. The
    message now gives the stress it is on the configured rod and says to negate the scale; negated,
    the reading is accepted (the advice works)."""
    mon = safety.SensorMonitor("force", AREA, (-80.0, 10.0), None, 1, 0)
    assert mon.update(-434.7, math.nan) == safety.SENSOR_ABSURD
    words = mon.message(safety.SENSOR_ABSURD, -434.7)
    assert "-434.7 N is 11.3 MPa on the 7 mm rod (stress.rod_diameter_mm)" in words, words
    assert "[-80, 10]" in words and "negate its scale" in words
    assert mon.update(434.7, math.nan) == ""
    far = mon.message(safety.SENSOR_ABSURD, 5000.0)        # too far either way: no sign advice
    assert "negate" not in far and "check the load cell's scale and unit (N)" in far, far
    transmitter = safety.SensorMonitor("stress", AREA, (-80.0, 10.0), None, 1, 0)
    assert transmitter.update(math.nan, 15.2) == safety.SENSOR_ABSURD
    assert "negate its scale" in transmitter.message(safety.SENSOR_ABSURD, 15.2)
    assert transmitter.update(math.nan, -15.2) == ""
