"""The benchmark scripts refuse what would silently measure nothing."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_bench_diagnose_refuses_an_only_filter_that_matches_no_case():
    """A full case name with its set's prefix ("thirteenth:thermal") matched nothing: the script
    printed nothing and exited 0, as if the set had run."""
    run = subprocess.run([sys.executable, "scripts/bench_diagnose.py", "--set", "general-thirteenth", "--only",
                          "thirteenth:thermal", "--no-probes"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert "no case of --set general-thirteenth" in run.stderr and "thermal_drift@default" in run.stderr
