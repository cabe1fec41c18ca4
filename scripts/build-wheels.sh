#!/usr/bin/env bash
# Builds the three wheels into DIR (default ./dist), reusing the repository's
# cargo target dir (after scripts/setup.sh the Rust parts are already compiled
# and this takes seconds):
#   sensaug        python/sensaug + the compiled core (maturin, root pyproject.toml)
#   sensaug-bridge firmware_bridge/python/sensaug_bridge + hi5.dbc, *.eds as package data
#   sensaug-rt     the real-time binary, installed on PATH (maturin bin, crates/sensaug-rt)
# Install: pip install DIR/*.whl (docs: README, "Install").
# Needs the .venv of scripts/setup.sh (maturin, pip).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=$(realpath -m "${1:-dist}")
mkdir -p "$OUT"
.venv/bin/maturin build --release -q -o "$OUT"
.venv/bin/maturin build --release -q -m crates/sensaug-rt/Cargo.toml -o "$OUT"
# setuptools builds in firmware_bridge/build and keeps files there between
# builds: start clean so a removed data file cannot reach the wheel.
rm -rf firmware_bridge/build
.venv/bin/python -m pip wheel -q --no-deps -w "$OUT" ./firmware_bridge
rm -rf firmware_bridge/build
ls "$OUT"/*.whl
