"""The base model's own identification domain, as a constraint every fit must respect.

A diagnosis recording is one drive. A recalibration or an effect fitted to it alone is free to
trade accuracy on the loops the base model was identified on for accuracy on this drive, and
blocks held out of the same recording share its drive, so they never see the trade. But the
base was fitted to measured loops: there, the truth is the base's output to within its
identification error. The anchor is that knowledge: full-range loops at the identification rate
and stresses (as the model's provenance records them, else a 3 Hz sinusoid, the seed paper's, at
the ends and middle of its stress range), the base's own output on them, and the base's error
there as the tolerance. Every training fit (never a held-out block) is held within it: each
loop's offset and scale are free (a sensor re-zeroed, a rod whose gain drifted since the
identification: a recalibration the diagnosis data may learn), its shape is not. Pure maths: no I/O.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..model import PARAMETER_BOUND
from ..recordings import Recording
from .data import RecData, prepare

ANCHOR_PERIODS = 2          # full-range loops per stress: the first settles the initial state, the second is held
MAX_SAMPLES = 4000          # per stress: a slow identification drive is sampled more coarsely
MAX_LOOPS = 8               # stresses at most (evenly chosen among the identification recordings')
DEFAULT_ID_HZ = 3.0         # without a record: the seed paper's identification drive, a 3 Hz sinusoid


def _number(x: Any) -> float:
    """A provenance number, or NaN (not recorded) for anything else: text, inf, or one past any
    model's number (`PARAMETER_BOUND`), which only an edit writes and whose square overflows."""
    try:
        v = float(x)
    except (TypeError, ValueError, OverflowError):
        return float("nan")
    return v if np.isfinite(v) and abs(v) <= PARAMETER_BOUND else float("nan")


def _mapping(prov: Any, key: str) -> dict[str, Any]:
    v = prov.get(key) if isinstance(prov, dict) else None
    return v if isinstance(v, dict) else {}


def identification_rate(model: Any) -> float:
    """The loop rate the model was identified at (`provenance.drive_frequency_hz`, which
    `gma-ffc identify` writes), else DEFAULT_ID_HZ."""
    prov = getattr(model, "provenance", None)
    f = _number(prov.get("drive_frequency_hz")) if isinstance(prov, dict) else float("nan")
    return f if f > 0 else DEFAULT_ID_HZ


def identification_loops(model: Any) -> list[tuple[float, float]]:
    """(stress MPa, the base's RMS error there) of each loop the model was identified on, from its
    provenance (`fit_stress_MPa`, `fit_rms_um`, which `gma-ffc identify` writes); without a record,
    the ends and middle of its stress range (0 MPa for a stress-independent model), with the RMS of the
    recorded errors (nan when there are none)."""
    prov = getattr(model, "provenance", None)
    fit_rms, stresses = (_mapping(prov, "fit_rms_um"), _mapping(prov, "fit_stress_MPa"))
    srange = model.stress_range_MPa
    recorded = [v for v in (_number(x) for x in fit_rms.values()) if v > 0]
    overall = float(np.sqrt(np.mean(np.square(recorded)))) if recorded else float("nan")
    if srange is None:
        return [(0.0, overall)]
    lo, hi = float(srange[0]), float(srange[1])
    out: list[tuple[float, float]] = []
    for name, s in stresses.items():
        s, e = _number(s), _number(fit_rms.get(name))
        if np.isfinite(s):
            out.append((min(max(s, lo), hi), e if e > 0 else float("nan")))
    if not out:
        out = [(lo, overall), (0.5 * (lo + hi), overall), (hi, overall)]
    out.sort()
    if len(out) > MAX_LOOPS:   # evenly over the stresses
        out = [out[int(k)] for k in np.linspace(0, len(out) - 1, MAX_LOOPS).round()]
    return out


def anchor_data(model: Any, dt: float, freq_hz: float | None = None) -> list[RecData]:
    """The anchor loops: one per stress level, the base's output as the measurement and its
    identification error there as `extra["anchor_tolerance_um"]` (nan: not recorded)."""
    f = identification_rate(model) if freq_hz is None else float(freq_hz)
    lo, hi = (float(v) for v in model.drive_range)
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi <= lo:
        return []
    dt = max(dt, ANCHOR_PERIODS / f / MAX_SAMPLES)
    n = max(int(round(ANCHOR_PERIODS / f / dt)), 16)
    t = np.arange(n) * dt
    u = lo + 0.5 * (hi - lo) * (1.0 - np.cos(2.0 * np.pi * f * t))
    srange = model.stress_range_MPa
    loops = identification_loops(model)
    recs = []
    for s, _ in loops:
        cols = {"time_s": t, model.drive_name: u, "displacement_um": np.zeros(n)}
        if srange is not None:
            cols["stress_MPa"] = np.full(n, s)
        recs.append(Recording(cols, {}, f"anchor@{s:.3g}MPa"))
    out = prepare(recs, model, "relaxed", measured=False)
    for d, (_, err) in zip(out, loops):
        d.y = np.asarray(model.simulate(d.t, d.u, d.s if srange is not None else None, initial_state=d.start),
                         dtype=float)
        d.rows = d.rows[d.t[d.rows] >= d.t[0] + 1.0 / f]        # after the first loop
        d.extra["anchor_tolerance_um"] = err
        d.extra["anchor_rule"] = "relaxed"
    return out


def measured_loops(model: Any, recordings: list[Recording]) -> list[RecData]:
    """The anchor from the identification recordings themselves (`diagnose --ident`): the measured
    loops, each from its own estimated initial state, scored after it settles (at most MAX_SAMPLES
    rows a loop), with the base's departure from the measurement there, offset and scale aside, as
    the tolerance: a fit may trade nothing on the loops the base was fitted to beyond what the base
    itself gets wrong there."""
    srange = model.stress_range_MPa
    out = prepare(recordings, model, "estimate")
    for d in out:
        stride = max(1, int(np.ceil(d.rows.size / MAX_SAMPLES)))
        d.rows = d.rows[::stride]
        yb = np.asarray(model.simulate(d.t, d.u, d.s if srange is not None else None, initial_state=d.start),
                        dtype=float)[d.rows]
        q, _ = np.linalg.qr(np.column_stack([np.ones(d.rows.size), d.y[d.rows]]))
        d.extra["anchor_tolerance_um"] = float(np.sqrt(np.mean((yb - q @ (q.T @ yb)) ** 2)))
        d.extra["anchor_rule"] = "estimate"
    return out


def anchor_words(model: Any, departures_um: list[float], measured: bool = False) -> str:
    """The validation's sentence on the anchor: what it was, and how far the extended model departs
    from it (an empty list: the base was kept as it is)."""
    loops = identification_loops(model)
    errors = [e for _, e in loops if np.isfinite(e)]
    span = (f"{min(errors):.3g}" if errors and max(errors) <= 1.005 * min(errors) else
            f"{min(errors):.3g}-{max(errors):.3g}" if errors else "")
    tolerance = (f"its identification error there ({span} um)" if errors else
                 "the data's noise floor (the model records no identification error)")
    # a stress-independent model (MPI) has no stress: its loops are at the one load it was identified at
    where = ("" if model.stress_range_MPa is None else
             f" at {len(loops)} stress level{'s' if len(loops) != 1 else ''}")
    if measured:
        text = (" Every fit was held, on the measured identification recordings (--ident), to within the base's "
                "own error there, offset and scale aside (those the data may recalibrate), so no fit trades the "
                "loops the base was fitted to for this drive")
    else:
        text = (f" Every fit was held, on the loops the base was identified on ({identification_rate(model):.3g} Hz "
                f"full-range loops{where}), within {tolerance} of the base's own output, offset "
                "and scale aside (those the data may recalibrate), so no fit trades those loops for this drive")
    if not departures_um:
        return text + "."
    dev = float(np.sqrt(np.mean(np.square(departures_um))))
    return text + f": the extended model departs from them by {dev:.3g} um RMS."
