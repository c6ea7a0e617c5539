"""Plots people look at before they read numbers (matplotlib, headless Agg backend)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .atomic import atomic_write
from .drive import drive_quantity, drive_unit
from .errors import InputError
from .identification_checks import burn_in_end
from .protocols import Model
from .recordings import Recording


def _figure(nrows: int, ncols: int, size: tuple[float, float]) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(nrows, ncols, figsize=size, squeeze=False, constrained_layout=True)


def check_plot_name(path: str | Path, option: str = "--plot") -> None:
    """InputError, before any work, unless matplotlib writes an image format named by `path`'s
    suffix (a name without one is saved as PNG). Its own list, so the two never disagree."""
    if str(path) == "-":
        raise InputError(f"{option} -: plots are saved to a file, not to standard output; "
                         "give a name such as loops.png")
    suffix = Path(path).suffix.lstrip(".").lower()
    if not suffix:
        return
    from matplotlib.backend_bases import FigureCanvasBase

    formats = FigureCanvasBase.get_supported_filetypes()
    if suffix not in formats:
        raise InputError(f"{option} {path}: cannot save a plot as .{suffix}; name it "
                         f"{Path(path).with_suffix('.png')} (or .{', .'.join(sorted(formats))})")


def save_figure(fig: Any, path: str | Path) -> None:
    """Save atomically (a crash never leaves half an image) and free the figure."""
    import matplotlib.pyplot as plt

    fmt = Path(path).suffix.lstrip(".").lower() or "png"
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, format=fmt, dpi=110, bbox_inches="tight")
    plt.close(fig)


def plot_loops(model: Model, recordings: Sequence[Recording], path: str | Path | None = None,
               fitted_from: Sequence[int] | None = None) -> Any:
    """Measured vs modelled loops, one column per recording, and under each the residual over
    time on its own scale (the loops hide a 0.1 um misfit that the residual shows). Returns the
    figure when no path is given (tests check its layout). `fitted_from`: each recording's first
    fitted sample as identify scored it (`RecordingFit.fitted_from`; 0 where every sample was
    fitted, as for a recording whose first sweep is a large share of it); else after the first sweep."""
    n = len(recordings)
    fig, axes = _figure(2, n, (3.6 * n + 1.4, 5.6))
    greyed = False
    for k, rec in enumerate(recordings):
        ax, axr = axes[0, k], axes[1, k]
        measured = rec.column("displacement_um")
        stress = rec.stress_MPa if model.stress_range_MPa is not None else None
        pred = model.simulate(rec.time_s, rec.drive, stress, measured_um=measured)
        start = burn_in_end(rec.drive) if fitted_from is None else int(fitted_from[k])
        ax.plot(rec.drive[start:], measured[start:], lw=1.0, color="0.3", label="measured")
        ax.plot(rec.drive[start:], pred[start:], lw=1.0, color="tab:red", ls="--", label="model")
        err = np.sqrt(np.mean((pred[start:] - measured[start:]) ** 2))
        # the same number, rounded the same way, as identify's table
        title = rec.name if rec.stress_MPa is None else f"{np.median(rec.stress_MPa):.4g} MPa"
        ax.set_title(f"{title}  (RMS {err:.4f} um)", fontsize=9)
        unit = drive_unit(rec.drive_name)
        ax.set_xlabel(f"{drive_quantity(rec.drive_name)} ({unit})")
        ax.set_ylabel("displacement (um)")
        ax.grid(alpha=0.3)
        axr.plot(rec.time_s, measured - pred, lw=0.7, color="tab:red")
        if start > 0:
            axr.axvspan(rec.time_s[0], rec.time_s[start], color="0.85", alpha=0.7)
            greyed = True
        axr.set_xlabel("time (s)")
        axr.set_ylabel("measured - model (um)")
        axr.grid(alpha=0.3)
    axes[0, -1].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), frameon=False)
    fig.suptitle(f"{model.kind.upper()} model vs measurements" + (" (grey: first sweep, not fitted)" if greyed else ""),
                 fontsize=11)
    if path is None:
        return fig
    save_figure(fig, path)
    return None
