#!/usr/bin/env python3
"""Does the advice for an effect short only of the evidence work? (`outcome.short_of_the_evidence`)

    python scripts/short_of_the_evidence.py

The nineteenth general draw's stress-dependent play on the default actuator (never tuned) took all
an effect must of the held-out error, with 5.98 nats of evidence where 6 are needed. Its diagnosis
is run three times, each with its identification loops: on the recording as drawn; on one twice as
long (the same drive kind, 84 s); and on that longer one cut into two runs of 42 s, each with its
own start and sensor zero, as two sessions would be. Prints each outcome, verdict, the rounds'
effective samples and the best's evidence, and the note the first one gives.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.cases import case_recordings  # noqa: E402
from benchmarks.general import GENERAL_NINETEENTH_SEED, general_cases  # noqa: E402
from gma_ffc.diagnose.engine import diagnose  # noqa: E402

CASE = "nineteenth:stress_dependent_play@default"


def summary(label: str, dg) -> str:
    rounds = "; ".join(f"round {r['round']}: {r['n_eff']:.0f} effective samples, best {r['table'][0][0]} "
                       f"{r['table'][0][2]:.3g} nats" for r in dg.rounds if r['table'])   # none: all set aside
    return f"{label}: {dg.outcome}, verdict {dg.verdict or '-'} ({rounds})"


def main() -> None:
    case = {c.name: c for c in general_cases(GENERAL_NINETEENTH_SEED, prefix="nineteenth")}[CASE]
    model, ident, rec = case_recordings(case)
    dg = diagnose(model, [rec], identification=ident)
    print(summary(f"one run, {rec.time_s[-1]:.0f} s", dg), flush=True)
    for note in dg.cannot_conclude:
        if "may be what is missing" in note:
            print(f"  note: {note}")
    model, ident, long_run = case_recordings(case, scale=2.0)
    print(summary(f"one run twice as long, {long_run.time_s[-1]:.0f} s",
                  diagnose(model, [long_run], identification=ident)), flush=True)
    half = long_run.time_s[-1] / 2
    runs = [long_run.rows(long_run.time_s < half, "first.csv"), long_run.rows(long_run.time_s >= half, "second.csv")]
    print(summary("the same as two runs", diagnose(model, runs, identification=ident)), flush=True)


if __name__ == "__main__":
    main()
