"""The column-sign check: a displacement moving against the model is a column fault; a falling
actuator modelled as falling, a hold, or an ordinary model error is not."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from gma_ffc.diagnose.polarity import INVERTED_CORRELATION, displacement_inverted


def _rec(y: np.ndarray, scored: int | None = None) -> SimpleNamespace:
    mask = np.ones(y.size, bool) if scored is None else np.arange(y.size) >= y.size - scored
    return SimpleNamespace(name="r.csv", y=y, t=np.arange(y.size) * 1e-3, mask=mask, n_scored=int(mask.sum()))


T = np.arange(4000) * 1e-3
MODEL = 20 - 18 * np.cos(2 * np.pi * 3 * T)
NOISE = 0.03 * np.random.default_rng(0).standard_normal(T.size)


@pytest.mark.parametrize("gain", [1.0, 0.6, -1.0, -0.3])
def test_the_sign_of_the_gain_decides_not_its_size(gain):
    found = displacement_inverted([_rec(gain * MODEL + NOISE)], [MODEL], noise_um=0.03)
    if gain > 0:
        assert found is None
    else:
        assert found is not None and found.correlation <= INVERTED_CORRELATION
        assert found.gain == pytest.approx(gain, rel=0.05) and "flip the column's sign" in found.words()


def test_a_falling_actuator_with_a_falling_model_and_a_model_error_are_not_faults():
    lagged = 20 - 18 * np.cos(2 * np.pi * 3 * T - 0.6)         # a large lag: an effect, not a sign
    assert displacement_inverted([_rec(-MODEL + NOISE)], [-MODEL], noise_um=0.03) is None
    assert displacement_inverted([_rec(lagged + NOISE)], [MODEL], noise_um=0.03) is None


def test_a_prediction_that_barely_moves_is_not_judged():
    hold = 10 + 0.1 * np.sin(2 * np.pi * 0.2 * T)          # 0.2 um of model against a drift
    drift = 10 - 2 * T
    assert displacement_inverted([_rec(drift + NOISE)], [hold], noise_um=0.03) is None
    assert displacement_inverted([_rec(-hold + NOISE)], [hold], noise_um=0.001) is not None


def test_only_the_scored_samples_are_judged_when_there_are_some():
    y = MODEL + NOISE
    y[:1000] = -MODEL[:1000]                         # an unscored start that runs against the model
    assert displacement_inverted([_rec(y, scored=3000)], [MODEL], noise_um=0.03) is None
