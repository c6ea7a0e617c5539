#!/usr/bin/env bash
# Regenerate the example models shipped in config/models/ from the simulated actuator, so the
# example configs run out of the box. Deterministic (fixed seed).
set -euo pipefail
cd "$(dirname "$0")/.."
GMA=${GMA:-.venv/bin/gma-ffc}
PY=${PY:-.venv/bin/python}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
"$PY" -m hil_sim record --kind identification --out "$tmp" --seed 2026 --effects noise >/dev/null
mkdir -p config/models
"$GMA" identify "$tmp"/identification_*.csv -o config/models/sim_sdpi.yaml
"$GMA" identify "$tmp"/identification_-11.3MPa.csv -o config/models/sim_mpi_11MPa.yaml
