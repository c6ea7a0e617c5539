"""Extended-model files written before the effect redesign (issue 9) still load and behave the
same: fixtures written by the old code (one model with every block, and the models `diagnose`
built for two benchmark cases) with its simulate, stepper and invert outputs."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np
import pytest

from gma_ffc.modelio import model_from_dict

FIXTURES = sorted((Path(__file__).parent / "fixtures").glob("extended_v1_*.json.gz"))


@pytest.fixture(params=FIXTURES, ids=lambda p: p.name.split(".")[0])
def fixture(request):
    with gzip.open(request.param, "rt") as fh:
        return json.load(fh)


def test_a_version_1_file_loads_and_behaves_as_before(fixture):
    m = model_from_dict(fixture["model"])
    assert m.kind == "extended"
    t, u, s = (np.asarray(fixture[k]) for k in ("time_s", "drive", "stress_MPa"))
    np.testing.assert_allclose(m.simulate(t, u, s), fixture["simulate"], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(m.simulate(t, u, s, initial_drive=float(u[0])), fixture["simulate_from_rest"],
                               rtol=1e-9, atol=1e-9)
    f = m.forward_stepper(float(t[1] - t[0]), initial_drive=float(u[0]))
    np.testing.assert_allclose([f.step(float(a), float(b)) for a, b in zip(u, s)], fixture["forward_stepper"],
                               rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(m.invert(t, np.asarray(fixture["simulate_from_rest"]), s), fixture["invert"],
                               rtol=1e-9, atol=1e-9)


def test_a_version_1_file_is_written_back_the_same(fixture):
    d = model_from_dict(fixture["model"]).to_dict()
    assert d == fixture["model"]
