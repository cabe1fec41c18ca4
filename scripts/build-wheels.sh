#!/usr/bin/env bash
# Builds the three wheels into DIR (default ./dist), installable on any x86_64
# Linux with glibc >= 2.17 (manylinux2014: Ubuntu 18.04 and later, Debian 10,
# RHEL 8, ...) and CPython >= 3.11:
#   sensaug        python/sensaug + the compiled core (maturin, root pyproject.toml)
#   sensaug-bridge firmware_bridge/python/sensaug_bridge + hi5.dbc, *.eds as package data
#   sensaug-rt     the real-time binary, installed on PATH (maturin bin, crates/sensaug-rt)
# Install: pip install DIR/*.whl (docs: README, "Install").
#
# It needs cargo and python3 (with venv) only: its build tools live in their
# own small environment ($SENSAUG_BUILD_ENV, default target/wheel-build-env;
# scripts/wheel-build-requirements.txt), not in the test venv. zig links the
# Rust parts against glibc 2.17's symbols (maturin --zig); maturin's auditwheel
# check refuses a wheel whose binaries need more. The Rust build goes to
# target/x86_64-unknown-linux-gnu/ (the first build compiles every crate,
# later ones reuse it). Each step prints a line; cargo prints its own.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=$(realpath -m "${1:-dist}")
ENV_DIR=$(realpath -m "${SENSAUG_BUILD_ENV:-target/wheel-build-env}")
PY=${PYTHON:-python3}
step() { printf '\n==> [%s, %d s] %s\n' "$1" "$SECONDS" "$2"; }

step 1/5 "build tools into $ENV_DIR (maturin, ziglang, twine)"
[ -x "$ENV_DIR/bin/python" ] || "$PY" -m venv "$ENV_DIR"
"$ENV_DIR/bin/python" -m pip install -q --disable-pip-version-check -r scripts/wheel-build-requirements.txt
# maturin finds zig as `python -m ziglang` of the environment on PATH.
export PATH="$ENV_DIR/bin:$PATH" VIRTUAL_ENV="$ENV_DIR"
mkdir -p "$OUT"

step 2/5 "sensaug: the Python API, the compiled core and the docs pages (profile: pyproject.toml)"
# The docs pages go into the package (`sensaug docs NAME` prints them) for
# the build only (not git-ignored: maturin leaves ignored files out); the
# checkout's editable install reads docs/ itself.
rm -rf python/sensaug/docs
trap 'rm -rf python/sensaug/docs' EXIT
mkdir python/sensaug/docs
cp docs/*.md python/sensaug/docs/
maturin build --strip --zig --compatibility manylinux2014 -o "$OUT"
rm -rf python/sensaug/docs

step 3/5 "sensaug-rt: the real-time binary"
maturin build --release --strip --zig --compatibility manylinux2014 -m crates/sensaug-rt/Cargo.toml -o "$OUT"

step 4/5 "sensaug-bridge: pure Python with its protocol files"
# setuptools builds in firmware_bridge/build and keeps files there between
# builds: start clean so a removed data file cannot reach the wheel.
rm -rf firmware_bridge/build
python -m pip wheel -q --disable-pip-version-check --no-deps -w "$OUT" ./firmware_bridge
rm -rf firmware_bridge/build

step 5/5 "twine check --strict (the metadata PyPI would accept)"
twine check --strict "$OUT"/sensaug*.whl
echo
ls -l "$OUT"/sensaug*.whl | awk '{ printf "%8.0f kB  %s\n", $5 / 1e3, $NF }'
echo "done in $SECONDS s; install: pip install $OUT/*.whl"
