"""The control law alone (issue 10): `FeedforwardController.update` is the batch inverse, sample
for sample, allocates nothing, and applies the drive-range policy."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from allocation import worst_call_allocation
from gma_ffc.control.envelope import DriveRange
from gma_ffc.control.law import FeedforwardController
from gma_ffc.control.reference import Sine
from gma_ffc.modelio import load_model

MODEL = Path(__file__).resolve().parents[1] / "config" / "models" / "sim_sdpi.yaml"


def law_for(model, ref, policy="warn"):
    stepper = model.inverse_stepper(1e-3, initial_drive=0.0)
    start = model.invert_initial_state(ref.batch(np.zeros(1)), -15.2)[0]
    stepper.reset(0.0, start)
    return FeedforwardController(model, ref, stepper, drive=DriveRange(*model.drive_range, policy)), start


def test_update_is_the_batch_inverse_sample_for_sample():
    model = load_model(MODEL)
    ref = Sine(3.0, 12.0, 20.0, lead_s=0.002)
    law, start = law_for(model, ref)
    t = np.arange(3000) * 1e-3
    stress = -15.2 + 2.0 * np.sin(2 * np.pi * 0.5 * t)
    ticks = np.array([law.update(float(a), float(s)) for a, s in zip(t, stress)])
    batch = model.invert(t, ref.batch(t), stress, initial_play_state=start)
    np.testing.assert_allclose(ticks, batch, rtol=0, atol=1e-12)


def test_update_allocates_nothing():
    model = load_model(MODEL)
    law, _ = law_for(model, Sine(3.0, 12.0, 20.0))
    for k in range(200):
        law.update(k * 1e-3, -15.2)
    worst, _ = worst_call_allocation(lambda k: law.update((200 + k) * 1e-3, -15.2), 200)
    assert worst <= 0


@pytest.mark.parametrize("policy", ["warn", "clamp", "fault"])
def test_a_drive_beyond_the_model_is_flagged_and_clamped_only_when_asked(policy):
    model = load_model(MODEL)
    lo, hi = model.drive_range
    law, _ = law_for(model, Sine(3.0, 60.0, 60.0), policy)     # far beyond the model's stroke
    out, flagged = [], 0
    for k in range(400):
        out.append(law.update(k * 1e-3, -15.2))
        flagged += law.beyond
        assert not law.beyond or law.raw > hi or law.raw < lo      # flagged exactly when outside
    assert flagged > 0
    peaks = max(out)
    if policy == "clamp":
        assert peaks <= hi
    else:
        assert peaks > hi and math.isfinite(peaks)
