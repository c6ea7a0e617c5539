"""Fit and score candidate effects on top of a model: the searches, and what a round's scores mean.

`search_all` searches several effects' parameters on held-out blocks (in parallel threads);
`score_round` turns a round's searches into frozen `state.Trial`s with the penalised held-out
log-likelihood gain of each (on the residual's effective sample count); `evidence_weight` says
what such a gain means as a weight. Deciding what to accept is `selection`'s job; this module only measures. Pure maths.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable, Sequence

import numpy as np
from scipy import special

from ..effects import REGISTRY
from ..effects.base import geom_refine, polish_factor
from ..effects.static import StaticMap
from ..extended import ExtendedModel
from .fitting import Fitter
from .specs import Spec
from .search import SearchResult, search
from .state import Trial

Specs = tuple[Spec, Spec, Spec]          # fold A's, fold B's and the all-data spec


def loglik_gain(n_eff: float, loss_without: float, loss: float, n_params: int) -> float:
    """Penalised held-out log-likelihood gain (nats) of a model that takes the loss per sample from
    `loss_without` to `loss` on n_eff effectively independent samples, one nat per parameter."""
    return 0.5 * n_eff * math.log(loss_without / max(loss, 1e-300)) - n_params


def evidence_weight(gain_nats: float) -> float:
    """The Akaike weight of the model with an effect against the same model without it, from the
    penalised held-out log-likelihood gain: 1 / (1 + exp(-gain)); 0 where no gain was measured.
    Each effect is weighed against its own absence, so a weight never depends on which other
    candidates a round fitted or set aside (a round's shared weights gave a named effect 0.000
    beside a look-alike the leave-one-out refused)."""
    return float(special.expit(gain_nats)) if math.isfinite(gain_nats) else 0.0


def effective_samples(resid: np.ndarray, lengths: Sequence[int]) -> float:
    """Independent samples in a residual: per recording, its length over the integrated
    autocorrelation time, by Geyer's initial monotone sequence (the sums of neighbouring pairs of
    autocorrelations, taken while they stay positive and falling: no cut-off to choose, the data
    say where the correlation has died out)."""
    total = 0.0
    start = 0
    for n in lengths:
        r = resid[start:start + n]
        start += n
        total += r.size / max(correlation_time(r), 1.0)
    return max(total, 1.0)


def correlation_time(r: np.ndarray) -> float:
    """Integrated autocorrelation time 1 + 2 sum_k rho_k of a series (Geyer 1992, initial monotone
    sequence estimator); 1 for a series too short or flat to say."""
    if r.size < 8:
        return 1.0
    x = r - r.mean()
    var = float(x @ x)
    if var <= 0:
        return 1.0
    m = 1 << int(np.ceil(np.log2(2 * x.size)))
    f = np.fft.rfft(x, m)
    rho = np.fft.irfft(f * np.conj(f), m)[: x.size // 2] / var
    pairs = rho[: 2 * (rho.size // 2)].reshape(-1, 2).sum(axis=1)     # Gamma_k = rho_2k + rho_2k+1
    stop = np.flatnonzero(pairs <= 0)
    pairs = pairs[: stop[0] if stop.size else pairs.size]
    pairs = np.minimum.accumulate(pairs)
    return float(-1.0 + 2.0 * pairs.sum())


def params_of(fitter: Fitter, effect: str, spec: Spec, coef: np.ndarray, names: list[str]) -> dict[str, float]:
    """An effect's reported parameters for a spec and its all-data coefficients."""
    return REGISTRY[effect].fitted_params(fitter, spec[effect], dict(zip(names, coef)))


def build_extended(model: Any, fitter: Fitter, spec: Spec, coef: np.ndarray, names: list[str],
                   effects: list[str]) -> ExtendedModel:
    """The extended model for a spec and its all-data coefficients (through the file form, so it is validated)."""
    c = dict(zip(names, (float(v) for v in coef)))
    blocks = StaticMap.fitted_blocks(fitter, None, c)
    for cls in fitter.effects:
        if cls.name in spec:
            blocks.update(cls.fitted_blocks(fitter, spec[cls.name], c))
    return ExtendedModel(model, blocks, effects)


def search_all(fitter: Fitter, base: Specs, names: list[str], workers: int) -> dict[str, SearchResult]:
    """Search several effects on top of `base`, in parallel threads (the kernels release the GIL).
    Each effect's search on a base is made once per fitter (`Fitter.searched`): the swap pass searches
    the slot of the effect accepted last on the base its round searched it on, with the same rivals."""

    def one(name: str) -> SearchResult:
        return fitter.searched(("search", base, name), lambda: _search_one(fitter, base, name, workers))

    n = min(workers, max(len(names), 1))
    if n <= 1:
        return {name: one(name) for name in names}
    with ThreadPoolExecutor(max_workers=n) as pool:
        return dict(zip(names, pool.map(one, names)))


def search_variant(fitter: Fitter, base: Specs, name: str, variant: Callable[[Any], Any], workers: int) -> SearchResult:
    """`name` searched on top of `base` again, every point of its grid in the form `variant` gives
    (`SignatureFailure.variant`: creep from rest); made once per fitter, as every search is."""
    return fitter.searched(("search", base, name, variant),
                           lambda: _search_one(fitter, base, name, workers, variant))


def _search_one(fitter: Fitter, base: Specs, name: str, workers: int,
                variant: Callable[[Any], Any] | None = None) -> SearchResult:
    """One effect searched on top of `base`: its own search, or jointly with a look-alike already in it
    (or an effect whose fit its arrival reshapes: `rescales`); each grid point in the form `variant`
    gives, when given (its refine keeps that form)."""
    cls = REGISTRY[name]
    own_grid = [variant(p) for p in cls.grid(fitter)] if variant is not None else list(cls.grid(fitter))
    partner = next((p for p in cls.joint_with + cls.rescales if p in base[2]), None)
    if partner is None:
        return _own_search(fitter, base, name, workers, points=own_grid)

    # look-alikes trade off against each other: re-search the accepted one's value with the new one
    def make_joint(s: Spec, p: Any) -> Spec:
        return s.with_(name, p[0]).with_(partner, REGISTRY[partner].scaled_for_partner(s[partner], p[1]))

    def refine(f: Fitter, p: Any, level: int) -> list:
        own = cls.refine(f, p[0], level)
        out = [(q, p[1]) for q in own] if own is not None else []
        return out + [(p[0], min(p[1] * m, 1.5)) for m in geom_refine(1.0, 1.6, level)]

    grid = [(p, k) for p in own_grid for k in cls.joint_scales]
    found = search(fitter, base, make_joint, grid, refine, workers=workers)
    return _descend(fitter, base, found, name, partner, workers) if REGISTRY[partner].joint_refit else found


def _own_search(fitter: Fitter, base: Specs, name: str, workers: int, start: Any = None,
                grid: bool = True, points: Sequence[Any] | None = None) -> SearchResult:
    """One effect's own search on top of `base` (its grid, or the `points` given, then zoom and
    polish), from `start` as well when given; without its grid, the zoom from `start` alone."""
    cls = REGISTRY[name]

    def make(s: Spec, p: Any) -> Spec:
        return s.with_(name, p)

    own = list(cls.grid(fitter)) if points is None else list(points)
    points = ([] if start is None else [start]) + (own if grid else [])
    return search(fitter, base, make, points, cls.refine, cls.zoom_levels, cls.polish, workers, cls.after_polish)


def rezoom(fitter: Fitter, base: Specs, name: str, workers: int) -> SearchResult:
    """`name`'s zoom and polish again on top of `base`, from where `base` has it (no grid)."""
    return _own_search(fitter, base, name, workers, start=base[2][name], grid=False)


JOINT_POLISH_EVALS = 40    # per free coordinate of the pair's joint polish: its valley is coupled (a lag's time
                           # constant against a resonance's damping); on the fourth draw's eddy-and-resonance pair
                           # its four polishes stopped after 82-160 evaluations (three converged, one at the cap)


def _descend(fitter: Fitter, base: Specs, joint: SearchResult, name: str, partner: str,
             workers: int) -> SearchResult:
    """The pair searched again from a joint search (`descend`), for a partner whose look-alike part
    is not one parameter: a resonance fitted alone beside eddy currents takes the lag's phase as
    damping and moves its frequency and load law with it (damping 0.38 where the rig's is 0.10);
    scaling its damping alone took the held-out RMS from 1.72 to 1.63 um, the descent to 0.43 um
    (`fourth:rate_dependence+mechanical_dynamics`). Each search includes the point it starts from,
    so no step can leave a worse all-data fit.

    The descent is kept only where the partner it leaves leans on `name`: without it, that partner
    fits worse than the one accepted. Otherwise the gain is the partner's own search run again, and
    it would be credited to an effect that adds nothing (a 0.02 ms lag beside a lone resonance,
    `mechanical_dynamics#3`): the joint search's result stands."""
    found = descend(fitter, joint, name, partner, workers)
    alone = fitter.score(tuple(s.without(name) for s in found.specs))      # type: ignore[arg-type]
    return found if alone.all_mse > fitter.score(base).all_mse else joint


def descend(fitter: Fitter, start: SearchResult, name: str, partner: str, workers: int) -> SearchResult:
    """From `start`: the partner's whole search (grid, zoom, polish) with `name` held, `name`'s with
    the partner held, then both polished together (`_joint_polish`). Coordinate steps alone zig-zag
    down the pair's coupled valley: on the fourth draw's eddy-and-resonance pair three rounds of them
    took 18-26 s and stopped short (all-data MSE 0.157 and 0.779 beside a lag and a delay); one round
    and the joint polish took 8-12 s and reached 0.158 and 0.577."""
    step = _own_search(fitter, start.specs, partner, workers, start=start.specs[2][partner])
    step = _own_search(fitter, step.specs, name, workers, start=step.specs[2][name])
    return _joint_polish(fitter, step, name, partner, workers)


def _joint_polish(fitter: Fitter, found: SearchResult, name: str, partner: str, workers: int) -> SearchResult:
    """Nelder-Mead over the pair's parameters together, from where `found` has them: the partner's own
    polish coordinates (a resonance's log frequency where the drive excites it, log damping, log
    moving mass) and the log of `name`'s one parameter (a lag's time constant, a delay). Its points
    are scored like any search's, so the folds choose among them; `found` stands for a partner
    without a polish."""
    space = REGISTRY[partner].polish(fitter, found.specs[2][partner])
    if space is None:
        return found
    n, partner_at = space
    own = float(found.specs[2][name])

    def at(x: np.ndarray) -> tuple[Any, float]:
        return partner_at(x[:n]), own * float(polish_factor(x[n]))

    def make(s: Spec, p: tuple[Any, float]) -> Spec:
        return s.with_(partner, p[0]).with_(name, p[1])

    without_both: Specs = tuple(s.without(name).without(partner) for s in found.specs)  # type: ignore[assignment]
    return search(fitter, without_both, make, [(found.specs[2][partner], own)],
                  polish=lambda _f, _p: (n + 1, at), workers=workers, polish_evals=JOINT_POLISH_EVALS)


def score_round(fitter: Fitter, base: Specs, loss_without: float, names: list[str], rnd: int,
                workers: int) -> tuple[list[Trial], float]:
    """Each effect of `names` searched on top of `base` and scored: the trials, best first (by
    held-out loss), and the effective sample count of the best one's held-out residual."""
    results = search_all(fitter, base, names, workers)
    if not names:
        return [], math.nan
    leader = min(names, key=lambda n: results[n].cv_loss)
    # effective sample count of the noise, from the best candidate's held-out residual
    n_eff = effective_samples(fitter.test_residuals(results[leader].specs), fitter.segment_lengths)
    gains = [loglik_gain(n_eff, loss_without, results[n].cv_loss, REGISTRY[n].count_params(fitter)) for n in names]
    trials = [Trial(n, results[n], params_of(fitter, n, results[n].specs[2], results[n].coef_all, results[n].names),
                    rnd, g) for n, g in zip(names, gains)]
    trials.sort(key=lambda t: t.cv_loss)
    return trials, n_eff
