"""Recordings from the simulated GMA, in the format of docs/recordings.md.

Each kind is a set of experiments (drive signal + load mass over time) run on a fresh plant.
The files carry what a rig would log (source, sample rate, seed, load mass) but never which
effects the simulator had switched on; that goes to DIR/manifest.yaml, so a diagnosis tool
cannot cheat by reading it from the recording.

    from hil_sim.record import make_recording, make_recordings
    rec = make_recording("identification", stress_MPa=-15.2, effects=["noise"])
    recs = make_recordings("multifreq", effects=["eddy", "noise"], seed=3)
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np
import yaml

from gma_ffc.atomic import atomic_write
from gma_ffc.errors import InputError
from gma_ffc.recordings import Recording, write_recording

from .plant import EFFECTS, GMAPlant, PlantConfig

IDENTIFICATION_STRESSES_MPA = (-11.3, -13.2, -15.2, -19.1, -21.5, -24.0)
"""The paper's four stresses and two in between (for validation between identified stresses)."""
MULTIFREQ_HZ = (1.0, 3.0, 10.0, 30.0, 50.0, 100.0, 200.0)
STEP_LEVELS_A = (0.5, 1.5, 2.5, 1.0, 2.0, 0.0)
STRESS_CHANGE_MASSES_KG = (0.0, 15.3, 30.6, 49.8, 0.0)
RISING_STRESSES_MPA = (-13.2, -19.1)
RISING_SEGMENTS = ((3.0, 8.0), (20.0, 4.0), (60.0, 3.0))
"""(Hz, s): each a sine whose amplitude grows from 0 A to the full range and decays back."""
PRECONDITION_S = 1.5
"""A full-range cycle at 2 Hz, then a second at 0 A: the rod as any earlier run leaves it."""
COLUMN_ORDER = ("time_s", "current_A", "current_cmd_A", "stress_MPa", "displacement_um",
                "force_N", "temperature_C")
MAX_CURRENT_A = 3.0


@dataclass
class Experiment:
    """One recording to make: a command, a load mass per sample, and what the file will say."""

    name: str
    time_s: np.ndarray
    current_cmd_A: np.ndarray
    load_mass_kg: np.ndarray
    description: str
    extra: dict[str, Any] = field(default_factory=dict)
    preconditioned: bool = False      # run PRECONDITION_S of cycling and rest first, not recorded


def _sine(freq_hz: float, periods: float, fs: float, amplitudes: Sequence[float] = (1.0,)) -> tuple:
    """Unipolar raised-cosine current 0..MAX (starts at zero); one amplitude per block of periods."""
    per_block = int(round(periods * fs / freq_hz))
    t = np.arange(per_block * len(amplitudes)) / fs
    amp = np.repeat(np.asarray(amplitudes, dtype=float), per_block)
    i = 0.5 * MAX_CURRENT_A * amp * (1.0 - np.cos(2.0 * np.pi * freq_hz * t))
    return t, i


def _fmt_stress(s: float) -> str:
    return f"{s:.1f}MPa"


def _mass_for(cfg: PlantConfig, stress_MPa: float) -> float:
    """The load mass that puts the rod at `stress_MPa`, refused below the preload."""
    mass = cfg.mass_for_stress(stress_MPa)
    if mass < -1e-6:
        raise InputError(f"stress {stress_MPa} MPa is below the preload ({cfg.rig.preload_stress_MPa} MPa): "
                         f"a load mass cannot reduce the compression")
    return max(mass, 0.0)


def identification(cfg: PlantConfig, stresses: Sequence[float] = IDENTIFICATION_STRESSES_MPA,
                   minor_loops: bool = False, fs: float = 2000.0, freq_hz: float = 3.0,
                   periods: int = 4) -> list[Experiment]:
    """3 Hz sine over the full range at each stress (optionally then shrinking minor loops)."""
    amps = [1.0] + ([0.8, 0.6, 0.4] if minor_loops else [])
    out = []
    for s in stresses:
        mass = _mass_for(cfg, s)
        t, i = _sine(freq_hz, periods, fs)
        if minor_loops:   # full loops first, then one period per smaller amplitude
            i = np.concatenate([i, _sine(freq_hz, 1, fs, amps[1:])[1]])
            t = np.arange(i.size) / fs
        out.append(Experiment(f"identification_{_fmt_stress(s)}", t, i, np.full(t.size, mass),
                              f"{freq_hz:g} Hz sine 0-{MAX_CURRENT_A:g} A"
                              + (", then minor loops" if minor_loops else ""),
                              {"load_mass_kg": round(mass, 3)}))
    return out


def rising(cfg: PlantConfig, stresses: Sequence[float] = RISING_STRESSES_MPA,
           segments: Sequence[tuple[float, float]] = RISING_SEGMENTS, fs: float = 2000.0) -> list[Experiment]:
    """The identification experiment labs record: at each stress, sines whose amplitude grows from
    0 A to the full range and decays back (a sin^2 envelope), one after the other at each (Hz, s)
    of `segments`. The rod was cycled and came to rest before (`preconditioned`): from a
    demagnetised rod the first rise would be a virgin curve, which no run after the first shows."""
    if not segments:
        raise InputError("rising: give at least one (Hz, s) segment")
    parts = []
    for f, dur in segments:
        if not (0 < f < fs / 4 and dur > 0):
            raise InputError(f"segment ({f} Hz, {dur} s): the frequency must be positive and below a quarter "
                             f"of {fs:g} Hz sampling, the duration positive")
        t = np.arange(int(round(dur * fs))) / fs
        envelope = np.sin(np.pi * t / dur) ** 2                    # 0 at both ends, 1 in the middle
        parts.append(0.5 * MAX_CURRENT_A * envelope * (1.0 - np.cos(2.0 * np.pi * f * t)))
    i = np.concatenate(parts)
    t = np.arange(i.size) / fs
    what = ", ".join(f"{f:g} Hz for {d:g} s" for f, d in segments)
    out = []
    for s in stresses:
        mass = _mass_for(cfg, s)
        out.append(Experiment(f"rising_{_fmt_stress(s)}", t, i, np.full(t.size, mass),
                              f"sines 0-{MAX_CURRENT_A:g} A, amplitude rising from 0 and decaying back: {what}",
                              {"load_mass_kg": round(mass, 3)}, preconditioned=True))
    return out


def multifreq(cfg: PlantConfig, frequencies: Sequence[float] = MULTIFREQ_HZ, fs: float = 10000.0,
              load_mass_kg: float = 0.0) -> list[Experiment]:
    """Full-range sines from 1 to 200 Hz, at least 3 periods and 0.5 s each, one file per frequency."""
    out = []
    for f in frequencies:
        if not 0 < f < fs / 4:
            raise InputError(f"frequency {f} Hz must be positive and below a quarter of {fs:g} Hz sampling")
        periods = max(3, int(np.ceil(0.5 * f)))
        t, i = _sine(f, periods, fs)
        out.append(Experiment(f"multifreq_{f:g}Hz", t, i, np.full(t.size, load_mass_kg),
                              f"{f:g} Hz sine 0-{MAX_CURRENT_A:g} A", {"load_mass_kg": load_mass_kg}))
    return out


def long_run(cfg: PlantConfig, drive_s: float = 150.0, rest_s: float = 90.0, fs: float = 1000.0,
             load_mass_kg: float = 0.0) -> list[Experiment]:
    """Minutes of 3 Hz full-range drive (the coil heats up), then zero current (it cools down)."""
    t, i = _sine(3.0, 3.0 * drive_s, fs)
    rest = np.zeros(int(round(rest_s * fs)))
    i = np.concatenate([i, rest])
    t = np.arange(i.size) / fs
    return [Experiment("long_run", t, i, np.full(t.size, load_mass_kg),
                       f"3 Hz sine 0-{MAX_CURRENT_A:g} A for {drive_s:g} s, then 0 A for {rest_s:g} s",
                       {"load_mass_kg": load_mass_kg})]


def steps(cfg: PlantConfig, levels: Sequence[float] = STEP_LEVELS_A, hold_s: float = 12.0,
          fs: float = 1000.0, load_mass_kg: float = 0.0) -> list[Experiment]:
    """Current steps up and down, each held long enough to watch the displacement relax."""
    n = int(round(hold_s * fs))
    i = np.concatenate([np.zeros(int(fs))] + [np.full(n, lv) for lv in levels])
    t = np.arange(i.size) / fs
    return [Experiment("steps", t, i, np.full(t.size, load_mass_kg),
                       f"current steps {', '.join(f'{v:g}' for v in levels)} A, {hold_s:g} s each",
                       {"load_mass_kg": load_mass_kg})]


def stress_change(cfg: PlantConfig, masses: Sequence[float] = STRESS_CHANGE_MASSES_KG,
                  hold_s: float = 4.0, fs: float = 2000.0) -> list[Experiment]:
    """3 Hz full-range sine while the load mass changes stepwise (the stress column follows)."""
    n = int(round(hold_s * fs))
    t, i = _sine(3.0, 3.0 * hold_s * len(masses), fs)
    m = np.repeat(np.asarray(masses, dtype=float), n)[: t.size]
    if m.size < t.size:
        m = np.concatenate([m, np.full(t.size - m.size, masses[-1])])
    return [Experiment("stress_change", t, i, m,
                       f"3 Hz sine 0-{MAX_CURRENT_A:g} A; load mass "
                       f"{' -> '.join(f'{v:g}' for v in masses)} kg every {hold_s:g} s",
                       {"load_mass_kg": "varies, see force_N"})]


KINDS: dict[str, Callable[..., list[Experiment]]] = {
    "identification": identification, "multifreq": multifreq, "long": long_run,
    "steps": steps, "stress_change": stress_change, "rising": rising,
}


def _resolve_config(cfg: PlantConfig | None, effects: Iterable[str] | None) -> PlantConfig:
    cfg = cfg if cfg is not None else PlantConfig()
    return cfg.with_effects(effects) if effects is not None else cfg


def config_id(cfg: PlantConfig) -> str:
    """A short fingerprint of the whole plant config, to match a file with its manifest entry."""
    blob = json.dumps(cfg.to_dict(), sort_keys=True).encode()
    return hashlib.sha256(blob).hexdigest()[:12]


def experiments(kind: str, cfg: PlantConfig, **options: Any) -> list[Experiment]:
    if kind not in KINDS:
        raise InputError(f"unknown recording kind '{kind}'; choose from {', '.join(KINDS)}")
    try:
        return KINDS[kind](cfg, **options)
    except TypeError as exc:
        raise InputError(f"kind '{kind}': bad option ({exc})") from None


def run_plant(plant: GMAPlant, t: np.ndarray, i: np.ndarray, mass: Any, fs: float,
              preconditioned: bool = False) -> dict[str, np.ndarray]:
    """The plant's run from its demagnetised start or, `preconditioned`, after PRECONDITION_S (not
    returned) of one full-range cycle at 2 Hz and rest at 0 A under the first load: the rod as an
    earlier run leaves it."""
    if not preconditioned:
        return plant.run(t, i, load_mass_kg=mass)
    n0 = int(round(PRECONDITION_S * fs))
    t0 = np.arange(n0) / fs
    pre = np.where(t0 < 0.5, 0.5 * float(np.max(i)) * (1 - np.cos(2 * np.pi * 2.0 * t0)), 0.0)
    m = np.broadcast_to(np.asarray(mass, dtype=float), t.shape)
    full = plant.run(np.r_[t0, t - t[0] + PRECONDITION_S], np.r_[pre, i], load_mass_kg=np.r_[np.full(n0, m[0]), m])
    return {k: v[n0:] if k != "time_s" else t for k, v in full.items()}


def simulate(exp: Experiment, cfg: PlantConfig, seed: int) -> Recording:
    """Run one experiment on a fresh plant and package it as a recording."""
    fs = 1.0 / float(np.median(np.diff(exp.time_s)))
    out = run_plant(GMAPlant(cfg, seed=seed), exp.time_s, exp.current_cmd_A, exp.load_mass_kg, fs,
                    exp.preconditioned)
    columns = {name: out[name] for name in COLUMN_ORDER}
    meta: dict[str, Any] = {
        "source": f"hil_sim simulated GMA ({exp.name})",
        "sample_rate_hz": round(fs, 6),
        "seed": seed,
        "drive": exp.description,
        **exp.extra,
        # No config fingerprint here: one could be matched against every effect combination.
        "effects": "see manifest.yaml",
    }
    return Recording(columns, meta, f"{exp.name}.csv")


def make_recordings(kind: str, cfg: PlantConfig | None = None, seed: int = 0,
                    effects: Iterable[str] | None = None, **options: Any) -> list[Recording]:
    """Every recording of a kind; file k uses seed*1000 + k so each has its own noise."""
    c = _resolve_config(cfg, effects)
    return [simulate(e, c, seed * 1000 + k) for k, e in enumerate(experiments(kind, c, **options))]


def make_recording(kind: str, cfg: PlantConfig | None = None, seed: int = 0,
                   effects: Iterable[str] | None = None, stress_MPa: float | None = None,
                   frequency_hz: float | None = None, **options: Any) -> Recording:
    """One recording: for `identification` at `stress_MPa`, for `multifreq` at `frequency_hz`."""
    if stress_MPa is not None:
        if kind != "identification":
            raise InputError("stress_MPa selects an identification recording; for other kinds set the load mass")
        options["stresses"] = [stress_MPa]
    if frequency_hz is not None:
        if kind != "multifreq":
            raise InputError("frequency_hz selects a multifreq recording")
        options["frequencies"] = [frequency_hz]
    c = _resolve_config(cfg, effects)
    return simulate(experiments(kind, c, **options)[0], c, seed * 1000)


def write_recordings(kind: str, out_dir: str | Path, cfg: PlantConfig | None = None, seed: int = 0,
                     effects: Iterable[str] | None = None, progress: Any = None,
                     **options: Any) -> list[Path]:
    """Write one CSV per experiment plus DIR/manifest.yaml (which holds the effects); atomic each."""
    c = _resolve_config(cfg, effects)
    exps = experiments(kind, c, **options)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a directory")
    paths = []
    entries = []
    for k, e in enumerate(exps):
        rec = simulate(e, c, seed * 1000 + k)
        path = out / f"{e.name}.csv"
        write_recording(path, rec)
        paths.append(path)
        entries.append({"file": path.name, "seed": seed * 1000 + k, "drive": e.description, **e.extra})
        if progress is not None:
            progress.advance(note=path.name)
    manifest = {
        "generator": "python -m hil_sim record",
        "kind": kind,
        "seed": seed,
        "effects": c.enabled_effects,
        "stress_dependent_width": c.magnetics.stress_dependent_width,
        "plant_config_id": config_id(c),
        "files": entries,
        "plant_config": c.to_dict(),
    }
    with atomic_write(out / "manifest.yaml", "w", encoding="utf-8") as fh:
        yaml.safe_dump(manifest, fh, sort_keys=False)
    return paths


__all__ = ["EFFECTS", "KINDS", "Experiment", "experiments", "make_recording", "make_recordings",
           "write_recordings", "config_id"]
