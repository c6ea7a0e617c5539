"""The hot path allocates nothing (issue 10): one step of every model kind's steppers, measured
with tracemalloc around single steps after a warm-up, for SDPI, MPI and the extended model."""

from __future__ import annotations

from pathlib import Path

import pytest

from allocation import worst_call_allocation
from gma_ffc.modelio import load_model

ROOT = Path(__file__).resolve().parents[1]


def extended_model():
    from gma_ffc.extended import ExtendedModel

    base = load_model(ROOT / "config" / "models" / "sim_sdpi.yaml")
    return ExtendedModel(base, {
        "eddy_lag": {"tau_s": 0.0005}, "delay": {"delay_s": 0.002},
        "static": {"offset_um": 0.1, "gain": 1.01, "stress_gain_per_MPa": 0.001, "quadratic_per_um": 0.0001,
                   "center_um": 20.0, "stress_ref_MPa": -15.0},
        "creep": {"gain": 0.01, "tau_s": 2.0},
        "thermal": {"gain_um_per_A2": 0.05, "tau_s": 30.0},
        "saturation": {"lo": 0.0, "hi": 3.0, "lin_lo": 0.1, "quad_lo": 0.01, "lin_hi": 0.1, "quad_hi": 0.01,
                       "play_thresholds": [1.6, 1.8], "play_coefficients": [0.2, 0.1]},
        "dynamics": {"f_ref_hz": 300.0, "zeta": 0.1, "beta_per_MPa": 0.0, "stress_ref_MPa": -15.0},
    }, [])


MODELS = {
    "sdpi": lambda: load_model(ROOT / "config" / "models" / "sim_sdpi.yaml"),
    "mpi": lambda: load_model(ROOT / "config" / "models" / "sim_mpi_11MPa.yaml"),
    "extended": extended_model,
}


@pytest.mark.parametrize("kind", sorted(MODELS))
@pytest.mark.parametrize("direction", ["forward", "inverse"])
def test_a_step_allocates_nothing(kind, direction):
    model = MODELS[kind]()
    stepper = model.forward_stepper(1e-3, initial_drive=0.0) if direction == "forward" else \
        model.inverse_stepper(1e-3, initial_drive=0.0)
    values = [0.5 + 0.4 * (k % 37) / 37.0 for k in range(200)] if direction == "forward" else \
        [10.0 + 10.0 * (k % 37) / 37.0 for k in range(200)]
    for v in values:                       # warm-up: JIT, lazily built buffers
        stepper.step(v, -15.0)
    worst, peak = worst_call_allocation(lambda k: stepper.step(values[k % len(values)], -15.0), len(values))
    assert worst <= 0, f"{kind} {direction} step retained {worst} bytes"
    # Nothing transient beyond what calling compiled code costs: each numba dispatch boxes ~100 B
    # for an instant (the extended stepper makes two such calls per block chain). numpy scalar
    # maths on the way (0-d arrays, ~100 B each, several per expression) pushes a step past this.
    assert peak <= 256, f"{kind} {direction} step allocated up to {peak} bytes on the way"
