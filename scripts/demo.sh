#!/usr/bin/env bash
# The main job on its embedded default: set up, then run `sensaug demo`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/python -m sensaug "${@:-demo}"
