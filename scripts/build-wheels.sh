#!/usr/bin/env bash
# Builds the three wheels into DIR (default ./dist), reusing the repository's
# cargo target dir (after scripts/setup.sh the Rust parts are already compiled
# and this takes seconds):
#   sensaug        python/sensaug + the compiled core (maturin, root pyproject.toml)
#   sensaug-bridge firmware_bridge/python/sensaug_bridge + hi5.dbc, *.eds as package data
#   sensaug-rt     the real-time binary, installed on PATH (maturin bin, crates/sensaug-rt)
# Install: pip install DIR/*.whl (docs: README, "Install").
# Runs scripts/setup.sh first (maturin, the warm target dir) unless
# SENSAUG_SKIP_SETUP=1 (tests/test_install.py, inside an already set-up run).
set -euo pipefail
cd "$(dirname "$0")/.."
[ "${SENSAUG_SKIP_SETUP:-0}" = 1 ] || bash scripts/setup.sh
OUT=$(realpath -m "${1:-dist}")
mkdir -p "$OUT"
.venv/bin/maturin build -q -o "$OUT"  # profile: pyproject.toml
.venv/bin/maturin build --release -q -m crates/sensaug-rt/Cargo.toml -o "$OUT"
# setuptools builds in firmware_bridge/build and keeps files there between
# builds: start clean so a removed data file cannot reach the wheel.
rm -rf firmware_bridge/build
.venv/bin/python -m pip wheel -q --no-deps -w "$OUT" ./firmware_bridge
rm -rf firmware_bridge/build
ls "$OUT"/*.whl
