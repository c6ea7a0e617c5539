"""The nightly tier (`nightly`, pyproject.toml; `scripts/test.sh --nightly`) holds only past
never-tuned draws' cases: the default suite keeps every other test, so leaving the tier out keeps
the suite within 15 minutes without leaving a feature untested there."""

from __future__ import annotations

import ast
import re
from pathlib import Path

TESTS = Path(__file__).parent
PAST_DRAW = re.compile(r"GENERAL_[A-Z_]+_SEED")


def _nightly_tests() -> list[tuple[str, ast.FunctionDef]]:
    found = []
    for path in sorted(TESTS.glob("test_*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and any(
                    "nightly" in ast.unparse(d) for d in node.decorator_list):
                found.append((path.name, node))
    return found


def test_every_nightly_test_diagnoses_a_past_draws_case():
    tests = _nightly_tests()
    assert tests, "no test is marked nightly: drop the marker and the --nightly option, or mark the draws' cases"
    for name, fn in tests:
        assert PAST_DRAW.search(ast.unparse(fn)), f"{name}::{fn.name} is nightly but names no past draw's seed"


def test_the_default_suite_leaves_out_the_nightly_tier_and_the_nightly_run_takes_it_in():
    script = (TESTS.parent / "scripts" / "test.sh").read_text()
    assert 'tier=(-m "not nightly")' in script and '"${1:-}" = "--nightly"' in script
    assert "scripts/test.sh --nightly" in (TESTS.parent / ".ci" / "nightly").read_text()
