"""Plots people look at before they read numbers (matplotlib, headless Agg backend)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .atomic import atomic_write
from .identify import burn_in_end
from .recordings import Recording


def _figure(nrows: int, ncols: int, size: tuple[float, float]) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(nrows, ncols, figsize=size, squeeze=False, constrained_layout=True)


def save_figure(fig: Any, path: str | Path) -> None:
    """Save atomically (a crash never leaves half an image) and free the figure."""
    import matplotlib.pyplot as plt

    fmt = Path(path).suffix.lstrip(".").lower() or "png"
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, format=fmt, dpi=110, bbox_inches="tight")
    plt.close(fig)


def plot_loops(model: Any, recordings: Sequence[Recording], path: str | Path) -> None:
    """Measured vs modelled displacement-current loops, one panel per recording."""
    n = len(recordings)
    cols = min(n, 4)
    rows = (n + cols - 1) // cols
    fig, axes = _figure(rows, cols, (3.6 * cols, 3.0 * rows))
    for ax, rec in zip(axes.flat, recordings):
        stress = rec.stress_MPa if getattr(model, "stress_range_MPa", None) is not None else None
        pred = model.simulate(rec.time_s, rec.drive, stress)
        start = burn_in_end(rec.drive)
        ax.plot(rec.drive[start:], rec.displacement_um[start:], lw=1.0, color="0.3", label="measured")
        ax.plot(rec.drive[start:], pred[start:], lw=1.0, color="tab:red", ls="--", label="model")
        err = np.sqrt(np.mean((pred[start:] - rec.displacement_um[start:]) ** 2))
        title = rec.name if rec.stress_MPa is None else f"{np.median(rec.stress_MPa):.3g} MPa"
        ax.set_title(f"{title}  (RMS {err:.3f} um)", fontsize=9)
        ax.set_xlabel(rec.drive_name.replace("_", " [") + "]")
        ax.set_ylabel("displacement [um]")
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    axes.flat[0].legend(fontsize=8)
    fig.suptitle(f"{model.kind.upper()} model vs measurements", fontsize=11)
    save_figure(fig, path)
