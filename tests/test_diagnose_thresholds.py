"""Each selection threshold of diagnose, moved 30 % either way, leaves the verdicts of a fast
benchmark subset unchanged (issue 9): a threshold that flips them would be a tuned number, not a
principle. The subset: a null case, a slow effect and a fast effect. Thresholds are moved through
the estimator's constructor (`EffectSelector`), where each one's reason is written down.

A round's search (`score_round`) is a pure function of the fitter's data and loss, the effects
already in the model and the effects tried. Only `huber_k` changes its inputs (the loss); the
other thresholds decide on its results. So the searches are memoised by those inputs across the
moves: a move that takes the same path as the defaults pays only for its decisions, and one that
takes another path searches afresh. This keeps the test to a tenth of its cost (14 moves x 3
diagnoses were 40 % of the suite's time), and what it asserts is unchanged. The memo is on disk, so
the xdist workers share it: the defaults' path is searched once, not once per worker, and the
`diagnosed` fixture (tests/conftest.py) shares it too: test_diagnose_cases diagnoses the same three
cases at the same length with the default thresholds, which is the defaults' path itself."""

from __future__ import annotations

import inspect

import pytest

from gma_ffc.diagnose.selection import EffectSelector

THRESHOLDS = ("min_mse_ratio", "min_loglik_gain", "noise_factor", "model_error_factor", "slow_ratio_max",
              "huber_k", "ambiguous_nats")
SUBSET = ("null#1", "thermal_drift#3", "time_delay#2")
DEFAULTS = {k: p.default for k, p in inspect.signature(EffectSelector).parameters.items()}


@pytest.fixture(scope="module")
def cases(session_folder):
    """The subset's models and recordings, made once per session and shared by the xdist workers
    (`session_cache`: each worker that runs a move made all three before, 3 s of CPU each time)."""
    from session_cache import once_per_session

    def make():
        from benchmarks import cases as bench

        by_name = {c.name: c for c in bench.cases()}
        return {name: bench.make_case(by_name[name], scale=0.5) + (by_name[name].truth,) for name in SUBSET}
    return once_per_session(session_folder, "threshold cases", make)


def test_every_threshold_is_a_documented_constructor_argument():
    doc = EffectSelector.__doc__ or ""
    for name in THRESHOLDS:
        assert name in DEFAULTS and f"{name} (" in doc, name


@pytest.mark.slow
@pytest.mark.parametrize("name", THRESHOLDS)
@pytest.mark.parametrize("factor", [0.7, 1.3])
def test_verdicts_do_not_flip_when_a_threshold_moves_30_percent(cases, memoised_rounds, name, factor):
    value = DEFAULTS[name]
    if name == "min_mse_ratio":            # a ratio below 1: move the margin (1 - r), not r itself
        moved = 1.0 - (1.0 - value) * factor
    else:
        moved = value * factor
    for case, (model, rec, truth) in cases.items():
        sel = EffectSelector(**{name: moved}).fit(model, [rec])
        assert set(sel.verdict_) == set(truth), f"{name} x{factor}: {case} -> {sel.verdict_} ({sel.outcome_})"
