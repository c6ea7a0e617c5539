"""How many CPUs a diagnosis uses (`GMA_FFC_CPUS`): at most one search thread per usable CPU, the
same result whatever the count, and a bad value is the user's to fix."""

from __future__ import annotations

import os

import pytest

from benchmarks import cases as bench
from gma_ffc.diagnose.selection import EffectSelector, usable_cpus
from gma_ffc.errors import InputError


def test_the_environment_caps_the_search_threads(monkeypatch):
    monkeypatch.setenv("GMA_FFC_CPUS", "3")
    assert usable_cpus() == 3
    monkeypatch.delenv("GMA_FFC_CPUS")
    assert usable_cpus() == len(os.sched_getaffinity(0))


@pytest.mark.parametrize("text", ["two", "0", "-1", "1.5"])
def test_a_bad_cpu_count_says_what_to_give(monkeypatch, text):
    monkeypatch.setenv("GMA_FFC_CPUS", text)
    with pytest.raises(InputError, match="GMA_FFC_CPUS.*whole number from 1 up.*unset it"):
        usable_cpus()


def test_one_thread_or_two_give_the_same_diagnosis(monkeypatch):
    case = {c.name: c for c in bench.cases()}["thermal_drift#3"]
    model, rec = bench.make_case(case, scale=0.2)     # 7.8 s of it: heating is named there too, at a third of the cost
    runs = {}
    for cpus in ("1", "2"):
        monkeypatch.setenv("GMA_FFC_CPUS", cpus)
        sel = EffectSelector(workers=2).fit(model, [rec])
        runs[sel.threads_] = sel.diagnosis_
    assert sorted(runs) == [1, 2]
    one, two = runs[1], runs[2]
    assert one.verdict == two.verdict == ["thermal_drift"]
    assert one.rms_after_um == two.rms_after_um      # each score is computed alone: no sum's order depends on threads
