#!/usr/bin/env bash
# Writes BENCHMARKS.md from one run: the Rust workloads (per-call timings and
# callgrind instruction counts) and the peers (filterpy, scipy) and the Python
# API on the same problems, side by side (benches/report.py). The criterion
# benches (including the robot tick) stay available separately:
#   cargo bench -p sensaug-core --bench numerics
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/python benches/report.py "$@"
