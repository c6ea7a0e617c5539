#!/usr/bin/env bash
# Install gma-ffc into .venv and run the whole job on the built-in simulated actuator.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet -e .
exec .venv/bin/gma-ffc demo "$@"
