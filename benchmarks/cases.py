"""The diagnose benchmark's concealed cases on the simulated rig (hil_sim): a base SDPI identified
from separate quasi-static recordings, and one noisy diagnosis recording with one effect (or two,
or none) switched on in the plant. Shared by scripts/bench_diagnose.py and the tests, so both
judge diagnose on exactly the same cases; the truth stays in `Case.truth`, never in the files.
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from gma_ffc.identify import SDPIIdentifier
from gma_ffc.recordings import Recording

from hil_sim.plant import GMAPlant, PlantConfig
from hil_sim.record import run_plant

FS = 2000.0
LABELS = ("rate_dependence", "mechanical_dynamics", "thermal_drift", "creep", "time_delay",
          "stress_dependent_play", "saturation")


@dataclass
class Case:
    name: str
    truth: tuple[str, ...]
    configure: Callable[[PlantConfig], None]
    magnitude: str
    seed: int
    drive_max: float = 1.9          # diagnosis drive peak (A); > identified range only for saturation
    loads: int = 2                  # load levels in the diagnosis run (3 where a stress effect must be decidable)
    id_max: float = 2.0             # identification drive peak (A)
    notes: dict[str, Any] = field(default_factory=dict)
    start_s: float = 0.0            # the diagnosis recording starts this late: cut mid-cycle, mid-history
    falling: bool = False           # mounted the other way round: displacement falls as the drive rises
    voltage: bool = False           # the drive column is labelled voltage_V (a voltage-driven actuator)
    drive: str = "mixed"            # "mixed" (`diagnosis_drive`) or "rising" (`rising_drive`)


def _set(**sections: dict[str, Any]) -> Callable[[PlantConfig], None]:
    def apply(cfg: PlantConfig) -> None:
        for sec, values in sections.items():
            obj = getattr(cfg, sec)
            for k, v in values.items():
                setattr(obj, k, v)
    return apply


def _both(*fns: Callable[[PlantConfig], None]) -> Callable[[PlantConfig], None]:
    def apply(cfg: PlantConfig) -> None:
        for f in fns:
            f(cfg)
    return apply


def cases() -> list[Case]:
    out: list[Case] = []
    seed = 100
    grades: dict[str, list[tuple[str, dict[str, Any]]]] = {
        "rate_dependence": [("eddy", {"enabled": True, "time_constant_ms": v}) for v in (0.6, 1.5, 4.0)],
        "time_delay": [("delay", {"enabled": True, "delay_ms": v}) for v in (0.5, 1.5, 4.0)],
        "mechanical_dynamics": [("dynamics", {"enabled": True, "damping_ratio": v}) for v in (0.3, 0.12, 0.04)],
        "thermal_drift": [("thermal", {"enabled": True, "drift_um_per_K": v}) for v in (0.08, 0.2, 0.5)],
        "creep": [("creep", {"enabled": True, "gains": [v, v, v]}) for v in (0.02, 0.04, 0.08)],
        "stress_dependent_play": [("magnetics", {"stress_dependent_width": True, "width_change_per_MPa": v})
                                  for v in (0.1, 0.2, 0.35)],
    }
    for label, settings in grades.items():
        for k, (sec, values) in enumerate(settings):
            seed += 1
            out.append(Case(f"{label}#{k + 1}", (label,), _set(**{sec: values}), f"{sec} {values}", seed,
                            loads=3 if label == "stress_dependent_play" else 2))
    for k, peak in enumerate((2.6, 3.2, 3.9)):
        seed += 1
        out.append(Case(f"saturation#{k + 1}", ("saturation",), _set(), f"drive to {peak} A, model identified to 1.5 A",
                        seed, drive_max=peak, id_max=1.5))
    for k in range(4):
        seed += 1
        out.append(Case(f"null#{k + 1}", (), _set(), "no missing physics", seed))
    seed += 1
    out.append(Case("thermal+dynamics", ("thermal_drift", "mechanical_dynamics"),
                    _set(thermal={"enabled": True, "drift_um_per_K": 0.3},
                         dynamics={"enabled": True, "damping_ratio": 0.08}),
                    "heating while the load (and the resonance) changes", seed))
    seed += 1
    out.append(Case("delay+eddy", ("time_delay", "rate_dependence"),
                    _set(delay={"enabled": True, "delay_ms": 2.0}, eddy={"enabled": True, "time_constant_ms": 2.0}),
                    "delay and eddy lag at the same frequencies", seed))
    seed += 1
    out.append(Case("thermal+delay", ("thermal_drift", "time_delay"),
                    _set(thermal={"enabled": True, "drift_um_per_K": 0.2}, delay={"enabled": True, "delay_ms": 1.0}),
                    "heating while the load changes, with a delay", seed))
    # nulls at three loads, where stress_dependent_play is testable too: the four above dwell at two,
    # so a false stress_dependent_play could not show (added 2026-11-24; seeds the counter's next)
    for k in range(3):
        seed += 1
        out.append(Case(f"null#{5 + k}", (), _set(), "no missing physics, three loads", seed, loads=3))
    return out


def rising_cases() -> list[Case]:
    """The rising-amplitude family (issue 31): each effect at the development set's middle
    magnitude and three nulls, on `rising_drive` recordings (sines whose amplitude grows from the
    drive's minimum and decays to it, as labs identify). Seeds fixed when the set was made
    (2026-11-25). A development set: it was looked at while the scoring was built."""
    out: list[Case] = []
    settings: list[tuple[str, dict[str, Any]]] = [
        ("rate_dependence", {"eddy": {"enabled": True, "time_constant_ms": 1.5}}),
        ("time_delay", {"delay": {"enabled": True, "delay_ms": 1.5}}),
        ("mechanical_dynamics", {"dynamics": {"enabled": True, "damping_ratio": 0.12}}),
        ("thermal_drift", {"thermal": {"enabled": True, "drift_um_per_K": 0.2}}),
        ("creep", {"creep": {"enabled": True, "gains": [0.04, 0.04, 0.04]}}),
        ("stress_dependent_play", {"magnetics": {"stress_dependent_width": True, "width_change_per_MPa": 0.2}}),
    ]
    for k, (label, sections) in enumerate(settings):
        out.append(Case(f"rising:{label}", (label,), _set(**sections), f"{sections}", 31101 + k,
                        loads=3 if label == "stress_dependent_play" else 2, drive="rising"))
    for k in range(3):
        out.append(Case(f"rising:null#{k + 1}", (), _set(), "no missing physics", 31201 + k,
                        loads=3 if k == 2 else 2, drive="rising"))
    return out


RISING_HOLDOUT_SEED = 20261131   # fixed before the set was first run; never changed to move a result


def rising_holdout_cases() -> list[Case]:
    """The rising-amplitude family's never-tuned set: each effect at a magnitude drawn from its range
    (`EFFECT_RANGES`), two nulls and a pair, seeds drawn once from RISING_HOLDOUT_SEED. Quoted apart
    from `rising_cases`, which the scoring was developed on."""
    rng = np.random.default_rng(RISING_HOLDOUT_SEED)
    out: list[Case] = []
    for label in EFFECT_RANGES:
        sec, values = _effect_drawn(label, rng)
        out.append(Case(f"rising-holdout:{label}", (label,), _set(**{sec: values}), f"{sec} {values}",
                        int(rng.integers(10_000, 99_999)), loads=3 if label == "stress_dependent_play" else 2,
                        drive="rising"))
    for k in range(2):
        out.append(Case(f"rising-holdout:null#{k + 1}", (), _set(), "no missing physics",
                        int(rng.integers(10_000, 99_999)), drive="rising"))
    tau, zeta = float(np.round(rng.uniform(1.0, 3.0), 2)), float(np.round(rng.uniform(0.06, 0.2), 3))
    out.append(Case("rising-holdout:eddy+dynamics", ("rate_dependence", "mechanical_dynamics"),
                    _set(eddy={"enabled": True, "time_constant_ms": tau},
                         dynamics={"enabled": True, "damping_ratio": zeta}),
                    f"eddy tau {tau} ms with a resonance (zeta {zeta})", int(rng.integers(10_000, 99_999)),
                    drive="rising"))
    return out


def sdp_variant_cases() -> list[Case]:
    """Stress-dependent play beyond the development set's three plain cases: six more, seeds and
    magnitudes fixed when the set was made (2026-11-23), on the variants users bring (plain,
    voltage-labelled, falling, cut mid-cycle). A development set (it was looked at), kept apart
    because the three plain cases alone overstated how well this effect is found and removed."""
    out = []
    for k, (v, variant) in enumerate(((0.12, "plain"), (0.2, "voltage"), (0.28, "falling"), (0.33, "cut"),
                                      (0.25, "voltage"), (0.16, "plain"))):
        out.append(Case(f"sdp_variant#{k + 1}", ("stress_dependent_play",),
                        _set(magnetics={"stress_dependent_width": True, "width_change_per_MPa": v}),
                        f"magnetics width_change_per_MPa {v} ({variant})", 7001 + k, loads=3,
                        voltage=variant == "voltage", falling=variant == "falling",
                        start_s=0.7 if variant == "cut" else 0.0))
    return out


HOLDOUT_SEED = 20261122   # fixed before the set was first run; never changed to move a result

# each effect's plant setting and the range its magnitude is drawn from (the never-tuned sets)
EFFECT_RANGES: dict[str, tuple[str, str, tuple[float, float]]] = {
    "rate_dependence": ("eddy", "time_constant_ms", (0.8, 3.5)),
    "time_delay": ("delay", "delay_ms", (0.7, 3.5)),
    "mechanical_dynamics": ("dynamics", "damping_ratio", (0.05, 0.25)),
    "thermal_drift": ("thermal", "drift_um_per_K", (0.12, 0.45)),
    "creep": ("creep", "gains", (0.03, 0.07)),
    "stress_dependent_play": ("magnetics", "width_change_per_MPa", (0.15, 0.35)),
}


def _effect_drawn(label: str, rng: np.random.Generator) -> tuple[str, dict[str, Any]]:
    """The plant section and settings that switch effect `label` on at a magnitude drawn from its range."""
    sec, key, (lo, hi) = EFFECT_RANGES[label]
    v = float(np.round(rng.uniform(lo, hi), 3))
    values: dict[str, Any] = {key: [v, v, v] if key == "gains" else v}
    values["stress_dependent_width" if sec == "magnetics" else "enabled"] = True
    return sec, values


def holdout_cases() -> list[Case]:
    """The never-tuned set: magnitudes, seeds and variants drawn once from HOLDOUT_SEED.

    Nothing in diagnose may be adjusted while looking at these results; they are quoted apart from
    `cases()`, which the thresholds were developed on. Each effect at a magnitude drawn from its range,
    nulls, a pair, and the families users bring: cut mid-cycle, voltage-labelled, falling polarity.
    """
    rng = np.random.default_rng(HOLDOUT_SEED)
    out: list[Case] = []
    for label in EFFECT_RANGES:
        sec, values = _effect_drawn(label, rng)
        variant = ("plain", "cut", "voltage", "falling")[int(rng.integers(4))]
        out.append(Case(f"holdout:{label}", (label,), _set(**{sec: values}), f"{sec} {values} ({variant})",
                        int(rng.integers(10_000, 99_999)), loads=3 if label == "stress_dependent_play" else 2,
                        start_s=float(np.round(rng.uniform(0.1, 1.9), 3)) if variant == "cut" else 0.0,
                        voltage=variant == "voltage", falling=variant == "falling"))
    peak = float(np.round(rng.uniform(2.7, 3.6), 2))
    out.append(Case("holdout:saturation", ("saturation",), _set(), f"drive to {peak} A, model identified to 1.5 A",
                    int(rng.integers(10_000, 99_999)), drive_max=peak, id_max=1.5))
    for k, variant in enumerate(("plain", "cut", "voltage", "falling")):
        out.append(Case(f"holdout:null#{k + 1}", (), _set(), f"no missing physics ({variant})",
                        int(rng.integers(10_000, 99_999)),
                        start_s=float(np.round(rng.uniform(0.1, 1.9), 3)) if variant == "cut" else 0.0,
                        voltage=variant == "voltage", falling=variant == "falling"))
    tau, zeta = float(np.round(rng.uniform(1.0, 3.0), 2)), float(np.round(rng.uniform(0.06, 0.2), 3))
    out.append(Case("holdout:eddy+dynamics", ("rate_dependence", "mechanical_dynamics"),
                    _set(eddy={"enabled": True, "time_constant_ms": tau},
                         dynamics={"enabled": True, "damping_ratio": zeta}),
                    f"eddy tau {tau} ms with a resonance (zeta {zeta})", int(rng.integers(10_000, 99_999))))
    return out


OTHER_PLANTS_SEED = 20261124   # fixed before the set was first run; never changed to move a result
OTHER_PLANTS_HOLDOUT_SEED = 20261125   # a second draw, fixed before its first run, after the first was looked at


def other_plant_cases(n_plants: int = 6, seed: int = OTHER_PLANTS_SEED, prefix: str = "plant") -> list[Case]:
    """Actuators that are not hil_sim's default one: Jiles-Atherton parameters, magnetostriction,
    stress coupling, preload, rod length and sensor noise drawn once from OTHER_PLANTS_SEED over
    the ranges a Terfenol-D rig spans. Each plant gives a null case (nothing missing) and a case
    with one effect drawn at a magnitude from its range, so a threshold that only holds for the
    default actuator shows. Quoted apart from the development and never-tuned sets. The first draw
    (OTHER_PLANTS_SEED) was looked at and a fix made on it; OTHER_PLANTS_HOLDOUT_SEED's was not."""
    rng = np.random.default_rng(seed)
    out: list[Case] = []
    labels = list(EFFECT_RANGES)
    for k in range(n_plants):
        plant = {"magnetics": {"pinning_A_per_m": float(np.round(rng.uniform(1500, 4000))),
                               "anhysteretic_shape_A_per_m": float(np.round(rng.uniform(5000, 10000))),
                               "reversibility": float(np.round(rng.uniform(0.1, 0.35), 3)),
                               "saturation_magnetostriction_ppm": float(np.round(rng.uniform(900, 1500))),
                               "stress_coupling": float(np.round(rng.uniform(0.6, 1.2), 3))},
                 "rig": {"preload_stress_MPa": float(np.round(rng.uniform(-15, -8), 2)),
                         "rod_length_mm": float(np.round(rng.uniform(60, 100)))},
                 "noise": {"displacement_std_um": float(np.round(rng.uniform(0.01, 0.05), 4))}}
        label = labels[int(rng.integers(len(labels)))]
        sec, values = _effect_drawn(label, rng)
        seeds = rng.integers(10_000, 99_999, 2)
        about = (f"JA k {plant['magnetics']['pinning_A_per_m']:.0f} a {plant['magnetics']['anhysteretic_shape_A_per_m']:.0f} "
                 f"c {plant['magnetics']['reversibility']}, preload {plant['rig']['preload_stress_MPa']} MPa")
        out.append(Case(f"{prefix}{k + 1}:null", (), _set(**plant), f"no missing physics ({about})", int(seeds[0]),
                        loads=3))
        with_effect = copy.deepcopy(plant)
        with_effect.setdefault(sec, {}).update(values)
        out.append(Case(f"{prefix}{k + 1}:{label}", (label,), _set(**with_effect), f"{sec} {values} ({about})",
                        int(seeds[1]), loads=3 if label == "stress_dependent_play" else 2))
    return out


def diagnosis_drive(rng: np.random.Generator, peak: float, scale: float = 1.0,
                    loads: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A mixed experiment: sines at several frequencies, steps with holds, a pause with a load change."""
    lo = 0.05
    mid, amp = 0.5 * (peak + lo), 0.5 * (peak - lo)
    segs: list[np.ndarray] = []
    for f, dur in ((rng.uniform(3, 5), 8.0), (rng.uniform(15, 25), 6.0), (rng.uniform(50, 80), 6.0)):
        t = np.arange(int(dur * scale * FS)) / FS
        segs.append(mid - amp * np.cos(2 * np.pi * f * t))
    first_pause = sum(x.size for x in segs)
    if loads == 3:
        segs.append(np.zeros(int(3 * scale * FS)))
    levels = rng.uniform(lo + 0.1 * amp, peak - 0.1 * amp, 6)
    segs.append(np.repeat(levels, int(1.5 * scale * FS)))
    pause_start = sum(x.size for x in segs)
    segs.append(np.zeros(int(4 * scale * FS)))
    t = np.arange(int(6 * scale * FS)) / FS
    segs.append(mid - amp * np.cos(2 * np.pi * rng.uniform(8, 12) * t))
    i = np.concatenate(segs)
    t = np.arange(i.size) / FS
    m1, m2 = rng.uniform(0, 12), rng.uniform(28, 45)
    if rng.random() < 0.5:
        m1, m2 = m2, m1
    if loads == 3:   # a middle load first, changed during an extra pause after the sines
        m0 = rng.uniform(16, 24)
        mass0 = np.where(t < t[first_pause] + scale * rng.uniform(0.5, 1.5), m0, m1)
    else:
        mass0 = np.full(t.size, m1)
    # the load changes during the zero-current pause while the rod cools (so heating and stress change
    # together across the recording); every effect and the hysteresis see both loads
    t_change = t[pause_start] + scale * rng.uniform(0.5, 1.5)
    mass = np.where(t < t_change, mass0, m2)
    return t, i, mass


def rising_drive(rng: np.random.Generator, peak: float, scale: float = 1.0,
                 loads: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The standard identification experiment: sines whose amplitude grows from the drive's minimum
    to its peak and decays back, at several frequencies, with a rest at the minimum in which the load
    changes (with `loads` 3, a middle load first, changed in an extra rest after the first three)."""
    segs: list[np.ndarray] = []
    for f, dur in ((rng.uniform(3, 5), 8.0), (rng.uniform(15, 25), 6.0), (rng.uniform(50, 80), 6.0)):
        t = np.arange(int(dur * scale * FS)) / FS
        envelope = np.sin(np.pi * t / (dur * scale)) ** 2          # 0 at both ends, 1 in the middle
        segs.append(peak * envelope * 0.5 * (1 - np.cos(2 * np.pi * f * t)))
    first_rest = sum(x.size for x in segs)
    if loads == 3:
        segs.append(np.zeros(int(3 * scale * FS)))
    rest = sum(x.size for x in segs)
    segs.append(np.zeros(int(4 * scale * FS)))
    t = np.arange(int(8 * scale * FS)) / FS
    segs.append(peak * np.clip(t / (6 * scale), 0, 1) * 0.5 * (1 - np.cos(2 * np.pi * rng.uniform(8, 12) * t)))
    i = np.concatenate(segs)
    t = np.arange(i.size) / FS
    m1, m2 = rng.uniform(0, 12), rng.uniform(28, 45)
    if rng.random() < 0.5:
        m1, m2 = m2, m1
    mass0 = np.where(t < t[first_rest] + scale * rng.uniform(0.5, 1.5), rng.uniform(16, 24), m1) if loads == 3 \
        else np.full(t.size, m1)
    mass = np.where(t < t[rest] + scale * rng.uniform(0.5, 1.5), mass0, m2)
    return t, i, mass


def record(cfg: PlantConfig, t: np.ndarray, i: np.ndarray, mass: Any, name: str, seed: int,
           preconditioned: bool = False) -> Recording:
    """A recording of the case's actuator. `preconditioned`: the rod was cycled over the drive
    range and came to rest at zero before the recording began (as after any earlier run), not
    demagnetised: hil_sim starts from a demagnetised rod, whose first rise is a virgin curve no
    hysteresis state of a loop reproduces."""
    out = run_plant(GMAPlant(cfg, seed=seed), t, i, mass, FS, preconditioned)
    return Recording({"time_s": t, "current_A": out["current_A"], "stress_MPa": out["stress_MPa"],
                      "displacement_um": out["displacement_um"]}, {}, name)


def case_plant(case: Case) -> PlantConfig:
    """The case's actuator: hil_sim's defaults with the case's settings, noise and the effects it enables."""
    cfg = PlantConfig()
    case.configure(cfg)
    return cfg.with_effects(["noise"] + [e for e in ("eddy", "dynamics", "thermal", "creep", "delay")
                                         if getattr(cfg, e).enabled])


def make_case(case: Case, scale: float = 1.0, effect_free: bool = False) -> tuple[Any, Recording]:
    """The base model (from separate 3 Hz recordings) and the concealed diagnosis recording.

    `effect_free`: the case's twin with the plant's switchable effects off in every recording (the
    identification ones too) and the same drives, loads and noise: the base model's error on it is
    the floor of the model class on this experiment, what an extended model can at best reach."""
    model, _, rec = case_recordings(case, scale, effect_free)
    return model, rec


def case_recordings(case: Case, scale: float = 1.0,
                    effect_free: bool = False) -> tuple[Any, list[Recording], Recording]:
    """`make_case`, with the identification recordings the base model was made from (what a user
    gives `diagnose --ident`)."""
    rng = np.random.default_rng(case.seed)
    cfg = case_plant(case)
    cfg.magnetics = copy.deepcopy(cfg.magnetics)
    if effect_free:
        cfg = cfg.with_effects(["noise"])
        cfg.magnetics.stress_dependent_width = False
    # base model: separate quasi-static 3 Hz recordings at four loads, same actuator (the rising
    # family's as labs identify: the amplitude growing from the drive's minimum and decaying to it)
    rising = case.drive == "rising"
    ident_recs = []
    for k, m in enumerate((0.0, 15.0, 30.0, 50.0)):
        t = np.arange(int((4 if rising else 3) * FS)) / FS
        envelope = np.sin(np.pi * t / 4.0) ** 2 if rising else 1.0
        i = envelope * 0.5 * case.id_max * (1 - np.cos(2 * np.pi * 3 * t))
        ident_recs.append(record(cfg, t, i, m, f"id_{k}.csv", case.seed * 10 + k, preconditioned=rising))
    if case.falling:
        ident_recs = [_variant(r, case) for r in ident_recs]
    model = SDPIIdentifier().fit(ident_recs).model_
    if case.voltage:
        d = model.to_dict()
        d["drive_name"], d["units"]["drive"] = "voltage_V", "V"
        model = type(model).from_dict(d)
    t, i, mass = (rising_drive if rising else diagnosis_drive)(rng, case.drive_max, scale, case.loads)
    rec = _variant(record(cfg, t, i, mass, "recording.csv", case.seed, preconditioned=rising), case)
    if case.start_s > 0:
        keep = rec.time_s >= rec.time_s[0] + case.start_s
        rec = rec.rows(keep, rec.name)
    if case.voltage:
        ident_recs = [_variant(r, dataclasses.replace(case, falling=False)) for r in ident_recs]
    return model, ident_recs, rec


def _variant(rec: Recording, case: Case) -> Recording:
    """The recording as the case's user brings it: falling displacement, drive labelled in volts."""
    cols = dict(rec.columns)
    if case.falling:
        cols["displacement_um"] = -cols["displacement_um"]
    if case.voltage:
        cols["voltage_V"] = cols.pop("current_A")
    return Recording(cols, dict(rec.metadata), rec.name)


SHORT_SLOW_S = 2.0      # of the mixed drive's first sine (3-5 Hz): 6-10 cycles
SHORT_FAST_S = 0.8      # of its second (15-25 Hz, from 8 s): 12-20 cycles; 36 reversals or more in all, over
                        # diagnose's floor of 32
FAST_SINE_AT_S = 8.0    # where `diagnosis_drive`'s second sine starts (at scale 1)


def short_runs(rec: Recording) -> list[Recording]:
    """A mixed-drive case's diagnosis recording as a lab's two short runs: the first seconds of its
    slow sine and a fraction of a second of its faster one, each a recording of its own (two
    frequencies: at one, a lag fits any phase-like class error, tests/test_diagnose_trust.py)."""
    t0 = float(rec.time_s[0])
    spans = (("slow.csv", t0, t0 + SHORT_SLOW_S), ("fast.csv", FAST_SINE_AT_S, FAST_SINE_AT_S + SHORT_FAST_S))
    return [rec.rows((rec.time_s >= a) & (rec.time_s < b), name) for name, a, b in spans]
