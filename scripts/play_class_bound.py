"""How far the identification loops let a play model go on the probes (issue 31's 1.5x on play cases).

Stress-dependent play stays below issue 31's 1.5x on its probes at other loads, rates and shapes.
The effect-free twin's floor says the model class could do better. This asks three sharper questions,
per probe held at one load (the other-rate and other-shape probes):

* at-stress: the PI core identified on the one identification loop nearest the probe's stress, as a
  lab would identify at that load. It knows the loop width there exactly, with no law across loads.
* at-stress, rising: the PI core identified at the probe's load on a 3 Hz sine whose amplitude rises
  from the drive's minimum to its peak and decays back (8 s), recorded from the case's actuator:
  the standard identification experiment, with nested minor loops the full loops lack.
* self-fit: the PI core identified on the probe itself, scored on it. What the class can reach on
  that drive when it is fitted to it (a bound no model fitted elsewhere can be asked to reach).

Where the diagnosis' extended model already beats at-stress, the loops the lab identified on do not
fix the probe's minor loops; where at-stress rising does no better, neither do minor loops to fit on.
The gap to self-fit is then beyond any core identified on loops, not in the width law
(`scripts/play_minor_loops.py`, `scripts/return_point_memory.py`). Each case is diagnosed as
`scripts/bench_diagnose.py --set general-DRAW` does.

    python scripts/play_class_bound.py                          # the twenty-fourth draw's play cases
    python scripts/play_class_bound.py --draw twenty-third fifth
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

PLAY = "stress_dependent_play"


def draw_cases(draw: str, truths: tuple[tuple[str, ...], ...] = ((PLAY,),)) -> list:
    """The cases of a general draw (by its name in `bench_diagnose.py --set general-NAME`) whose
    missing physics is one of `truths` (default: the play cases)."""
    from benchmarks import general
    seed = getattr(general, f"GENERAL_{draw.upper().replace('-', '_')}_SEED", None)
    if seed is None:
        raise SystemExit(f"{Path(sys.argv[0]).stem}: error: no draw '{draw}' in benchmarks/general.py "
                         "(names as in bench_diagnose.py --set general-NAME, e.g. twenty-fourth)")
    return [c for c in general.general_cases(seed, prefix=draw) if c.truth in truths]


def rising_at(case, stress_MPa: float):
    """A rising-and-decaying 3 Hz sine at the load that gives `stress_MPa`, from the case's actuator
    (preconditioned, as the rising family's identification runs), as the case's user records it."""
    from benchmarks.cases import FS, _variant, case_plant, record

    cfg = case_plant(case)
    t = np.arange(int(8.0 * FS)) / FS
    i = np.sin(np.pi * t / t[-1]) ** 2 * 0.5 * case.id_max * (1 - np.cos(2 * np.pi * 3.0 * t))
    rec = record(cfg, t, i, cfg.mass_for_stress(stress_MPa), "rising_at_stress.csv", case.seed * 10 + 9,
                 preconditioned=True)
    return _variant(rec, dataclasses.replace(case, falling=False) if case.voltage else case)   # as its loops


def one_case(case) -> None:
    from benchmarks.probes import case_recordings, probe_recordings, probe_scores
    from gma_ffc.diagnose.engine import diagnose
    from gma_ffc.identify import identify

    model, ident, rec = case_recordings(case)
    extended = diagnose(model, [rec], identification=ident).extended
    for probe in probe_recordings(case):
        if np.ptp(probe.stress_MPa) > 0.5:           # the history probe changes its load: no one loop is "at" it
            continue
        level = float(np.median(probe.stress_MPa))
        nearest = min(ident, key=lambda r: abs(float(np.median(r.stress_MPa)) - level))
        others = {"extended": extended, "at-stress": identify([nearest]),
                  "at-stress rising": identify([rising_at(case, level)]), "self-fit": identify([probe])}
        # each on the same samples: from where the base's state is known (`probe_scores`)
        scores = {name: probe_scores(model, other, [probe])[0] for name, other in others.items()}
        figures = {"base": scores["extended"].base_um, **{name: sc.extended_um for name, sc in scores.items()}}
        print(f"{case.name:44s} {probe.name:22s} {level:7.2f} MPa ({nearest.name} at "
              f"{float(np.median(nearest.stress_MPa)):6.2f})  "
              + "  ".join(f"{k} {v:.3f}" for k, v in figures.items()), flush=True)


def each_play_case(doc: str, header: str, per_case, argv: list[str] | None = None,
                   truths: tuple[tuple[str, ...], ...] = ((PLAY,),)) -> int:
    """The command line the play scripts share: `--draw NAME ...`, then `per_case` on each case of
    those draws whose missing physics is one of `truths` (default: the play cases)."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--draw", nargs="+", default=["twenty-fourth"], help="general draws by name")
    args = ap.parse_args(argv)
    cases = [case for draw in args.draw for case in draw_cases(draw, truths)]     # a bad name stops before any output
    print(header)
    for case in cases:
        per_case(case)
    return 0


def main(argv: list[str] | None = None) -> int:
    return each_play_case(__doc__ or "", "RMS in um on each probe held at one load, from where the base's state is known",
                          one_case, argv)


if __name__ == "__main__":
    raise SystemExit(main())
