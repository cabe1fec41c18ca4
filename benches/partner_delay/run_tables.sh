#!/usr/bin/env bash
# The full table, one trial per (cell, seed), one process per (config, seed):
# both partner families with partner motor-noise gains 0 and 0.1, and two
# robustness configurations (damped family: motor-noise gain 0.3; 0.1 with a
# 10% gain drift of time constant 10 s) on the first seed given.
#   bash benches/partner_delay/run_tables.sh <tag> <seed>...
# Results: benches/partner_delay/results/<tag>_<family>_km<k>[_drift<d>]_s<seed>.json
set -euo pipefail
cd "$(dirname "$0")/../.."
tag=$1; shift
one() {  # family km drift seed
  local out=benches/partner_delay/results/${tag}_$1_km$2$( [ "$3" = 0 ] || echo _drift$3 )_s$4.json
  [ -f "$out" ] || .venv/bin/python benches/partner_delay/table.py --family "$1" --km "$2" --drift "$3" --seeds "$4" --out "$out"
}
for s in "$@"; do
  for fam in paper damped; do
    for km in 0 0.1; do one $fam $km 0 "$s"; done
  done
done
one damped 0.3 0 "$1"
one damped 0.1 0.1 "$1"
