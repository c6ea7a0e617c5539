"""No function in gma_ffc/ is longer than 60 lines (issue 34, first for control/): short enough to
read at once.

A function's length is its span in the source, from its `def` line (decorators included) to its
last line, docstring and comments included: what a reader has to hold in view. Nested functions
count inside their parent, and on their own too."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "gma_ffc"
MAX_LINES = 60


def function_lengths(source: str) -> dict[str, int]:
    """{qualified name: lines} of every function and method in `source`."""
    out: dict[str, int] = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                first = min([child.lineno] + [d.lineno for d in child.decorator_list])
                out[prefix + child.name] = child.end_lineno - first + 1   # type: ignore[operator]
                visit(child, prefix + child.name + ".")
            elif isinstance(child, ast.ClassDef):
                visit(child, prefix + child.name + ".")
            else:
                visit(child, prefix)

    visit(ast.parse(source), "")
    return out


def test_the_measure_counts_what_a_reader_sees():
    src = "class A:\n    @staticmethod\n    def f():\n        '''doc'''\n\n        return 1\n\n\ndef g():\n    def h():\n        pass\n"
    assert function_lengths(src) == {"A.f": 5, "g": 3, "g.h": 2}     # decorator to last line


def test_no_function_in_the_package_is_over_60_lines():
    files = sorted(PACKAGE.rglob("*.py"))
    assert len(files) >= 80                        # the package is where the test looks
    long = {f"{path.relative_to(PACKAGE)}:{name}": n for path in files
            for name, n in function_lengths(path.read_text()).items() if n > MAX_LINES}
    assert not long, f"functions over {MAX_LINES} lines: {long}"
