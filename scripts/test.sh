#!/usr/bin/env bash
# Every check CI runs: formatting, lints, Rust tests, Python tests, and the
# SocketCAN run on a real Linux CAN stack in a VM (scripts/test-socketcan.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cargo fmt --all -- --check
cargo clippy --workspace --all-targets -- -D warnings
cargo test --workspace --release
# can-utils' log2asc is the independent reader of the bus capture in
# tests/test_capture.py; a fresh machine has it only after test-socketcan.sh
# below installed it, so install it first (CI runs as root).
# Xvfb (an X server without a screen; Mesa's llvmpipe renders OpenGL) runs
# the participant's display in tests/test_display.py; xdotool presses its keys.
if { ! command -v log2asc > /dev/null || ! command -v xvfb-run > /dev/null || ! command -v xdotool > /dev/null; } \
    && [ "$(id -u)" = 0 ]; then
    apt-get update -q > /dev/null
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends can-utils xvfb xauth xdotool \
        libgl1-mesa-dri libglu1-mesa > /dev/null
fi
.venv/bin/python -m pytest -q -rs tests
SENSAUG_SKIP_SETUP=1 bash scripts/test-socketcan.sh  # the Linux CAN stack in a QEMU VM, ~4 min (docs/socketcan.md)
