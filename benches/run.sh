#!/usr/bin/env bash
# Writes BENCHMARKS.md from one run: the Rust workloads (per-call timings and
# callgrind instruction counts) and the peers (filterpy, scipy) and the Python
# API on the same problems, side by side, the robot tick's tail, the rig
# tick on the loopback bus and the loop's wake-up latency against cyclictest
# under SCHED_OTHER and SCHED_FIFO (benches/report.py). The criterion
# benches (the same workloads) stay available separately:
#   cargo bench -p sensaug-core --bench numerics
source "$(dirname "$0")/setup.sh"
.venv/bin/python benches/report.py "$@"
