#!/usr/bin/env bash
# Criterion benches of the Rust core, then the oracles (scipy, filterpy) on
# the same problems, in one run: compare the medians side by side.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
rm -rf target/criterion
cargo bench -p sensaug-core --bench numerics -- --warm-up-time 1 --measurement-time 3
.venv/bin/python benches/compare_oracles.py
