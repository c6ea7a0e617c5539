"""Creep as material behaviour: its law is the identification loops' too, and it carries to other sessions.

The base model was identified on loops that crept. It absorbed part of the creep into their
shape, so creep put in front of it is counted twice, and a gain fitted beside it comes out too
small. With the identification recordings (`diagnose --ident`), the law (time constant and gain)
is fitted on those loops, and the core is identified again through the creep's exact inverse.

hil_sim's creep adds three lags of the magnetostrictive stroke, each of gain g, to the stroke:
y = (1 + g sum_k L_k) x. Normalised to a unit static gain, its instantaneous gain is 1 / (1 + 3 g).
gma-ffc's creep block has the instantaneous gain 1 - gain, so the plant's gain in its terms is
3 g / (1 + 3 g).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks.cases import case_plant, case_recordings
from benchmarks.general import GENERAL_SIXTH_SEED, general_cases
from benchmarks.probes import pooled, probe_recordings, probe_scores
from gma_ffc.diagnose.engine import diagnose
from gma_ffc.effects.creep import creep_inverse, relaxation


@settings(max_examples=60, deadline=None)
@given(gain=st.floats(0.0, 0.5), tau=st.floats(0.05, 50.0), n=st.integers(2, 400), seed=st.integers(0, 2**31 - 1),
       uneven=st.booleans())
def test_the_creep_inverse_gives_back_the_core_output(gain, tau, n, seed, uneven):
    rng = np.random.default_rng(seed)
    yc = np.cumsum(rng.normal(size=n))
    dt = rng.uniform(1e-4, 0.1, n) if uneven else np.full(n, 1e-3)
    y = yc + gain * relaxation(yc, dt, tau)
    back = creep_inverse(y, dt, gain, tau)
    assert np.allclose(back, yc, rtol=1e-9, atol=1e-9 * (1.0 + float(np.abs(yc).max())))


@pytest.mark.slow
def test_the_creep_law_of_the_identification_loops_carries_to_a_later_session():
    case = {c.name: c for c in general_cases()}["gen:creep@default"]
    model, ident, rec = case_recordings(case, scale=0.5)
    dg = diagnose(model, [rec], identification=ident)
    assert dg.verdict == ["creep"]
    law = {c.effect: c.params for c in dg.candidates}["creep"]
    creep = case_plant(case).creep
    g = creep.gains[0]
    # within 20 % of the plant's gain: a creep gain off by more than that left the history probe's
    # error at twice the floor in the investigation of this fix (0.10 against 0.135: 0.33 um vs 0.15 um)
    assert law["gain"] == pytest.approx(3 * g / (1 + 3 * g), rel=0.2)
    # the plant's middle time constant within a factor of two: a factor of three still carried 4x
    assert 0.5 < law["tau_s"] / creep.time_constants_s[1] < 2.0
    probes = {s.name: s for s in probe_scores(model, dg.extended, probe_recordings(case))}
    history = probes["probe_history.csv"]          # a staircase with 2-5 s holds: creep, at other loads
    assert history.extended_um < 0.5 * history.base_um
    assert math.isfinite(history.extended_um)


@pytest.mark.nightly
def test_a_creep_time_constant_the_identification_loops_cannot_tell_is_chosen_on_the_recording():
    """The sixth never-tuned draw's creep on a drawn actuator (looked at once, then fixed; it is no
    longer quoted as unseen). Its 3 s identification loops preferred creep's fastest time constant
    (1 s) by 4 % in RSS, where the plant's middle part is at 3 s. The law from the loops alone then
    failed creep's check (a fit at its fastest time constant), and nothing was named. The 40 s
    recording diagnosed tells the time constant; the loops still give the gain."""
    case = {c.name: c for c in general_cases(GENERAL_SIXTH_SEED, prefix="sixth")}["sixth:creep@other"]
    model, ident, rec = case_recordings(case)
    dg = diagnose(model, [rec], identification=ident)
    assert dg.verdict == ["creep"]
    law = {c.effect: c.params for c in dg.candidates}["creep"]
    creep = case_plant(case).creep
    assert 0.5 < law["tau_s"] / creep.time_constants_s[1] < 2.0   # as the development case's test above
    scores = probe_scores(model, dg.extended, probe_recordings(case))
    # issue 31's floor for every effect case on recordings diagnose never saw
    assert pooled(scores, "extended_um") < pooled(scores, "base_um") / 1.5


@pytest.mark.slow
def test_creep_is_named_from_the_recordings_when_the_identification_loops_show_none():
    """Loops recorded without creep (an actuator identified before its creep showed; hil_sim's own
    example records them with noise alone) give creep a gain of zero on them. Tied to that, creep
    could not be named: this run was unexplained, and a user's 240 s run (3 Hz, then a 90 s rest)
    was named heating. Loops that show no creep leave its gain to the recordings diagnosed, as
    without them. The creep here is the tuned set's smallest (three parts of 0.02)."""
    from benchmarks.cases import _set
    from gma_ffc.effects.creep import LOOPS_SHOW_NO_CREEP

    case = {c.name: c for c in general_cases()}["gen:creep@default"]
    case = dataclasses.replace(case, configure=_set(creep={"enabled": True, "gains": [0.02] * 3}))
    model, ident, _ = case_recordings(case, scale=0.5, effect_free=True)      # the loops without creep
    rec = case_recordings(case, scale=0.5)[2]                                  # the run with it
    dg = diagnose(model, [rec], identification=ident)
    assert dg.verdict == ["creep"], dg.explanation
    gain = {c.effect: c.params for c in dg.candidates}["creep"]["gain"]
    assert gain > 10 * LOOPS_SHOW_NO_CREEP          # fitted on the run, not the loops' zero
    # within a factor of two of the plant's (0.040 against 0.057: its time constant trades with the gain)
    assert 0.5 < gain / (3 * 0.02 / (1 + 3 * 0.02)) < 2.0


@settings(max_examples=60, deadline=None)
@given(duration=st.floats(5.0, 3600.0), dt=st.floats(1e-4, 0.01), where=st.floats(0.0, 1.0), level=st.integers(1, 3))
def test_the_search_keeps_creep_within_what_the_recordings_can_tell(duration, dt, where, level):
    """A central time constant beyond half the longest recording is a drift any slow effect gives:
    a user's 240 s run of heating and creep got creep at 348 s, heating's drift taken as creep. The
    zoom stays within the grid's span, as the grid does."""
    from types import SimpleNamespace

    from gma_ffc.effects.creep import MIN_CREEP_TAU_S, Creep, time_constants

    fitter = SimpleNamespace(dt_min=dt, duration_max=duration, identification=[])
    grid = time_constants(fitter)
    tau = float(grid[0] * (grid[-1] / grid[0]) ** where)
    for t in Creep.refine(fitter, tau, level):
        assert MIN_CREEP_TAU_S <= t <= grid[-1] * (1 + 1e-12)


@settings(max_examples=60, deadline=None)
@given(tau=st.floats(0.05, 50.0), n=st.integers(2, 400), seed=st.integers(0, 2**31 - 1))
def test_creep_under_way_is_never_more_than_its_gain_times_the_stroke(tau, n, seed):
    """Whatever history came before a recording, creep's term per unit gain stays within the core
    output's range: the bound `start_beyond_reach` holds a fitted start to."""
    rng = np.random.default_rng(seed)
    yc = np.cumsum(rng.normal(size=n))
    term = relaxation(yc, np.full(n, 1e-2), tau)
    assert float(np.max(np.abs(term))) <= float(np.ptp(yc)) * (1.0 + 1e-12)


def test_a_start_term_beyond_what_creep_can_hold_fails_creeps_signature():
    """hil_sim's realistic actuator on steps: heating's rise after the unscored start was fitted as
    creep dying away, -6.96 um against 3.8 um that creep of its gain can hold. A start within the
    bound passes; beyond it, of either sign, fails and names the recording."""
    from types import SimpleNamespace

    from gma_ffc.effects.creep import start_beyond_reach
    from gma_ffc.model_reach import model_reach_um

    model, _, _ = case_recordings(general_cases()[0])
    yc = np.linspace(0.0, 5.0, 200)
    gain = 0.08
    most = gain * max(5.0, model_reach_um(model))

    def check(start):
        result = SimpleNamespace(names=["creep_gain", "creep_start_0"], coef_all=np.array([gain, start]),
                                 specs=(None, None, None))
        fitter = SimpleNamespace(core=lambda spec: [(yc, yc)], data=[SimpleNamespace(name="steps.csv")])
        return SimpleNamespace(result=result, fitter=fitter, model=model)

    assert start_beyond_reach(check(0.9 * most), gain) is None
    assert start_beyond_reach(check(-0.9 * most), gain) is None
    for start in (1.1 * most, -1.1 * most):
        beyond = start_beyond_reach(check(start), gain)
        assert beyond is not None and beyond[0] == "steps.csv" and beyond[1] == start and beyond[2] == pytest.approx(most)


def test_creep_beside_heating_searches_heatings_time_constant_again(monkeypatch):
    """Beside creep, heating keeps one time constant: its faster part and creep are look-alikes. A
    heating fitted before creep joined had split into a slow part (343 s) and a part 8x faster (43 s,
    the plant's 60 s); left at 343 s, creep beside it was worse than none (0.148 against 0.100 um held
    out) and was never named. Creep's search now tries heating's time constant from its faster
    part's to its own, and never faster than heating can be."""
    from types import SimpleNamespace

    from gma_ffc.diagnose import scoring
    from gma_ffc.diagnose.specs import Spec
    from gma_ffc.effects import REGISTRY
    from gma_ffc.effects.thermal import MIN_THERMAL_TAU_S, THERMAL_FAST_RATIO

    seen = {}

    def fake_search(fitter, base, make, grid, refine=None, *args, **kwargs):
        seen["specs"] = [make(base[2], p) for p in grid]
        return SimpleNamespace(specs=base)

    monkeypatch.setattr(scoring, "search", fake_search)
    monkeypatch.setattr(REGISTRY["creep"], "grid", classmethod(lambda cls, fitter: [3.0, 30.0]))
    for heating_tau in (343.0, 40.0):
        heated = Spec({"thermal_drift": heating_tau})
        scoring._search_one(SimpleNamespace(), (heated, heated, heated), "creep", 1)
        taus = {s["thermal_drift"] for s in seen["specs"]}
        assert {s["creep"] for s in seen["specs"]} == {3.0, 30.0}
        assert heating_tau in taus and min(taus) == max(heating_tau * THERMAL_FAST_RATIO, MIN_THERMAL_TAU_S)


def test_creep_from_rest_has_no_start_terms_and_keeps_its_form_through_the_search():
    """`FromRest`: creep's columns without any recording's start term; its zoom, its grid for the
    leave-one-out and a spec keep that form (a spec's parameters are made plain, equal to equal)."""
    from types import SimpleNamespace

    from gma_ffc.diagnose.specs import Spec
    from gma_ffc.effects.creep import Creep, FromRest, central_tau

    t = np.arange(400) * 0.01
    d = SimpleNamespace(t=t, dt=np.full(t.size, 0.01))
    fitter = SimpleNamespace(data=[d], cached_table=lambda rec, key, compute: compute(),
                             identification=[], duration_max=4.0, dt_min=0.01)

    def names(p):
        r = SimpleNamespace(yc=np.sin(t), d=d, cols=[], names=[])
        Creep.columns(fitter, r, p)
        return r.names

    assert names(3.0) == ["creep_gain", "creep_start_0"] and names(FromRest(3.0)) == ["creep_gain"]
    assert central_tau(FromRest(3.0)) == 3.0
    assert Creep.fitted_params(fitter, FromRest(3.0), {"creep_gain": 0.02}) == {"tau_s": 3.0, "gain": 0.02, "from_rest": 1.0}
    assert all(isinstance(q, FromRest) for q in Creep.refine(fitter, FromRest(3.0), 1))
    assert all(isinstance(q, FromRest) for q in Creep.grid_like(fitter, FromRest(3.0)))
    assert not any(isinstance(q, FromRest) for q in Creep.grid_like(fitter, 3.0))
    assert Spec({"creep": FromRest(np.float64(3.0))}) == Spec({"creep": FromRest(3.0)})
    assert Spec({"creep": FromRest(3.0)}) != Spec({"creep": 3.0})


def test_heating_and_creep_on_steps_from_rest_are_both_named():
    """hil_sim's heating and creep, identified on loops with both, diagnosed on steps from rest: the
    creep beside heating put -2.31 um under way at the start, more than creep of its gain can hold
    (1.66 um), and was set aside; heating alone was named (0.066 um held out). Creep is searched
    again from rest: both are named, and the model file follows the fit (0.0215 um both ways)."""
    from gma_ffc.identify import SDPIIdentifier
    from hil_sim.record import make_recordings

    effects = ["thermal", "creep", "noise"]
    model = SDPIIdentifier().fit(make_recordings("identification", effects=effects, seed=24)).model_
    steps = make_recordings("steps", effects=effects, seed=25)
    dg = diagnose(model, steps)
    assert set(dg.verdict) == {"thermal_drift", "creep"}, dg.verdict
    creep = next(c for c in dg.candidates if c.effect == "creep")
    assert creep.params.get("from_rest") == 1.0
    assert dg.rms_written_um < 2.0 * dg.rms_after_um < 0.1 * dg.rms_before_um


def test_creeps_start_terms_stay_only_where_they_earn_their_place_as_an_effect_must(monkeypatch):
    """A model file runs from rest, so start terms must pay for themselves as an effect does, against
    creep from rest, one parameter a recording. hil_sim's creep and eddy currents (multifreq and
    steps runs): 0.0740 um held out with them, 0.0752 from rest, and the model file ran at 0.138 um
    with them, 0.078 um from rest. Where the start holds creep under way, they stay."""
    from types import SimpleNamespace

    import gma_ffc.diagnose.selection as selection
    from gma_ffc.diagnose.state import Trial
    from gma_ffc.effects.creep import FromRest

    selector = selection.EffectSelector()
    problem = SimpleNamespace(data=[object()] * 8, noise=0.0212, fitter=None)

    def chosen(with_start_rms, rest_rms, effect="creep"):
        trial = Trial(effect, SimpleNamespace(cv_loss=with_start_rms ** 2, specs=(None, None, {effect: 3.3})), {}, 1)
        rest = Trial(effect, SimpleNamespace(cv_loss=rest_rms ** 2, specs=(None, None, {effect: FromRest(3.8)})), {}, 1)
        monkeypatch.setattr(selector, "_retried", lambda problem, sel, t, form, n_eff: rest)
        return selector._start_earned(problem, None, trial, 5000.0)

    assert chosen(0.0740, 0.0752).result.cv_loss == 0.0752 ** 2          # a sliver: from rest
    assert chosen(0.0740, 0.2000).result.cv_loss == 0.0740 ** 2          # creep under way at the starts: kept
    assert chosen(0.0740, 0.0752, "thermal_drift").result.cv_loss == 0.0740 ** 2   # no start form: as fitted
