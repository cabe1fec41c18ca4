#!/usr/bin/env bash
# cyclictest (Debian rt-tests) as the baseline for the loop's wake-up jitter.
source "$(dirname "$0")/setup.sh"
# [seconds per round] [rounds per policy]: defaults 2 and 5.
.venv/bin/python benches/loop_jitter.py "$@"
