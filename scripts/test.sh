#!/usr/bin/env bash
# Install gma-ffc with its test extras into .venv, type-check, and run the test suite on 3 workers.
# `scripts/test.sh --nightly` runs the nightly tier too (.ci/nightly): the past never-tuned draws'
# cases diagnosed end to end (pyproject.toml's `nightly` marker), 30-100 s each on 2 cores, which
# would take the suite past its 15 minutes. Other arguments go to pytest.
set -euo pipefail
tier=(-m "not nightly")
if [ "${1:-}" = "--nightly" ]; then
    tier=()
    shift
fi
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install --quiet --upgrade pip
# --no-compile: pip would byte-compile every module of every dependency (16 of 34 s on a clean clone);
# Python compiles the ones the tests import, once, when they first load
.venv/bin/python -m pip install --quiet --no-compile -e '.[test]'
# ... which needs Python allowed to write that bytecode. A host that forbids it (PYTHONDONTWRITEBYTECODE,
# set on some CI images) makes every process compile scipy, pyarrow and the package from source again:
# 6.4 s against 2.3 s to import the CLI, paid by each xdist worker and each CLI run a test starts.
# The bytecode goes into this checkout's own .venv and __pycache__ folders (.gitignore).
unset PYTHONDONTWRITEBYTECODE
# The type-check (the typed part of the package, pyproject.toml [tool.mypy]) runs beside the tests: it
# is one process for ~14 s, and the tests leave a core idle for longer than that while their workers
# start and finish. Its verdict still decides: the script fails when mypy finds anything.
mypy_log=$(mktemp)
.venv/bin/python -m mypy >"$mypy_log" 2>&1 &
mypy_pid=$!
trap 'kill "$mypy_pid" 2>/dev/null || true; rm -f "$mypy_log"' EXIT
# Three workers on two cores: the real-time tests go to one of them, together (`--dist loadgroup`,
# tests/conftest.py), and mostly wait on the wall clock; the other two keep the cores busy meanwhile.
# --durations: the slowest tests are printed at the end, so a suite that nears its 15 minutes shows where
tests=0
.venv/bin/python -m pytest -n 3 --dist loadgroup --durations=15 ${tier[@]+"${tier[@]}"} "$@" || tests=$?
types=0
wait "$mypy_pid" || types=$?
cat "$mypy_log"
if [ "$types" -ne 0 ]; then
    echo "mypy found type errors (above): fix them, then run this script again" >&2
    exit "$types"
fi
exit "$tests"
