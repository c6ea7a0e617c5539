"""The catalog of physical extensions: what each one is, when it can be tested, how it is searched.

Every entry is a small physical model added to the SDPI core (see `extended`), with the
nonlinear parameters searched here and its gains solved by least squares in `fitting`. Grids
are set by the data (sample period, duration, drive range), never by a particular simulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from .data import stress_levels
from .fitting import Fitter, Spec, geom_refine


@dataclass(frozen=True)
class Effect:
    name: str
    physics: str
    n_params: int                      # parameters the block adds (nonlinear + gains)
    testable: Callable[[Fitter], tuple[bool, str]]
    grid: Callable[[Fitter], Sequence[Any]]
    make: Callable[[Spec, Any], Spec]
    refine: Callable[[Fitter, Any, int], Sequence[Any]] | None   # (fitter, point, zoom level 1..)
    present: Callable[[Spec], bool]

    def remove(self, spec: Spec) -> Spec:
        """The spec without this effect's block."""
        return spec.with_(**{FIELDS[self.name]: (False if self.name in ("stress_dependent_play", "saturation") else None)})


def _always(_: Fitter) -> tuple[bool, str]:
    return True, ""


def _exceedance(f: Fitter) -> tuple[float, float]:
    """Fractions of samples whose drive lies beyond the identified range by more than 2 % of it."""
    margin = 0.02 * f.drive_span
    n = sum(d.u.size for d in f.data)
    above = sum(int(np.sum(d.u > f.drive_hi + margin)) for d in f.data) / n
    below = sum(int(np.sum(d.u < f.drive_lo - margin)) for d in f.data) / n
    return below, above


def _saturation_testable(f: Fitter) -> tuple[bool, str]:
    below, above = _exceedance(f)
    if below + above < 0.005:
        return False, ("the drive stays inside the range the model was identified on "
                       f"({f.drive_lo:.3g}..{f.drive_hi:.3g}), so saturation beyond it cannot be tested; "
                       "record with a drive beyond that range to test it")
    return True, ""


def _stress_testable(f: Fitter) -> tuple[bool, str]:
    if f.model.stress_range_MPa is None:
        return False, ("the model is stress-independent (MPI), so a stress dependence of the play weights "
                       "cannot be tested; identify an SDPI from recordings at several loads")
    if not f.stress_varies:
        return False, ("all recordings are at (nearly) one stress, so play weights that change with stress "
                       "cannot be told from ordinary hysteresis error; record loops at three or more loads "
                       "spanning the model's stress range")
    levels = stress_levels(f.data)
    if len(levels) < 3:
        return False, (f"the recordings dwell at only {len(levels)} distinct stress level(s) "
                       f"({', '.join(f'{v:.3g}' for v in levels)} MPa): anything else that differs between those "
                       "parts of the data (temperature, drive content, a leftover of another effect) would look like "
                       "a stress dependence; record loops at three or more loads spanning the model's stress range")
    return True, ""


def _delay_grid(f: Fitter) -> np.ndarray:
    return np.geomspace(0.25 * f.dt_min, min(0.2, max(f.duration_max / 10, 2 * f.dt_min)), 16)


def _eddy_grid(f: Fitter) -> np.ndarray:
    return np.geomspace(0.25 * f.dt_min, min(0.5, max(f.duration_max / 10, 2 * f.dt_min)), 16)


def _creep_grid(f: Fitter) -> np.ndarray:
    # creep is slow: its fastest component (tau / 10) is no quicker than 0.1 s, else it is a lag look-alike
    lo = max(20 * f.dt_min, MIN_CREEP_TAU_S)
    hi = max(f.duration_max / 2, 2 * lo)
    return np.geomspace(lo, hi, 12)


def _thermal_grid(f: Fitter) -> np.ndarray:
    # a coil and rod heat up over tens of seconds at least (thermal mass); faster "heating" is creep-like
    lo = max(50 * f.dt_min, MIN_THERMAL_TAU_S)
    hi = max(5 * f.duration_max, 2 * lo)
    return np.geomspace(lo, hi, 12)


def _dynamics_grid(f: Fitter) -> list[tuple[float, float, float]]:
    """Resonance frequency x damping, load-independent; the load dependence is refined afterwards."""
    nyq = 0.5 / f.dt_min
    f_lo = max(2.0, 20.0 / max(f.duration_max, 1e-9))
    freqs = np.geomspace(f_lo, 0.8 * nyq, 18) if 0.8 * nyq > f_lo else np.array([0.8 * nyq])
    zetas = (0.02, 0.05, 0.12, 0.25, 0.45)
    return [(float(fr), z, 0.0) for fr in freqs for z in zetas]


# relative play-threshold steps at which the core's loop widening is linearised (a chord, not only the
# tangent: a loop that widens by tens of percent across the loads is not linear in the scale)
WIDTH_STEPS = (-0.3, 0.1, 0.3, 1.0)
MIN_THERMAL_TAU_S = 10.0   # thermal time constant of a coil and rod: tens of seconds and more
MIN_CREEP_TAU_S = 1.0      # creep's central time constant (its components span 0.1x..10x of it)
MAX_ZETA = 0.5   # a resonance must peak; heavier damping is a lag/delay look-alike and is left to those


def _stress_extent(f: Fitter) -> float:
    return max(f.stress_top - min(float(d.s.min()) for d in f.data), 1e-9)


def _dynamics_refine(f: Fitter, p: tuple[float, float, float], level: int) -> list[tuple[float, float, float]]:
    """Zoom on (resonance at the lightest load, damping, frequency ratio heaviest/lightest load)."""
    fr, z, b = p
    span = _stress_extent(f)
    ratio = 1.0 / math.sqrt(1.0 + b * span)          # f(most compressive) / f(least compressive)

    def point(f_top: float, zeta: float, rat: float) -> tuple[float, float, float]:
        rat = min(max(rat, 0.15), 1.0)
        return (float(f_top), float(min(zeta, MAX_ZETA)), float((rat ** -2 - 1.0) / span) if f.stress_varies else 0.0)

    out = [point(fr * k, z, ratio) for k in geom_refine(1.0, 1.4, level)]
    out += [point(fr, z * k, ratio) for k in geom_refine(1.0, 2.4, level)]
    if f.stress_varies:
        out += [point(fr * math.sqrt(ratio / min(ratio * k, 1.0)), z, ratio * k) for k in geom_refine(1.0, 1.5, level)]
        if level == 1 and b == 0.0:
            # load-dependent resonance: keep the geometric-mean frequency, spread the ends apart
            out += [point(fr / math.sqrt(r), z, r) for r in (0.8, 0.63, 0.5, 0.4, 0.3)]
    return out


def _ratio(grid_lo: float, grid_hi: float, n: int) -> float:
    return (grid_hi / grid_lo) ** (1.0 / (n - 1))


CATALOG: dict[str, Effect] = {
    "rate_dependence": Effect(
        "rate_dependence",
        "eddy currents / magnetic diffusion: the field in the rod lags the coil current by a time constant "
        "(first-order lag), so loops widen and tilt as the drive gets faster",
        1, _always, _eddy_grid, lambda s, p: s.with_(eddy_tau=float(p)),
        lambda _f, p, lv: geom_refine(p, _ratio(1, 8000, 16), lv), lambda s: s.eddy_tau is not None),
    "mechanical_dynamics": Effect(
        "mechanical_dynamics",
        "rod and load mass on the rod's stiffness with damping: a second-order resonance whose frequency "
        "falls as the load mass (and so the compressive stress) grows",
        3, _always, _dynamics_grid, lambda s, p: s.with_(dynamics=tuple(float(v) for v in p)),
        _dynamics_refine, lambda s: s.dynamics is not None),
    "thermal_drift": Effect(
        "thermal_drift",
        "Joule heating of the coil and rod: an offset that follows the drive squared through a thermal "
        "time constant (plus a part 8x faster, if still slower than 10 s: the coil heats quicker than the rod) and "
        "cools back at zero current",
        3, _always, _thermal_grid, lambda s, p: s.with_(thermal_tau=float(p)),
        lambda _f, p, lv: [max(q, MIN_THERMAL_TAU_S) for q in geom_refine(p, _ratio(1, 10, 12), lv)],
        lambda s: s.thermal_tau is not None),
    "creep": Effect(
        "creep",
        "slow relaxation of the displacement after the drive changes, in the direction of the last change",
        2, _always, _creep_grid, lambda s, p: s.with_(creep_tau=float(p)),
        lambda _f, p, lv: [max(q, MIN_CREEP_TAU_S) for q in geom_refine(p, _ratio(1, 30, 12), lv)],
        lambda s: s.creep_tau is not None),
    "time_delay": Effect(
        "time_delay",
        "a transport delay in the amplifier, sensor or acquisition: the whole response shifts in time, "
        "so its phase lag grows in proportion to frequency",
        1, _always, _delay_grid, lambda s, p: s.with_(delay_s=float(p)),
        lambda _f, p, lv: geom_refine(p, _ratio(1, 3000, 16), lv), lambda s: s.delay_s is not None),
    "stress_dependent_play": Effect(
        "stress_dependent_play",
        "the play-operator weights and the loop width (the play thresholds, the 'coercive current') change "
        "with stress, which the SDPI assumes they do not",
        5, _stress_testable, lambda f: list(WIDTH_STEPS), lambda s, p: s.with_(stress_play=float(p)), None,
        lambda s: bool(s.stress_play)),
    "saturation": Effect(
        "saturation",
        "the drive goes beyond the range the model was identified on, where the material's curve bends "
        "(towards saturation, or steeper first) while the model extrapolates straight on",
        2, _saturation_testable, lambda f: [True], lambda s, p: s.with_(saturation=bool(p)), None,
        lambda s: s.saturation),
}

ORDER = tuple(CATALOG)
FIELDS = {"rate_dependence": "eddy_tau", "mechanical_dynamics": "dynamics", "thermal_drift": "thermal_tau",
          "creep": "creep_tau", "time_delay": "delay_s", "stress_dependent_play": "stress_play",
          "saturation": "saturation"}
