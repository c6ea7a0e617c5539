#!/usr/bin/env python3
"""How well can any Prandtl-Ishlinskii core follow a case's nested minor loops? (issue 31)

    python scripts/pi_minor_loops.py [CASE ...]       (default: a null case and both play cases)

The light-load probe of `benchmarks.probes` ends with a two-tone drive: small fast loops nested
in a slow large one. For each case this prints three RMS errors on that part, in um:
  - `base`: the case's base model (identified on the 3 Hz loops), from its estimated start;
  - `width law`: the core identified on the same loops through the plant's loop width law
    expressed at the model's reference stress (the best the width law can do);
  - `self-fit`: an SDPI identified on the two-tone part itself (10 and 20 plays), the least
    error of the model class on those loops. A floor far above the noise means the loops break
    the class's rule (Masing's: minor loops are the major loop's branches, halved), and no law
    in stress can recover them;
  - `Preisach N`: a discrete Preisach model fitted on the same part by least squares, with free
    weights on N(N-1)/2 relays (an N-level grid over the probe's drive range) plus a linear term.
    Its minor loops need not be the major loop's (it obeys only congruency), so it tells whether
    a richer classical core would follow these loops. Its relays start from rest at the probe's
    minimum and run through the whole probe.

`--duhem` prints instead whether a Duhem class (Bouc-Wen elements, no return-point memory, like
the simulated rod's Jiles-Atherton magnetics) beside the plays would: fitted on the two-tone part
itself, and fitted on the probe's rising triangle before it (after its first second) then judged
on the two-tone part. A class that fits the loops only when it sees them is flexibility, not a law.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.cases import case_plant, case_recordings  # noqa: E402
from benchmarks.general import general_cases  # noqa: E402
from benchmarks.probes import _prediction, pooled, probe_recordings, probe_scores  # noqa: E402
from gma_ffc.effects.kernels import play_bank  # noqa: E402
from gma_ffc.extended import ExtendedModel  # noqa: E402
from gma_ffc.identify import SDPIIdentifier  # noqa: E402
from gma_ffc.recordings import Recording  # noqa: E402

TWO_TONE_FROM_S = 8.0          # the probe's rising triangle lasts 8 s; the two-tone drive follows
DEFAULT = ("gen:null#1@default", "gen:stress_dependent_play@default", "gen:stress_dependent_play@other")


def rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(a ** 2)))


def other_shape_probe(case) -> tuple[Recording, np.ndarray]:
    """The light-load probe and the mask of its two-tone part."""
    probe = next(p for p in probe_recordings(case) if p.name == "probe_other_shape.csv")
    return probe, probe.time_s >= probe.time_s[0] + TWO_TONE_FROM_S


def two_tone(case) -> Recording:
    probe, keep = other_shape_probe(case)
    return probe.rows(keep, "two_tone")


def relay_states(drive: np.ndarray, levels: int, span: tuple[float, float] | None = None) -> np.ndarray:
    """States (0 down, 1 up) of the Preisach relays alpha > beta on a `levels` grid over `span`
    (default: the drive's range), from rest."""
    grid = np.linspace(*(span or (drive.min(), drive.max())), levels)
    up, down = np.meshgrid(grid, grid, indexing="ij")
    above = down < up
    up, down = up[above], down[above]
    state = np.zeros(up.size)
    out = np.empty((drive.size, up.size))
    for k, u in enumerate(drive):
        state[u >= up] = 1.0
        state[u <= down] = 0.0
        out[k] = state
    return out


def fitted_rms(cols: np.ndarray, y: np.ndarray, train: np.ndarray, test: np.ndarray) -> float:
    """RMS on `test` of a least-squares fit (with an offset) on `train`."""
    a = np.column_stack([cols, np.ones(y.size)])
    w = np.linalg.lstsq(a[train], y[train], rcond=None)[0]
    return rms(a[test] @ w - y[test])


def preisach_self_fit(case, levels: int) -> float:
    """RMS of a least-squares Preisach fit on the two-tone part (relays from the probe's start)."""
    probe, keep = other_shape_probe(case)
    cols = np.column_stack([relay_states(probe.drive, levels), probe.drive])
    return fitted_rms(cols, probe.displacement_um, keep, keep)


def bouc_wen(drive: np.ndarray, beta: float, gamma: float, substeps: int = 20) -> np.ndarray:
    """A Bouc-Wen element (exponent 1, unit slope) from rest: dz = du - beta |du| z - gamma du |z|."""
    z = np.zeros(drive.size)
    for k in range(1, drive.size):
        du = (drive[k] - drive[k - 1]) / substeps
        zk = z[k - 1]
        for _ in range(substeps):
            zk += du - beta * abs(du) * zk - gamma * du * abs(zk)
        z[k] = zk
    return z


def play_columns(drive: np.ndarray, n: int = 20) -> np.ndarray:
    """n plays over half the drive's span, from its first value, and their squares (a PI core's
    output map, as the SDPI's dead-zones give it)."""
    span = float(np.ptp(drive))
    out = play_bank(np.ascontiguousarray(drive, dtype=float), np.linspace(0.0, 0.45 * span, n), float(drive[0]))
    return np.column_stack([out, out ** 2 / span])


def duhem_columns(drive: np.ndarray) -> np.ndarray:
    """25 Bouc-Wen elements (rates 2-40 per drive span, five ratios of gamma to beta) and their squares."""
    span = float(np.ptp(drive))
    cols = []
    for rate in (2, 5, 10, 20, 40):
        for rho in (-0.9, -0.5, 0.0, 0.5, 0.9):
            a = rate / span
            cols.append(bouc_wen(drive, a * (1 - rho) / 2, a * (1 + rho) / 2))
    z = np.column_stack(cols)
    return np.column_stack([z, z ** 2 / span])


def print_duhem(name: str, case) -> None:
    """The plays alone and beside the Duhem elements: self-fit and carried from the triangle."""
    probe, keep = other_shape_probe(case)
    y = probe.displacement_um
    triangle = (probe.time_s > probe.time_s[0] + 1.0) & ~keep
    plays = play_columns(probe.drive)
    both = np.column_stack([plays, duhem_columns(probe.drive)])
    print(f"{name}: two-tone part, self-fit: plays {fitted_rms(plays, y, keep, keep):.3f}, plays + Duhem "
          f"{fitted_rms(both, y, keep, keep):.3f} um; fitted on the triangle: plays {fitted_rms(plays, y, triangle, keep):.3f}, "
          f"plays + Duhem {fitted_rms(both, y, triangle, keep):.3f} um", flush=True)


def width_law_model(case, model, recordings):
    """The core identified on `recordings` through the plant's own width law, at the model's
    reference stress."""
    mag = case_plant(case).magnetics
    if not mag.stress_dependent_width:
        return None
    ref = float(model.reference_stress_MPa)
    k = mag.width_change_per_MPa / (1.0 + mag.width_change_per_MPa * (mag.width_reference_MPa - ref))
    core = SDPIIdentifier(loop_width=(k, ref)).fit(recordings).model_
    return ExtendedModel(core, {"loop_width": {"kappa_per_MPa": k, "stress_ref_MPa": ref}})


def print_pooled(name: str, case) -> None:
    """The pooled probe RMS of cores identified on more data than the loops (see the docstring)."""
    model, ident, rec = case_recordings(case)
    probes = probe_recordings(case)
    cores = {"width law": lambda: width_law_model(case, model, ident),
             "width law, loops + recording": lambda: width_law_model(case, model, [*ident, rec]),
             "plain, loops + recording": lambda: SDPIIdentifier().fit([*ident, rec]).model_}
    for label, make in cores.items():
        core = make()
        if core is None:                           # an effect-free plant has no width law
            continue
        scores = probe_scores(model, core, probes)
        before, after = pooled(scores, "base_um"), pooled(scores, "extended_um")
        shape = next(s for s in scores if s.name == "probe_other_shape.csv")
        print(f"{name}, {label}: probes {before:.3f} -> {after:.3f} um ({before / after:.2f}x); "
              f"light-load probe {shape.base_um:.3f} -> {shape.extended_um:.3f} um", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*", default=list(DEFAULT))
    ap.add_argument("--pooled", action="store_true", help="pooled probe RMS of cores fitted on more data")
    ap.add_argument("--duhem", action="store_true", help="a Duhem class beside the plays, self-fit and carried")
    args = ap.parse_args()
    by_name = {c.name: c for c in general_cases()}
    for name in args.cases:
        case = by_name[name]
        if args.pooled:
            print_pooled(name, case)
            continue
        if args.duhem:
            print_duhem(name, case)
            continue
        model, ident, _ = case_recordings(case)
        part = two_tone(case)
        y = part.displacement_um
        row = {"base": rms(_prediction(model, part) - y)}
        wide = width_law_model(case, model, ident)
        if wide is not None:                       # an effect-free plant has no width law
            row["width law"] = rms(_prediction(wide, part) - y)
        for n_play in (10, 20):
            own = SDPIIdentifier(n_play=n_play).fit([part]).model_
            row[f"self-fit {n_play}"] = rms(own.simulate(part.time_s, part.drive, part.stress_MPa,
                                                         measured_um=y) - y)
        for levels in (30, 45):
            row[f"Preisach {levels}"] = preisach_self_fit(case, levels)
        figures = ", ".join(f"{k} {v:.3f}" for k, v in row.items())
        print(f"{name}: two-tone part ({np.ptp(y):.1f} um peak to peak): {figures}", flush=True)


if __name__ == "__main__":
    main()
