#!/usr/bin/env bash
# Install gma-ffc with its test extras into .venv, type-check, and run the whole test suite on 2 workers.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet -e '.[test]'
.venv/bin/python -m mypy          # the typed part of the package (pyproject.toml [tool.mypy]) must stay clean
exec .venv/bin/python -m pytest -n 2 "$@"
