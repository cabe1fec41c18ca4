#!/usr/bin/env bash
# Every check CI runs: formatting, lints, Rust tests, Python tests, and the
# SocketCAN run on a real Linux CAN stack in a VM (scripts/test-socketcan.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cargo fmt --all -- --check
cargo clippy --workspace --all-targets -- -D warnings
cargo test --workspace --release
.venv/bin/python -m pytest -q tests
SENSAUG_SKIP_SETUP=1 bash scripts/test-socketcan.sh  # the Linux CAN stack in a QEMU VM, ~4 min (docs/socketcan.md)
