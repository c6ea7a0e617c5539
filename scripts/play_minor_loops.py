"""Where the play cases' other-shape probe misses, and whether a Preisach core would reach it.

`scripts/play_class_bound.py` found that no PI core identified away from the other-shape probe does
better than the base there. This splits that probe into its two parts (an 8 s triangle whose
amplitude rises from the drive's minimum and decays back, then a two-tone drive: small fast loops
inside slow ones) and adds a discretised Preisach core: relays on a grid of LEVELS drive levels,
weighted by ridge least squares (a class whose minor loops are free, unlike a PI core's). Each core
is identified on a 3 Hz rising-amplitude sine at the probe's load (`play_class_bound.rising_at`),
and, as the class's bound, on the probe itself. RMS in um on the base's settled samples.

    python scripts/play_minor_loops.py                      # the twenty-fourth draw's play cases
    python scripts/play_minor_loops.py --draw twenty-third
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from pi_minor_loops import other_shape_probe, relay_states  # noqa: E402

LEVELS = 48            # relay grid: 16 levels left a staircase of 0.2 A steps (self-fit worse than the base)
RIDGE = 1e-3           # of the mean diagonal of X'X: relays no sample tells apart stay small


def relay_design(u: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """An offset column and the relays' states on the shared grid, all down at the start (a rod at
    rest at the drive's minimum)."""
    return np.column_stack([np.ones(u.size), relay_states(u, LEVELS + 1, (lo, hi))])


def preisach_fit(X: np.ndarray, y: np.ndarray, start: int = 0) -> np.ndarray:
    """Relay weights by ridge least squares on the rows from `start` on."""
    X, y = X[start:], y[start:]
    G = X.T @ X
    return np.linalg.solve(G + RIDGE * np.trace(G) / G.shape[0] * np.eye(G.shape[0]), X.T @ y)


def one_case(case) -> None:
    from benchmarks.probes import _prediction, case_recordings
    from gma_ffc.identify import identify
    from gma_ffc.initial_state import settled_index
    from play_class_bound import rising_at

    model, _, _ = case_recordings(case)
    probe, two_tone = other_shape_probe(case)
    rising = rising_at(case, float(np.median(probe.stress_MPa)))
    lo, hi = min(rising.drive.min(), probe.drive.min()), max(rising.drive.max(), probe.drive.max())
    start = min(settled_index(model, probe.drive), probe.time_s.size - 1)
    y = probe.displacement_um
    on_probe = relay_design(probe.drive, lo, hi)
    predictions = {
        "base": _prediction(model, probe),
        "PI rising": _prediction(identify([rising]), probe),
        "Preisach rising": on_probe @ preisach_fit(relay_design(rising.drive, lo, hi), rising.displacement_um),
        "PI self-fit": _prediction(identify([probe]), probe),
        "Preisach self-fit": on_probe @ preisach_fit(on_probe, y, start),
    }
    cut = int(np.argmax(two_tone))
    for part, rows in (("whole", slice(start, None)), ("triangle", slice(start, cut)), ("two-tone", slice(cut, None))):
        cells = "  ".join(f"{k} {np.sqrt(np.mean((v - y)[rows] ** 2)):.3f}" for k, v in predictions.items())
        print(f"{case.name:44s} {part:9s} {cells}", flush=True)


def main(argv: list[str] | None = None) -> int:
    from play_class_bound import each_play_case

    return each_play_case(__doc__ or "", "RMS in um on the other-shape probe, from where the base's state is known",
                          one_case, argv)


if __name__ == "__main__":
    raise SystemExit(main())
