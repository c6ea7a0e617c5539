"""Creep: slow, distributed relaxation of the displacement after the drive changes."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Mapping

import numpy as np
from scipy import optimize

from ..model_reach import model_reach_um
from . import kernels as K
from .base import (BatchSignals, CoreAround, EffectBase, FitData, Regressors, SignatureCheck, SignatureFailure,
                   StepSignals, finite, geom_refine, grid_ratio, positive, time_steps)
from .thermal import THERMAL_FAST_RATIO

CREEP_SPREAD = (0.1, 1.0, 10.0)   # time constants relative to tau_s: a distributed (log-like) relaxation
MIN_CREEP_TAU_S = 1.0             # creep's central time constant (its components span 0.1x..10x of it)


@dataclass(frozen=True)
class FromRest:
    """A creep search point with no creep under way at any recording's start (`rest_form`): the
    form creep's fit takes unless the start terms earn their place as an effect must
    (`EffectSelector._start_earned`), or when they hold more than creep of its gain can
    (`start_beyond_reach`). Such a start is another slow drift, and a recording from rest holds no
    start at all. hil_sim's heating and creep on steps: the start took heating's rise (-2.31 um,
    where 1.66 um is the most), and creep was set aside; from rest, both are named, 0.066 -> 0.021
    um held out."""

    inner: Any        # the point itself: a central time constant, or (tau, gain) with the loops' law


def _inner(p: Any) -> Any:
    return p.inner if isinstance(p, FromRest) else p


class Creep(EffectBase):
    name: ClassVar[str] = "creep"
    keys: ClassVar[tuple[str, ...]] = ("creep",)
    block_keys: ClassVar[Mapping[str, tuple[str, ...]]] = {"creep": ("gain", "tau_s")}
    stage: ClassVar[str] = "sum"
    follows_drive: ClassVar[bool] = True    # lag(y_c) - y_c: at a loop's rate, a loss of gain the base absorbed
    position: ClassVar[int] = 60
    inverted: ClassVar[Mapping[str, str]] = {"creep": "exact (closed form with the static map)"}
    physics: ClassVar[str] = "slow relaxation of the displacement after the drive changes, in the direction of the last change"
    n_params: ClassVar[int] = 2
    slow: ClassVar[bool] = True
    # Beside creep, heating keeps one time constant (its faster part and creep are look-alikes:
    # `thermal.Thermal.columns`). A heating fitted before creep joined split into a slow part and a
    # part 8x faster; left at the slow one, creep could not join: hil_sim's heating (60 s) and creep
    # on one 240 s run, heating at 343 s plus 43 s, was 0.100 um held out, and 0.148-0.45 um with
    # creep beside its slow part alone. So heating's time constant is searched again with creep, from
    # its faster part's (1/8) to its own, with the two's geometric middle (0.35) between; the zoom
    # refines the scale.
    rescales: ClassVar[tuple[str, ...]] = ("thermal_drift",)
    joint_scales: ClassVar[tuple[float, ...]] = (THERMAL_FAST_RATIO, 0.35, 1.0)
    rest_form: ClassVar[Callable[[Any], Any] | None] = FromRest

    def __init__(self, block: Mapping[str, Any]) -> None:
        super().__init__(block)
        self.gain = finite(block, "gain", "creep")
        self.tau_s = positive(block, "tau_s", "creep")

    def apply(self, y: np.ndarray, sig: BatchSignals) -> np.ndarray:
        return y + self.gain * relaxation(sig.yc, sig.dt, self.tau_s)

    def state(self, dt: float, stress_ref: float, inverse: bool) -> "_CreepState":
        return _CreepState(self.gain, [K.lag_coeff(dt, self.tau_s * k) for k in CREEP_SPREAD])

    # ---- diagnosis
    @classmethod
    def reshapes(cls, fitter: FitData) -> bool:
        """With identification loops that show creep, it is material behaviour: the core is identified
        again through it (the base absorbed the loops' creep into their shape). Loops that show none
        leave its gain to the recordings diagnosed, as without them (`law_from_loops`)."""
        return law_from_loops(fitter)

    @classmethod
    def grid(cls, fitter: FitData) -> Any:
        """Creep's central time constants; with the identification loops, each with the gain those
        loops show at it (`loop_gain`): the core is identified again through that law. The loops
        fit the gain, the recordings diagnosed choose the time constant: 3 s loops cannot tell 1 s
        from 3 s (a drawn actuator's loops preferred the fastest by 4 % in RSS, where the plant's
        middle part is at 3 s), a recording tens of seconds long can."""
        taus = time_constants(fitter)
        return [_with_loop_gain(fitter, float(t)) for t in taus] if law_from_loops(fitter) else taus

    @classmethod
    def refine(cls, fitter: FitData, p: Any, level: int) -> list[Any] | None:
        """Around p by the spacing of creep's own grid, which follows the recording. With the loops,
        one zoom level (tau to about 10 %: a factor of three off still carried 4x on the probes), as
        each point there is an identification of the core. Within the grid's span: a central time
        constant beyond half the longest recording is a drift the recordings cannot tell from any
        other slow one (heating's)."""
        if isinstance(p, FromRest):
            inner = cls.refine(fitter, p.inner, level)
            return None if inner is None else [FromRest(q) for q in inner]
        from_loops = law_from_loops(fitter)
        if from_loops and level > 1:
            return None
        g = time_constants(fitter)
        taus = [min(max(q, MIN_CREEP_TAU_S), float(g[-1]))
                for q in geom_refine(central_tau(p), grid_ratio(g[0], g[-1], g.size), level)]
        return [_with_loop_gain(fitter, t) for t in taus] if from_loops else taus

    @classmethod
    def fit_core(cls, fitter: FitData, core: Any, p: Any) -> Any:
        """The core identified again on the identification loops through the creep law p (tau, gain),
        with the creep around it; a core another effect already reshaped is kept, creep around it."""
        tau, gain = _inner(p)
        again = fitter.identified_core(creep=(gain, tau)) if core is fitter.model else None
        return CreepingCore(core if again is None else again, gain, tau)

    @classmethod
    def count_params(cls, fitter: FitData) -> int:
        """Its gain and time constant, and each recording's creep at its start (counted from rest
        too: the form was chosen after a fit with them)."""
        return cls.n_params + len(fitter.data)

    @classmethod
    def grid_like(cls, fitter: FitData, p: Any) -> Any:
        grid = cls.grid(fitter)
        return [FromRest(q) for q in grid] if isinstance(p, FromRest) else grid

    @classmethod
    def columns(cls, fitter: FitData, r: Regressors, p: Any) -> None:
        """The creep term per unit gain (with the law, its gain is in the core: `fit_core`), and per
        recording the creep under way at its start: a recording rarely starts from rest, and the
        state its history left decays with creep's time constants. One column: a history slow
        against the drive (any loop faster than creep's fastest part) leaves every part at one level."""
        tau, from_rest, p = central_tau(p), isinstance(p, FromRest), _inner(p)
        if not isinstance(p, tuple):
            r.cols.append(relaxation(r.yc, r.d.dt, p))
            r.names.append("creep_gain")
        if from_rest:
            return
        decay = fitter.cached_table(r.d, ("creep_start", tau), lambda: start_decay(r.d.t, tau))   # shared by a search's specs
        for i, owner in enumerate(fitter.data):
            r.cols.append(decay if owner is r.d else np.zeros_like(decay))
            r.names.append(f"creep_start_{i}")

    @classmethod
    def fitted_params(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, float]:
        from_rest, p = isinstance(p, FromRest), _inner(p)
        tau, gain = p if isinstance(p, tuple) else (p, coef.get("creep_gain", float("nan")))
        return {"tau_s": float(tau), "gain": float(gain), **({"from_rest": 1.0} if from_rest else {})}

    @classmethod
    def fitted_blocks(cls, fitter: FitData, p: Any, coef: Mapping[str, float]) -> dict[str, dict[str, Any]]:
        law = cls.fitted_params(fitter, p, coef)
        return {"creep": {"gain": law["gain"], "tau_s": law["tau_s"]}}

    @classmethod
    def signature(cls, check: SignatureCheck) -> SignatureFailure | None:
        """Creep is motion that goes on after the drive stops changing: its term, lag(y_c) - y_c, is
        largest where the drive turns round or holds, so its gain must show there. On the slowest
        40 % of samples it must cut the error by as much as a rate-independent effect must
        (`slow_ratio_max`); a gain from the fast parts alone is the refit of the other columns
        absorbing a loop shape the core cannot follow.

        A fit whose central time constant runs to the fastest the search allows (its fastest part at
        0.1 s) wants a quicker relaxation than creep's: a lag look-alike that a leftover of eddy
        currents, a delay or the core's own shape gives as well, and a law not determined by the data.
        On simulated actuators with nothing missing, creep fitted to rising-amplitude sines runs there.

        Creep goes on in the direction of the drive's last change (a positive gain: the displacement
        reaches part of a step at once and the rest over time). A fit that overshoots each change and
        relaxes back against it (a negative gain) is not creep: on a short run, heating's slow rise
        fits that way (a 7.8 s heating recording was named creep at -2.3 % before this rule)."""
        gain = float(check.params.get("gain", 0.0))
        if gain < 0.0:
            return SignatureFailure(
                f"its fit relaxes against the drive's last change (a gain of {gain * 100:+.3g} % of each step), where "
                "creep goes on in that direction: a slow drift of another cause (heating) or of the model's own shape")
        beyond = start_beyond_reach(check, gain)
        if beyond is not None:
            name, start, most = beyond
            return SignatureFailure(
                f"its fit puts {start:+.3g} um of creep under way at the start of {name}, more than creep of that gain "
                f"can hold ({most:.3g} um, over the model's whole stroke): a slow drift of another cause (heating) "
                "fitted as creep left by the recording's unknown history", variant=cls.rest_form)
        tau = central_tau(check.result.specs[2][cls.name])
        fastest = float(time_constants(check.fitter)[0])
        if tau <= fastest * (1.0 + 1e-9):
            return SignatureFailure(
                f"its fit runs to the fastest time constant creep may have ({fastest:.3g} s, its fastest part "
                f"{fastest * CREEP_SPREAD[0]:.2g} s): the relaxation the data want is quicker than creep, a lag that a "
                "leftover of another effect or of the model's own shape gives as well")
        return check.gain_from_fast_parts("creep shows most where the drive stops changing, so this is the "
                                          "leftover of a loop shape the model cannot follow")

    @staticmethod
    def describe(params: Mapping[str, float], unit: str) -> str:
        text = (f"creep of {params['gain'] * 100:+.3g} % of each step relaxing over time constants around "
                f"{params['tau_s']:.3g} s (0.1x to 10x)")
        if params.get("from_rest"):
            text += (", fitted from rest, as a model file runs it: creep under way at the runs' starts did "
                     "not earn its place in the fit, or held more than creep of its gain can (a slow drift of "
                     "another cause)")
        return text


def start_beyond_reach(check: SignatureCheck, gain: float) -> tuple[str, float, float] | None:
    """(recording, its fitted creep under way at the start in um, the most creep of `gain` holds) for
    the recording whose start term is largest against that, when it is beyond it; else None.

    The creep term is gain x mean_k(lag(y_c) - y_c), and a lag of y_c stays within y_c's range: so
    whatever history came before, the creep at a start is at most gain x the core's stroke (the
    larger of the model's reach over its identified drive range and the recordings' own). A start
    beyond it is a drift of another kind: hil_sim's realistic actuator on steps (heating beside
    creep) fitted -6.96 um at the start against 3.8 um at most, the heating's rise taken as creep
    dying away; the extended model file, which carries no start, then missed by 3.1 um."""
    coef = dict(zip(check.result.names, check.result.coef_all))
    starts = [(d.name, float(coef.get(f"creep_start_{i}", 0.0))) for i, d in enumerate(check.fitter.data)]
    name, start = max(starts, key=lambda pair: abs(pair[1]), default=("", 0.0))
    if start == 0.0:
        return None
    cores = check.fitter.core(check.result.specs[2])
    most = abs(gain) * max([float(np.ptp(yc)) for _, yc in cores if yc.size] + [_reach(check.model)])
    return (name, start, most) if abs(start) > most else None


def _reach(model: Any) -> float:
    """The model's largest |output| over its identified drive range (0 when that is not finite)."""
    reach = model_reach_um(model)
    return reach if math.isfinite(reach) else 0.0


def central_tau(p: Any) -> float:
    """Creep's central time constant from a search point: tau, or (tau, gain) with the loops' law."""
    p = _inner(p)
    return float(p[0] if isinstance(p, tuple) else p)


def time_constants(fitter: FitData) -> np.ndarray:
    """Creep's grid of central time constants. Creep is slow: its fastest component (tau / 10) is no
    quicker than 0.1 s, else it is a lag look-alike; its central one is at most half the recording.
    Twelve points; seven with the identification loops, where each point is an identification of
    the core (a ratio of 1.65 on a 40 s recording, about 10 % in tau after one zoom). Loops that
    show no creep (`law_from_loops`) keep the seven: they were asked at those points, and the
    zoom reaches the twelve's figure (0.0731 um held out both ways on hil_sim's default creep)."""
    lo = max(20 * fitter.dt_min, MIN_CREEP_TAU_S)
    hi = max(fitter.duration_max / 2, 2 * lo)
    return np.geomspace(lo, hi, 7 if fitter.identification else 12)


def creep_inverse(y: np.ndarray, dt: np.ndarray, gain: float, tau_s: float) -> np.ndarray:
    """The core output that creep turns into y (the exact inverse of `Creep.apply`)."""
    taus = np.array([tau_s * k for k in CREEP_SPREAD])
    return K.creep_inverse(np.ascontiguousarray(y, dtype=float), np.ascontiguousarray(dt, dtype=float),
                           float(gain), taus)


def start_decay(t: np.ndarray, tau_s: float) -> np.ndarray:
    """mean_k exp(-(t - t_0) / (tau s_k)): how the creep under way at a recording's start dies away."""
    since = t - t[0]
    return np.mean([np.exp(-since / (tau_s * k)) for k in CREEP_SPREAD], axis=0)


def relaxation(yc: np.ndarray, dt: np.ndarray, tau_s: float) -> np.ndarray:
    """mean_k (lag(y_c, tau s_k) - y_c): the creep term per unit gain."""
    acc = np.zeros_like(yc)
    for k in CREEP_SPREAD:
        acc += K.lag_filter(yc, dt, tau_s * k, float(yc[0])) - yc
    return acc / len(CREEP_SPREAD)


class _CreepState:
    """Forward: the lags of y_c. Inverse: their term g mean_k a_k (z_k - yc) is linear in this sample's
    y_c, so it joins the static map's closed-form root (exact)."""

    def __init__(self, gain: float, a: list[float]) -> None:
        self.g = gain
        self.a = a
        self.z = [0.0] * len(a)
        self.first = True

    def reset(self, initial_drive: float) -> None:
        for k in range(len(self.z)):
            self.z[k] = 0.0
        self.first = True

    def step(self, x: StepSignals) -> None:
        yc = x.yc
        acc = 0.0
        for k in range(len(self.z)):
            z = yc if self.first else self.a[k] * self.z[k] + (1.0 - self.a[k]) * yc
            self.z[k] = z
            acc += z - yc
        x.y += self.g * acc / len(self.z)
        self.first = False

    def inverse_step(self, x: StepSignals) -> None:
        if self.first:
            return
        n = len(self.z)
        ga = 0.0
        zc = 0.0
        for k in range(n):
            ga += self.g * self.a[k] / n
            zc += self.g * self.a[k] * self.z[k] / n
        x.const += zc
        x.lin -= ga

    def commit(self, x: StepSignals) -> None:
        yc = x.yc
        for k in range(len(self.z)):
            self.z[k] = yc if self.first else self.a[k] * self.z[k] + (1.0 - self.a[k]) * yc
        self.first = False


class CreepingCore(CoreAround):
    """A core with creep around it: what the diagnosis runs while it judges a creep law whose
    core was identified again through it (`Creep.fit_core`). Only the batch simulation: the
    extended model puts the creep block after the plain core itself."""

    def __init__(self, base: Any, gain: float, tau_s: float) -> None:
        self.base = base
        self.gain = float(gain)
        self.tau_s = float(tau_s)

    def simulate(self, time_s: Any, drive: Any, stress_MPa: Any = None, **start: Any) -> np.ndarray:
        y = np.asarray(self.base.simulate(time_s, drive, stress_MPa, **start), dtype=float)
        return y + self.gain * relaxation(y, time_steps(time_s)[0], self.tau_s)


# the law on the identification loops: gains of 0 to half of each step (past half, the slow part of the
# response would be the larger: not a creep of the stroke), its time constant between the neighbours
# of the best point of creep's own grid
CREEP_GAIN_MAX = 0.5
CREEP_GAIN_TOL = 1e-3             # a tenth of a percent of each step: far below what a probe can tell
LOOPS_SHOW_NO_CREEP = 2 * CREEP_GAIN_TOL   # a loops' gain below it is zero within the bounded search's tolerance
                                          # (it never evaluates the bound itself); hil_sim's default creep (3 x 0.01) is 15x it


def loop_gain(fitter: FitData, tau: float) -> float:
    """Creep's gain at central time constant tau, as the identification loops show it. The core
    identified again through creep is a hysteresis whose output the creep filters; here that core
    is stood in for by a linear family around the base (per loop: the base's output and its square,
    plays at the base's thresholds, an offset), so the gain is the minimiser of a least-squares
    profile over y = (1 + gain R_tau)[X] w, not an identification per point. Every sample of a loop
    counts, from its first: identification runs start from rest, and the first second after the
    drive starts is where creep's fast part shows (the gain from the settled rows alone came out
    38 % high on a drawn actuator)."""
    loops = fitter.cached(("creep_loops",), lambda: [_linear_family(fitter, d) for d in fitter.identification])
    return _gain_profile(loops, tau)[1]


def law_from_loops(fitter: FitData) -> bool:
    """Whether creep's law comes from the identification loops: they are given, and show creep at one
    time constant of its grid at least. Loops recorded without it (an actuator identified before its
    creep showed, or a simulated one with creep switched off there) give a gain within the gain
    search's tolerance of zero at every one. Tied to those loops, creep could then not be named at
    all, and a look-alike (heating) took its place; its gain is then fitted on the recordings
    diagnosed, as without the loops."""
    if not fitter.identification:
        return False
    return fitter.cached(("creep_in_loops",), lambda: max(
        _with_loop_gain(fitter, float(t))[1] for t in time_constants(fitter)) > LOOPS_SHOW_NO_CREEP)


def _with_loop_gain(fitter: FitData, tau: float) -> tuple[float, float]:
    """(tau, the loops' gain at it), tau on the lattice of the grid and its zooms, to four significant
    digits: one identification per point, and zooms from two best points that land on the same tau
    share it (rounding alone let 4.208 s and 4.207 s, one point, be identified twice)."""
    tau = float(f"{_on_lattice(fitter, tau):.4g}")
    return tau, fitter.cached(("creep_gain", tau), lambda: loop_gain(fitter, tau))


ZOOM_LATTICE = 9      # two zoom levels of geom_refine (3 ** 2 steps per grid spacing)


def _on_lattice(fitter: FitData, tau: float) -> float:
    """tau snapped to the nearest point of creep's grid zoomed twice (`geom_refine`'s steps of a
    ninth of the grid's spacing, in log): a zoom point reached from two rounded centres is one."""
    g = time_constants(fitter)
    log_ratio = np.log(grid_ratio(g[0], g[-1], g.size))
    steps = round(float(np.log(tau / g[0]) / log_ratio) * ZOOM_LATTICE) / ZOOM_LATTICE
    return float(g[0] * np.exp(steps * log_ratio))


def _linear_family(fitter: FitData, d: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(columns X, time steps, displacement) of one identification loop: the stand-in for the core."""
    s = d.s if fitter.model.stress_range_MPa is not None else None
    yc = np.asarray(fitter.model.simulate(d.t, d.u, s, initial_state=d.start), dtype=float)
    th = np.asarray(getattr(fitter.model, "play_thresholds", fitter.play_thresholds), dtype=float)
    plays = K.play_bank(np.ascontiguousarray(d.u, dtype=float), th, float(d.u[0]))
    return np.column_stack([np.ones_like(yc), plays, yc, yc * yc]), d.dt, d.y


def _gain_profile(loops: list[tuple[np.ndarray, np.ndarray, np.ndarray]], tau: float) -> tuple[float, float]:
    """(least residual sum of squares, its gain) over the gains, at creep time constant tau."""
    filtered = [np.column_stack([relaxation(np.ascontiguousarray(x[:, j]), dt, tau) for j in range(x.shape[1])])
                for x, dt, _ in loops]

    def rss(gain: float) -> float:
        out = 0.0
        for (x, _, y), r in zip(loops, filtered):
            a = x + gain * r
            w = np.linalg.lstsq(a, y, rcond=None)[0]
            out += float(np.sum((y - a @ w) ** 2))
        return out

    best = optimize.minimize_scalar(rss, bounds=(0.0, CREEP_GAIN_MAX), method="bounded",
                                    options={"xatol": CREEP_GAIN_TOL})
    return float(best.fun), float(best.x)
