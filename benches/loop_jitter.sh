#!/usr/bin/env bash
# cyclictest (Debian rt-tests) as the baseline for the loop's wake-up jitter.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
if ! command -v cyclictest >/dev/null; then
    apt-get update -qq && apt-get install -y -qq rt-tests
fi
# [seconds per round] [rounds per policy]: defaults 2 and 5.
.venv/bin/python benches/loop_jitter.py "$@"
