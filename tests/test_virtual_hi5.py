"""The virtual Hi5 drive, driven as a host would drive the real one, over the sensaug_udp bus.

Most tests run the drive in a thread on its own port (`drive` fixture) and talk
to it from a second bus; the CLI tests run it as a subprocess. Motion is
checked against `sensaug.Plant` stepped directly with the same torques.

Timing is printed, not asserted, except the watchdog's bounds: it must not
fire early (strict: the drive's clock starts after our send), and it must fire
within watchdog + WATCHDOG_MARGIN_S. The drive wakes exactly at the deadline
(its receive timeout is cut to it), so on an idle machine it is late by
scheduler latency (well under 1 ms, see the printed number); the 1 s margin
only has to survive a loaded 2-core VM running tests in parallel, where a
thread can be descheduled for hundreds of ms, while still catching a watchdog
that never fires.
"""

from __future__ import annotations

import math
import random
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import can
import pytest
from drive_threads import DriveThread, drive_factory

import sensaug
from sensaug_bridge import protocol as p  # noqa: E402
from sensaug_bridge.protocol import FaultFlag, State  # noqa: E402
from sensaug_bridge.udp_bus import BROADCAST_ADDR, free_port  # noqa: E402
from sensaug_bridge.virtual_hi5 import DriveConfig, VirtualHi5  # noqa: E402

# Resolution of the Feedback fields, read from the DBC (the single source).
_FEEDBACK = p.load_database().get_message_by_name("Feedback")
POS_LSB = _FEEDBACK.get_signal_by_name("position").scale
VEL_LSB = _FEEDBACK.get_signal_by_name("velocity").scale

NODE = 1
RECV_S = 3.0
WATCHDOG_MARGIN_S = 1.0


# -- helpers -----------------------------------------------------------------------------


def expect(
    bus: can.BusABC,
    name: str,
    pred: Callable[[Any], bool] = lambda m: True,
    timeout: float = RECV_S,
    node: int = NODE,
) -> Any:
    """The next `name` frame from `node` satisfying `pred` (others are skipped)."""
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        msg = bus.recv(left)
        if msg is None:
            break
        found = p.classify(msg.arbitration_id)
        if found == (name, node):
            decoded = p.decode(msg).message
            if pred(decoded):
                return decoded
    pytest.fail(f"no {name} frame from node {node} within {timeout} s")


def frames_for(bus: can.BusABC, seconds: float) -> list[p.Decoded]:
    out = []
    deadline = time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0:
        msg = bus.recv(left)
        if msg is not None:
            out.append(p.decode(msg))
    return out


def enable(bus: can.BusABC, watchdog_ms: int = 200, node: int = NODE, sequence: int = 0) -> None:
    """Enable with the longest watchdog the protocol allows; the drive then expects ``sequence``."""
    bus.send(p.SetState(True, watchdog_ms, sequence).encode(node))
    expect(bus, "Fault", lambda f: f.state == State.ENABLED, node=node)


def command(bus: can.BusABC, torque_nm: float, seq: int, node: int = NODE) -> p.Feedback:
    bus.send(p.TorqueCommand(torque_nm, seq).encode(node))
    return expect(bus, "Feedback", node=node)


def encoder(x: float, counts: int = DriveConfig().encoder_counts_per_rev) -> float:
    step = 2 * math.pi / counts
    return round(x / step) * step


#: A VirtualHi5 on its thread; ``host`` is the host's bus.
Drive = DriveThread[can.BusABC]


@pytest.fixture
def start_drive() -> Iterator[Callable[..., Drive]]:
    """Factory: a drive thread on a fresh port, and a host bus opened before it boots."""
    yield from drive_factory(
        lambda **config: DriveThread(lambda bus: VirtualHi5(bus, DriveConfig(**config)), lambda bus: bus)
    )


@pytest.fixture
def drive(start_drive: Callable[..., Drive]) -> Drive:
    return start_drive()


# -- protocol ----------------------------------------------------------------------------


def test_protocol_ids_crc_and_round_trip():
    assert p.BASE_IDS == {
        "EmergencyStop": 0x010,
        "Fault": 0x080,
        "TorqueCommand": 0x200,
        "Feedback": 0x280,
        "SetState": 0x300,
        "ClearFaults": 0x320,
        "Heartbeat": 0x700,
    }
    assert p.frame_id("TorqueCommand", 15) == 0x20F and p.classify(0x70F) == ("Heartbeat", 15)
    assert p.classify(0x123) is None
    # CRC-16/IBM-3740 catalogue check value.
    assert p.crc16(b"123456789") == 0x29B1
    msg = p.TorqueCommand(-1.234567, 200).encode(3)
    data = bytes(msg.data)
    assert msg.arbitration_id == 0x203 and msg.dlc == 8 and p.crc_ok(data, 0x203)
    assert data[5] == 0
    assert p.decode(msg) == p.Decoded("TorqueCommand", 3, p.TorqueCommand(-1.234567, 200))
    # The frame id is the data id: the same bytes for node 4 fail the CRC.
    assert not p.crc_ok(data, 0x204)
    bad = bytearray(data)
    bad[0] ^= 1
    with pytest.raises(p.ProtocolError) as err:
        p.TorqueCommand.decode(bytes(bad), 0x203)
    assert err.value.kind == "crc"
    hb = p.Heartbeat(State.FAULT, FaultFlag.WATCHDOG | FaultFlag.SEQUENCE, 7, 1, 2, 3, 255, 4)
    assert p.decode(hb.encode(0)).message == hb
    for torque in (3000.0, 10.5, -10.000002):
        with pytest.raises(p.ProtocolError):
            p.TorqueCommand(torque, 0).encode(1)  # outside the DBC's [-10, 10] N m
    for wd in (0, 4, 201, 65535):
        with pytest.raises(p.ProtocolError):
            p.SetState(True, wd).encode(1)  # outside the DBC's 5..=200 ms
    with pytest.raises(p.ProtocolError):
        p.frame_id("Feedback", 16)


# -- the drive ---------------------------------------------------------------------------


def test_boots_disabled_and_heartbeats(drive: Drive):
    t0 = time.monotonic()
    first = []
    while sum(d.name == "Heartbeat" for d in first) < 3 and time.monotonic() - t0 < RECV_S:
        msg = drive.host.recv(RECV_S)
        assert msg is not None
        first.append(p.decode(msg))
    names = [(d.name, getattr(d.message, "state", None)) for d in first]
    assert names[:3] == [("Fault", State.BOOT), ("Fault", State.DISABLED), ("Heartbeat", State.DISABLED)]
    beats = [d.message for d in first if d.name == "Heartbeat"]
    assert [b.counter for b in beats] == [0, 1, 2]
    assert all(b.state == State.DISABLED and b.fault_flags == FaultFlag.NONE for b in beats)
    print(f"3 heartbeats (10 Hz nominal: 0.2 s) took {time.monotonic() - t0:.3f} s")


def test_torque_ignored_unless_enabled(drive: Drive):
    expect(drive.host, "Heartbeat")
    drive.host.send(p.TorqueCommand(1.0, 1).encode(NODE))
    assert not [d for d in frames_for(drive.host, 0.2) if d.name == "Feedback"]
    assert drive.drive.ignored == 1 and drive.drive.plant.x == 0.0


def test_feedback_echoes_sequence_and_matches_plant(drive: Drive):
    enable(drive.host, sequence=250)
    ref = sensaug.Plant(mass=0.0035, damping=0.0, coulomb=0.0, dt_s=1e-3, x0=0.0, v0=0.0)
    torques = [0.01 * math.sin(0.2 * k) + 0.002 for k in range(60)]
    for k, tau in enumerate(torques):
        seq = (250 + k) % 256  # wraps through 255 -> 0
        fb = command(drive.host, tau, seq)
        x, v = ref.step(round(tau * 1e6) / 1e6)  # the wire carries 1e-6 N m steps
        assert fb.sequence == seq and fb.state == State.ENABLED
        assert not fb.torque_limited and not fb.fault_active
        assert abs(fb.position_rad - encoder(x)) <= 0.5 * POS_LSB + 1e-12, (k, fb.position_rad, x)
        assert abs(fb.velocity_rad_s - v) <= 0.5 * VEL_LSB + 1e-12, (k, fb.velocity_rad_s, v)
    # Exactly one feedback each: nothing more arrives.
    assert not [d for d in frames_for(drive.host, 0.1) if d.name == "Feedback"]
    assert drive.drive.accepted == len(torques)


def test_torque_beyond_limit_rejected_and_counted_not_clamped(start_drive):
    drive = start_drive(torque_limit_nm=0.5, max_velocity_rad_s=1000.0, heartbeat_period_s=0.05)
    enable(drive.host)
    ref = sensaug.Plant(mass=0.0035, dt_s=1e-3)
    torques = [2.0, -7.0, 0.5, -0.25]
    for seq, tau in enumerate(torques):  # back to back: rejected commands do not feed the watchdog
        drive.host.send(p.TorqueCommand(tau, seq).encode(NODE))
    fbs = {d.message.sequence: d.message for d in frames_for(drive.host, 0.3) if d.name == "Feedback"}
    # Only the two within the limit were applied, the sequence going on past
    # the rejected ones. Read as one backlog the drive answers only the last
    # (seq 3); read one by one, both: either way each answer is the plant
    # after the accepted commands up to it.
    assert set(fbs) in ({3}, {2, 3}), sorted(fbs)
    for seq, tau in zip((2, 3), torques[2:]):
        x, v = ref.step(tau)
        if seq in fbs:
            fb = fbs[seq]
            assert not fb.torque_limited
            assert abs(fb.position_rad - encoder(x)) <= 0.5 * POS_LSB + 1e-12
            assert abs(fb.velocity_rad_s - v) <= 0.5 * VEL_LSB + 1e-12
    assert drive.drive.range_errors == 2 and drive.drive.accepted == 2
    hb = expect(drive.host, "Heartbeat", lambda h: h.range_errors == 2)
    assert hb.fault_flags in (FaultFlag.NONE, FaultFlag.WATCHDOG)  # no more commands: the watchdog may fire


def test_watchdog_faults_then_clear_and_reenable(drive: Drive):
    enable(drive.host, watchdog_ms=100)
    for seq in range(3):
        last_send = time.monotonic()  # before the send: the drive's timer restarts later than this
        command(drive.host, 0.01, seq)  # feedback proves the command was accepted
    fault = expect(drive.host, "Fault", lambda f: f.state == State.FAULT)
    elapsed = time.monotonic() - last_send
    print(f"watchdog 100 ms: FAULT seen {elapsed * 1e3:.1f} ms after the last accepted command was sent")
    assert fault.fault_flags == FaultFlag.WATCHDOG
    assert 0.100 <= elapsed <= 0.100 + WATCHDOG_MARGIN_S
    assert drive.drive.torque_nm == 0.0
    # Latched: commands are ignored, no feedback, until ClearFaults.
    drive.host.send(p.TorqueCommand(0.01, 4).encode(NODE))
    assert not [d for d in frames_for(drive.host, 0.15) if d.name == "Feedback"]
    hb = expect(drive.host, "Heartbeat")
    assert hb.state == State.FAULT and hb.fault_flags == FaultFlag.WATCHDOG
    drive.host.send(p.SetState(True, 100).encode(NODE))  # enable refused in FAULT
    drive.host.send(p.ClearFaults().encode(NODE))
    cleared = expect(drive.host, "Fault", lambda f: f.state != State.FAULT)
    assert cleared.state == State.DISABLED and cleared.fault_flags == FaultFlag.NONE
    enable(drive.host, sequence=9)
    fb = command(drive.host, 0.01, 9)  # the sequence the enable named
    assert fb.sequence == 9 and fb.state == State.ENABLED


def test_emergency_stop(drive: Drive):
    enable(drive.host)
    command(drive.host, 0.5, 0)
    drive.host.send(p.EmergencyStop().encode(NODE))
    fault = expect(drive.host, "Fault", lambda f: f.state == State.FAULT)
    assert fault.fault_flags == FaultFlag.EMERGENCY_STOP
    assert drive.drive.torque_nm == 0.0
    drive.host.send(p.TorqueCommand(0.5, 1).encode(NODE))
    assert not [d for d in frames_for(drive.host, 0.15) if d.name == "Feedback"]


def test_overspeed_faults(start_drive):
    drive = start_drive(max_velocity_rad_s=1.0)
    enable(drive.host)
    assert not command(drive.host, 3.0, 0).fault_active  # v = 0.857 rad/s
    drive.host.send(p.TorqueCommand(3.0, 1).encode(NODE))  # v = 1.71 rad/s
    frames = {d.name: d.message for d in frames_for(drive.host, 0.3) if d.name in ("Feedback", "Fault")}
    assert frames["Feedback"].fault_active and frames["Feedback"].state == State.FAULT
    assert frames["Fault"].state == State.FAULT and frames["Fault"].fault_flags == FaultFlag.OVERSPEED
    assert drive.drive.torque_nm == 0.0


def test_other_nodes_ignored_silently(start_drive):
    drive = start_drive(node=3)
    expect(drive.host, "Heartbeat", node=3)
    drive.host.send(p.SetState(True, 100).encode(1))  # node 1: not this drive
    drive.host.send(p.TorqueCommand(0.1, 0).encode(1))
    enable(drive.host, node=3)
    assert command(drive.host, 0.1, 0, node=3).sequence == 0
    assert drive.drive.unknown_ids == 0 and drive.drive.accepted == 1


def test_bad_frames_dropped_counted_no_crash(start_drive):
    drive = start_drive(heartbeat_period_s=0.05)
    host = drive.host
    enable(host, sequence=10)
    assert command(host, 0.01, 10).sequence == 10
    good = bytes(p.TorqueCommand(0.01, 11).encode(NODE).data)
    tid = p.frame_id("TorqueCommand", NODE)
    bad_crc = good[:7] + bytes([good[7] ^ 0xFF])
    host.send(can.Message(arbitration_id=tid, data=bad_crc, is_extended_id=False))  # crc
    host.send(can.Message(arbitration_id=tid + 1, data=good, is_extended_id=False))  # crc: node 2's id
    host.send(can.Message(arbitration_id=tid, data=good[:7], is_extended_id=False))  # length
    host.send(can.Message(arbitration_id=0x123, data=[1], is_extended_id=False))  # unknown id
    host.send(can.Message(arbitration_id=p.frame_id("SetState", NODE), data=[1], is_extended_id=False))  # length
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    raw.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
    raw.bind(("127.0.0.1", 0))
    try:
        raw.sendto(b"garbage", (BROADCAST_ADDR, drive.port))  # length (size)
        raw.sendto(struct.pack("<IB3x8s", 0x8000_0201, 8, good), (BROADCAST_ADDR, drive.port))  # unknown (EFF)
    finally:
        raw.close()
    fb = command(host, 0.01, 11)  # still alive and in sequence
    assert fb.sequence == 11
    want = dict(crc_errors=1, length_errors=3, sequence_errors=0, unknown_ids=2)
    hb = expect(
        host, "Heartbeat", lambda h: all(getattr(h, k) == v for k, v in want.items()) and h.state == State.ENABLED
    )
    assert hb.fault_flags == FaultFlag.NONE
    assert drive.drive.accepted == 2


def test_second_command_source_latches_a_sequence_fault(drive: Drive):
    """A valid command that is not the next one (here: a replay of the last) is a
    second source on the bus: torque 0, FAULT(SEQUENCE), and nothing is accepted."""
    enable(drive.host, sequence=100)
    command(drive.host, 0.2, 100)
    command(drive.host, 0.2, 101)
    drive.host.send(p.TorqueCommand(0.2, 101).encode(NODE))
    fault = expect(drive.host, "Fault", lambda f: f.state == State.FAULT)
    assert fault.fault_flags == FaultFlag.SEQUENCE
    assert drive.drive.torque_nm == 0.0 and drive.drive.sequence_errors == 1
    drive.host.send(p.TorqueCommand(0.2, 102).encode(NODE))
    assert not [d for d in frames_for(drive.host, 0.15) if d.name == "Feedback"]
    assert drive.drive.accepted == 2


def test_random_valid_frames_are_accepted_only_in_sequence():
    """1,000 valid-CRC commands with random sequences, each after a fresh enable:
    only those carrying the expected sequence are applied; every other one faults."""
    rng = random.Random(7)
    accepted = 0
    with can.Bus(interface="sensaug_udp", channel=free_port()) as bus:
        hi5 = VirtualHi5(bus, DriveConfig())  # driven directly, no thread
        hi5.start()
        for _ in range(1000):
            expected, seq = rng.randrange(256), rng.randrange(256)
            hi5.fault_flags = FaultFlag.NONE
            hi5._set_state(State.DISABLED)
            hi5.handle(p.SetState(True, 200, expected).encode(NODE), time.monotonic())
            assert hi5.state == State.ENABLED
            before = hi5.accepted
            hi5.handle(p.TorqueCommand(0.1, seq).encode(NODE), time.monotonic())
            if hi5.accepted > before:
                assert seq == expected
                accepted += 1
            else:
                assert seq != expected and hi5.state == State.FAULT
                assert hi5.fault_flags == FaultFlag.SEQUENCE
    print(f"1000 valid frames with random sequences: {accepted} accepted (each the expected one)")
    assert accepted < 20


def test_watchdog_change_refused_while_enabled(drive: Drive):
    """SetState(enable) with another watchdog while ENABLED is refused (counted); the
    same watchdog only resyncs. So a stray SetState cannot stretch the watchdog."""
    enable(drive.host, watchdog_ms=50, sequence=0)
    command(drive.host, 0.0, 0)
    drive.host.send(p.SetState(True, 200, 5).encode(NODE))  # refused: watchdog change
    raw = bytes([1]) + (65535).to_bytes(2, "little") + bytes([0])
    drive.host.send(can.Message(arbitration_id=p.frame_id("SetState", NODE), data=raw, is_extended_id=False))
    drive.host.send(p.SetState(True, 50, 77).encode(NODE))  # resync only
    t_last = time.monotonic()
    command(drive.host, 0.0, 77)
    fault = expect(drive.host, "Fault", lambda f: f.state == State.FAULT)
    elapsed = time.monotonic() - t_last
    print(f"watchdog 50 ms after two refused changes: FAULT {elapsed * 1e3:.0f} ms after the last command")
    assert fault.fault_flags == FaultFlag.WATCHDOG
    assert elapsed <= 0.050 + WATCHDOG_MARGIN_S
    assert drive.drive.ignored == 2 and drive.drive.watchdog_s == 0.050


def test_error_counters_saturate_at_255(drive: Drive):
    drive.drive.crc_errors = 1000
    hb = drive.drive.heartbeat()
    assert hb.crc_errors == 255
    assert p.Heartbeat.decode(bytes(hb.encode(NODE).data)).crc_errors == 255


# -- the command line --------------------------------------------------------------------


def _console_script() -> list[str]:
    script = Path(sys.executable).with_name("sensaug-virtual-hi5")
    return [str(script)] if script.exists() else [sys.executable, "-m", "sensaug_bridge.virtual_hi5"]


def test_sigterm_shuts_down_cleanly_and_logs(tmp_path: Path):
    port = free_port()
    log = tmp_path / "hi5.npz"
    with can.Bus(interface="sensaug_udp", channel=port) as host:
        proc = subprocess.Popen(
            [*_console_script(), "--channel", str(port), "--log", str(log), "--duration", "60"],
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            expect(host, "Heartbeat", timeout=15.0)
            enable(host)
            torques = [0.02, -0.01, 3.0]
            for seq, tau in enumerate(torques):
                command(host, tau, seq)
            proc.send_signal(signal.SIGTERM)
            rc = proc.wait(timeout=10)
            _, stderr = proc.communicate()
            tail = frames_for(host, 0.2)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert rc == 0, stderr
    assert [d.name for d in tail][-2:] == ["Fault", "Heartbeat"]
    assert tail[-2].message.state == State.DISABLED
    print(stderr.strip())
    import numpy as np

    data = np.load(log)
    assert list(data["sequence"]) == [0, 1, 2]
    assert list(data["torque_nm"]) == [0.02, -0.01, 3.0]
    assert data["position_rad"].shape == data["velocity_rad_s"].shape == data["t_s"].shape == (3,)


def test_duration_option_exits_zero():
    port = free_port()
    t0 = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "sensaug_bridge.virtual_hi5", "-c", str(port), "--duration", "0.3", "-q"],
        timeout=30,
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    print(f"--duration 0.3: process ran {time.monotonic() - t0:.2f} s including start-up")


def test_cli_rejects_bad_config():
    proc = subprocess.run(
        [sys.executable, "-m", "sensaug_bridge.virtual_hi5", "--mass", "-1", "--duration", "0"],
        timeout=30,
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2 and "mass" in proc.stderr
