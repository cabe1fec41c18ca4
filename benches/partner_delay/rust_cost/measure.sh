#!/usr/bin/env bash
# Instructions per tick of each piece of work: callgrind totals of 11000 and
# 1000 ticks, their difference over 10000 (set-up cancels).
#   bash benches/partner_delay/rust_cost/measure.sh
set -euo pipefail
cd "$(dirname "$0")"
cargo build --release -q
bin=target/release/partner_delay_cost
for w in ring coarse fine eval kf gains_tick fine_tick; do
  n=()
  for t in 1000 11000; do
    n+=($(valgrind --tool=callgrind --callgrind-out-file=/dev/null $bin $w $t 2>&1 | awk '/Collected/ {print $4}'))
  done
  echo "$w: $(( (${n[1]} - ${n[0]}) / 10000 )) instructions per tick"
done
