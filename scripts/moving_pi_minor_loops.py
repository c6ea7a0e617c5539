#!/usr/bin/env python3
"""Would a moving PI core follow a case's nested minor loops? (issue 31, after pi_minor_loops.py)

    python scripts/moving_pi_minor_loops.py [CASE ...] [--cache DIR] [--grid 25] [--sdpi-grid 5]
                                            [--parts plays,sdpi] [--preisach]
    (default: the cases of pi_minor_loops.py; on a shared 2-core host about 4 min a case for
    `--parts plays` and 4-10 min a case for `--parts sdpi`, its SDPI identifications and refinements,
    plus about a minute a case to simulate the recordings unless --cache holds them)

The moving PI is the PI analogue of Della Torre's moving Preisach model (the mean-field feedback of
Jiles-Atherton): y = F[x + a (y - y_c)], F a play superposition (with a static part or the SDPI's
dead-zone output map), a a scalar feedback gain of either sign, y_c the fitted data's mid output.
Each sample is an implicit equation, y - F_k(x_k + a (y - y_c)) = 0, F_k the superposition with
the plays' states of the sample before; it is solved by a bracketed secant (Illinois) search from
the previous output, to |residual| < 1e-9 um. A run where some sample found no root (largest
|residual| over 1e-6 um) is not scored (nan); the largest |residual| of the runs quoted is printed.
a is scanned on a grid even in the loop gain g = a s / (1 + a s), s the fitted data's mean slope
dy/dx (g in [-0.9, 0.9], a s from -0.47 to 9); a is printed as a s.

Per case, RMS in um on the light-load probe's two-tone part (`pi_minor_loops.other_shape_probe`):
  head       noise (the plant's displacement noise), base (the case's base model), Preisach 45
             (pi_minor_loops' congruency floor, with --preisach);
  plays only / plays + 6 static, self-fit: plays (20, w >= 0), [6 one-sided static dead-zones of
             the plays' input, free weights: a reversible curve], an offset, fitted on the part by
             bounded linear least squares on the columns of x + a (y_measured - y_c) for each a
             (an equation-error fit), the plays from rest at the probe's start; `a=0` the plain
             class's floor (simulated), `eq` the least equation error (at a_eq), `sim at a_eq` those
             weights simulated (the implicit recursion, its own output fed back: the figure that
             counts), `best sim` the least simulated RMS over the grid (at a_sim);
  plays + 6 static fitted on <ident 15 kg | ident 4 loads | diagnosis rec>: the same fit on the
             identification loop at the probe's load, on all four loops (one set of weights), or on
             the diagnosis recording (from each one's first full sweep), simulated on the whole probe
             and scored on its two-tone part: at a = 0; at a_own, the a of least simulated error on
             the data fitted (what a diagnosis could choose); at a_probe, the best on the probe;
  SDPI (20 plays), self-fit: the SDPI of pi_minor_loops' self-fit identified (SDPIIdentifier) on the
             part's drive x + a (y_measured - y_c) for 5 values of g in [-0.3, 0.9]; `SDPI sf` at a = 0
             (pi_minor_loops' `self-fit 20`), mSDPI eq / sim / best as above, then output-error
             refinement (play weights, the dead-zones' constant weights, the offset; start state
             held): `SDPI oe` with a = 0 held, `mSDPI oe` the least from every grid a >= 0 with a free;
  SDPI (10 plays) fitted on ident 4 loads: the base model's identification with the feedback (at
             a = 0 it is the base), judged on the part, a_own and a_probe as above.
Each scan line lists a s : (equation or own-data error) / (simulated or probe error).
"""

from __future__ import annotations

import argparse
import pickle
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit
from scipy.optimize import least_squares, lsq_linear

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from benchmarks.cases import case_plant, case_recordings  # noqa: E402
from benchmarks.general import general_cases  # noqa: E402
from benchmarks.probes import _prediction  # noqa: E402
from gma_ffc import operators as ops  # noqa: E402
from gma_ffc.errors import InputError  # noqa: E402
from gma_ffc.identify import SDPIIdentifier  # noqa: E402
from pi_minor_loops import DEFAULT, other_shape_probe, preisach_self_fit, rms  # noqa: E402

N_PLAY = 20
N_STATIC = 6              # static (reversible) dead-zones beside the plays
UNSOLVED_UM = 1e-6         # a run whose largest |residual| exceeds this found no root somewhere: not scored
LOOP_GAIN = (-0.9, 0.9)    # the grid: g = a s / (1 + a s), s the fitted data's mean slope dy/dx (a s = g / (1 - g))
SDPI_GAIN = (-0.3, 0.9)    # the moving SDPI's coarser grid


# -- the implicit recursion ------------------------------------------------------------------------
# kind 0: an SDPI's packed parameters (gma_ffc.operators); kind 1: a PlayFit's (see `PlayFit.packed`)

@njit(cache=True, nogil=True)
def _play_static(v: float, p: np.ndarray, state: np.ndarray, commit: bool) -> float:
    n_h, n_e = int(p[0]), int(p[1])
    u = v - p[2]
    y = p[3]
    for i in range(n_h):
        q = ops.play(u, p[4 + i], state[i])
        if commit:
            state[i] = q
        y += p[4 + n_h + i] * q
    for k in range(n_e):
        y += p[4 + 2 * n_h + n_e + k] * ops.deadzone(u, p[4 + 2 * n_h + k])
    return y


@njit(cache=True, nogil=True)
def _output(kind: int, v: float, s: float, p: np.ndarray, state: np.ndarray, commit: bool) -> float:
    if kind == 1:
        return _play_static(v, p, state, commit)
    return ops.forward_step(v, s, p, state) if commit else ops.forward_peek(v, s, p, state)


@njit(cache=True, nogil=True)
def _residual(kind: int, y: float, x: float, s: float, a: float, y_c: float, sign: float, p: np.ndarray,
              state: np.ndarray) -> float:
    return y - sign * _output(kind, x + a * (y - y_c), s, p, state, False)


@njit(cache=True, nogil=True)
def _solve(kind: int, y0: float, x: float, s: float, a: float, y_c: float, sign: float, p: np.ndarray,
           state: np.ndarray) -> float:
    """The root of _residual nearest y0 in the direction the residual points (Illinois)."""
    h0 = _residual(kind, y0, x, s, a, y_c, sign, p, state)
    if h0 == 0.0:
        return y0
    step = -h0
    y1, h1 = y0, h0
    for _ in range(60):                              # expand until the residual changes sign
        y1 = y0 + step
        h1 = _residual(kind, y1, x, s, a, y_c, sign, p, state)
        if h1 * h0 <= 0.0:
            break
        y0, h0, step = y1, h1, 2.0 * step
    if h1 * h0 > 0.0:                                # no sign change (checked by the caller)
        return y1
    lo, hlo, hi, hhi = y0, h0, y1, h1
    y = hi
    for _ in range(200):
        y = 0.5 * (lo + hi) if hhi == hlo else hi - hhi * (hi - lo) / (hhi - hlo)
        h = _residual(kind, y, x, s, a, y_c, sign, p, state)
        if abs(h) < 1e-9 or abs(hi - lo) < 1e-12:
            break
        if h * hhi < 0.0:
            lo, hlo = hi, hhi
        else:
            hlo *= 0.5
        hi, hhi = y, h
    return y


@njit(cache=True, nogil=True)
def moving_run(kind: int, x: np.ndarray, s: np.ndarray, a: float, y_c: float, sign: float, p: np.ndarray,
               state: np.ndarray, out: np.ndarray) -> float:
    """y_k = sign F_k(x_k + a (y_k - y_c)) sample by sample; returns the largest |residual|."""
    y = y_c
    worst = 0.0
    for k in range(x.shape[0]):
        y = _solve(kind, y, x[k], s[k], a, y_c, sign, p, state)
        worst = max(worst, abs(_residual(kind, y, x[k], s[k], a, y_c, sign, p, state)))
        out[k] = sign * _output(kind, x[k] + a * (y - y_c), s[k], p, state, True)
    return worst


# -- plays (and a reversible static part) fitted by bounded linear least squares ------------------

class PlayFit:
    """y = c + sum_i w_i H_{r_i}[v - v_c] + sum_k b_k S_{e_k}[v - v_c], w >= 0, b free: plays from
    rest at v[0], and n_static one-sided dead-zones of v (a reversible curve, the loops' bend)."""

    def __init__(self, v_lo: float, v_hi: float, n_static: int) -> None:
        self.v_c = 0.5 * (v_lo + v_hi)
        half = 0.5 * (v_hi - v_lo)
        self.r = np.arange(N_PLAY) * half / N_PLAY
        side = np.arange(1, n_static // 2 + 1) * half / (n_static // 2 + 1)
        self.e = np.r_[-side[::-1], side]

    def columns(self, v: np.ndarray) -> np.ndarray:
        out = np.empty((v.size, N_PLAY))
        u = np.ascontiguousarray(v - self.v_c)
        ops.play_outputs(u, self.r, np.full(N_PLAY, u[0]), out)
        static = [np.maximum(u - e, 0.0) if e > 0 else np.minimum(u - e, 0.0) for e in self.e]
        return np.column_stack([out, *static, np.ones(v.size)])

    def fit(self, A: np.ndarray, y: np.ndarray) -> float:
        """Weights and offset on rows A (of `columns`); returns the equation-error RMS."""
        lb = np.r_[np.zeros(N_PLAY), np.full(self.e.size + 1, -np.inf)]
        scale = np.maximum(np.linalg.norm(A, axis=0), 1e-12)
        x = lsq_linear(A / scale, y, bounds=(lb, np.inf), method="bvls").x / scale
        self.w, self.b, self.c = x[:N_PLAY], x[N_PLAY:-1], float(x[-1])
        return rms(A @ x - y)

    def packed(self) -> np.ndarray:
        return np.r_[N_PLAY, self.e.size, self.v_c, self.c, self.r, self.w, self.e, self.b].astype(float)

    def simulate(self, x: np.ndarray, a: float, y_c: float) -> tuple[np.ndarray, float]:
        """The moving run on drive x, the plays from rest at their first input."""
        out = np.empty(x.size)
        state = np.full(N_PLAY, x[0] - self.v_c)
        worst = moving_run(1, np.ascontiguousarray(x), np.zeros(x.size), a, y_c, 1.0, self.packed(), state, out)
        return out, worst


# -- the fits on one stretch of data ---------------------------------------------------------------

def a_grid(x: np.ndarray, y: np.ndarray, n: int, gain: tuple[float, float] = LOOP_GAIN) -> np.ndarray:
    """n values of a, evenly spaced in the loop gain g = a s / (1 + a s) (the share of the
    fed-back input in the plays' input along the mean slope s)."""
    g = np.linspace(*gain, n)
    return g / (1.0 - g) * np.ptp(x) / np.ptp(y)


def moving_pi_scan(runs: list[tuple[np.ndarray, np.ndarray, np.ndarray]], grid: np.ndarray, n_static: int,
                   judge: tuple[np.ndarray, np.ndarray] | None = None) -> list[dict]:
    """For each a: a PlayFit on the columns of x + a (y - y_c) over `runs` (each (x, y, rows fitted)),
    its equation error, its simulated error on the fitted rows, and simulated on `judge` (x, rows)."""
    y_all = np.concatenate([y[rows] for _, y, rows in runs])
    y_c = 0.5 * (y_all.min() + y_all.max())
    out = []
    for a in grid:
        vs = [x + a * (y - y_c) for x, y, _ in runs]
        pf = PlayFit(min(v.min() for v in vs), max(v.max() for v in vs), n_static)
        H = np.vstack([pf.columns(v)[rows] for v, (_, _, rows) in zip(vs, runs)])
        row = {"a": a, "eq": pf.fit(H, y_all), "fit": pf, "y_c": y_c}
        sims = [pf.simulate(x, a, y_c) for x, _, _ in runs]
        row["sim"] = rms(np.concatenate([ys[rows] - y[rows] for (ys, _), (_, y, rows) in zip(sims, runs)]))
        row["residual"] = max(w for _, w in sims)
        if judge is not None:
            yj, wj = pf.simulate(judge[0], a, y_c)
            row["judge"], row["residual"] = yj[judge[1]], max(row["residual"], wj)
        if not row["residual"] < UNSOLVED_UM:      # some sample's equation had no root near the last output
            row["sim"], row["judge"] = np.nan, np.nan
        out.append(row)
    return out


def feedback_drive(rec, a: float, y_c: float) -> np.ndarray:
    """x + a (y_measured - y_c): the drive a moving model's plays see, with the measured output fed back."""
    return rec.drive + a * (rec.displacement_um - y_c)


def fit_sdpi(recs: list, a: float, y_c: float, n_play: int):
    """The SDPI identified (SDPIIdentifier, n_play plays) on the drives x + a (y_measured - y_c):
    the moving SDPI's equation-error fit; None where the identifier refuses that drive."""
    try:
        return SDPIIdentifier(n_play=n_play).fit(
            [r.with_column(r.drive_name, feedback_drive(r, a, y_c)) for r in recs]).model_
    except InputError:                # too little of y follows the drive (a near -1 / slope)
        return None


def sdpi_start(model, rec, a: float, y_c: float) -> tuple[np.ndarray, np.ndarray]:
    """The clamped stress and the play state estimated from the measurement on the fed-back drive."""
    s = rec.stress_MPa
    if model.stress_range_MPa is not None:
        s = np.clip(s, *model.stress_range_MPa)
    _, s, state = model.batch_start(rec.time_s, feedback_drive(rec, a, y_c), s, measured_um=rec.displacement_um)
    return s, state


def sdpi_run(model, rec, a: float, y_c: float, p: np.ndarray | None = None,
             start: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, float]:
    """The moving SDPI simulated on rec (its own output fed back) and the largest |residual|."""
    s, state = sdpi_start(model, rec, a, y_c) if start is None else start
    out = np.empty(len(rec))
    worst = moving_run(0, np.ascontiguousarray(rec.drive), s, a, y_c, float(model.output_sign),
                       model._packed if p is None else p, state.copy(), out)
    return out, worst


def refine(model, rec, a: float, y_c: float, free_a: bool) -> tuple[float, float]:
    """Output-error refinement on rec of the play weights (>= 0), the dead-zones' constant weights,
    the output offset and (if free_a) a, from the equation-error fit; the start state held.
    Returns (simulated RMS, a)."""
    n_h, n_s = model.n_play, model.n_deadzone
    idx = np.r_[ops.HEADER + n_h + np.arange(n_h), ops.HEADER + 4 * n_h + n_s + np.arange(n_s), 5]
    p0 = model._packed.copy()
    start = sdpi_start(model, rec, a, y_c)
    y = rec.displacement_um
    scale_a = np.ptp(rec.drive) / np.ptp(y)

    def unpack(theta: np.ndarray) -> tuple[np.ndarray, float]:
        p = p0.copy()
        p[idx] = theta[: idx.size]
        return p, (a + theta[-1] * scale_a if free_a else a)

    def resid(theta: np.ndarray) -> np.ndarray:
        p, aa = unpack(theta)
        return sdpi_run(model, rec, aa, y_c, p, start)[0] - y

    theta0 = np.r_[p0[idx], [0.0] if free_a else []]
    lb = np.r_[np.zeros(n_h), np.full(theta0.size - n_h, -np.inf)]
    sol = least_squares(resid, theta0, bounds=(lb, np.inf), x_scale="jac", max_nfev=40, diff_step=1e-4)
    return rms(sol.fun), unpack(sol.x)[1]


# -- one case ----------------------------------------------------------------------------------------

def case_data(case, cache: Path | None) -> dict:
    """The case's base model, identification loops, diagnosis recording and light-load probe."""
    path = None if cache is None else cache / f"{case.name.replace(':', '_').replace('@', '_')}.pkl"
    if path is not None and path.exists():
        return pickle.loads(path.read_bytes())
    model, ident, rec = case_recordings(case)
    probe, keep = other_shape_probe(case)
    d = {"model": model, "ident": ident, "rec": rec, "probe": probe, "keep": keep}
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(pickle.dumps(d))
    return d


def noise_um(case) -> float:
    nz = case_plant(case).noise
    return float(np.hypot(nz.displacement_std_um, nz.displacement_quantum_um / np.sqrt(12.0)))


def plays_fit(d: dict, n_grid: int, n_static: int) -> dict:
    """The moving PI (plays, and n_static static dead-zones) on the two-tone part, from the probe's rest."""
    probe, keep = d["probe"], d["keep"]
    x, y = probe.drive, probe.displacement_um
    rows = np.flatnonzero(keep)
    scan = moving_pi_scan([(x, y, rows)], a_grid(x[rows], y[rows], n_grid), n_static)
    plain = min(scan, key=lambda r: abs(r["a"]))
    by_eq, by_sim = best(scan, "eq"), best(scan, "sim")
    return {"a=0": plain["sim"], "eq": by_eq["eq"], "sim at a_eq": by_eq["sim"], "a_eq": by_eq["a"],
            "best sim": by_sim["sim"], "a_sim": by_sim["a"], "residual": by_sim["residual"],
            "scan": [(r["a"], r["eq"], r["sim"]) for r in scan]}


def sdpi_scan(recs: list, judge, grid: np.ndarray, y_c: float, n_play: int) -> list[dict]:
    """For each a: the moving SDPI fitted on recs (equation error), its error on recs without
    feedback (`eq`, the measured output fed in) and simulated (`own`), and simulated on `judge`."""
    out = []
    for a in grid:
        model = fit_sdpi(recs, a, y_c, n_play)
        if model is None:
            out.append({"a": a, "eq": np.nan, "own": np.nan, "judge": np.nan, "model": None, "residual": 0.0})
            continue
        y = np.concatenate([r.displacement_um for r in recs])
        eq = np.concatenate([_prediction(model, r.with_column(r.drive_name, feedback_drive(r, a, y_c))) for r in recs])
        runs = [sdpi_run(model, r, a, y_c) for r in recs]
        jy, jw = sdpi_run(model, judge, a, y_c)
        worst = max([jw] + [w for _, w in runs])
        solved = 1.0 if worst < UNSOLVED_UM else np.nan
        out.append({"a": a, "eq": rms(eq - y), "own": solved * rms(np.concatenate([o for o, _ in runs]) - y),
                    "judge": solved * rms(jy - judge.displacement_um), "model": model, "residual": worst})
    return out


def best(scan: list[dict], key: str) -> dict:
    return min(scan, key=lambda r: np.nan_to_num(r[key], nan=np.inf))


def sdpi_self_fit(d: dict, n_grid: int) -> dict:
    """The moving SDPI on the two-tone part: grid of a (equation error, simulated), then output-error
    refinement at a = 0 (a held) and from every grid value a >= 0 (a free); the least of those."""
    part = d["probe"].rows(d["keep"], "two_tone")
    y = part.displacement_um
    y_c = 0.5 * (y.min() + y.max())
    scan = sdpi_scan([part], part, a_grid(part.drive, y, n_grid, SDPI_GAIN), y_c, N_PLAY)
    plain, by_eq, by_sim = min(scan, key=lambda r: abs(r["a"])), best(scan, "eq"), best(scan, "own")
    oe0, _ = refine(plain["model"], part, 0.0, y_c, free_a=False)
    refined = [refine(r["model"], part, r["a"], y_c, free_a=True) for r in scan if r["a"] >= 0 and r["model"]]
    oe, a_oe = min(refined)
    return {"SDPI sf": plain["own"], "mSDPI eq": by_eq["eq"], "mSDPI sim": by_eq["own"], "a_eq": by_eq["a"],
            "mSDPI best": by_sim["own"], "a_best": by_sim["a"], "SDPI oe": oe0, "mSDPI oe": oe, "a_oe": a_oe,
            "residual": by_sim["residual"], "scan": [(r["a"], r["eq"], r["own"]) for r in scan],
            "refined": refined}


def sdpi_transfer(d: dict, n_grid: int) -> dict:
    """The moving SDPI (10 plays, as the base: at a = 0 it is the base model) identified on the four
    identification loops, judged on the probe's two-tone part (both from estimated starts)."""
    part = d["probe"].rows(d["keep"], "two_tone")
    recs = d["ident"]
    y = np.concatenate([r.displacement_um for r in recs])
    x = np.concatenate([r.drive for r in recs])
    scan = sdpi_scan(recs, part, a_grid(x, y, n_grid, SDPI_GAIN), 0.5 * (y.min() + y.max()), 10)
    plain, own, top = min(scan, key=lambda r: abs(r["a"])), best(scan, "own"), best(scan, "judge")
    return {"a=0 own": plain["own"], "a=0 probe": plain["judge"], "a_own": own["a"], "own": own["own"],
            "probe at a_own": own["judge"], "a_probe": top["a"], "best probe": top["judge"],
            "residual": max(own["residual"], top["residual"]), "scan": [(r["a"], r["own"], r["judge"]) for r in scan]}


def transfer(d: dict, recs: list, n_grid: int, n_static: int) -> dict:
    """The moving PI (plays and static dead-zones) fitted on recs (from the first full sweep on),
    judged on the probe's two-tone part (run from the probe's rest)."""
    probe, keep = d["probe"], d["keep"]
    runs = [(r.drive, r.displacement_um, settled_rows(r.drive)) for r in recs]
    x = np.concatenate([x[rows] for x, _, rows in runs])
    y = np.concatenate([y[rows] for _, y, rows in runs])
    scan = moving_pi_scan(runs, a_grid(x, y, n_grid), n_static, judge=(probe.drive, keep))
    for r in scan:
        r["probe"] = rms(r["judge"] - probe.displacement_um[keep])
    plain, own, top = min(scan, key=lambda r: abs(r["a"])), best(scan, "sim"), best(scan, "probe")
    return {"a=0 own": plain["sim"], "a=0 probe": plain["probe"], "a_own": own["a"], "own": own["sim"],
            "probe at a_own": own["probe"], "a_probe": top["a"], "best probe": top["probe"],
            "residual": max(own["residual"], top["residual"]),
            "scan": [(r["a"], r["sim"], r["probe"]) for r in scan]}


def settled_rows(x: np.ndarray) -> np.ndarray:
    """Rows after the drive's first sweep to both ends of its range (the plays' rest forgotten)."""
    lo, hi = x.min() + 0.02 * np.ptp(x), x.max() - 0.02 * np.ptp(x)
    first_lo, first_hi = int(np.argmax(x <= lo)), int(np.argmax(x >= hi))
    return np.arange(max(first_lo, first_hi), x.size)


def fmt(row: dict, slope: float) -> str:
    """Figures in um; keys a_* as a times the part's mean slope."""
    return ", ".join(f"{k} {v * slope:+.2f}" if k.startswith("a_") else f"{k} {v:.3f}"
                     for k, v in row.items() if k not in ("scan", "residual", "refined"))


def print_scan(label: str, scan: list, slope: float) -> None:
    print(f"    a*slope:{label} " + " ".join(f"{a * slope:+.2f}:{e:.3f}/{m:.3f}" for a, e, m in scan), flush=True)


def print_plays(d: dict, n_grid: int, slope: float) -> None:
    for label, n_static in (("plays only", 0), (f"plays + {N_STATIC} static", N_STATIC)):
        pf = plays_fit(d, n_grid, n_static)
        print(f"  {label}, self-fit: {fmt(pf, slope)}; max |residual| {pf['residual']:.0e} um", flush=True)
        print_scan("eq/sim", pf["scan"], slope)
    sources = {"ident 15 kg": [d["ident"][1]], "ident 4 loads": d["ident"], "diagnosis rec": [d["rec"]]}
    for label, recs in sources.items():
        tr = transfer(d, recs, n_grid, N_STATIC)
        print(f"  plays + {N_STATIC} static fitted on {label}, probe = two-tone part: {fmt(tr, slope)}; "
              f"max |residual| {tr['residual']:.0e} um", flush=True)
        print_scan("own/probe", tr["scan"], slope)


def print_sdpi(d: dict, n_grid: int, slope: float) -> None:
    sd = sdpi_self_fit(d, n_grid)
    print(f"  SDPI ({N_PLAY} plays), self-fit: {fmt(sd, slope)}; max |residual| {sd['residual']:.0e} um", flush=True)
    print_scan("eq/sim", sd["scan"], slope)
    print("    refined from a >= 0 (a*slope:rms) " + " ".join(f"{a * slope:+.2f}:{e:.3f}" for e, a in sd["refined"]),
          flush=True)
    st = sdpi_transfer(d, n_grid)
    print(f"  SDPI (10 plays) fitted on ident 4 loads, probe = two-tone part: {fmt(st, slope)}; "
          f"max |residual| {st['residual']:.0e} um", flush=True)
    print_scan("own/probe", st["scan"], slope)


def print_case(name: str, case, d: dict, n_grid: int, sdpi_grid: int, preisach: bool, parts: str) -> None:
    t0 = time.time()
    part = d["probe"].rows(d["keep"], "two_tone")
    slope = np.ptp(part.displacement_um) / np.ptp(part.drive)
    head = {"noise": noise_um(case), "base": rms(_prediction(d["model"], part) - part.displacement_um)}
    if preisach:
        head["Preisach 45"] = preisach_self_fit(case, 45)
    print(f"{name}: two-tone part ({np.ptp(part.displacement_um):.1f} um, mean slope {slope:.1f} um/A; "
          f"a given as a*slope), RMS um: {fmt(head, slope)}", flush=True)
    if "plays" in parts:
        print_plays(d, n_grid, slope)
    if sdpi_grid and "sdpi" in parts:
        print_sdpi(d, sdpi_grid, slope)
    print(f"  ({time.time() - t0:.0f} s)", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*", default=list(DEFAULT))
    ap.add_argument("--grid", type=int, default=25, help="values of a on the moving PI's grid")
    ap.add_argument("--cache", type=Path, help="keep each case's recordings here (pickles) between runs")
    ap.add_argument("--sdpi-grid", type=int, default=5, help="values of a for the moving SDPI (0: none; ~30 s each)")
    ap.add_argument("--parts", default="plays,sdpi", help="plays (the linear fits and their transfer), sdpi, or both")
    ap.add_argument("--preisach", action="store_true", help="also the 45-level Preisach floor (slow)")
    args = ap.parse_args()
    by_name = {c.name: c for c in general_cases()}
    for name in args.cases:
        case = by_name[name]
        print_case(name, case, case_data(case, args.cache), args.grid, args.sdpi_grid, args.preisach, args.parts)


if __name__ == "__main__":
    main()
