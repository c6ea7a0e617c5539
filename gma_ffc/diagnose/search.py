"""Search one block's nonlinear parameters on held-out blocks: a grid, a zoom round the best points,
and a continuous polish (Nelder-Mead) where the zoom leaves them too coarse.

Each point is a spec the fitter (`fitting.Fitter`) scores: fold A's parameters fitted on fold A and
tested on fold B, and the other way round. Each fold chooses its own point by its training error,
so the held-out loss the selection compares never saw the rows it is measured on.
`leave_one_out_search` does the same with whole recordings left out in turn.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from .fitting import Fitter
from .specs import LeaveOneOut, LeftOut, Score, Spec

ZOOM_LEVELS = 3       # zoom levels of a search unless the effect says otherwise
POLISH_EVALS = 15     # per free coordinate: Nelder-Mead from the zoom's best point
POLISH_STEP = 0.03    # its first simplex: 3 % moves (the zoom's last steps are 0.5-1.5 %)


def _polish(fitter: Fitter, base: tuple[Spec, Spec, Spec], results: dict[Any, Score],
            run: Callable[[Iterable[Any]], None],
            polish: Callable[[Fitter, Any], tuple[int, Callable[[np.ndarray], Any]] | None],
            evals: int = POLISH_EVALS) -> None:
    """Nelder-Mead on the all-data training error from the best point so far; every point it
    visits joins `results`, so the folds choose among them too. Only for an effect whose best point
    already beats the spec without it on held-out blocks: polishing one that explains nothing
    would cost the evaluations and change no verdict."""
    from scipy.optimize import minimize

    best = min(results, key=lambda p: results[p].all_mse)
    space = polish(fitter, best)
    if space is None or sum(results[best].sq_test) >= sum(fitter.score(base).sq_test):
        return
    n, at = space

    def cost(x: np.ndarray) -> float:
        p = at(x)
        run([p])
        return results[p].all_mse

    f0 = results[best].all_mse
    simplex = np.vstack([np.zeros(n), POLISH_STEP * np.eye(n)])
    minimize(cost, np.zeros(n), method="Nelder-Mead",
             options={"initial_simplex": simplex, "maxfev": evals * n, "xatol": 1e-3,
                      "fatol": 1e-3 * max(f0, 1e-300)})


def _zoom_again(fitter: Fitter, results: dict[Any, Score], run: Callable[[Iterable[Any]], None],
                refine: Callable[[Fitter, Any, int], Sequence[Any] | None], zoom_levels: int,
                after_polish: Callable[[Fitter, Any], Sequence[Any]] | None = None) -> bool:
    """After the polish, the zoom's first level (and the effect's `after_polish` points) from its
    point; where that finds a better one, the other levels from there. A sharp resonance's load law
    shows only once its frequency and damping are close, and the zoom's law moves were made before
    the polish brought them close (the eighth general draw's resonance: the moving mass stayed 9x
    the plant's). True when the point moved."""
    def best() -> Any:
        return min(results, key=lambda p: results[p].all_mse)

    polished = best()
    run(list(refine(fitter, polished, 1) or []) + list(after_polish(fitter, polished) if after_polish else []))
    if best() == polished:
        return False
    for level in range(2, zoom_levels + 1):
        run(refine(fitter, best(), level) or [])
    return True


@dataclass
class SearchResult:
    specs: tuple[Spec, Spec, Spec]      # fold A, fold B, all data (each with the block's best parameters)
    cv_loss: float                      # held-out loss per sample (selection)
    cv_mse: float                       # held-out mean squared error (reported)
    all_mse: float
    n_test: int
    coef_all: np.ndarray
    names: list[str]
    evaluated: int


def search(fitter: Fitter, base: tuple[Spec, Spec, Spec], make: Callable[[Spec, Any], Spec],
           grid: Iterable[Any], refine: Callable[[Fitter, Any, int], Sequence[Any] | None] | None = None,
           zoom_levels: int = ZOOM_LEVELS,
           polish: Callable[[Fitter, Any], tuple[int, Callable[[np.ndarray], Any]] | None] | None = None,
           workers: int = 1, after_polish: Callable[[Fitter, Any], Sequence[Any]] | None = None,
           polish_evals: int = POLISH_EVALS) -> SearchResult:
    """Grid (plus local refinement, then an optional continuous polish of at most `polish_evals`
    evaluations per coordinate) over one block's parameters; per-fold choice by training error.
    The points of a grid or a zoom level are scored on up to `workers` threads (the kernels release
    the GIL): one effect's search can be most of a round (a resonance's 90-point grid took 24 s of a
    26 s round on 2 cores, the other thread idle)."""
    results: dict[Any, Score] = {}

    def score(p: Any) -> Score:
        return fitter.score((make(base[0], p), make(base[1], p), make(base[2], p)))

    def run(points: Iterable[Any]) -> None:
        new = list(dict.fromkeys(p for p in points if p not in results))      # in order, once each
        if workers > 1 and len(new) > 1:
            with ThreadPoolExecutor(max_workers=min(workers, len(new))) as pool:
                scores = list(pool.map(score, new))
        else:
            scores = [score(p) for p in new]
        results.update(zip(new, scores))       # in the points' order: ties go to the same point either way

    run(grid)
    if refine is not None:
        for level in range(1, zoom_levels + 1):
            best_points = {min(results, key=lambda p: results[p].train_mse(0)),
                           min(results, key=lambda p: results[p].train_mse(1)),
                           min(results, key=lambda p: results[p].all_mse)}
            for bp in best_points:
                run(refine(fitter, bp, level) or [])
    if polish is not None:
        _polish(fitter, base, results, run, polish, polish_evals)
        if refine is not None and _zoom_again(fitter, results, run, refine, zoom_levels, after_polish):
            _polish(fitter, base, results, run, polish, polish_evals)
    pa = min(results, key=lambda p: results[p].train_mse(0))
    pb = min(results, key=lambda p: results[p].train_mse(1))
    pall = min(results, key=lambda p: results[p].all_mse)
    ra, rb = results[pa], results[pb]
    n_test = ra.n_test[0] + rb.n_test[1]
    cv = (ra.sse_test[0] + rb.sse_test[1]) / max(n_test, 1)
    mse = (ra.sq_test[0] + rb.sq_test[1]) / max(n_test, 1)
    specs = (make(base[0], pa), make(base[1], pb), make(base[2], pall))
    final = fitter.score(specs, want_coef=True)
    assert final.coef_all is not None
    return SearchResult(specs, cv, mse, final.all_mse, n_test, final.coef_all, final.names, len(results))


def leave_one_out_search(fitter: Fitter, base: Spec, make: Callable[[Spec, Any], Spec], grid: Iterable[Any],
                         refine: Callable[[Fitter, Any, int], Sequence[Any] | None] | None = None,
                         zoom_levels: int = ZOOM_LEVELS) -> LeaveOneOut:
    """An effect's law judged on recordings it was not fitted on: for each recording left out, the
    effect's parameter chosen (grid, then zoom) by the training loss on the other recordings, its
    gains fitted there, and the left-out recording predicted. (No continuous polish: it would be
    one more search per recording.)"""
    results: dict[Any, list[LeftOut]] = {}

    def run(points: Iterable[Any]) -> None:
        for p in points:
            if p not in results:
                results[p] = fitter.left_out(make(base, p))

    run(grid)
    n = len(fitter.data)
    if refine is not None:
        for level in range(1, zoom_levels + 1):
            for bp in {min(results, key=lambda p: results[p][k].train_loss) for k in range(n)}:
                run(refine(fitter, bp, level) or [])
    chosen = [min(results, key=lambda p: results[p][k].train_loss) for k in range(n)]
    return LeaveOneOut.of([results[p][k] for k, p in enumerate(chosen)], chosen)
