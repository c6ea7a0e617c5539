"""`SDPIIdentifier(loop_width=...)`: the core identified with a loop width that follows stress
(issue 31: `diagnose --ident` identifies the core again through the stress_dependent_play effect's
width law). The paper's SDPI stays the default."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gma_ffc.effects.stress_play import WidenedCore
from gma_ffc.errors import InputError
from gma_ffc.identify import SDPIIdentifier
from gma_ffc.modelio import load_model
from gma_ffc.recordings import Recording

TRUE_KAPPA = 0.08      # per MPa: the loop widens 8 % per MPa of extra compression


@pytest.fixture(scope="module")
def widened_loops():
    """3 Hz full-range loops at four stresses from a known SDPI whose loop width follows stress."""
    model = load_model(Path(__file__).resolve().parents[1] / "config" / "models" / "sim_sdpi.yaml")
    ref = float(model.stress_range_MPa[1])
    core = WidenedCore(model, TRUE_KAPPA, ref)
    lo, hi = model.drive_range
    t = np.arange(3000) / 1000.0
    u = lo + 0.5 * (hi - lo) * (1 - np.cos(2 * np.pi * 3.0 * t))
    rng = np.random.default_rng(3)
    recs = []
    for k, s in enumerate(np.linspace(*model.stress_range_MPa, 4)):
        y = core.simulate(t, u, np.full(t.size, s), initial_drive=float(u[0])) + rng.normal(0, 0.01, t.size)
        recs.append(Recording({"time_s": t, "current_A": u, "stress_MPa": np.full(t.size, s),
                               "displacement_um": y}, {}, f"id_{k}.csv"))
    return model, ref, recs


def test_the_width_law_fits_loops_the_plain_sdpi_cannot(widened_loops):
    _, ref, recs = widened_loops
    plain = SDPIIdentifier().fit(recs)
    wide = SDPIIdentifier(loop_width=(TRUE_KAPPA, ref)).fit(recs)
    err_plain = max(f.rms_um for f in plain.report_)
    err_wide = max(f.rms_um for f in wide.report_)
    assert err_wide < 0.5 * err_plain, (err_wide, err_plain)
    assert isinstance(wide.core_, WidenedCore) and wide.core_.kappa == TRUE_KAPPA
    assert wide.model_.provenance["settings"]["loop_width"] == [TRUE_KAPPA, ref]
    assert plain.core_ is plain.model_ and "loop_width" not in plain.model_.provenance["settings"]


def test_the_fit_error_is_least_near_the_true_width_law(widened_loops):
    _, ref, recs = widened_loops
    err = {k: np.sqrt(np.mean([f.rms_um ** 2 for f in SDPIIdentifier(loop_width=(k, ref)).fit(recs).report_]))
           for k in (0.0, 0.04, TRUE_KAPPA, 0.16)}
    assert min(err, key=err.get) == TRUE_KAPPA, err


def test_a_width_law_needs_numbers(widened_loops):
    _, _, recs = widened_loops
    with pytest.raises(InputError, match="loop_width"):
        SDPIIdentifier(loop_width=(float("nan"), -11.0)).fit(recs)
