"""A resonance named at the loads a diagnosis saw is predicted at a load it never saw.

hil_sim's rig (not the model that diagnoses it) puts a load mass m = (-sigma A - F_preload) / g
on the rod's stiffness, so the resonance falls as the load grows. The diagnosis recording drives
the resonance hard at one load only (a 50-80 Hz sine at the middle load); the other loads see
steps and a slower sine. The fitted law must still carry to the probes' heavy load (46-50 kg,
beyond every load of the recording): that is what a law across loads is for (issue 31).

The past never-tuned draws' cases here are the nightly tier (`nightly`, pyproject.toml): one
diagnosis of 50-100 s each on 2 cores, they run with `scripts/test.sh --nightly`; the default
suite keeps this seed's two.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks.cases import case_plant, case_recordings
from benchmarks.general import general_cases
from gma_ffc.diagnose.engine import diagnose
from gma_ffc.effects.rod_load import static_stress

HEAVY_KG = 48.0      # the middle of the probes' heavy load (benchmarks.probes: 46-50 kg)


def law_at_the_heavy_load(dg, plant) -> tuple[float, float]:
    """The named resonance's frequency at the probes' heavy load, and the plant's there."""
    p = {c.effect: c.params for c in dg.candidates}["mechanical_dynamics"]
    heavy = plant.stress_for_mass(HEAVY_KG)
    f_heavy = p["f_ref_hz"] / math.sqrt(1.0 + p["beta_per_MPa"] * (p["stress_ref_MPa"] - heavy))
    return f_heavy, plant.resonance_hz(HEAVY_KG)


@pytest.mark.slow
def test_the_resonance_law_carries_to_a_load_the_diagnosis_never_held():
    case = {c.name: c for c in general_cases()}["gen:mechanical_dynamics@default"]
    model, ident, rec = case_recordings(case, scale=0.35)     # the law 0.6 % off at the heavy load, as at 0.5
    plant = case_plant(case)
    dg = diagnose(model, [rec], identification=ident)
    assert "mechanical_dynamics" in dg.verdict
    static = static_stress(rec.stress_MPa, np.gradient(rec.time_s))     # the loads, the inertial force filtered
    assert plant.stress_for_mass(HEAVY_KG) < float(static.min()) - 1.0   # beyond every load of the recording
    f_heavy, f_plant = law_at_the_heavy_load(dg, plant)
    # 5 %: the damping ratio is 0.2, so a 5 % frequency error moves the response near the peak by
    # about a quarter of its height; the law fitted before this test's fix was 11 % off
    assert f_heavy == pytest.approx(f_plant, rel=0.05)
    # the fit improves at each of the recording's three loads: the law is measured, and not said to be extrapolated
    assert not any("extrapolated" in line for line in dg.cannot_conclude), dg.cannot_conclude


@pytest.mark.nightly
def test_a_law_fitted_where_one_load_alone_shows_the_resonance_is_said_to_be_extrapolated_and_held():
    """The twenty-third never-tuned draw's resonance on a drawn actuator (looked at once; development
    since). Driven hard at its least compressive load only, the law came out 3x too steep: right
    there, 20 % low at the heaviest load, where a probe went from 2.5 to 6.0 um. The recording's
    heavy load shows no resonance (the base as given 0.19 um there, the fit 0.21 um), so the law's
    course there is extrapolated: diagnose says so, with the load to record at, and holds the
    resonance beyond the loads where the law was measured. Held, the probe there is no worse than
    the base (2.57 -> 2.66 um, against 6.04 um with the law's course)."""
    from benchmarks.general import GENERAL_TWENTY_THIRD_SEED
    from benchmarks.probes import probe_recordings, probe_scores

    case = {c.name: c for c in general_cases(GENERAL_TWENTY_THIRD_SEED, prefix="twenty-third")}[
        "twenty-third:mechanical_dynamics@other"]
    model, ident, rec = case_recordings(case)
    dg = diagnose(model, [rec], identification=ident)
    assert dg.verdict == ["mechanical_dynamics"]
    said = [line for line in dg.cannot_conclude if "extrapolated" in line]
    assert len(said) == 1 and "record a drive that excites the resonance" in said[0], dg.cannot_conclude
    static = static_stress(rec.stress_MPa, np.gradient(rec.time_s))
    heaviest = float(static.min())
    assert f"at {heaviest:.3g} MPa" in said[0] and "holds the resonance" in said[0]
    block = dg.extended.to_dict()["blocks"]["dynamics"]
    assert heaviest < block["law_held_below_MPa"] < float(static.max())
    rate = {s.name: s for s in probe_scores(model, dg.extended, probe_recordings(case))}["probe_other_rate.csv"]
    # 1.1x: the heavy-load probe the law's course made 2.35x worse than the base
    assert rate.extended_um < 1.1 * rate.base_um, (rate.base_um, rate.extended_um)


@pytest.mark.slow
def test_a_resonance_beside_eddy_currents_is_named_once_a_lag_is_in_the_model():
    """Eddy currents and a resonance together: the resonance's first fit runs to a lag's damping (its
    signature fails), and a delay stands in for the lag and part of the resonance. Once the delay is
    in the model, the resonance is tried again, with the delay re-searched beside it, and named.

    At 0.35-0.45 of the recording the first fit's polish stopped at damping 0.496, short of the cap
    it is clipped at (0.5): it passed the signature, was named alone, and the lag was left out
    (0.667 um held out, 4x what both leave). A fit within 3 % of the cap ran to it (`RUN_TO_BOUND`)."""
    case = {c.name: c for c in general_cases()}["gen:rate_dependence+mechanical_dynamics"]
    model, ident, rec = case_recordings(case, scale=0.35)
    dg = diagnose(model, [rec], identification=ident)
    assert sorted(dg.verdict) == ["mechanical_dynamics", "rate_dependence"], dg.explanation
    tau = {c.effect: c.params for c in dg.candidates}["rate_dependence"]["tau_s"]
    assert tau == pytest.approx(case_plant(case).eddy.time_constant_ms * 1e-3, rel=0.15)    # as below
    assert dg.rms_after_um < 0.1 * dg.rms_before_um     # 0.168 of 4.36 um with both, 0.667 with the resonance alone


@pytest.mark.nightly
def test_the_law_holds_when_the_identification_loops_reach_a_heavier_load():
    """The identification loops run to 24 MPa, the diagnosis recording to 21 MPa. On the heaviest
    loop the law's resonance (85 Hz) lags the 3 Hz drive by about 0.13 um, 1.5x that loop's
    identification error; the base absorbed that lag. Held below its own lag, that loop pulled the
    fit off the law, and a load-independent resonance won (the heavy-load probe: 4.0 -> 4.0 um, where
    the law gives 0.11 um). This case was the fourth never-tuned draw's; it is development since."""
    from benchmarks.general import GENERAL_FOURTH_SEED

    case = {c.name: c for c in general_cases(GENERAL_FOURTH_SEED, prefix="fourth")}["fourth:mechanical_dynamics@default"]
    model, ident, rec = case_recordings(case, scale=0.5)
    plant = case_plant(case)
    def heaviest(r):     # the static stress: a resonance's inertial force is not a load
        return float(static_stress(r.stress_MPa, np.gradient(r.time_s)).min())

    assert min(heaviest(r) for r in ident) < heaviest(rec) - 2.0
    dg = diagnose(model, [rec], identification=ident)
    assert dg.verdict == ["mechanical_dynamics"]
    f_heavy, f_plant = law_at_the_heavy_load(dg, plant)
    assert f_heavy == pytest.approx(f_plant, rel=0.05)     # 5 %: as above


@pytest.mark.nightly
def test_eddy_currents_beside_a_resonance_are_named_with_their_own_time_constant():
    """Fitted first, a resonance takes eddy currents' phase lag as damping (0.38 where the rig's is
    0.10), and a lag tried beside it then gained too little to be named. The resonance is searched
    again whole beside the lag (`scoring._descend`): both are named, and the lag's time constant is the
    rig's. This case was the fourth never-tuned draw's; it is development since."""
    from benchmarks.general import GENERAL_FOURTH_SEED

    dg, tau_rig_s = _eddy_and_resonance_diagnosed(GENERAL_FOURTH_SEED, "fourth")
    assert sorted(dg.verdict) == ["mechanical_dynamics", "rate_dependence"]
    tau = {c.effect: c.params for c in dg.candidates}["rate_dependence"]["tau_s"]
    # 15 %: a lag's time constant sets its phase at the resonance; the fit before the descent was 0.40 ms
    # against the rig's 1.40 ms (71 % off)
    assert tau == pytest.approx(tau_rig_s, rel=0.15)


@pytest.mark.nightly
def test_a_delay_named_before_eddy_currents_and_a_resonance_is_dropped_once_they_explain_it():
    """A delay is named first, then a resonance and eddy currents, which take its phase lag over.
    Forward selection alone kept the delay; with the others in place it no longer earns its place,
    and the backward pass drops it. The lag and the resonance were searched beside the delay, so
    they are fitted again without it (`_refit_after_drop`): the lag then has the rig's time constant.
    This case was the sixth never-tuned draw's (run once before the pass was added); it is
    development since."""
    from benchmarks.general import GENERAL_SIXTH_SEED

    dg, tau_rig_s = _eddy_and_resonance_diagnosed(GENERAL_SIXTH_SEED, "sixth")
    assert sorted(dg.verdict) == ["mechanical_dynamics", "rate_dependence"]
    dropped = {c.effect: c.reason for c in dg.candidates}["time_delay"]
    assert "no longer earns its place" in dropped
    tau = {c.effect: c.params for c in dg.candidates}["rate_dependence"]["tau_s"]
    assert tau == pytest.approx(tau_rig_s, rel=0.15)    # as above; fitted beside the delay it was 1.22 ms (rig 1.88)


@pytest.mark.nightly
def test_a_delay_that_took_part_of_the_lag_is_dropped_once_the_lag_may_take_it_back():
    """Searched beside a delay of a sample, eddy currents' lag came out 31 % short (1.86 ms, the rig's
    2.69 ms): removing the delay with the lag held there cost the fit, so the backward pass kept the
    delay, and a 0.54 ms delay was named the rig does not have. Its look-alikes are now zoomed again
    without it before its place is judged (`EffectSelector._without_rezoomed`): the delay goes, the
    lag has the rig's time constant, and the held-out error falls (0.45 -> 0.14 um at half length).
    This case was the eleventh never-tuned draw's; it is development since."""
    from benchmarks.general import GENERAL_ELEVENTH_SEED

    dg, tau_rig_s = _eddy_and_resonance_diagnosed(GENERAL_ELEVENTH_SEED, "eleventh")
    assert sorted(dg.verdict) == ["mechanical_dynamics", "rate_dependence"]
    assert "no longer earns its place" in {c.effect: c.reason for c in dg.candidates}["time_delay"]
    tau = {c.effect: c.params for c in dg.candidates}["rate_dependence"]["tau_s"]
    assert tau == pytest.approx(tau_rig_s, rel=0.15)    # as above


def _eddy_and_resonance_diagnosed(seed: int, prefix: str):
    """A general draw's eddy-and-resonance pair diagnosed on half its recording with its loops, and
    the rig's eddy time constant in s."""
    case = {c.name: c for c in general_cases(seed, prefix=prefix)}[f"{prefix}:rate_dependence+mechanical_dynamics"]
    model, ident, rec = case_recordings(case, scale=0.5)
    return diagnose(model, [rec], identification=ident), case_plant(case).eddy.time_constant_ms * 1e-3


@pytest.mark.nightly
def test_the_load_law_is_zoomed_again_once_the_polish_has_brought_the_damping_close():
    """The eighth never-tuned draw's resonance on the default actuator (damping 0.068, a falling
    actuator; looked at once, then fixed; no longer quoted as unseen). The zoom's load-law moves
    were scored while the damping was still the grid's 0.12; the polish then brought it to 0.07,
    with the moving mass left at 9x the plant's: 126 Hz where the drive excites it, right, but 103 Hz
    at the probes' heavy load where the plant has 86.5 Hz (other-rate probe 6.2 -> 4.4 um). At half
    length, as here, the law before the fix put 101 Hz there."""
    from benchmarks.general import GENERAL_EIGHTH_SEED

    case = {c.name: c for c in general_cases(GENERAL_EIGHTH_SEED, prefix="eighth")}["eighth:mechanical_dynamics@default"]
    model, ident, rec = case_recordings(case, scale=0.5)
    plant = case_plant(case)
    dg = diagnose(model, [rec], identification=ident)
    assert dg.verdict == ["mechanical_dynamics"]
    f_heavy, f_plant = law_at_the_heavy_load(dg, plant)
    assert f_heavy == pytest.approx(f_plant, rel=0.05)     # 5 %: as above


class _Loads:
    """The fitter's fields the resonance's law sweep reads: two loads, the fast drive at the heavier."""

    def __init__(self) -> None:
        t = np.arange(4000) / 2000.0
        self.data = [type("D", (), {"u": np.where(t < 1.0, 0.5, np.sin(2 * np.pi * 60 * t)), "dt": np.full(t.size, 5e-4),
                                    "s": np.where(t < 1.0, -12.0, -20.0)})()]
        self.stress_top, self.stress_bottom, self.stress_ref = -12.0, -20.0, -16.0
        self.stress_varies, self.dt_min = True, 5e-4

    def static_stress(self, d, clamped=False):
        return d.s


def test_after_its_polish_the_load_law_is_swept_whole_with_the_resonance_held_where_it_is_excited():
    from gma_ffc.effects.dynamics import LAW_SPREAD, LAW_SWEEP, Dynamics, _f_at, _f_max, _mass_stress

    fitter = _Loads()
    points = Dynamics.after_polish(fitter, (150.0, 0.07, 0.2))
    masses = sorted(_mass_stress(b) for _, _, b in points)
    extent = fitter.stress_top - fitter.stress_bottom
    assert masses[0] == pytest.approx(min(LAW_SPREAD) * extent) and masses[-1] == pytest.approx(max(LAW_SPREAD) * extent)
    assert max(b / a for a, b in zip(masses, masses[1:])) <= LAW_SWEEP * 1.01     # whole steps over the range
    # the fast drive is at -20 MPa; the lightest masses would put the resonance at the lightest load past
    # what the sampling resolves, where a point is capped (`_point`): those do not hold it
    resolved = [(f, b) for f, _, b in points if f < _f_max(fitter)]
    assert len(resolved) >= len(points) - 2
    held = [_f_at(f, b, fitter.stress_top, -20.0) for f, b in resolved]
    assert held == pytest.approx([_f_at(150.0, 0.2, fitter.stress_top, -20.0)] * len(resolved), rel=1e-12)


@pytest.mark.nightly
def test_a_delay_chosen_first_gives_way_to_eddy_currents_beside_a_resonance():
    """A delay mimics eddy currents and a resonance's phase together, so it wins the first round; a
    resonance beside it then gains only 10 %, short of the round's margin, and the delay alone was
    named. A round that accepts nothing, whose best is a look-alike of the last effect, tries the
    look-alikes together in its place (`EffectSelector._look_ahead`): the lag and the resonance
    explain the recording far better than the delay with the resonance, so they replace it, with
    the rig's time constant. This case was the eighth never-tuned draw's; it is development since."""
    from benchmarks.general import GENERAL_EIGHTH_SEED

    dg, tau_rig_s = _eddy_and_resonance_diagnosed(GENERAL_EIGHTH_SEED, "eighth")
    assert sorted(dg.verdict) == ["mechanical_dynamics", "rate_dependence"]
    assert "so it replaced time_delay" in dg.explanation
    tau = {c.effect: c.params for c in dg.candidates}["rate_dependence"]["tau_s"]
    assert tau == pytest.approx(tau_rig_s, rel=0.15)    # as above



def test_the_law_search_reaches_hil_sims_own_rig_whose_loads_dwarf_its_moving_mass():
    """hil_sim's rig: 1.5 kg moving under loads up to 50 kg, so the resonance falls from 497 Hz
    unloaded to 85 Hz at the heaviest load, a frequency ratio of 0.17 end to end. The law's search
    began at 0.22 (the lightest moving mass it tried, LAW_SPREAD's first), and a user's rising
    sines at two loads, steps and a load change were left unexplained at 1.76 um held out (named
    since, 0.21 um, the law 85.0 Hz at -24 MPa: docs/BENCHMARKS.md). The sweep now reaches
    beyond the rig's moving mass, and a law as steep as its frequency ratio is kept, not clamped."""
    from gma_ffc.effects.dynamics import Dynamics, _mass_stress, _point
    from gma_ffc.effects.rod_load import resonance_hz
    from hil_sim.plant import PlantConfig

    plant = PlantConfig()
    light, heavy = plant.rig.preload_stress_MPa, -24.0                    # unloaded, and 49.8 kg on it
    ratio = plant.resonance_hz(plant.mass_for_stress(heavy)) / plant.resonance_hz(0.0)
    rig_mass = plant.dynamics.moving_mass_kg * 9.81 / plant.rig.rod_area_m2 * 1e-6   # m g / A, MPa
    fitter = _Loads()
    fitter.stress_top, fitter.stress_bottom = light, heavy
    masses = [_mass_stress(b) for _, _, b in Dynamics.after_polish(fitter, (500.0, 0.05, 0.0))]
    assert min(masses) < rig_mass < max(masses)
    f, _, beta = _point(fitter, 497.0, 0.05, ratio)
    assert resonance_hz(f, beta, light, heavy) / f == pytest.approx(ratio, rel=1e-9)
