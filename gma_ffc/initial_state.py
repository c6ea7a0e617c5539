"""The hysteresis state at the first sample of a run: one rule shared by every model run.

A recording almost never starts with the actuator relaxed: it starts in the middle of a history
the file does not show. Each play operator's output at the first sample can be anywhere in
[x0 - r, x0 + r], and until the drive has swept 2 r past it, that unknown value shows in the
output. This module says which state to start from and from which sample on the choice no
longer matters. Pure maths: no I/O.

The rules (`InitialStateSpec`):
  - ``relaxed``: every play centred on the first drive value (an actuator demagnetised or
    depoled there).
  - ``drive:V``: relaxed at drive V, then moved to the first sample (a rig known to rest at V).
  - ``estimate`` (the default of simulate, invert, diagnose and the controller): with a measured
    displacement, the play states that best reproduce it until they are settled (a bounded
    least-squares fit, started from the monotone-stretch rule); without one, the states
    consistent with the first monotone stretch of the drive: a drive that first rises starts
    with every play as low as it can be (x0 - r), as if it had come up to x0; one that first
    falls, as high (x0 + r). "As it can be" is bounded by the model's drive range: a drive that
    has stayed within [lo, hi] leaves a play of threshold r between lo + r and hi - r (after a
    sweep to lo it sits at lo + r, not lo - r), so a run that starts at the bottom of the range
    starts at the major loop's corner, not below the loop (`monotone_play_state`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

KINDS = ("relaxed", "estimate", "drive", "plays")
DEFAULT = "estimate"


@dataclass(frozen=True)
class InitialStateSpec:
    """What the user asked for (``--initial-state relaxed|estimate|drive:VALUE|plays:FILE``).

    A ``plays`` spec holds the play outputs themselves (`plays`, the model's play units: drive -
    input_offset) and the file they came from (`source`); `gma_ffc.known_state.read_play_state`
    makes one, since `parse` does no I/O."""

    kind: str = DEFAULT
    drive: float | None = None
    plays: tuple[float, ...] | None = None
    source: str | None = None

    @classmethod
    def parse(cls, text: "str | InitialStateSpec") -> "InitialStateSpec":
        if isinstance(text, InitialStateSpec):
            return text
        t = str(text).strip()
        if t in ("relaxed", "estimate"):
            return cls(t)
        if t.startswith("drive:"):
            try:
                v = float(t.split(":", 1)[1])
            except ValueError:
                v = float("nan")
            if np.isfinite(v):
                return cls("drive", v)
        if t.startswith("plays:"):
            raise ValueError(f"initial state {text!r}: a known state (plays:FILE) is taken by gma-ffc "
                             "diagnose only (its file is read by gma_ffc.known_state); use relaxed, estimate "
                             "or drive:VALUE")
        raise ValueError(f"initial state {text!r}: use relaxed, estimate or drive:VALUE (e.g. drive:0)")

    def __str__(self) -> str:
        if self.kind == "plays":
            return f"plays:{self.source}"
        return f"drive:{self.drive:g}" if self.kind == "drive" else self.kind


@dataclass(frozen=True)
class ResolvedInitialState:
    """The forward play outputs at the first sample, from when they stop mattering, and why."""

    play_state: np.ndarray
    settled_index: int
    how: str


def first_direction(drive: np.ndarray, tol: float | None = None) -> int:
    """+1 if the drive first moves up (beyond `tol`), -1 if down, 0 if it never moves."""
    x = np.asarray(drive, dtype=float)
    if tol is None:
        tol = 1e-6 * max(float(np.ptp(x)), 1e-300)
    moved = np.flatnonzero(np.abs(x - x[0]) > tol)
    if moved.size == 0:
        return 0
    return 1 if x[moved[0]] > x[0] else -1


def settled_index(model: Any, drive: np.ndarray) -> int:
    """First sample from which the output no longer depends on the initial play states.

    A play of threshold r forgets its initial value once the drive has spanned 2r since the
    start: from a minimum its output is at most x_min + r, and rising to x_min + 2r pushes every
    starting value to x - r (and symmetrically). So the model has settled once the running range
    of the drive reaches twice the largest threshold; len(drive) if it never does.
    """
    x = np.asarray(drive, dtype=float)
    if x.size == 0:
        return 0
    span = np.maximum.accumulate(x) - np.minimum.accumulate(x)
    need = 2.0 * float(model.play_thresholds[-1]) * (1 - 1e-12)
    hit = np.flatnonzero(span >= need)
    return int(hit[0]) if hit.size else int(x.size)


def centred_range(model: Any) -> tuple[float, float]:
    """The model's drive range about its input offset, (-inf, inf) when the file has none."""
    lo, hi = (float(v) for v in getattr(model, "drive_range", (-np.inf, np.inf)))
    return lo - model.input_offset, hi - model.input_offset


def monotone_play_state(r: np.ndarray, v0: float, d: int, lo: float, hi: float) -> np.ndarray:
    """Plays (thresholds r) after the drive came monotonically to v0 from direction d, with a history
    inside [lo, hi] widened to hold v0: each play at v0 - d r, held within [min(lo + r, hi - r),
    max(lo + r, hi - r)], the values a history in that range can leave it at. Continuous and
    increasing in v0 (the zero-threshold play always follows), so `monotone_start_drive` inverts it."""
    if d == 0:
        return np.full_like(r, v0)
    a, b = min(lo, v0), max(hi, v0)
    if not (np.isfinite(a) and np.isfinite(b)):
        return v0 - d * r
    return np.clip(v0 - d * r, np.minimum(a + r, b - r), np.maximum(a + r, b - r))


def monotone_start_drive(w: np.ndarray, r: np.ndarray, z0: float, d: int, lo: float, hi: float) -> float:
    """The v0 whose `monotone_play_state` gives the play sum z0 (exactly, to rounding): a bracket,
    bisection, then one linear step on the piece found (the sum is piecewise linear in v0)."""
    def z(v: float) -> float:
        return float(np.dot(w, monotone_play_state(r, v, d, lo, hi)))

    total = float(np.sum(w))
    v = (z0 + d * float(np.dot(w, r))) / total          # the unbounded rule's answer: a first bracket end
    if d == 0 or not (np.isfinite(lo) and np.isfinite(hi)):
        return v
    span = max(hi - lo, float(r[-1]) if r.size else 0.0, 1e-12)
    a, b = v - span, v + span
    while z(a) > z0:
        a -= 2.0 * (b - a)
    while z(b) < z0:
        b += 2.0 * (b - a)
    for _ in range(200):
        m = 0.5 * (a + b)
        if m in (a, b):
            break
        if z(m) < z0:
            a = m
        else:
            b = m
    v = 0.5 * (a + b)
    p = monotone_play_state(r, v, d, lo, hi)
    moving = np.isclose(p, v - d * r, rtol=0.0, atol=1e-12 * max(1.0, abs(v)))   # plays not held at a bound
    slope = float(np.sum(w[moving]))
    return v + (z0 - z(v)) / slope if slope > 0 else v


def monotone_state(model: Any, drive: np.ndarray) -> tuple[np.ndarray, str]:
    """Play states consistent with the first monotone stretch of the drive (see module doc)."""
    u = np.asarray(drive, dtype=float)
    v0 = u[0] - model.input_offset
    d = first_direction(u)
    r = model.play_thresholds
    how = {1: "consistent with the first monotone stretch (the drive first rises)",
           -1: "consistent with the first monotone stretch (the drive first falls)",
           0: "relaxed at the first drive value (the drive never moves)"}[d]
    return monotone_play_state(r, v0, d, *centred_range(model)), how


def relaxed_state(model: Any, drive_value: float) -> np.ndarray:
    v0 = drive_value - model.input_offset
    return np.full_like(model.play_thresholds, v0)


def _clamp_to_first(model: Any, state: np.ndarray, first_drive: float) -> np.ndarray:
    """Move a state to the first sample as eq. (2) does: each play within +-r of the input."""
    v = first_drive - model.input_offset
    r = model.play_thresholds
    return np.clip(state, v - r, v + r)


def resolve(model: Any, drive: Any, stress_MPa: Any = None, spec: "str | InitialStateSpec" = DEFAULT,
            measured_um: Any = None, time_s: Any = None) -> ResolvedInitialState:
    """The initial play state of `model` (an SDPI/MPI core) for a run on `drive`."""
    x = np.ascontiguousarray(drive, dtype=float)
    sp = InitialStateSpec.parse(spec)
    if sp.kind == "plays":
        return given_state(model, sp, x[0])
    settled = settled_index(model, x)
    if sp.kind == "relaxed":
        return ResolvedInitialState(relaxed_state(model, x[0]), settled, "relaxed at the first drive value")
    if sp.kind == "drive" and sp.drive is not None:
        state = _clamp_to_first(model, relaxed_state(model, sp.drive), x[0])
        return ResolvedInitialState(state, settled, f"relaxed at drive {sp.drive:g}, then moved to the first sample")
    guess, how = monotone_state(model, x)
    if measured_um is None:
        return ResolvedInitialState(guess, settled, how + "; no measured displacement to estimate from")
    y = np.asarray(measured_um, dtype=float)
    if y.shape != x.shape:
        raise ValueError("measured displacement and drive differ in length")
    fitted, n_used = _fit_state(model, x, stress_MPa, y, guess, settled)
    if fitted is None:
        return ResolvedInitialState(guess, settled, how + "; the measured displacement could not improve on it")
    state = fitted
    where = "" if time_s is None or n_used >= len(x) else f" over the first {float(np.asarray(time_s)[n_used - 1] - np.asarray(time_s)[0]):.3g} s"
    return ResolvedInitialState(state, settled, f"estimated from the measured displacement{where} "
                                                f"(play states fitted until they settle)")


def given_state(model: Any, spec: InitialStateSpec, first_drive: float) -> ResolvedInitialState:
    """The play outputs a `plays` spec gives, held to eq. (2) at the first drive value (a no-op
    for a state followed along this drive column; a state followed along the command is a
    tracking error away). Known, so nothing waits for it to be forgotten: settled index 0.
    ValueError unless there is one finite value per play."""
    p = np.asarray(spec.plays if spec.plays is not None else (), dtype=float)
    n = int(np.asarray(model.play_thresholds).size)
    if p.shape != (n,) or not np.all(np.isfinite(p)):
        raise ValueError(f"initial state {spec}: the model has {n} plays, the state gives "
                         f"{p.size} values{'' if np.all(np.isfinite(p)) else ' (not all finite)'}")
    return ResolvedInitialState(_clamp_to_first(model, p, first_drive), 0,
                                f"known: the play outputs at the first sample, from {spec.source}")


RANDOM_HISTORIES = 4096      # random longer histories scored as starts (batches of numpy work)
HISTORY_SEARCH_SEED = 8      # fixed: the estimate is a deterministic function of the data
CLIMBS = 16                  # hill-climbs on the turning points of the best random histories
STARTS = 4                   # best starts the local search descends from
SCALAR_XTOL = 1e-3           # Brent's bracket, as a fraction of two grid steps (the joint polish finishes)
PAIR_GRID = 9                # points a side of the pairs' joint scan (the descents after it place the plays)
PAIR_STARTS = 4              # pairs descended from after the scan: the best move alone depends on the grid's luck
PAIR_ROWS = 64               # rows the scan scores at most (every k-th; the descents score all): short windows keep all
NEGLIGIBLE = 1e-6            # a play whose box moves the play sum by less than this share is not fitted


def _fit_state(model: Any, x: np.ndarray, stress: Any, y: np.ndarray, guess: np.ndarray,
               settled: int, max_points: int = 600) -> tuple[np.ndarray | None, int]:
    """Least squares for the play states over the samples where they matter.

    Each play's output is a clamp of its unknown initial value between two envelopes that depend
    on the drive alone (its outputs started from the bottom and the top of the admissible box),
    so the output is a known function of one number per play. The cost has many basins (flat
    clamps, valleys where plays act together), so the starts are states real histories leave: the
    rule's guess, the last two turning points on a zoomed grid, and hill-climbs over random histories
    of three to six turning points (`_starts`). From the best few, a coordinate search (a scan of
    each play's box, then scipy's bounded Brent search) and a joint bounded least-squares fit with
    the exact Jacobian (scipy's trust-region reflective solver).
    The window runs to the settled index plus a margin (at least 64 samples); NaN readings are
    ignored. Returns None when the fit does not beat the guess.
    """
    n = len(x)
    end = min(n, max(64, settled + max(16, settled // 4)))
    window = _envelopes(model, x, y, end, max_points)
    if window is None:
        return None, end
    v0, lo, hi, A, B, pick = window
    ys = y[pick] * float(getattr(model, "output_sign", 1.0))
    ws, offset = _deadzone_weights(model, stress, n, pick)
    r_s = model.deadzone_thresholds
    w_h = model.play_weights
    # the one-sided dead-zones (4) as one clamp: max(d, 0) where r > 0, min(d, 0) where r < 0,
    # d where r = 0 (the same numbers as three np.where branches, in two passes instead of six)
    dz_lo = np.where(r_s > 0, 0.0, -np.inf)
    dz_hi = np.where(r_s < 0, 0.0, np.inf)

    def output(z: np.ndarray, rows: Any = slice(None)) -> np.ndarray:   # z: (k, m) -> y: (k, m)
        d = z[..., None] - r_s
        np.maximum(d, dz_lo, out=d)
        np.minimum(d, dz_hi, out=d)
        return offset[rows] + np.einsum("kmj,mj->km", d, ws[rows])

    def slope(z: np.ndarray) -> np.ndarray:           # z: (m,) -> dy/dz: (m,), the active dead-zones' weights
        d = z[:, None] - r_s
        active = np.where(r_s > 0, d > 0, np.where(r_s < 0, d < 0, True))
        return (ws * active).sum(axis=1)

    def costs(states: np.ndarray, rows: Any = slice(None)) -> np.ndarray:   # (k, n_play) -> (k,)
        out = []
        for q in np.array_split(states, max(1, len(states) // 256)):
            z = (w_h * _clip(q[:, None, :], A[rows], B[rows])).sum(axis=2)
            out.append(((output(z, rows) - ys[rows]) ** 2).sum(axis=1))
        return np.concatenate(out)

    guess = np.clip(guess, lo, hi)
    guess_cost = float(costs(guess[None, :])[0])
    states, start_costs = _starts(v0, model.play_thresholds, guess, guess_cost, costs)
    results = [_descend(states[k], float(start_costs[k]), lo, hi, w_h, A, B, output, slope, ys)
               for k in np.argsort(start_costs, kind="stable")[:STARTS]]
    best_cost, p = min(results, key=lambda t: t[0])
    best_cost, p = _escape_by_pairs(p, best_cost, lo, hi, w_h, costs, ys.size,
                                    lambda q, c: _descend(q, c, lo, hi, w_h, A, B, output, slope, ys))
    if best_cost >= guess_cost:
        return None, end
    return p, end


def _escape_by_pairs(p: np.ndarray, best_cost: float, lo: np.ndarray, hi: np.ndarray, w_h: np.ndarray,
                     costs: Any, n_rows: int, descend: Any) -> tuple[float, np.ndarray]:
    """Leave a basin the descents cannot: plays that only move the output together sit in a valley
    whose wall a one-play scan and a local polish both see as a minimum (a CI-drawn case ended 1 %
    of the stroke off, the cost rising by 10 % on the straight line to the truth before it fell).
    Each pair of placeable plays is scanned jointly on a grid over their boxes, the rest held; the
    PAIR_STARTS pairs whose best move beats the state most are descended from, and the best
    descent kept if it beats the state."""
    free = np.flatnonzero(_movable(w_h, lo, hi))
    if free.size < 2:
        return best_cost, p
    i, j = (free[k] for k in np.triu_indices(free.size, 1))
    g = np.linspace(0.0, 1.0, PAIR_GRID)
    gi, gj = (np.tile(a.ravel(), i.size) for a in np.meshgrid(g, g, indexing="ij"))
    pair = np.repeat(np.arange(i.size), PAIR_GRID ** 2)
    moves = np.repeat(p[None, :], pair.size, axis=0)
    moves[np.arange(pair.size), i[pair]] = lo[i[pair]] + gi * (hi - lo)[i[pair]]
    moves[np.arange(pair.size), j[pair]] = lo[j[pair]] + gj * (hi - lo)[j[pair]]
    per_pair = costs(moves, slice(None, None, max(1, n_rows // PAIR_ROWS))).reshape(i.size, -1)
    best_move = np.argmin(per_pair, axis=1)
    tried = np.argsort(per_pair[np.arange(i.size), best_move], kind="stable")[:PAIR_STARTS]
    starts = moves[tried * PAIR_GRID ** 2 + best_move[tried]]
    cost, q = min((descend(s, c) for s, c in zip(starts, costs(starts))), key=lambda f: f[0])
    return (cost, q) if cost < best_cost else (best_cost, p)


def _envelopes(model: Any, x: np.ndarray, y: np.ndarray, end: int, max_points: int
               ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Over the window x[:end]: the first drive (in the plays' coordinates), each play's box at it,
    and the play outputs started from the box's bottom and top at the picked rows (the finite
    readings, at most max_points of them, evenly spread); None with fewer than 8 finite readings."""
    from . import operators as ops      # numba: not needed to parse --initial-state

    v = np.ascontiguousarray(x[:end] - model.input_offset)
    r = model.play_thresholds
    lo, hi = v[0] - r, v[0] + r
    low_env = np.empty((end, model.n_play))
    high_env = np.empty((end, model.n_play))
    ops.play_outputs(v, r, np.ascontiguousarray(lo), low_env)
    ops.play_outputs(v, r, np.ascontiguousarray(hi), high_env)
    pick = np.flatnonzero(np.isfinite(y[:end]))
    if pick.size < 8:
        return None
    if pick.size > max_points:
        pick = pick[np.linspace(0, pick.size - 1, max_points).astype(int)]
    return float(v[0]), lo, hi, low_env[pick], high_env[pick], pick


def _deadzone_weights(model: Any, stress: Any, n: int, pick: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The dead-zone weights (rows, n_deadzone) and the output offset (rows,) at the picked rows' stress."""
    s = np.zeros(pick.size) if model.stress_range_MPa is None else \
        np.asarray(model._stress_array(stress, n), dtype=float)[pick]
    c = model.deadzone_coeffs
    oc = model.output_coeffs
    return (c[0][None, :] + s[:, None] * (c[1][None, :] + s[:, None] * c[2][None, :]),
            oc[0] + s * (oc[1] + s * oc[2]))


def _starts(v0: float, r: np.ndarray, guess: np.ndarray, guess_cost: float,
            costs: Any) -> tuple[np.ndarray, np.ndarray]:
    """The local search's candidate starts and their costs: the rule's guess, then states real
    histories leave, so the search begins in the right basin rather than on a flat clamp. First the
    last two turning points before the recording on a grid, zoomed in; then longer histories, whose
    staircases two turning points cannot leave (a play above its neighbour after a smaller one
    moved down): a random search over three to six turning points."""
    reach = 2.0 * float(r[-1])
    step = reach / 11
    grid = np.linspace(0.0, reach, 12)
    hist = _history_states(v0, r, grid, grid)
    hist_costs = costs(np.array([h[2] for h in hist]))
    for _level in range(3):
        a0, b0 = hist[int(np.argmin(hist_costs))][:2]
        step /= 4
        near = np.arange(-4, 5) * step
        zoom = _history_states(v0, r, np.clip(a0 + near, 0.0, reach), np.clip(b0 + near, 0.0, reach))
        hist += zoom
        hist_costs = np.r_[hist_costs, costs(np.array([h[2] for h in zoom]))]
    many = _history_search(v0, r, reach, lambda q: costs(q, slice(None, None, 4)))
    states = np.array([guess] + [h[2] for h in hist] + list(many))
    return states, np.r_[guess_cost, hist_costs, costs(many)]


def _clip(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """np.clip without its Python-level wrapper (thousands of calls per fit): the same numbers."""
    return np.minimum(np.maximum(x, lo), hi)


def _history_states(v0: float, r: np.ndarray, a_grid: np.ndarray,
                    b_grid: np.ndarray) -> list[tuple[float, float, np.ndarray]]:
    """(a, b, play states) after a drive history ...-> v0+a -> v0-b -> v0 or ...-> v0-a -> v0+b
    -> v0: the last two turning points on a grid within the operators' reach. These are states
    a real history leaves, not corners of the admissible box."""
    out = []
    for a in a_grid:
        for b in b_grid:
            for sign in (1.0, -1.0):
                p = v0 + sign * a - sign * r                  # arrived at the first turning point
                p = np.clip(p, v0 - sign * b - r, v0 - sign * b + r)
                out.append((float(a), float(b), np.clip(p, v0 - r, v0 + r)))
    return out


def _turns_to_states(v0: float, r: np.ndarray, turns: np.ndarray, n_turns: np.ndarray) -> np.ndarray:
    """(k, n_play) play states after drives through `turns` (the first n_turns of each row; relaxed
    at the first) that end at v0."""
    p = np.repeat(turns[:, :1], r.size, axis=1)
    for j in range(1, turns.shape[1]):
        moved = np.clip(p, turns[:, j:j + 1] - r, turns[:, j:j + 1] + r)
        p = np.where((j < n_turns)[:, None], moved, p)
    return np.clip(p, v0 - r, v0 + r)


def _history_search(v0: float, r: np.ndarray, reach: float, cost: Any) -> np.ndarray:
    """States after random drives of three to six turning points within the operators' reach,
    then parallel hill-climbs on the turning points of the best few (each keeps its own lineage,
    so the starts stay in different basins). A fixed generator: the estimate is a deterministic
    function of the data. Returns every climb's best state, best first: all are candidate starts
    (a CI-drawn case reached its true basin only from one past the first four).

    Hand-written, measured against scipy's differential_evolution over the same six turning points
    and about the same 5,100 costs (40 x 6 a generation, 20 generations, vectorised): the search
    took 0.30 s against 0.05 s (20 random models, interleaved), and on the 400 random models of
    scripts/compare_initial_state.py two fits came out worse by up to 2.1e-4 of the stroke (and
    two better by up to 4.3e-4)."""
    rng = np.random.default_rng(HISTORY_SEARCH_SEED)
    turns = v0 + rng.uniform(-reach, reach, (RANDOM_HISTORIES, 6))
    n_turns = rng.integers(3, 7, RANDOM_HISTORIES)
    c = cost(_turns_to_states(v0, r, turns, n_turns))
    best = np.argsort(c, kind="stable")[:CLIMBS]
    turns, n_turns, c = turns[best], n_turns[best], c[best]
    for level in range(4):
        kids = np.repeat(turns, 16, axis=0) + rng.normal(0.0, 0.2 * reach / 3 ** level, (turns.shape[0] * 16, 6))
        kc = cost(_turns_to_states(v0, r, kids, np.repeat(n_turns, 16))).reshape(-1, 16)
        k = np.argmin(kc, axis=1)
        better = kc[np.arange(k.size), k] < c
        turns[better] = kids.reshape(-1, 16, 6)[np.flatnonzero(better), k[better]]
        c = np.where(better, kc[np.arange(k.size), k], c)
    order = np.argsort(c, kind="stable")
    return _turns_to_states(v0, r, turns[order], n_turns[order])


def _descend(p: np.ndarray, best_cost: float, lo: np.ndarray, hi: np.ndarray, w_h: np.ndarray,
             A: np.ndarray, B: np.ndarray, output: Any, slope: Any, ys: np.ndarray) -> tuple[float, np.ndarray]:
    """Coordinate search (scan, then Brent's bounded search) and a joint least-squares polish."""
    from scipy.optimize import minimize_scalar

    p = p.copy()

    def contrib(i: int, q: np.ndarray) -> np.ndarray:   # (k,) values of play i -> (k, m)
        return w_h[i] * _clip(q[:, None], A[:, i], B[:, i])

    def cost_of(z_rest: np.ndarray, i: int, cands: np.ndarray) -> np.ndarray:
        return ((output(z_rest[None, :] + contrib(i, cands)) - ys) ** 2).sum(axis=1)

    z = (w_h * _clip(p, A, B)).sum(axis=1)
    for _ in range(4):
        before = best_cost
        for i in np.flatnonzero(_movable(w_h, lo, hi)).tolist():
            z_rest = z - contrib(i, p[i:i + 1])[0]
            grid = np.r_[np.linspace(lo[i], hi[i], 33), p[i]]
            costs = cost_of(z_rest, i, grid)
            k = int(np.argmin(costs))
            best_p, best_c = grid[k], float(costs[k])
            if k < 33:                    # a grid point beat the current value: refine between its neighbours
                a, b = grid[max(k - 1, 0)], grid[min(k + 1, 32)]
                sol = minimize_scalar(lambda q: float(cost_of(z_rest, i, np.array([q]))[0]), bounds=(a, b),
                                      method="bounded", options={"xatol": SCALAR_XTOL * (b - a)})
                if sol.fun < best_c:
                    best_p, best_c = float(sol.x), float(sol.fun)
            p[i] = best_p
            z = z_rest + contrib(i, p[i:i + 1])[0]
            best_cost = best_c
        if before - best_cost <= 1e-12 * max(before, 1e-300):
            break
    return _joint_polish(p, best_cost, lo, hi, w_h, A, B, output, slope, ys)


def _movable(w_h: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The plays whose state the fit can place: those whose box moves the play sum by at least
    NEGLIGIBLE of what all boxes move it. A weight that identify's trust-region solver held at its
    zero bound comes out near 1e-9 of the others, not 0: its state changes the cost by rounding
    only, and a solver then sends it anywhere in its box."""
    reach = np.abs(w_h) * np.maximum(hi - lo, 0.0)
    return reach > NEGLIGIBLE * float(reach.sum())


def _joint_polish(p: np.ndarray, best_cost: float, lo: np.ndarray, hi: np.ndarray, w_h: np.ndarray,
                  A: np.ndarray, B: np.ndarray, output: Any, slope: Any, ys: np.ndarray) -> tuple[float, np.ndarray]:
    """Plays that only act together (both still inside their boxes) form valleys that a coordinate
    search crosses slowly: a joint bounded least-squares fit of the plays that can move the output
    finishes. The others keep the state their history left: the output cannot tell, but identify
    reuses the states as regressors (scipy's solver moved a play of weight 5e-10 to its bound, and
    the model identified from one piezo period predicted 5 % worse)."""
    free = _movable(w_h, lo, hi)
    if not free.any():
        return best_cost, p
    lo_f, span, w_f, A_f, B_f = lo[free], hi[free] - lo[free], w_h[free], A[:, free], B[:, free]
    z_held = (w_h[~free] * _clip(p[~free], A[:, ~free], B[:, ~free])).sum(axis=1)

    def resid(q: np.ndarray) -> np.ndarray:
        return output((z_held + (w_f * _clip(lo_f + q * span, A_f, B_f)).sum(axis=1))[None, :])[0] - ys

    def jac(q: np.ndarray) -> np.ndarray:   # exact where defined: the model is piecewise linear in the states
        pp = lo_f + q * span
        z = z_held + (w_f * _clip(pp, A_f, B_f)).sum(axis=1)
        return slope(z)[:, None] * ((pp > A_f) & (pp < B_f)) * (w_f * span)[None, :]

    q, cost = box_least_squares(resid, jac, np.clip((p[free] - lo_f) / span, 0.0, 1.0), max_nfev=20 * w_h.size)
    if cost < best_cost:
        p = p.copy()
        p[free], best_cost = lo_f + q * span, cost
    return best_cost, p


def box_least_squares(resid: Any, jac: Any, q: np.ndarray, max_nfev: int) -> tuple[np.ndarray, float]:
    """Least squares of resid(q) over the unit box, from q, with the exact Jacobian `jac`:
    scipy's trust-region reflective solver, then one exact active-set step (BVLS) on the model
    linearised where it ended, kept if the residuals themselves confirm it. The reflective steps
    crawl along a face where the box binds most variables: on one row of eleven, 220 evaluations
    ended 1.05e-4 above the optimum. Returns (q, sum of squares)."""
    from scipy.optimize import least_squares, lsq_linear

    sol = least_squares(resid, q, jac=jac, bounds=(0.0, 1.0), method="trf", xtol=1e-14, ftol=1e-14, gtol=1e-14,
                        max_nfev=max_nfev)
    q, cost = sol.x, float(2.0 * sol.cost)
    J = np.asarray(jac(q), dtype=float)
    live = np.any(J != 0.0, axis=0)          # a clipped state moves nothing here: it keeps its value
    if not live.any():
        return q, cost
    J = J[:, live]
    step = lsq_linear(J, J @ q[live] - sol.fun, bounds=(0.0, 1.0), method="bvls", tol=1e-12)   # sol.fun: resid(q)
    q_step = q.copy()
    q_step[live] = np.clip(step.x, 0.0, 1.0)      # BVLS may end a rounding outside (-1.1e-16)
    r = resid(q_step)
    cost_step = float(r @ r)
    return (q_step, cost_step) if cost_step < cost else (q, cost)
