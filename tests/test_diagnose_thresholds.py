"""Each selection threshold of diagnose, moved 30 % either way, leaves the verdicts of a fast
benchmark subset unchanged (issue 9): a threshold that flips them would be a tuned number, not a
principle. The subset: a null case, a slow effect and a fast effect."""

from __future__ import annotations

import pytest

import gma_ffc.diagnose.engine as engine

THRESHOLDS = ("MIN_MSE_RATIO", "MIN_LOGLIK_GAIN", "NOISE_FACTOR", "MODEL_ERROR_FACTOR", "SLOW_RATIO_MAX",
              "HUBER_K", "AMBIGUOUS_NATS")
SUBSET = ("null#1", "thermal_drift#3", "time_delay#2")


@pytest.fixture(scope="module")
def cases():
    from gma_ffc import sil_cases as bench

    by_name = {c.name: c for c in bench.cases()}
    return {name: bench.make_case(by_name[name], scale=0.5) + (by_name[name].truth,) for name in SUBSET}


@pytest.mark.slow
@pytest.mark.parametrize("name", THRESHOLDS)
@pytest.mark.parametrize("factor", [0.7, 1.3])
def test_verdicts_do_not_flip_when_a_threshold_moves_30_percent(cases, monkeypatch, name, factor):
    value = getattr(engine, name)
    if name == "MIN_MSE_RATIO":            # a ratio below 1: move the margin (1 - r), not r itself
        monkeypatch.setattr(engine, name, 1.0 - (1.0 - value) * factor)
    else:
        monkeypatch.setattr(engine, name, value * factor)
    for case, (model, rec, truth) in cases.items():
        dg = engine.diagnose(model, [rec])
        assert set(dg.verdict) == set(truth), f"{name} x{factor}: {case} -> {dg.verdict} ({dg.outcome})"
