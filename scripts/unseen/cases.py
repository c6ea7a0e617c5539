"""Concealed, unlabelled diagnosis cases from the alternative rig (alt_plant), truth kept apart.

Each case is a folder with `ident/` (quasi-static 3 Hz sweeps at four stresses, for
`gma-ffc identify`) and `tests/` (the recordings `gma-ffc diagnose` judges). Case folders and
files get neutral random names; the files carry no effect, level or plant parameters. The truth
goes to `manifest.yaml` next to (not inside) the case folders.

Design: every effect of the spec's vocabulary at a clear and a subtle level, two cases with two
effects at once, and null cases (no missing physics, only noise) that are confounded the same
way: load changes while the coil heats (with a temperature column showing the heating), fast
drives on a rig without rate effects, step sequences on a rig without creep. Each rig is a
slightly different specimen (stroke and loop width vary per case).

    python scripts/unseen/cases.py --out DIR [--seed N] [--quick] [--cases KEY,...]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))

from alt_plant import EFFECTS, AltGMAPlant, AltPlantConfig  # noqa: E402
import signals as sg  # noqa: E402

from gma_ffc.recordings import Recording, write_recording  # noqa: E402

IDENT_STRESSES_MPA = (-11.3, -15.0, -19.5, -24.0)
IDENT_RATE_HZ = 1250.0
IDENT_PERIODS = 6
FULL_RANGE_A = (0.0, 2.0)
NARROW_RANGE_A = (0.0, 1.5)   # saturation cases are identified on less than the tests use


@dataclass
class TestRun:
    """One test recording: a drive generator, a sample rate, a duration and a load profile."""

    shape: str
    rate_hz: float
    duration_s: float
    params: dict = field(default_factory=dict)
    load_kg: float = 0.0
    load_changes: list[tuple[float, float]] = field(default_factory=list)


@dataclass
class CaseSpec:
    key: str                                  # readable key for --cases (never written into case files)
    effects: dict[str, str]                   # effect -> "clear" | "subtle"; {} for null cases
    tests: list[TestRun]
    ident_range_A: tuple[float, float] = FULL_RANGE_A
    log_temperature: bool = False
    note: str = ""


def _drive(run: TestRun, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    p = dict(run.params)
    lo, hi = p.pop("lo", 0.05), p.pop("hi", 1.9)
    shape = run.shape
    if shape == "triangle":
        return sg.triangle(t, p["freq_hz"], lo, hi)
    if shape == "chirp":
        return sg.log_chirp(t, p["f0_hz"], p["f1_hz"], lo, hi)
    if shape == "random":
        return sg.band_limited_random(t, p.get("f_lo_hz", 0.5), p["f_hi_hz"], lo, hi, rng)
    if shape == "steps":
        return sg.random_steps(t, p["hold_s"], lo, hi, rng, p.get("dither_A", 0.0), p.get("dither_hz", 0.0))
    if shape == "minor":
        return sg.decaying_triangle(t, p["freq_hz"], lo, hi, p.get("final_fraction", 0.3))
    if shape == "heat_then_cool":  # strong drive, then a weak one: the coil heats, then cools
        split = p["split_s"]
        hot = sg.triangle(t, p["freq_hz"], lo, hi)
        cool = sg.triangle(t, p["cool_freq_hz"], lo, lo + p["cool_swing_A"])
        return np.where(t < split, hot, cool)
    raise ValueError(f"unknown test shape {shape!r}")


def _tr(shape: str, rate: float, dur: float, load: float = 0.0, changes=None, **params) -> TestRun:
    return TestRun(shape, rate, dur, params, load, list(changes or []))


def _effect_tests(effect: str) -> list[TestRun]:
    """Test recordings that excite one effect, each with something else changing at the same time."""
    if effect == "rate_dependence":
        return [_tr("chirp", 5000, 8.0, 12.0, f0_hz=1.0, f1_hz=160.0),
                _tr("random", 5000, 6.0, 40.0, f_hi_hz=120.0),
                _tr("triangle", 1000, 5.0, 25.0, [(2.4, 50.0)], freq_hz=2.0)]
    if effect == "mechanical_dynamics":
        return [_tr("chirp", 5000, 8.0, 60.0, f0_hz=2.0, f1_hz=260.0, lo=0.6, hi=1.3),
                _tr("random", 5000, 6.0, 22.0, f_hi_hz=220.0, lo=0.6, hi=1.3),
                _tr("triangle", 1000, 4.0, 5.0, freq_hz=3.5)]
    if effect == "thermal_drift":
        return [_tr("heat_then_cool", 1000, 120.0, 0.0, [(47.0, 35.0)], freq_hz=2.5, split_s=75.2,
                    cool_freq_hz=2.0, cool_swing_A=0.6, lo=0.05, hi=1.95),
                _tr("steps", 1000, 50.0, 20.0, hold_s=(2.0, 6.0), dither_A=0.25, dither_hz=4.0, lo=0.3, hi=1.9)]
    if effect == "creep":
        return [_tr("steps", 1000, 90.0, 15.0, hold_s=(4.0, 12.0)),
                _tr("steps", 1000, 50.0, 45.0, [(24.0, 30.0)], hold_s=(3.0, 9.0), dither_A=0.08, dither_hz=6.0),
                _tr("triangle", 1000, 4.0, 5.0, freq_hz=3.0)]
    if effect == "time_delay":
        return [_tr("random", 5000, 6.0, 18.0, f_hi_hz=150.0),
                _tr("chirp", 2000, 8.0, 35.0, f0_hz=1.0, f1_hz=120.0),
                _tr("triangle", 1000, 4.0, 0.0, freq_hz=3.0)]
    if effect == "stress_dependent_play":
        return [_tr("triangle", 2000, 16.0, 0.0, [(4.0, 25.0), (8.0, 50.0), (12.0, 64.0)], freq_hz=4.0),
                _tr("random", 1000, 10.0, 60.0, f_hi_hz=10.0),
                _tr("minor", 1000, 6.0, 8.0, freq_hz=2.0, final_fraction=0.3)]
    if effect == "saturation":
        return [_tr("triangle", 1000, 6.0, 20.0, freq_hz=2.0, lo=0.05, hi=2.1),
                _tr("steps", 1000, 30.0, 40.0, hold_s=(1.5, 4.0), dither_A=0.15, dither_hz=5.0, lo=0.1, hi=2.1),
                _tr("random", 1000, 8.0, 10.0, f_hi_hz=8.0, lo=0.05, hi=2.05)]
    raise ValueError(effect)


def _null_tests(variant: int) -> list[TestRun]:
    """No missing physics; the same confounders and shapes as the effect cases."""
    if variant == 0:   # fast drives on a rig with no rate effects or dynamics
        return [_tr("chirp", 5000, 8.0, 12.0, f0_hz=1.0, f1_hz=160.0),
                _tr("random", 5000, 6.0, 40.0, f_hi_hz=150.0),
                _tr("triangle", 1000, 4.0, 25.0, [(2.1, 50.0)], freq_hz=3.0)]
    if variant == 1:   # coil heats (temperature logged) while the load changes: compensated rig, no drift
        return [_tr("heat_then_cool", 1000, 120.0, 0.0, [(47.0, 35.0)], freq_hz=2.5, split_s=75.2,
                    cool_freq_hz=2.0, cool_swing_A=0.6, lo=0.05, hi=1.95),
                _tr("steps", 1000, 40.0, 20.0, hold_s=(2.0, 6.0), dither_A=0.25, dither_hz=4.0, lo=0.3, hi=1.9)]
    if variant == 2:   # steps and load staircase on a rig without creep or stress-dependent play
        return [_tr("steps", 1000, 60.0, 15.0, hold_s=(4.0, 12.0)),
                _tr("triangle", 2000, 16.0, 0.0, [(4.0, 25.0), (8.0, 50.0), (12.0, 64.0)], freq_hz=4.0)]
    if variant == 3:   # slow random and minor loops within the identified range
        return [_tr("random", 1000, 10.0, 60.0, f_hi_hz=10.0),
                _tr("minor", 1000, 6.0, 8.0, freq_hz=2.0, final_fraction=0.3),
                _tr("random", 2000, 6.0, 30.0, f_hi_hz=60.0)]
    if variant == 4:   # everything mixed, as a user would bring it
        return [_tr("chirp", 2000, 8.0, 35.0, f0_hz=1.0, f1_hz=120.0),
                _tr("steps", 1000, 40.0, 45.0, [(20.0, 30.0)], hold_s=(3.0, 9.0), dither_A=0.08, dither_hz=6.0),
                _tr("triangle", 1000, 6.0, 20.0, freq_hz=2.0, lo=0.05, hi=1.95)]
    raise ValueError(variant)


def all_cases() -> list[CaseSpec]:
    """The full benchmark: 7 effects x 2 levels, 2 two-effect cases, 5 null cases."""
    cases: list[CaseSpec] = []
    for effect in EFFECTS:
        for level in ("clear", "subtle"):
            cases.append(CaseSpec(
                key=f"{effect}-{level}", effects={effect: level}, tests=_effect_tests(effect),
                ident_range_A=NARROW_RANGE_A if effect == "saturation" else FULL_RANGE_A,
                log_temperature=effect == "thermal_drift" or level == "subtle"))
    delay_eddy = _effect_tests("time_delay")[:2] + _effect_tests("rate_dependence")[:1]
    cases.append(CaseSpec("time_delay+rate_dependence", {"time_delay": "clear", "rate_dependence": "subtle"},
                          delay_eddy, note="delay at the same frequencies as the eddy lag"))
    cases.append(CaseSpec("thermal_drift+mechanical_dynamics", {"thermal_drift": "clear", "mechanical_dynamics": "clear"},
                          _effect_tests("thermal_drift")[:1] + _effect_tests("mechanical_dynamics")[:1],
                          log_temperature=False, note="heating with a load change, plus a resonance"))
    for v in range(5):
        cases.append(CaseSpec(f"null-{v}", {}, _null_tests(v), log_temperature=v in (1, 4)))
    return cases


QUICK_KEYS = ("time_delay-clear", "thermal_drift-clear", "mechanical_dynamics-clear", "saturation-clear",
              "null-0", "null-1")

_IDENT_NAMES: tuple[Callable[[int], str], ...] = (
    lambda k: f"cal_{k}.csv", lambda k: f"quasi{k:02d}.csv", lambda k: f"loop-{chr(97 + k)}.csv",
    lambda k: f"id_run{k + 1}.csv")
_TEST_NAMES: tuple[Callable[[int], str], ...] = (
    lambda k: f"run_{k + 1:02d}.csv", lambda k: f"acq{k + 7:04d}.csv", lambda k: f"meas_{chr(65 + k)}.csv",
    lambda k: f"trial{k + 3}.csv", lambda k: f"log_{k}.csv")


def _specimen(rng: np.random.Generator) -> AltPlantConfig:
    """A slightly different actuator per case, so nothing can be learnt from one specimen."""
    return AltPlantConfig(stroke_um=float(rng.uniform(21.0, 25.0)),
                          half_width_A=float(rng.uniform(0.13, 0.19)),
                          stroke_loss_per_MPa=float(rng.uniform(0.020, 0.028)),
                          shape_exponent=float(rng.uniform(1.2, 1.4)))


def _config_for(spec: CaseSpec, rng: np.random.Generator) -> AltPlantConfig:
    cfg = _specimen(rng)
    for effect, level in spec.effects.items():
        cfg = cfg.with_effect(effect, level)
    return cfg


def _recording(out: dict[str, np.ndarray], rate_hz: float, with_temperature: bool) -> Recording:
    cols = {"time_s": out["time_s"], "current_A": out["current_A"], "stress_MPa": np.round(out["stress_MPa"], 4),
            "displacement_um": out["displacement_um"]}
    if with_temperature:
        cols["temperature_C"] = out["temperature_C"]
    return Recording(cols, {"source": "alt rig", "sample_rate_hz": float(rate_hz)})


def _run_conditioned(plant: AltGMAPlant, t: np.ndarray, drive: np.ndarray, load: np.ndarray,
                     rate_hz: float) -> dict[str, np.ndarray]:
    """Run after one unlogged 2 Hz cycle up to the record's peak and back, as a rig is cycled before logging.

    Without it every record would start on the virgin curve of a demagnetised rod, a start-up
    transient that is not one of the effects under test.
    """
    tc = sg.time_axis(rate_hz, 0.5)
    pre = drive[0] + 0.5 * (drive.max() - drive[0]) * (1.0 - np.cos(2 * np.pi * 2.0 * tc))
    n = tc.size
    full = plant.run(np.concatenate((tc, t + tc[-1] + 1.0 / rate_hz)), np.concatenate((pre, drive)),
                     np.concatenate((np.full(n, load[0]), load)))
    out = {k: v[n:].copy() for k, v in full.items()}
    out["time_s"] = t.copy()
    return out


def generate(out_dir: str | Path, seed: int = 0, keys: list[str] | None = None) -> dict:
    """Write the cases under out_dir and the truth to out_dir/manifest.yaml; returns the manifest."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    specs = all_cases()
    known = {s.key for s in specs}
    if keys:
        unknown = [k for k in keys if k not in known]
        if unknown:
            raise ValueError(f"unknown case key(s) {unknown}; known: {sorted(known)}")
        specs = [s for s in specs if s.key in keys]
    master = np.random.default_rng(seed)
    order = master.permutation(len(specs))      # case ids do not follow the effect order
    manifest: dict = {"seed": seed, "generator": "scripts/unseen/cases.py", "cases": []}
    for pos in order:
        spec = specs[pos]
        case_seed = int(master.integers(2**31))
        rng = np.random.default_rng(case_seed)
        case_id = f"case_{rng.integers(16**4):04x}"
        while (out_dir / case_id).exists():
            case_id = f"case_{rng.integers(16**4):04x}"
        cfg = _config_for(spec, rng)
        ident_name = _IDENT_NAMES[int(rng.integers(len(_IDENT_NAMES)))]
        test_name = _TEST_NAMES[int(rng.integers(len(_TEST_NAMES)))]
        ident_files, test_files = [], []
        lo, hi = spec.ident_range_A
        for k, stress in enumerate(rng.permutation(IDENT_STRESSES_MPA)):
            t = sg.time_axis(IDENT_RATE_HZ, IDENT_PERIODS / 3.0)
            drive = sg.cosine_sweep(t, 3.0, lo, hi)
            res = AltGMAPlant(cfg, seed=int(rng.integers(2**31))).run(t, drive, cfg.mass_for_stress(float(stress)))
            path = out_dir / case_id / "ident" / ident_name(k)
            path.parent.mkdir(parents=True, exist_ok=True)
            write_recording(path, _recording(res, IDENT_RATE_HZ, False))
            ident_files.append(path.name)
        for k, run in enumerate(spec.tests):
            t = sg.time_axis(run.rate_hz, run.duration_s)
            drive = _drive(run, t, rng)
            load = sg.load_profile(t, run.load_changes, run.load_kg)
            res = _run_conditioned(AltGMAPlant(cfg, seed=int(rng.integers(2**31))), t, drive, load, run.rate_hz)
            path = out_dir / case_id / "tests" / test_name(k)
            path.parent.mkdir(parents=True, exist_ok=True)
            write_recording(path, _recording(res, run.rate_hz, spec.log_temperature))
            test_files.append({"file": path.name, "shape": run.shape, "rate_hz": run.rate_hz,
                               "duration_s": run.duration_s, "params": run.params, "load_kg": run.load_kg,
                               "load_changes": [list(c) for c in run.load_changes]})
        manifest["cases"].append({
            "id": case_id, "key": spec.key, "effects": sorted(spec.effects), "levels": dict(spec.effects),
            "note": spec.note, "ident_files": ident_files, "ident_range_A": list(spec.ident_range_A),
            "test_files": test_files, "seed": case_seed,
            "plant": {k: v for k, v in asdict(cfg).items() if v != getattr(AltPlantConfig(), k)}})
    (out_dir / "manifest.yaml").write_text(yaml.safe_dump(manifest, sort_keys=False))
    return manifest


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="folder for the case folders and manifest.yaml")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help=f"only {', '.join(QUICK_KEYS)}")
    ap.add_argument("--cases", help="comma-separated case keys (see manifest 'key')")
    a = ap.parse_args(argv)
    keys = list(QUICK_KEYS) if a.quick else (a.cases.split(",") if a.cases else None)
    try:
        m = generate(a.out, a.seed, keys)
    except ValueError as e:
        print(f"cases: {e}", file=sys.stderr)
        return 2
    print(f"{len(m['cases'])} cases in {a.out}; truth in {Path(a.out) / 'manifest.yaml'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
