"""The core identified again through a named input-side effect (`gma_ffc.diagnose.rebase`).

A base identified on loops that a delay or eddy lag shaped has that lag in its loops already; put
the effect in front of it and the lag is undone twice. The re-identified core, through the effect,
must give back the base on its own loops, where the base with the effect in front does not."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks import cases as bench
from gma_ffc.diagnose.anchor import anchor_data
from gma_ffc.diagnose.rebase import reidentify_through
from gma_ffc.extended import ExtendedModel


@pytest.fixture(scope="module")
def base():
    case = next(c for c in bench.cases() if c.name == "time_delay#2")
    return bench.make_case(case, scale=0.25)[0]


@pytest.mark.parametrize("block", [{"delay": {"delay_s": 0.0015}}, {"eddy_lag": {"tau_s": 0.002}}])
def test_core_and_effect_give_back_the_base_on_its_own_loops(base, block) -> None:
    inputs = [e for e in ExtendedModel(base, block).chain if e.stage == "input"]
    core = reidentify_through(base, inputs, anchor_data(base, 1 / bench.FS))
    assert core is not None
    assert core.drive_range == base.drive_range and core.stress_range_MPa == base.stress_range_MPa
    assert core.provenance["reidentified"]["identified_through"] == list(block)
    assert core.provenance["fit_rms_um"] == base.provenance["fit_rms_um"]     # the truth is known no better
    rebased, doubled = ExtendedModel(core, block), ExtendedModel(base, block)
    worst = max(base.provenance["fit_rms_um"].values())
    for d in anchor_data(base, 1 / bench.FS):
        k = d.rows                                   # after the first loop
        miss_rebased = np.sqrt(np.mean((rebased.simulate(d.t, d.u, d.s, initial_state="relaxed") - d.y)[k] ** 2))
        miss_doubled = np.sqrt(np.mean((doubled.simulate(d.t, d.u, d.s, initial_state="relaxed") - d.y)[k] ** 2))
        assert miss_rebased < worst                  # within the base's own identification error there
        assert miss_rebased < 0.25 * miss_doubled    # the lag is not undone twice


def test_a_model_without_its_identification_record_is_left_as_it_is(base) -> None:
    bare = type(base).from_dict({**base.to_dict(), "provenance": {}})
    inputs = [e for e in ExtendedModel(bare, {"delay": {"delay_s": 0.001}}).chain if e.stage == "input"]
    assert reidentify_through(bare, inputs, anchor_data(bare, 1 / bench.FS)) is None
    assert reidentify_through(base, [], anchor_data(base, 1 / bench.FS)) is None
