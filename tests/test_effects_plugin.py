"""Adding an effect means adding one file (issue 9): a test-only effect (`mains_pickup_effect.py`),
registered with one call, is fitted and named by the diagnosis, written to and read from the
extended model's file, simulated batch and sample by sample, and inverted, with no other file touched."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gma_ffc import effects
from gma_ffc.diagnose.selection import EffectSelector
from gma_ffc.extended import ExtendedModel
from gma_ffc.modelio import model_from_dict
from gma_ffc.recordings import Recording
from mains_pickup_effect import MainsPickup

RIPPLE_UM = (0.4, -0.3)       # sin, cos amplitudes at 50 Hz


@pytest.fixture
def registered():
    effects.register(MainsPickup)    # the one line a new effect adds to gma_ffc/effects/__init__.py
    try:
        yield MainsPickup
    finally:
        effects.unregister(MainsPickup.name)


@pytest.fixture(scope="module")
def case():
    from benchmarks import cases as bench

    by_name = {c.name: c for c in bench.cases()}
    model, rec = bench.make_case(by_name["null#1"], scale=0.5)
    t = rec.time_s
    w = 2 * math.pi * 50.0 * (t - t[0])
    cols = dict(rec.columns)
    cols["displacement_um"] = cols["displacement_um"] + RIPPLE_UM[0] * np.sin(w) + RIPPLE_UM[1] * np.cos(w)
    return model, Recording(cols, dict(rec.metadata), "null_with_mains.csv")


@pytest.mark.slow
def test_a_registered_effect_is_fitted_named_saved_and_simulated(registered, case):
    model, rec = case
    sel = EffectSelector().fit(model, [rec])
    assert sel.verdict_ == ["mains_pickup"], (sel.verdict_, sel.outcome_)
    (named,) = [c for c in sel.candidates_ if c.accepted]
    assert named.params["f_hz"] == 50.0
    assert named.params["sin_um"] == pytest.approx(RIPPLE_UM[0], abs=0.05)
    assert named.params["cos_um"] == pytest.approx(RIPPLE_UM[1], abs=0.05)
    assert "mains pickup at 50 Hz" in sel.diagnosis_.explanation
    ext = sel.extended_model_
    d = ext.to_dict()
    assert "mains_pickup" in d["blocks"] and d["inverted"]["mains_pickup"].startswith("exact")
    loaded = model_from_dict(d)
    t, u = rec.time_s[:2000], rec.drive[:2000]
    s = rec.stress_MPa[:2000]
    batch = loaded.simulate(t, u, s, initial_drive=float(u[0]))
    np.testing.assert_allclose(batch, ext.simulate(t, u, s, initial_drive=float(u[0])), rtol=1e-12, atol=1e-12)
    without = ExtendedModel(model, {k: v for k, v in d["blocks"].items() if k != "mains_pickup"})
    ripple = batch - without.simulate(t, u, s, initial_drive=float(u[0]))
    assert np.ptp(ripple) == pytest.approx(2 * math.hypot(*RIPPLE_UM), rel=0.15)
    fwd = loaded.forward_stepper(float(t[1] - t[0]), initial_drive=float(u[0]))
    np.testing.assert_allclose([fwd.step(float(a), float(b)) for a, b in zip(u, s)], batch, rtol=1e-9, atol=1e-9)
    # the inverse subtracts the ripple: simulating its drive gives the reference back
    ref = batch
    drive = loaded.invert(t, ref, s)
    x0 = model.drive_range[0]
    back = loaded.simulate(t, drive, s, initial_drive=x0)
    assert np.sqrt(np.mean((back[200:] - ref[200:]) ** 2)) < 0.05 * np.ptp(ref)


def test_an_unregistered_block_is_refused_and_registering_twice_is_an_error(registered):
    with pytest.raises(ValueError, match="registered already"):
        effects.register(MainsPickup)
    effects.unregister(MainsPickup.name)
    from gma_ffc.errors import ModelError
    with pytest.raises(ModelError, match="unknown block"):
        ExtendedModel(None, {"mains_pickup": {"f_hz": 50.0, "sin_um": 0.1, "cos_um": 0.0}})
    effects.register(MainsPickup)
