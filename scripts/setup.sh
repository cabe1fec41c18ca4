#!/usr/bin/env bash
# Creates .venv (if missing), installs the Python dependencies and builds the
# extension module into it. Idempotent; every other script starts with it.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -r requirements-dev.txt
# The CAN bridge package: virtual Hi5 driver, python-can plugin (entry point).
# First: sensaug depends on it, and it is not on PyPI.
.venv/bin/python -m pip install -q -e firmware_bridge
# maturin develop installs the package in editable mode with the compiled
# module built optimised: the profile is pyproject.toml's `extension`
# (release + thin LTO; the estimators are too slow unoptimised).
VIRTUAL_ENV="$PWD/.venv" .venv/bin/maturin develop -q
# The real-time binary used by the rig experiment and its tests.
cargo build --release -q -p sensaug-rt
