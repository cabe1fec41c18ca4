#!/usr/bin/env bash
# Runs INSIDE the QEMU guest that scripts/test-socketcan.sh boots (virtme-ng:
# the host's filesystem read-only, OUT writable). Brings up vcan0 (and vcan1
# behind a slow qdisc), runs the Rust SocketCAN tests, then three rig runs of
# sensaug-rt against a virtual drive on python-can's socketcan interface,
# each recorded with candump: a clean three-phase run and a short run under a
# cangen fuzz on the Hi5 drive, and the clean run on the CiA 402 drive
# (OUT/cia402.toml: the same configuration with [rig] drive = "cia402"), and
# on the standard CiA 402 drive (no 0x2000: --standard; OUT/cia402_standard.toml,
# rig.cia402.freshness = "standard"); then `sensaug doctor` with vcan0 up.
# Only collects; every check is made on the host (check.py).
# Usage: inner.sh REPO OUT RUST_TEST_BINARY 'DRIVE_ARGS' (the virtual drive's
# plant options from the configuration: --dt, --mass, ...)
set -u
REPO=$1 OUT=$2 TESTBIN=$3 DRIVE_ARGS=$4
PY=$REPO/.venv/bin/python
RT=$REPO/target/release/sensaug-rt
stamp() { date +%s.%N; }
note() { echo "$1=$2" >> "$OUT/inner.env"; }
note guest_start "$(stamp)"
exec >> "$OUT/inner.log" 2>&1
set -x

modprobe vcan && modprobe can_raw || { note setup_failed modprobe; exit 1; }
ip link add vcan0 type vcan && ip link set vcan0 up || { note setup_failed vcan0; exit 1; }
# vcan1: a token bucket at 8 kbit/s holding at most 512 bytes, so its
# transmit queue fills (ENOBUFS) -- the Rust full-queue test uses it.
ip link add vcan1 type vcan && ip link set vcan1 up &&
    tc qdisc add dev vcan1 root tbf rate 8kbit burst 256 limit 512 || { note setup_failed vcan1; exit 1; }
note vcan_up "$(stamp)"

# -- 1. the transport's kernel-bus tests ---------------------------------------
SENSAUG_VCAN=vcan0 SENSAUG_VCAN_SLOW=vcan1 timeout 120 "$TESTBIN" --ignored vcan --test-threads 1 --nocapture \
    > "$OUT/rust_tests.txt" 2>&1
note rust_tests_rc $?
note rust_tests_done "$(stamp)"

# -- 2. rig runs -----------------------------------------------------------------
# run NAME CONFIG FUZZ(0|1) PROFILE(hi5|cia402) [EXTRA DRIVE ARGS]
run() {
    local name=$1 config=$2 fuzz=$3 profile=$4 extra=${5:-}
    # The controller's first frame to node 1 once its socket is open: the Hi5
    # SetState, the CiA 402 master's first SDO request.
    local first_cmd
    case $profile in
        hi5) first_cmd=301 ;;
        cia402) first_cmd=601 ;;
    esac
    local dir=$OUT/$name
    mkdir -p "$dir"
    # Every frame on the bus, error frames too (#FFFFFFFF: all error classes).
    (cd "$dir" && exec candump -l "vcan0,0:0,#FFFFFFFF") &
    local dump=$!
    # The drive starts well before the loop: under emulation importing numpy,
    # python-can and cantools takes ~15 s.
    "$PY" -m "sensaug_bridge.virtual_$profile" -i socketcan -c vcan0 $DRIVE_ARGS $extra --duration 600 \
        --log "$dir/drive.npz" 2> "$dir/drive.stderr" &
    local drive=$!
    note "${name}_drive_started" "$(stamp)"
    # Its first heartbeat (both profiles: 0x701) says it is up.
    timeout 180 candump -n 1 vcan0,701:7FF > /dev/null
    note "${name}_drive_up_rc" $?
    note "${name}_drive_up" "$(stamp)"
    # Error frames during the run: the controller must count them, not stall.
    # Sent once its first command shows its socket is open: under emulation
    # on a loaded host it starts seconds after the drive is up.
    (timeout 180 candump -n 1 "vcan0,$first_cmd:7FF" > /dev/null
     for i in 1 2 3 4 5; do sleep 0.2; cansend vcan0 20000004#0000000000000000; done) &
    local errs=$!
    local fz=
    if [ "$fuzz" = 1 ]; then
        # Random ids, lengths, payloads, mixed EFF/FD/RTR frames: 500, one per 8 ms.
        (sleep 1; exec cangen vcan0 -g 8 -I r -L r -D r -m -n 500) &
        fz=$!
    fi
    note "${name}_loop_start" "$(stamp)"
    timeout 300 "$RT" "$config" --can socketcan:vcan0 --log "$dir/log.csv" --stats "$dir/stats.json" \
        > "$dir/rt.stdout" 2> "$dir/rt.stderr"
    note "${name}_rt_rc" $?
    note "${name}_loop_end" "$(stamp)"
    wait $errs
    [ -n "$fz" ] && { wait "$fz"; note "${name}_cangen_rc" $?; }
    # The drive must still be alive (it exits 0 on SIGTERM after a clean stop).
    if kill -0 "$drive" 2>/dev/null; then note "${name}_drive_alive" 1; else note "${name}_drive_alive" 0; fi
    sleep 0.5
    kill -TERM "$drive"
    wait "$drive"
    note "${name}_drive_rc" $?
    sleep 0.5
    kill -INT "$dump"
    wait "$dump"
    note "${name}_cangen_sent" "${fz:+500}"
}

run clean "$REPO/configs/hi5_vcan.toml" 0 hi5
run fuzz "$OUT/fuzz.toml" 1 hi5
run cia402 "$OUT/cia402.toml" 0 cia402
run cia402_standard "$OUT/cia402_standard.toml" 0 cia402 --standard
# The host check with a CAN interface present (exit code and report kept).
SENSAUG_RT="$RT" timeout 120 "$PY" -m sensaug doctor "$OUT/cia402.toml" --can socketcan:vcan0 \
    > "$OUT/doctor.txt" 2>&1
note doctor_rc $?
note guest_end "$(stamp)"
note done 1
