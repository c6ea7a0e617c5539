"""Probe recordings: the same simulated actuator at loads, rates and drive shapes its diagnosis never saw.

A diagnosis is judged on held-out time blocks of the recordings it was given; those blocks share
their drive and loads, so a law that does not hold at another load or rate still scores well
there. The probes are the harder question (issue 31): each case's plant, with the same missing
physics, recorded again in separate sessions (each from rest, cold) at loads the diagnosis
recording never held, at drive rates outside its bands, and with drive shapes it never had:

* `other_rate`: a heavy load (46-50 kg, beyond the diagnosis' loads), a 30-45 Hz sine (between
  the diagnosis' 15-25 Hz and 50-80 Hz bands; its harmonics reach the loaded resonance), then
  a slower 1.5-2.5 Hz sine;
* `other_shape`: a light load (12.5-15.5 kg), a triangle whose amplitude rises from the drive's
  minimum to its peak and decays back (nested minor loops), then a two-tone drive;
* `history`: a middle load (24.5-27.5 kg) changed to a heavy one mid-run, a staircase up and
  down with 2-5 s holds (creep), a long full-range 9-13 Hz on phase (heating) and a pause.

Nothing here is seen by `diagnose`. `probe_scores` simulates a base model and its extended model
on each probe from the state each estimates from the measurement (as `gma-ffc simulate` does),
scores both on the same samples (after the base's state has settled) and pools them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from gma_ffc.initial_state import settled_index
from gma_ffc.recordings import Recording

from .cases import FS, Case, _variant, case_plant, case_recordings, record

PROBE_SEED = 31031   # fixed before the probes were first run (issue 31); mixed with each case's seed
PROBES = ("other_rate", "other_shape", "history")


def _sine(f_hz: float, dur_s: float, lo: float, hi: float) -> np.ndarray:
    t = np.arange(int(round(dur_s * FS))) / FS
    return lo + 0.5 * (hi - lo) * (1.0 - np.cos(2.0 * np.pi * f_hz * t))


def _other_rate(rng: np.random.Generator, peak: float) -> tuple[np.ndarray, np.ndarray]:
    lo = 0.05
    i = np.concatenate([_sine(rng.uniform(30, 45), 6.0, lo, peak), _sine(rng.uniform(1.5, 2.5), 4.0, lo, peak)])
    return i, np.full(i.size, rng.uniform(46, 50))


def _other_shape(rng: np.random.Generator, peak: float) -> tuple[np.ndarray, np.ndarray]:
    lo = 0.05
    f = rng.uniform(4, 7)
    t = np.arange(int(8.0 * FS)) / FS
    envelope = np.sin(np.pi * t / t[-1])                       # rises from the minimum to the peak, decays back
    phase = (f * t) % 1.0
    tri = 1.0 - np.abs(2.0 * phase - 1.0)                       # 0..1 triangle, starting at its minimum
    rising = lo + (peak - lo) * envelope * tri
    t2 = np.arange(int(6.0 * FS)) / FS
    f1, f2 = rng.uniform(1.5, 2.5), rng.uniform(14, 20)
    two = 0.5 * (1 - np.cos(2 * np.pi * f1 * t2)) * 0.7 + 0.5 * (1 - np.cos(2 * np.pi * f2 * t2)) * 0.3
    i = np.concatenate([rising, lo + (peak - lo) * two])
    return i, np.full(i.size, rng.uniform(12.5, 15.5))


def _history(rng: np.random.Generator, peak: float) -> tuple[np.ndarray, np.ndarray]:
    lo = 0.05
    levels = np.concatenate([np.sort(rng.uniform(lo, peak, 3)), np.sort(rng.uniform(lo, peak, 3))[::-1]])
    stairs = np.concatenate([np.full(int(rng.uniform(2, 5) * FS), v) for v in levels])
    on = _sine(rng.uniform(9, 13), 12.0, lo, peak)
    pause = np.zeros(int(5.0 * FS))
    i = np.concatenate([_sine(2.0, 0.5, lo, peak), stairs, on, pause])
    m_mid, m_heavy = rng.uniform(24.5, 27.5), rng.uniform(46, 50)
    change = int(0.5 * FS) + stairs.size + int(rng.uniform(3, 8) * FS)     # during the on phase
    mass = np.where(np.arange(i.size) < change, m_mid, m_heavy)
    return i, mass


_SHAPES = {"other_rate": _other_rate, "other_shape": _other_shape, "history": _history}


def probe_recordings(case: Case, effect_free: bool = False) -> list[Recording]:
    """The case's probes: its plant (with its missing physics, or none for the effect-free twin),
    each probe a separate session from rest, as the case's user records them (falling, volts)."""
    cfg = case_plant(case)
    if effect_free:
        cfg = cfg.with_effects(["noise"])
        cfg.magnetics.stress_dependent_width = False
    rng = np.random.default_rng([PROBE_SEED, case.seed])
    out = []
    for k, name in enumerate(PROBES):
        i, mass = _SHAPES[name](rng, case.drive_max)
        t = np.arange(i.size) / FS
        rec = record(cfg, t, i, mass, f"probe_{name}.csv", int(rng.integers(1, 2**31 - 1)))
        out.append(_variant(rec, case))
    return out


@dataclass
class ProbeScore:
    name: str
    base_um: float
    extended_um: float
    samples: int


def _prediction(model: Any, rec: Recording) -> np.ndarray:
    """The model's displacement from its estimated start. The stress is clamped to the model's
    range, as the diagnosis compares it, unless the model transforms the stress itself (the
    rod_load dynamics take the load cell's reading, inertial force and all)."""
    rng = model.stress_range_MPa
    s = None
    if rng is not None:
        s = rec.stress_MPa if getattr(model, "transforms_stress", False) else np.clip(rec.stress_MPa, *rng)
    return np.asarray(model.simulate(rec.time_s, rec.drive, s, measured_um=rec.displacement_um), dtype=float)


def probe_scores(base: Any, extended: Any, probes: Sequence[Recording]) -> list[ProbeScore]:
    """RMS of the base and of the extended model on each probe, on the same samples: from where the
    base's state no longer depends on the unknown start (`settled_index`)."""
    core = getattr(base, "base", base)
    out = []
    for rec in probes:
        start = min(settled_index(core, rec.drive), rec.time_s.size - 1)
        yb = _prediction(base, rec)
        ye = _prediction(extended, rec)
        y = rec.displacement_um
        out.append(ProbeScore(rec.name, float(np.sqrt(np.mean((yb - y)[start:] ** 2))),
                              float(np.sqrt(np.mean((ye - y)[start:] ** 2))), int(y.size - start)))
    return out


def pooled(scores: Sequence[ProbeScore], which: str) -> float:
    """The RMS over every scored sample of all probes."""
    sq = sum(getattr(s, which) ** 2 * s.samples for s in scores)
    return float(np.sqrt(sq / max(sum(s.samples for s in scores), 1)))


def probe_bound(scores: Sequence[ProbeScore]) -> tuple[str, float]:
    """The probe that alone bounds the pooled gain most, and that bound: the gain if every other
    probe were met exactly and it kept the better of its two errors (the base's or the extended
    model's). Where one drive shape is beyond the model class, this says how far the rest could go."""
    before = pooled(scores, "base_um")
    n = sum(s.samples for s in scores)
    worst = max(scores, key=lambda s: min(s.base_um, s.extended_um) ** 2 * s.samples)
    left = min(worst.base_um, worst.extended_um) * np.sqrt(worst.samples / max(n, 1))
    return worst.name, (before / left if left > 0 else float("inf"))


def models_on_probes(case: Case, variants: Mapping[str, Callable[[Any], Any]]) -> tuple[Any, float, float, dict[str, float]]:
    """A case diagnosed with its identification loops (as `scripts/bench_diagnose.py --set general`
    does), and the pooled probe RMS, in um, of the base, of the diagnosis' extended model, and of each
    model `variants[name](diagnosis)` gives (a variant of it, or the one before a fitting step)."""
    from gma_ffc.diagnose.engine import diagnose

    model, ident, rec = case_recordings(case)
    dg = diagnose(model, [rec], identification=ident)
    probes = probe_recordings(case)
    fitted = probe_scores(model, dg.extended, probes)
    others = {name: pooled(probe_scores(model, make(dg), probes), "extended_um") for name, make in variants.items()}
    return dg, pooled(fitted, "base_um"), pooled(fitted, "extended_um"), others


def two_models_on_probes(case: Case, other: Callable[[Any], Any]) -> tuple[Any, float, float, float]:
    """`models_on_probes` with one variant: (diagnosis, base, extended, the variant's) pooled RMS."""
    dg, base, fitted, others = models_on_probes(case, {"other": other})
    return dg, base, fitted, others["other"]
