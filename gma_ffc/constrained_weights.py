"""The operators' weights as the variables of bounded least squares: Proposition 3.1 as simple bounds.

The seed paper's Proposition 3.1 makes an SDPI invertible: the play weight at threshold 0 is
positive, and every cumulative dead-zone weight, from the centre outwards, is positive. Written in
the right variables, each is a lower bound on one variable, which a bounded least-squares solver
meets exactly:
- a dead-zone superposition's weights as the slopes of its linear pieces (`slope_basis`,
  `slopes_to_weights`, `weights_to_slopes`);
- the play weights with w_h0's floor as a share of all of them (`PlayWeights`);
- a slope's quadratic law in stress, the bound held at every stress of the range: a quadratic
  programme on a grid grown by the exact worst stress (`slopes_in_stress`), or through the law's
  Bernstein coefficients where that does not converge (`bernstein_fit`).

`identify` uses them in every fit, so it never produces a model it refuses. Pure maths: no I/O.
"""

from __future__ import annotations

import numpy as np
from scipy import optimize


def slope_basis(z: np.ndarray, r: np.ndarray) -> np.ndarray:
    """phi_k(z): the length of z's path inside each linear piece of a dead-zone superposition.

    sum_k s_k phi_k(z) equals sum_j w_j S_{r_j}(z) when s are the pieces' slopes (the cumulative
    weights from the centre outwards), so bounds on s are Proposition 3.1.
    """
    m = len(r)
    c = (m - 1) // 2
    out = np.empty((len(z), m))
    lo = r[c - 1] if c > 0 else -np.inf
    hi = r[c + 1] if c + 1 < m else np.inf
    out[:, c] = np.clip(z, lo, hi)
    for k in range(c + 1, m):
        top = r[k + 1] if k + 1 < m else np.inf
        out[:, k] = np.clip(z, r[k], top) - r[k]
    for k in range(c - 1, -1, -1):
        bottom = r[k - 1] if k > 0 else -np.inf
        out[:, k] = np.clip(z, bottom, r[k]) - r[k]
    return out


def slopes_to_weights(s: np.ndarray) -> np.ndarray:
    """Slopes of the linear pieces -> dead-zone weights (works on the last axis, any leading axes)."""
    s = np.asarray(s, dtype=float)
    m = s.shape[-1]
    c = (m - 1) // 2
    w = np.empty_like(s)
    w[..., c] = s[..., c]
    w[..., c + 1:] = np.diff(s[..., c:], axis=-1)
    w[..., :c] = s[..., :c] - s[..., 1: c + 1]
    return w


def weights_to_slopes(w: np.ndarray) -> np.ndarray:
    """Dead-zone weights -> the slopes of the linear pieces: `slopes_to_weights` undone (cumulative
    sums from the centre outwards)."""
    w = np.asarray(w, dtype=float)
    m = w.shape[-1]
    c = (m - 1) // 2
    s = np.empty_like(w)
    s[..., c:] = np.cumsum(w[..., c:], axis=-1)
    s[..., : c + 1] = np.cumsum(w[..., c::-1], axis=-1)[..., ::-1]
    return s


W0_MIN_SHARE = 1e-3
"""The zero-threshold play's least share of all play weights, a constraint of every fit (not a
check after it): Proposition 3.1 needs w_h0 > 0, and the inverse's gain just after a reversal is
1/w_h0 times the loop's, so the share keeps it within 1000x the loop's mean gain. A wide, square
loop (a ferroelectric driven beyond its coercive field) is flat just after each reversal and
pulls w_h0 to its bound, wherever that is: a bound relative to the previous pass let it walk down
by 1e-6 per pass to 1e-12, and the model failed its own invertibility check."""

W0_MIN_GAIN = 1e-6
"""...and w_h0 is at least this share of the data's mean gain (stroke over drive span), so it
stays positive however the other weights fall: far below any real loop's slope (which the share
above already holds it to), far above rounding in the weights' units, whatever the drive's unit."""


class PlayWeights:
    """Play weights as a fit's bounded variables: w_i = q_i for i >= 1 and
    w_0 = q_0 + a sum_{i>=1} q_i with a = W0_MIN_SHARE / (1 - W0_MIN_SHARE), so bounds q >= lower
    are exactly w_0 >= W0_MIN_SHARE sum(w) (plus q_0 >= the gain floor) and w_i >= 0: Proposition
    3.1 and w_h0's floor as the bounds of a bounded least-squares problem."""

    def __init__(self, n: int, gain: float) -> None:
        a = W0_MIN_SHARE / (1.0 - W0_MIN_SHARE)
        self.T = np.eye(n)
        self.T[0, 1:] = a                       # w = T q
        self.lower = np.r_[W0_MIN_GAIN * max(gain, 1e-300), np.zeros(n - 1)]

    def weights(self, q: np.ndarray) -> np.ndarray:
        return self.T @ q

    def variables(self, w: np.ndarray) -> np.ndarray:
        """The q of weights w, moved onto the bounds where w breaks them (a start for a fit)."""
        return np.maximum(np.linalg.solve(self.T, w), self.lower)


BERNSTEIN = {0: np.array([[1.0]]), 1: np.array([[1.0, -1.0], [1.0, 1.0]]),
             2: np.array([[1.0, -1.0, 1.0], [1.0, 0.0, -1.0], [1.0, 1.0, 1.0]])}
"""Per degree, the map from a polynomial's coefficients (a_0..a_d in u) to its Bernstein coefficients
on u in [-1, 1]; the polynomial is a weighted mean of those there, so all of them >= eps keeps it >= eps."""


def bernstein_fit(A: np.ndarray, y: np.ndarray, degree: int, n_s: int, eps: float) -> np.ndarray:
    """The stress step's least squares with every dead-zone slope's Bernstein coefficients >= eps:
    Proposition 3.1 at every stress of the range as simple bounds, so a bounded least-squares solver
    meets it exactly (a sufficient condition, so it may fit a little worse than the exact constraint;
    used when that one's solver fails). Columns as `_fit_stress` builds them: slopes [p, k], then the rest."""
    n_coef = (degree + 1) * n_s
    to_poly = np.kron(np.linalg.inv(BERNSTEIN[degree]), np.eye(n_s))   # Bernstein [j, k] -> polynomial [p, k]
    Ab = np.hstack([A[:, :n_coef] @ to_poly, A[:, n_coef:]])
    scale = np.linalg.norm(Ab, axis=0)
    scale[scale == 0] = 1.0
    lower = np.r_[np.full(n_coef, eps), np.full(A.shape[1] - n_coef, -np.inf)] * scale
    b = bounded_least_squares(Ab / scale, y, lower) / scale
    return np.r_[to_poly @ b[:n_coef], b[n_coef:]]


def intermediate_grid(z_lo: float, z_hi: float, l: int) -> np.ndarray:
    """2l+1 dead-zone thresholds at equal intervals over z's range on each side of 0 (`_regrid`)."""
    k = np.arange(1, l + 1) / (l + 1)
    return np.r_[(k * z_lo)[::-1], 0.0, k * z_hi]


def slopes_and_offset(z: np.ndarray, r_s: np.ndarray) -> np.ndarray:
    """The regrid's design: the dead-zone pieces' slope basis at z (`slope_basis`) and the offset."""
    return np.hstack([slope_basis(z, r_s), np.ones((len(z), 1))])


def determined(A: np.ndarray) -> bool:
    """Whether the data fix every coefficient of A's columns that they touch at all: a slope whose
    piece no sample reaches has a zero column and is left at its bound, but a piece between samples
    only adds a constant beyond it, which trades with the offset and its neighbours without limit
    (a six-level drive's slopes went to +-6.4e13 and broke Proposition 3.1's floor)."""
    used = np.linalg.norm(A, axis=0) > 0
    return bool(np.linalg.matrix_rank(A[:, used]) == int(used.sum()))


def deadzones_determined(z: np.ndarray, z_lo: float, z_hi: float, l: int) -> int:
    """The most dead-zones below 2l+1 whose slopes the plays' output z fixes (1 at least: one piece
    and the offset are fixed by any z that is not constant)."""
    for m in range(l - 1, 0, -1):
        if determined(slopes_and_offset(z, intermediate_grid(z_lo, z_hi, m))):
            return 2 * m + 1
    return 1


def bounded_least_squares(A: np.ndarray, y: np.ndarray, lower: np.ndarray, max_iter: int | None = None) -> np.ndarray:
    """argmin |A x - y| with x >= lower (scipy's `lsq_linear`, trust-region reflective). Its
    reflective step multiplies an infinite stride (towards the absent upper bound) by a zero
    direction and then discards that candidate; numpy's "invalid value" warning from there is
    scipy's working, not the fit's, so it is not shown (a hypothesis-drawn recording put it on the
    CLI's output). A NaN in the result would still reach the model's own finiteness check."""
    with np.errstate(invalid="ignore"):
        return optimize.lsq_linear(A, y, bounds=(lower, np.inf), lsmr_tol="auto", max_iter=max_iter).x


def powers_to_sigma(mid: float, half: float, degree: int) -> np.ndarray:
    """Matrix T with [c0, c1, c2] = T @ [a0..a_degree] for sum a_p u^p, u = (sigma - mid)/half."""
    T = np.zeros((3, degree + 1))
    T[0, 0] = 1.0
    if degree >= 1:
        T[0, 1], T[1, 1] = -mid / half, 1.0 / half
    if degree >= 2:
        T[0, 2], T[1, 2], T[2, 2] = mid * mid / half ** 2, -2 * mid / half ** 2, 1.0 / half ** 2
    return T


def _slope_rows(u_pts: np.ndarray, degree: int, n_s: int, col_scale: np.ndarray) -> np.ndarray:
    """The linear map from the scaled coefficients to the slopes at stresses u_pts, one row per (u, k)."""
    rows = np.zeros((len(u_pts) * n_s, len(col_scale)))
    for a, u in enumerate(u_pts):
        for p in range(degree + 1):
            for k in range(n_s):
                rows[a * n_s + k, p * n_s + k] = u ** p
    return rows / col_scale


def slopes_in_stress(A: np.ndarray, y: np.ndarray, col_scale: np.ndarray, degree: int, n_s: int) -> np.ndarray:
    """The scaled coefficients of the least squares (A / col_scale, y) with every dead-zone slope at
    least eps at every normalised stress u in [-1, 1]: Proposition 3.1 across the stress range.

    A's first (degree + 1) * n_s columns are the slopes' power coefficients in [p, k] order. SLSQP
    runs on a grid of stresses grown by the exact worst point (`lowest_slope`); where that does not
    converge to a feasible point, Proposition 3.1 becomes simple bounds (`bernstein_fit`). eps is
    1e-3 of the largest slope at the range's centre: small enough not to bend the fit, large
    enough that the inverse's slopes stay finite.
    """
    As = A / col_scale
    G, g = As.T @ As, As.T @ y
    G += 1e-12 * np.trace(G) / len(G) * np.eye(len(G))     # a ridge at rounding level: G may be singular
    theta_s = np.linalg.solve(G, g)
    s_scale = float(np.max(np.abs(_slope_rows(np.array([0.0]), degree, n_s, col_scale) @ theta_s))) or 1.0
    eps = 1e-3 * s_scale
    grid = list(np.linspace(-1.0, 1.0, 21))
    for _ in range(10):
        C = _slope_rows(np.array(grid), degree, n_s, col_scale)
        if np.all(C @ theta_s >= eps * (1 - 1e-9)):
            worst_u, worst_v = lowest_slope(theta_s / col_scale, degree, n_s)
            if worst_v >= eps * (1 - 1e-6):
                break
            grid.append(worst_u)
            C = _slope_rows(np.array(grid), degree, n_s, col_scale)
        res = optimize.minimize(
            lambda t: 0.5 * t @ G @ t - g @ t, theta_s, jac=lambda t: G @ t - g, method="SLSQP",
            constraints=[{"type": "ineq", "fun": lambda t, C=C: C @ t - eps, "jac": lambda t, C=C: C}],
            options={"maxiter": 500, "ftol": 1e-14})
        theta_s = res.x
    if lowest_slope(theta_s / col_scale, degree, n_s)[1] < eps * (1 - 1e-6):
        theta_s = bernstein_fit(A, y, degree, n_s, eps) * col_scale
    return theta_s


def lowest_slope(theta: np.ndarray, degree: int, n_s: int) -> tuple[float, float]:
    """Exact minimum over u in [-1, 1] of every slope polynomial (the ends, and a quadratic's
    vertex inside): (where, value)."""
    poly = theta[: (degree + 1) * n_s].reshape(degree + 1, n_s)
    worst_u, worst_v = 0.0, np.inf
    for k in range(n_s):
        a = poly[:, k]
        cands = [-1.0, 1.0]
        if degree == 2 and a[2] > 0:
            v = -a[1] / (2 * a[2])
            if -1 < v < 1:
                cands.append(float(v))
        for u in cands:
            val = sum(a[p] * u ** p for p in range(degree + 1))
            if val < worst_v:
                worst_u, worst_v = u, val
    return worst_u, float(worst_v)
