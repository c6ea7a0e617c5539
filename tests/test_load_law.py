"""A resonance's law across loads is said to be extrapolated when the fit improves over a narrow
band of the recordings' loads only (`gma_ffc/diagnose/load_law.py`), and not otherwise."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gma_ffc.diagnose import load_law
from gma_ffc.effects import rod_load as RL
from gma_ffc.effects import rod_load_kernels as RK

LAW = {"f_ref_hz": 176.0, "beta_per_MPa": 0.26, "stress_ref_MPa": -11.4}


def _loads(improved_at: list[float], rng: np.random.Generator, at=(-11.5, -15.0, -20.0)):
    """Three loads of 4,000 samples; the 'after' residual a tenth of the 'before' at the loads listed."""
    static = np.concatenate([np.full(4000, s) + 0.2 * rng.standard_normal(4000) for s in at])
    before = rng.standard_normal(static.size)
    after = before.copy()
    for s in improved_at:
        near = np.abs(static - s) < 1.0
        after[near] *= 0.1
    scored = np.ones(static.size, bool)
    return [static], [scored], [before], [after]


def test_a_law_improved_at_one_load_of_three_is_said_to_be_extrapolated_with_the_load_to_record():
    span = load_law.improved_span(*_loads([-11.5], np.random.default_rng(1)), improves=0.75)
    words = load_law.extrapolation_words(span, LAW)
    assert "extrapolated" in words and "record a drive that excites the resonance" in words
    far = float(re.search(r"fast steps\) at (-?[\d.]+) MPa", words).group(1))
    assert far < -19.0                          # the heaviest load, farthest from the one improved
    said = float(re.search(r"about the ([\d.]+) Hz the law puts there", words).group(1))
    assert said == pytest.approx(load_law.law_frequency(LAW, far), rel=0.01)     # far as printed: 3 digits


def test_a_law_improved_at_the_loads_at_both_ends_is_measured():
    span = load_law.improved_span(*_loads([-11.5, -20.0], np.random.default_rng(2)), improves=0.75)
    assert span is not None and load_law.extrapolation_words(span, LAW) == ""


def test_nothing_is_said_when_nothing_improves_or_the_stress_does_not_vary():
    rng = np.random.default_rng(3)
    assert load_law.improved_span(*_loads([], rng), improves=0.75) is None
    static, scored, before, after = _loads([-11.5], rng, at=(-15.0, -15.0, -15.0))
    flat = [np.full_like(static[0], -15.0)]
    assert load_law.improved_span(flat, scored, before, after, improves=0.75) is None
    assert load_law.extrapolation_words(None, LAW) == ""


def test_a_load_passed_through_on_the_way_shows_nothing_of_the_law():
    """A bin with under MIN_BIN_SHARE of the samples (a load passed through) does not widen the span."""
    rng = np.random.default_rng(4)
    static, scored, before, after = _loads([-11.5], rng)
    passing = np.full(int(0.5 * load_law.MIN_BIN_SHARE * static[0].size), -20.0)
    static = [np.concatenate([static[0], passing])]
    before = [np.concatenate([before[0], np.ones(passing.size)])]
    after = [np.concatenate([after[0], 0.01 * np.ones(passing.size)])]
    scored = [np.ones(static[0].size, bool)]
    assert "extrapolated" in load_law.extrapolation_words(load_law.improved_span(static, scored, before, after, 0.75), LAW)


@settings(max_examples=60, deadline=None)
@given(st.floats(-30.0, -1.0), st.floats(0.0, 2.0), st.floats(10.0, 500.0), st.floats(-30.0, -1.0),
       st.one_of(st.none(), st.floats(-30.0, -1.0)))
def test_the_law_frequency_is_the_one_the_model_runs(s_ref, beta, f_ref, s, held_below):
    """The advice's frequency is the model's own at that load: the controller's stepper (the static
    stress as given) sets the same resonance, a held law included, and it is finite everywhere."""
    block = RL.make_block(f_ref, 0.1, beta, s_ref, held=(-math.inf if held_below is None else held_below, math.inf))
    params = {k: v for k, v in block.items() if k != "form"}
    f = load_law.law_frequency(params, s)
    stepper = RL.RodLoadStepper(block, 1e-3)
    stepper.a_lp = 0.0
    stepper.static(s)
    assert math.isfinite(f) and f > 0
    assert f == pytest.approx(stepper.w_last / (2.0 * math.pi), rel=1e-12)
    x = 1.0 + beta * (s_ref - s)
    if held_below is None and x > RK.MIN_MASS_FACTOR:
        assert f == pytest.approx(f_ref / math.sqrt(x), rel=1e-12)      # the law's formula (`rod_load`)
