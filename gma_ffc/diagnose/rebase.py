"""The core identified again through the named input-side effects, on the base's own loops.

A base model identified on measured loops has absorbed into its hysteresis whatever the missing
input-side effect (eddy lag, a delay) did to those loops: at the identification rate, its loops
are the true core's seen through the effect. Putting the effect in front of that base undoes the
lag twice, and the controller tracks worse at the very rate the base was best at. The remedy is
the identification's own: fit the core to the base's loops (which the base reproduces to within
its identification error) with the drive passed through the effect first, so that core and effect
together give back the base there. Pure maths: no I/O.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

import numpy as np

from ..errors import InputError, ModelError
from ..effects.creep import creep_inverse
from ..identify import SDPIIdentifier
from ..model import SDPIModel
from ..recordings import Recording
from .data import RecData


REIDENTIFY_ROWS = 2000
"""Samples per loop a re-identification fits (`SDPIIdentifier.max_rows`; `identify` takes 6000). A
diagnosis identifies the core again per creep time constant and loop width, ~30 times. Loops of a
slow drive sampled at kHz rates hold many samples per feature: every second or third of them moved
the re-identified loops' error by 0.03 % (a resonance pair's 29 fits), at less than half the CPU."""


def reidentify_through(model: Any, inputs: Sequence[Any], loops: Sequence[RecData]) -> SDPIModel | None:
    """An SDPI/MPI core whose output through the input-side effects `inputs` (effect objects of an
    extended model, in path order) reproduces `model` on its own identification loops `loops` (the
    anchor's: the base's output on them, or the measured identification recordings); None when the
    model is not one `gma-ffc identify` wrote (its settings and loops unknown) or the fit fails. The
    new core keeps the base's drive range, name and provenance (its loops and errors: the truth is
    known there to within those, not better), with a note of what it was identified through."""
    if not inputs:
        return None
    return identify_on(model, loops, inputs)


def identify_on(model: Any, loops: Sequence[RecData], inputs: Sequence[Any] = (),
                loop_width: tuple[float, float] | None = None,
                creep: tuple[float, float] | None = None) -> SDPIModel | None:
    """The core identified again on `loops` by the base's own settings (`provenance.settings`), the
    drive passed through the input-side effects `inputs` first, with a loop width that follows
    stress when `loop_width` is given (`SDPIIdentifier.loop_width`), and the displacement taken back
    through a creep (gain, tau s) when `creep` is given (the core is what creeps); None when the
    model is not one `gma-ffc identify` wrote or the fit fails."""
    if not loops or not isinstance(model, SDPIModel) or "fit_stress_MPa" not in model.provenance:
        return None
    if loop_width is not None and model.stress_range_MPa is None:
        return None
    prov = model.provenance
    recs = []
    for d in loops:
        u3 = d.u
        for eff in inputs:
            u3 = eff.apply_input(u3, d.dt, d.dt_med, float(u3[0]))
        y = d.y if creep is None else creep_inverse(d.y, d.dt, creep[0], creep[1])
        cols = {"time_s": d.t, model.drive_name: np.ascontiguousarray(u3), "displacement_um": y}
        if model.stress_range_MPa is not None:
            cols["stress_MPa"] = d.s
        recs.append(Recording(cols, {}, d.name))
    settings = prov.get("settings")
    settings = settings if isinstance(settings, dict) else {}
    zero = settings.get("zero", "shared")
    ident = SDPIIdentifier(n_play=int(settings.get("n_play", 10)), n_deadzone=int(settings.get("n_deadzone", 7)),
                           refine=bool(settings.get("refine", True)), max_rows=REIDENTIFY_ROWS,
                           initial_state=model.initial_state,
                           zero=zero if zero in ("shared", "per_recording") else "shared", loop_width=loop_width)
    try:
        core = ident.fit(recs).model_
    except (InputError, ModelError, np.linalg.LinAlgError, ValueError):
        return None
    if (core.stress_range_MPa is None) != (model.stress_range_MPa is None) or core.output_sign != model.output_sign:
        return None
    note: dict[str, Any] = {"by": "gma-ffc diagnose, on the base's own identification loops",
                            "fit_rms_um": {f.name: round(f.rms_um, 6) for f in ident.report_}}
    if inputs:
        note["identified_through"] = [k for eff in inputs for k in eff.to_blocks()]
    if loop_width is not None:
        note["loop_width"] = [float(v) for v in loop_width]
    if creep is not None:
        note["creep"] = [float(v) for v in creep]
    return dataclasses.replace(core, drive_range=model.drive_range, drive_name=model.drive_name,
                               stress_range_MPa=model.stress_range_MPa,
                               provenance={**prov, "reidentified": note})
