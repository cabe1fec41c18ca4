# Sourced by the benchmark scripts (benches/run.sh, benches/loop_jitter.sh):
# from the repository's root, the project set up, and cyclictest (Debian
# rt-tests) installed, the baseline of the loop's wake-up latency.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
bash scripts/setup.sh
if ! command -v cyclictest >/dev/null; then
    apt-get update -qq && apt-get install -y -qq rt-tests
fi
