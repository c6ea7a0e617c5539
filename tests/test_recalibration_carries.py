"""The static recalibration keeps curvature and a stress gain only where they carry to other loads.

The eleventh never-tuned draw's heating with creep: both effects named, but the recalibration fitted
beside them (curvature, stress gain) took up part of the slow effects on the one recording, and the
probes at other loads, rates and drive shapes gained only 1.22x over the base. Judged by leaving
each of the recording's stress levels out, those terms do not carry, and are left out (issue 31:
an effect that does not improve the conditions it was not fitted on is not accepted).
A whole draw's case (75 s on 2 cores): the nightly tier's (`scripts/test.sh --nightly`).
"""

from __future__ import annotations

import pytest

from benchmarks.cases import case_recordings
from benchmarks.general import GENERAL_ELEVENTH_SEED, general_cases
from benchmarks.probes import pooled, probe_recordings, probe_scores
from gma_ffc.diagnose.engine import diagnose
from gma_ffc.effects.static import StaticMap


@pytest.mark.nightly
def test_heating_with_creep_keeps_only_the_recalibration_that_carries_to_other_loads():
    case = {c.name: c for c in general_cases(GENERAL_ELEVENTH_SEED, prefix="eleventh")}["eleventh:thermal_drift+creep"]
    model, ident, rec = case_recordings(case)      # whole: at half or 3/4 length heating is not named
    dg = diagnose(model, [rec], identification=ident)
    assert set(dg.verdict) == {"thermal_drift", "creep"}
    static = next(b for b in dg.extended.chain if isinstance(b, StaticMap)).static
    assert static["quadratic_per_um"] == 0.0 and static["stress_gain_per_MPa"] == 0.0
    scores = probe_scores(model, dg.extended, probe_recordings(case))
    # issue 31's target for every effect case: 1.5x better than the base at the loads never seen
    assert pooled(scores, "base_um") > 1.5 * pooled(scores, "extended_um")


def _with_curvature(rec, curvature_at):
    """The recording with a curvature of the displacement added at the stress levels `curvature_at`
    picks (a mask of its samples)."""
    import numpy as np

    from gma_ffc.recordings import DISPLACEMENT, Recording

    y = rec.displacement_um
    cols = dict(rec.columns)
    cols[DISPLACEMENT] = y + 0.002 * (y - y.mean()) ** 2 * curvature_at(rec.stress_MPa)
    return Recording(cols, dict(rec.metadata), rec.source)


def test_a_curvature_the_core_has_at_every_load_is_kept():
    """The guard beside the rule: a curvature of the displacement at all three loads of the recording
    carries to each load left out, and stays in the recalibration."""
    import numpy as np

    from gma_ffc.diagnose import recalibration
    from gma_ffc.diagnose.problem import setup
    from gma_ffc.diagnose.selection import EffectSelector

    case = {c.name: c for c in general_cases()}["gen:null#1@default"]     # the mixed drive at three loads
    model, _, rec = case_recordings(case, scale=0.5)
    rec = _with_curvature(rec, np.ones_like)
    selector = EffectSelector()
    problem = setup(selector, model, [rec], lambda _m: None)
    assert len(problem.fitter.level_blocks()) == 3
    sel = recalibration.carried(problem, selector._open(problem))
    assert "quadratic" in sel.fit.names
