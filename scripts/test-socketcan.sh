#!/usr/bin/env bash
# SocketCAN on the real Linux CAN stack. This machine's kernel has no CAN
# support, so the distribution kernel is booted under QEMU (TCG emulation:
# KVM guests hang at boot here) with virtme-ng, the host's filesystem shared;
# inside, vcan0 carries the whole experiment: sensaug-rt on socketcan:vcan0,
# the virtual drive on python-can's socketcan interface (the Hi5 drive, then
# the CiA 402 drive), candump recording, a cangen fuzz, and the Rust
# transport's kernel-bus tests
# (scripts/vcan/inner.sh). The results are checked here (scripts/vcan/check.py).
# docs/socketcan.md has the measured numbers.
#
# Installs what it needs (apt: qemu-system-x86 linux-image-amd64 can-utils
# iproute2 kmod busybox-static; pip: virtme-ng into .venv), idempotently.
# One VM at a time, bounded by `timeout`. Prints the elapsed time; exit 0
# only if every check passed. Outputs in out/socketcan/ (SENSAUG_VCAN_OUT).
set -euo pipefail
cd "$(dirname "$0")/.."
REPO=$PWD
T0=$(date +%s.%N)
elapsed() { python3 -c "import sys; print(f'{float(sys.argv[2]) - float(sys.argv[1]):.0f}')" "$T0" "$(date +%s.%N)"; }
fail() { echo "test-socketcan: FAIL: $*  ($(elapsed) s)" >&2; exit 1; }

[ "${SENSAUG_SKIP_SETUP:-0}" = 1 ] || bash scripts/setup.sh

# -- tools ---------------------------------------------------------------------
APT_PKGS="qemu-system-x86 linux-image-amd64 can-utils iproute2 kmod busybox-static"
kernel() { ls -1 /boot/vmlinuz-* 2>/dev/null | sort -V | tail -n 1; }
missing=
for tool in qemu-system-x86_64 candump cangen cansend tc ip modprobe busybox; do
    command -v "$tool" > /dev/null || missing="$missing $tool"
done
[ -n "$(kernel)" ] || missing="$missing kernel"
if [ -n "$missing" ]; then
    echo "test-socketcan: installing ($missing missing): $APT_PKGS"
    [ "$(id -u)" = 0 ] || fail "need root to apt-get install $APT_PKGS"
    apt-get update -q > /dev/null
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends $APT_PKGS > /dev/null
fi
KERNEL=$(kernel)
[ -n "$KERNEL" ] || fail "no kernel under /boot after installing linux-image-amd64"
KVER=${KERNEL#/boot/vmlinuz-}
[ -d "/lib/modules/$KVER" ] || fail "no modules for $KVER in /lib/modules (vcan is a module)"
[ -x .venv/bin/vng ] || .venv/bin/python -m pip install -q "virtme-ng>=1.42,<2"
export PATH="$REPO/.venv/bin:$PATH"  # vng runs virtme-run from the same venv

# -- host-side builds: the Rust test binary, the fuzz and CiA 402 configurations -
TESTBIN=$(cargo test -q -p sensaug-bridge --release --lib --no-run --message-format=json 2>/dev/null |
    .venv/bin/python -c 'import json, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("executable"):
        print(m["executable"])')
[ -x "$TESTBIN" ] || fail "could not build the sensaug-bridge test binary"
[ -x target/release/sensaug-rt ] || fail "target/release/sensaug-rt missing (scripts/setup.sh builds it)"

OUT=$(realpath -m "${SENSAUG_VCAN_OUT:-out/socketcan}")
rm -rf "$OUT"
mkdir -p "$OUT"
.venv/bin/python scripts/vcan/check.py --write-fuzz-config "$OUT/fuzz.toml"
.venv/bin/python scripts/vcan/check.py --write-cia402-config "$OUT/cia402.toml"
.venv/bin/python scripts/vcan/check.py --write-cia402-standard-config "$OUT/cia402_standard.toml"
# The drive simulates the configuration's plant, one step of plant.dt_s per command.
DRIVE_ARGS=$(.venv/bin/python scripts/vcan/check.py --drive-args configs/hi5_vcan.toml)

# -- the VM ---------------------------------------------------------------------
echo "test-socketcan: booting $KERNEL under QEMU/TCG (about 40 s), then four rig runs and sensaug doctor (~4-7 min)"
echo "host_start=$(date +%s.%N)" > "$OUT/host.env"
set +e
timeout "${SENSAUG_VCAN_TIMEOUT:-900}" vng --disable-kvm --force-9p \
    --run "$KERNEL" --user root --rwdir "$OUT" \
    --exec "bash $REPO/scripts/vcan/inner.sh $REPO $OUT $TESTBIN '$DRIVE_ARGS'" > "$OUT/vng.log" 2>&1
vm_rc=$?
set -e
echo "host_end=$(date +%s.%N)" >> "$OUT/host.env"
echo "vm_rc=$vm_rc" >> "$OUT/host.env"
[ "$vm_rc" = 124 ] && fail "the VM did not finish within ${SENSAUG_VCAN_TIMEOUT:-900} s (see $OUT/vng.log, $OUT/inner.log)"

# -- checks ---------------------------------------------------------------------
if .venv/bin/python scripts/vcan/check.py "$OUT"; then
    echo "test-socketcan: PASS  ($(elapsed) s in all; details in $OUT/summary.json)"
else
    fail "see above and $OUT/inner.log"
fi
