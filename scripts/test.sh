#!/usr/bin/env bash
# Install gma-ffc with its test extras into .venv, type-check, and run the whole test suite on 3 workers.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet -e '.[test]'
.venv/bin/python -m mypy          # the typed part of the package (pyproject.toml [tool.mypy]) must stay clean
# Three workers on two cores: the real-time tests go to one of them, together (`--dist loadgroup`,
# tests/conftest.py), and mostly wait on the wall clock; the other two keep the cores busy meanwhile.
exec .venv/bin/python -m pytest -n 3 --dist loadgroup "$@"
