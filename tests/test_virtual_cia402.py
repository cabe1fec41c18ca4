"""The virtual CiA 402 drive, driven as a CANopen master would drive a real one,
over the sensaug_udp bus; the same drive tests as the virtual Hi5 drive's
(tests/test_virtual_hi5.py): boot, enable, feedback against ``sensaug.Plant``,
torque beyond the limit rejected (not clamped), the watchdog (here the
heartbeat consumer 0x1016) with fault reset and re-enable, quick stop (the
e-stop), overspeed, bad frames, clean shutdown of the CLI.

The host side here writes raw frames (the byte layouts are checked against
python-canopen by tests/test_cia402_golden.py and the Rust master by
firmware_bridge/tests/cia402_golden.rs). Timing is printed, not asserted, except
the watchdog's bounds, as in the Hi5 tests.
"""

from __future__ import annotations

import contextlib
import math
import signal
import struct
import subprocess
import sys
import threading
import time
from typing import Callable, Iterator, Optional

import can
import pytest
from drive_threads import DriveThread, drive_factory

import sensaug
from sensaug_bridge.udp_bus import free_port
from sensaug_bridge.virtual_cia402 import Cia402Config, Cia402State, Fault, VirtualCia402

NODE = 1
MASTER = 127
RECV_S = 3.0
WATCHDOG_MARGIN_S = 1.0
RATED_MNM = Cia402Config().rated_torque_mnm
COUNTS = Cia402Config().encoder_counts_per_rev
RAD_PER_COUNT = 2 * math.pi / COUNTS
#: The Rust master's 0x1019 synchronous counter overflow value (od.rs SYNC_COUNTER_OVERFLOW).
SYNC_COUNTER_OVERFLOW = 240


# -- a raw-frame master ------------------------------------------------------------------


class Host:
    def __init__(self, bus: can.BusABC, node: int = NODE) -> None:
        self.bus, self.node = bus, node
        #: Frames `expect` read past (EMCYs arrive between the TPDOs they explain).
        self.skipped: list[can.Message] = []
        #: The last SYNC's counter (1..SYNC_COUNTER_OVERFLOW, as the Rust master counts).
        self.sync_counter = 0

    def send(self, can_id: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))

    def expect(self, can_id: int, pred: Callable[[bytes], bool] = lambda d: True, timeout: float = RECV_S) -> bytes:
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            msg = self.bus.recv(left)
            if msg is None:
                break
            if msg.arbitration_id == can_id and pred(bytes(msg.data)):
                return bytes(msg.data)
            self.skipped.append(msg)
        pytest.fail(f"no frame {can_id:#x} within {timeout} s")

    def frames_for(self, seconds: float) -> list[can.Message]:
        out = []
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            msg = self.bus.recv(left)
            if msg is not None:
                out.append(msg)
        return out

    def sdo_write(self, index: int, sub: int, value: bytes) -> bytes:
        cmd = 0x23 | ((4 - len(value)) << 2)
        self.send(0x600 + self.node, struct.pack("<BHB", cmd, index, sub) + value.ljust(4, b"\0"))
        return self.expect(0x580 + self.node, lambda d: d[1:4] == struct.pack("<HB", index, sub))

    def sdo_read(self, index: int, sub: int = 0) -> bytes:
        self.send(0x600 + self.node, struct.pack("<BHB4x", 0x40, index, sub))
        return self.expect(0x580 + self.node, lambda d: d[1:4] == struct.pack("<HB", index, sub))

    def nmt(self, command: int) -> None:
        self.send(0x000, bytes([command, self.node]))

    def heartbeat(self) -> None:
        self.send(0x700 + MASTER, bytes([0x05]))

    def cycle(self, controlword: int, torque_per_mille: int = 0) -> tuple[int, int, int, int]:
        """RPDO1 + SYNC with the next counter; the drive's TPDO1 and TPDO2, both
        echoing that counter: (statusword, position, velocity, torque)."""
        self.send(0x200 + self.node, struct.pack("<Hh", controlword, torque_per_mille))
        self.sync_counter = self.sync_counter % SYNC_COUNTER_OVERFLOW + 1
        self.send(0x080, bytes([self.sync_counter]))
        statusword, position, echo1 = struct.unpack("<HiB", self.expect(0x180 + self.node))
        velocity, torque, echo2 = struct.unpack("<ihB", self.expect(0x280 + self.node))
        assert echo1 == echo2 == self.sync_counter, (echo1, echo2, self.sync_counter)
        return statusword, position, velocity, torque

    def set_up(self, consumer_ms: int = 0) -> None:
        """What the Rust master does at boot: mode 10, the heartbeat consumer, NMT start."""
        assert self.sdo_write(0x6060, 0, bytes([10]))[0] == 0x60
        if consumer_ms:
            self.heartbeat()
            assert self.sdo_write(0x1016, 1, struct.pack("<I", (MASTER << 16) | consumer_ms))[0] == 0x60
        self.nmt(0x01)

    def enable(self) -> None:
        assert state_of(self.cycle(0x06)[0]) == Cia402State.READY_TO_SWITCH_ON
        assert state_of(self.cycle(0x07)[0]) == Cia402State.SWITCHED_ON
        assert state_of(self.cycle(0x0F)[0]) == Cia402State.OPERATION_ENABLED


def state_of(statusword: int) -> Cia402State:
    return Cia402State(statusword & ~(1 << 11))


def emcy(host: Host, code: int) -> bytes:
    """The EMCY with this code: already read past, or the next one."""
    for msg in host.skipped:
        if msg.arbitration_id == 0x080 + host.node and struct.unpack_from("<H", msg.data)[0] == code:
            host.skipped.remove(msg)
            return bytes(msg.data)
    return host.expect(0x080 + host.node, lambda d: struct.unpack_from("<H", d)[0] == code)


#: A VirtualCia402 on its thread; ``host`` the master's side (:class:`Host`).
Drive = DriveThread[Host]


@pytest.fixture
def start_drive() -> Iterator[Callable[..., Drive]]:
    yield from drive_factory(
        lambda **config: DriveThread(
            lambda bus: VirtualCia402(bus, Cia402Config(**config)), lambda bus: Host(bus, config.get("node", NODE))
        )
    )


@pytest.fixture
def drive(start_drive: Callable[..., Drive]) -> Drive:
    return start_drive()


# -- boot ----------------------------------------------------------------------------------


def test_boots_pre_operational_with_heartbeats_and_no_pdos(drive: Drive):
    host = drive.host
    t0 = time.monotonic()
    first = [host.expect(0x700 + NODE) for _ in range(3)]
    assert first == [b"\x00", b"\x7f", b"\x7f"]  # boot-up, then PRE-OPERATIONAL beats
    print(f"boot-up + 2 heartbeats (10 Hz nominal: 0.1 s) took {time.monotonic() - t0:.3f} s")
    device_type = host.sdo_read(0x1000)
    assert device_type[0] == 0x43 and struct.unpack_from("<I", device_type, 4)[0] == 0x00020192
    sw = host.sdo_read(0x6041)
    assert state_of(struct.unpack_from("<H", sw, 4)[0]) == Cia402State.SWITCH_ON_DISABLED
    assert struct.unpack_from("<I", host.sdo_read(0x6072), 4)[0] == 3000  # 3 N m / 1 N m rated
    # PDOs need NMT OPERATIONAL: a SYNC now gets no TPDO and changes nothing.
    host.send(0x200 + NODE, struct.pack("<Hh", 0x06, 0))
    host.send(0x080, b"")
    assert not [m for m in host.frames_for(0.2) if m.arbitration_id in (0x180 + NODE, 0x280 + NODE)]
    assert drive.drive.state == Cia402State.SWITCH_ON_DISABLED and drive.drive.syncs == 0


def test_sdo_refusals_are_aborts(drive: Drive):
    host = drive.host
    resp = host.sdo_write(0x6041, 0, b"\x00\x00")  # read-only
    assert resp[0] == 0x80 and struct.unpack_from("<I", resp, 4)[0] == 0x06010002
    resp = host.sdo_write(0x6060, 0, bytes([3]))  # profile torque mode: not supported
    assert resp[0] == 0x80 and struct.unpack_from("<I", resp, 4)[0] == 0x06090030
    resp = host.sdo_read(0x5FFF)  # no such object
    assert resp[0] == 0x80 and struct.unpack_from("<I", resp, 4)[0] == 0x06020000
    host.sdo_write(0x6060, 0, bytes([10]))
    assert host.sdo_read(0x6061)[4] == 10  # the mode display follows


# -- enable and motion -----------------------------------------------------------------------


def test_enable_needs_the_torque_mode(drive: Drive):
    host = drive.host
    host.nmt(0x01)  # no 0x6060 = 10 written
    assert state_of(host.cycle(0x06)[0]) == Cia402State.READY_TO_SWITCH_ON
    assert state_of(host.cycle(0x07)[0]) == Cia402State.SWITCHED_ON
    assert state_of(host.cycle(0x0F, 100)[0]) == Cia402State.SWITCHED_ON
    assert drive.drive.steps == 0 and drive.drive.plant.x == 0.0


def test_feedback_matches_plant_with_per_mille_torque(drive: Drive):
    host = drive.host
    host.set_up()
    host.enable()  # the enabling SYNC already steps the plant with torque 0
    ref = sensaug.Plant(mass=0.0035, damping=0.0, coulomb=0.0, dt_s=1e-3, x0=0.0, v0=0.0)
    ref.step(0.0)
    torques_nm = [0.01 * math.sin(0.2 * k) + 0.002 for k in range(60)]
    for tau in torques_nm:
        per_mille = round(tau / (RATED_MNM * 1e-6))  # the wire carries 1 mN m steps
        sw, pos, vel, torque = host.cycle(0x0F, per_mille)
        x, v = ref.step(per_mille * RATED_MNM * 1e-6)
        assert state_of(sw) == Cia402State.OPERATION_ENABLED and not sw & (1 << 11)
        assert torque == per_mille
        assert pos == round(x / RAD_PER_COUNT), (pos, x)
        assert vel == round(v / RAD_PER_COUNT), (vel, v)
    assert drive.drive.steps == len(torques_nm) + 1
    # One TPDO pair per SYNC: nothing more arrives.
    assert not [m for m in host.frames_for(0.1) if m.arbitration_id in (0x180 + NODE, 0x280 + NODE)]


def test_tpdos_echo_the_counter_of_the_sync_they_answer(drive: Drive):
    """0x2000 in both TPDOs: the SYNC's counter byte (through the wrap from
    the overflow value back to 1), 0 for a SYNC without a counter."""
    host = drive.host
    host.set_up()
    host.enable()
    host.sync_counter = SYNC_COUNTER_OVERFLOW - 2
    for _ in range(4):  # 239, 240, 1, 2: cycle() asserts both echoes
        host.cycle(0x0F)
    assert host.sync_counter == 2
    host.send(0x200 + NODE, struct.pack("<Hh", 0x0F, 0))
    host.send(0x080, b"")
    assert host.expect(0x180 + NODE)[6] == 0 and host.expect(0x280 + NODE)[6] == 0
    assert struct.unpack_from("<B", host.sdo_read(0x2000), 4)[0] == 0


def test_a_backlog_steps_every_sync_and_answers_only_the_last(drive: Drive):
    """Frames queued while the drive's process was not running (here: its
    loop is paused) are one backlog: each SYNC steps the plant with the
    RPDO1 before it, in order, and only the last SYNC is answered; the
    superseded answers would reach the master stale, after a later SYNC."""
    host = drive.host
    host.set_up()
    host.enable()  # the enabling SYNC steps the plant once, at torque 0
    drive.stop.set()
    drive.thread.join(timeout=5)
    syncs = drive.drive.syncs
    torques = [40, -10, 25, 5, -30]
    for per_mille in torques:
        host.send(0x200 + NODE, struct.pack("<Hh", 0x0F, per_mille))
        host.sync_counter = host.sync_counter % SYNC_COUNTER_OVERFLOW + 1
        host.send(0x080, bytes([host.sync_counter]))
    time.sleep(0.05)  # every frame is queued at the drive's socket
    drive.stop = threading.Event()
    drive.thread = threading.Thread(target=drive.drive.run, kwargs={"stop": drive.stop, "duration_s": 30.0}, daemon=True)
    drive.thread.start()
    answers = [m for m in host.frames_for(0.3) if m.arbitration_id in (0x180 + NODE, 0x280 + NODE)]
    assert [(m.arbitration_id, m.data[6]) for m in answers] == [(0x180 + NODE, host.sync_counter),
                                                               (0x280 + NODE, host.sync_counter)]
    ref = sensaug.Plant(mass=0.0035, dt_s=1e-3)
    for per_mille in [0, *torques]:
        x, v = ref.step(per_mille * RATED_MNM * 1e-6)
    _, position, _ = struct.unpack("<HiB", answers[0].data)
    velocity, torque, _ = struct.unpack("<ihB", answers[1].data)
    assert drive.drive.steps == 1 + len(torques) and drive.drive.syncs == syncs + len(torques)
    assert (position, velocity, torque) == (round(x / RAD_PER_COUNT), round(v / RAD_PER_COUNT), torques[-1])


def test_a_pdo_mapping_written_over_sdo_is_what_the_tpdo_then_carries(drive: Drive):
    """CiA 301's remapping sequence (COB-ID invalid, count 0, entries, count,
    COB-ID valid) on TPDO2: torque actual first, then velocity actual, no
    echo; the next SYNC's TPDO2 has that layout (6 bytes)."""
    host = drive.host
    ok = 0x60
    assert host.sdo_write(0x1801, 1, struct.pack("<I", 0x80000000 | 0x280 + NODE))[0] == ok
    assert host.sdo_write(0x1A01, 0, bytes([0]))[0] == ok
    assert host.sdo_write(0x1A01, 1, struct.pack("<I", 0x60770010))[0] == ok
    assert host.sdo_write(0x1A01, 2, struct.pack("<I", 0x606C0020))[0] == ok
    assert host.sdo_write(0x1A01, 0, bytes([2]))[0] == ok
    assert host.sdo_write(0x1801, 1, struct.pack("<I", 0x280 + NODE))[0] == ok
    host.set_up()
    host.send(0x200 + NODE, struct.pack("<Hh", 0x06, 0))
    host.send(0x080, bytes([1]))
    assert host.expect(0x180 + NODE)[6] == 1
    torque, velocity = struct.unpack("<hi", host.expect(0x280 + NODE))
    assert (torque, velocity) == (0, 0)


def test_torque_beyond_max_rejected_and_counted_not_clamped(start_drive):
    d = start_drive(torque_limit_nm=0.5, max_velocity_rad_s=1000.0)
    host = d.host
    assert struct.unpack_from("<H", host.sdo_read(0x6072), 4)[0] == 500
    host.set_up()
    host.enable()
    ref = sensaug.Plant(mass=0.0035, dt_s=1e-3)
    ref.step(0.0)
    for per_mille, applied in [(2000, 0), (-7000, 0), (500, 500), (-250, -250)]:
        sw, pos, vel, torque = host.cycle(0x0F, per_mille)
        x, v = ref.step(applied * RATED_MNM * 1e-6)
        assert torque == applied
        assert bool(sw & (1 << 11)) == (applied != per_mille)  # internal limit active
        assert pos == round(x / RAD_PER_COUNT) and vel == round(v / RAD_PER_COUNT)
    # One EMCY for the run of two rejected cycles.
    code, register, flags = struct.unpack_from("<HBB", emcy(host, 0x8611))
    assert register & 1
    assert d.drive.range_errors == 2 and d.drive.state == Cia402State.OPERATION_ENABLED


# -- faults ---------------------------------------------------------------------------------


def test_watchdog_is_the_heartbeat_consumer_then_fault_reset_and_reenable(drive: Drive):
    host = drive.host
    host.set_up(consumer_ms=100)
    host.enable()
    for _ in range(3):
        last_beat = time.monotonic()  # before the send: the drive's timer restarts later
        host.heartbeat()
        host.cycle(0x0F, 10)
    # SYNCs go on, the heartbeat does not: the consumer trips.
    frame = emcy(host, 0x8130)
    elapsed = time.monotonic() - last_beat
    print(f"heartbeat consumer 100 ms: EMCY 0x8130 seen {elapsed * 1e3:.1f} ms after the last heartbeat was sent")
    assert 0.100 <= elapsed <= 0.100 + WATCHDOG_MARGIN_S
    assert frame[3] == Fault.HEARTBEAT
    sw, _, _, torque = host.cycle(0x0F, 10)
    assert state_of(sw) == Cia402State.FAULT and torque == 0
    assert drive.drive.faults == Fault.HEARTBEAT
    steps = drive.drive.steps
    # Fault reset needs a rising edge of bit 7: holding it does nothing more.
    host.heartbeat()
    assert state_of(host.cycle(0x80)[0]) == Cia402State.SWITCH_ON_DISABLED
    emcy(host, 0x0000)  # error reset
    assert state_of(host.cycle(0x80)[0]) == Cia402State.SWITCH_ON_DISABLED
    host.heartbeat()
    host.enable()
    assert drive.drive.steps == steps + 1 and drive.drive.faults == Fault.NONE


def test_a_heartbeat_queued_during_the_drives_own_stall_counts_in_time():
    """After this process stalled (emulation: the QEMU VM), the frames queued
    meanwhile are handled as one backlog; a master heartbeat among them
    reached the drive in time, so the consumer does not trip on the
    backlog's earlier frames. Without one in the backlog it trips."""
    now = [0.0]
    bus = can.Bus(interface="sensaug_udp", channel=free_port())
    try:
        d = VirtualCia402(bus, Cia402Config(), clock=lambda: now[0])
        d.start()
        d._set_consumer((MASTER << 16) | 100)
        d._on_master_heartbeat(0x700 + MASTER, bytearray(b"\x05"), now[0])  # armed
        sync = can.Message(arbitration_id=0x080, data=bytes([1]), is_extended_id=False)
        beat = can.Message(arbitration_id=0x700 + MASTER, data=b"\x05", is_extended_id=False)
        now[0] = 0.35  # a 350 ms stall of the drive, 100 ms consumer
        d._handle_backlog([sync, beat])
        assert d.heartbeat_events == 0
        now[0] = 0.70  # 350 ms more, no heartbeat queued: lost
        d._handle_backlog([sync])
        assert d.heartbeat_events == 1
        d.stop()
    finally:
        bus.shutdown()


def test_watchdog_waits_for_the_first_heartbeat_and_ignores_other_nodes(drive: Drive):
    host = drive.host
    host.sdo_write(0x6060, 0, bytes([10]))
    assert host.sdo_write(0x1016, 1, struct.pack("<I", (MASTER << 16) | 50))[0] == 0x60
    host.nmt(0x01)
    host.enable()
    host.send(0x700 + 5, b"\x05")  # another node's heartbeat does not arm it
    host.frames_for(0.2)
    sw, *_ = host.cycle(0x0F, 0)
    assert state_of(sw) == Cia402State.OPERATION_ENABLED and drive.drive.heartbeat_events == 0


def test_quick_stop_is_the_emergency_stop(drive: Drive):
    host = drive.host
    host.set_up()
    host.enable()
    host.cycle(0x0F, 200)
    sw, _, _, torque = host.cycle(0x02, 200)
    assert state_of(sw) == Cia402State.QUICK_STOP_ACTIVE and torque == 0
    steps = drive.drive.steps
    # Enable does not leave quick stop; only "disable voltage" does, then enable again.
    assert state_of(host.cycle(0x0F, 200)[0]) == Cia402State.QUICK_STOP_ACTIVE
    assert drive.drive.steps == steps
    assert state_of(host.cycle(0x00)[0]) == Cia402State.SWITCH_ON_DISABLED
    host.enable()


def test_overspeed_faults_after_the_step(start_drive):
    d = start_drive(max_velocity_rad_s=0.5)
    host = d.host
    host.set_up()
    host.enable()
    states = []
    for _ in range(5):
        sw, _, vel, torque = host.cycle(0x0F, 1000)  # 1 N m on 0.0035 kg m^2: 0.29 rad/s per ms
        states.append(state_of(sw))
        if states[-1] == Cia402State.FAULT:
            break
    assert states[-1] == Cia402State.FAULT and torque == 0
    assert abs(vel * RAD_PER_COUNT) > 0.5  # the step that tripped it is reported
    assert emcy(host, 0x8400)[3] == Fault.OVERSPEED


def test_nmt_stop_while_enabled_faults(drive: Drive):
    host = drive.host
    host.set_up()
    host.enable()
    host.nmt(0x02)
    emcy(host, 0x8100)
    assert drive.drive.state == Cia402State.FAULT and drive.drive.torque_per_mille == 0


def test_a_reset_sends_its_boot_up_and_restores_the_stored_parameters(drive: Drive):
    """NMT reset node (0x81) restarts the drive as a power cycle would: the
    boot-up message, PRE-OPERATIONAL heartbeats, SwitchOnDisabled, every
    SDO-written value back to the EDS's and the config's (mode 0, heartbeat
    consumer off, 0x6072 the configured 3000), no fault latched, no PDOs."""
    host = drive.host
    host.set_up(consumer_ms=500)
    assert host.sdo_write(0x6072, 0, struct.pack("<H", 2500))[0] == 0x60
    host.enable()
    host.heartbeat()
    host.cycle(0x0F, 40)
    host.nmt(0x81)
    assert host.expect(0x700 + NODE, lambda d: d in (b"\x00", b"\x7f")) == b"\x00"  # boot-up first
    assert host.expect(0x700 + NODE) == b"\x7f"
    assert drive.drive.resets == 1 and drive.drive.faults == Fault.NONE
    assert struct.unpack_from("<b", host.sdo_read(0x6060), 4)[0] == 0
    assert struct.unpack_from("<H", host.sdo_read(0x6072), 4)[0] == 3000
    assert struct.unpack_from("<I", host.sdo_read(0x1016, 1), 4)[0] == 0
    assert state_of(struct.unpack_from("<H", host.sdo_read(0x6041), 4)[0]) == Cia402State.SWITCH_ON_DISABLED
    host.send(0x200 + NODE, struct.pack("<Hh", 0x0F, 40))
    host.send(0x080, bytes([1]))
    assert not [m for m in host.frames_for(0.2) if m.arbitration_id in (0x180 + NODE, 0x280 + NODE)]


def test_other_nodes_and_bad_frames_are_ignored(drive: Drive):
    host = drive.host
    host.set_up()
    host.send(0x200 + 2, struct.pack("<Hh", 0x06, 0))  # another node's RPDO
    host.bus.send(can.Message(arbitration_id=0x12345, data=b"\x01", is_extended_id=True))
    host.bus.send(can.Message(arbitration_id=0x201, is_remote_frame=True, is_extended_id=False))
    host.send(0x600 + NODE, b"\x40\x00")  # a short SDO request
    host.send(0x000, b"\x02")  # an NMT command without its node byte
    host.send(0x200 + NODE, struct.pack("<H", 0x06))  # a short RPDO1
    host.send(0x080, b"\x01\x02")  # a SYNC longer than its counter
    host.send(0x180 + NODE, b"\x01")  # someone else on the drive's TPDO1 id
    host.frames_for(0.2)
    assert state_of(host.cycle(0x00)[0]) == Cia402State.SWITCH_ON_DISABLED
    assert drive.drive.unknown_frames == 3 and drive.drive.length_errors == 4
    assert drive.drive.node.nmt.state == "OPERATIONAL" and drive.drive.syncs == 1
    host.enable()


# -- the CLI ----------------------------------------------------------------------------------


def _cli(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "sensaug_bridge.virtual_cia402", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


@contextlib.contextmanager
def cli_drive(*args: str) -> Iterator[tuple[Host, subprocess.Popen]]:
    """The CLI drive on a free port, booted (its boot-up seen), and a host
    on the same bus; killed at the end if still running."""
    port = free_port()
    with can.Bus(interface="sensaug_udp", channel=port) as bus:
        host = Host(bus)
        proc = _cli("-c", str(port), *args)
        try:
            host.expect(0x700 + NODE, lambda d: d == b"\x00", timeout=30.0)  # boot-up
            yield host, proc
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()


def test_cli_sigterm_is_a_clean_shutdown(tmp_path):
    with cli_drive("--log", str(tmp_path / "log.npz")) as (host, proc):
        host.set_up(consumer_ms=500)
        host.enable()
        for _ in range(20):
            host.heartbeat()
            host.cycle(0x0F, 5)
        proc.send_signal(signal.SIGTERM)
        last_sw = host.expect(0x180 + NODE)
        assert state_of(struct.unpack_from("<H", last_sw)[0]) == Cia402State.SWITCH_ON_DISABLED
        host.expect(0x700 + NODE, lambda d: d == b"\x04")  # the last heartbeat: STOPPED
        _, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert "'steps': 21" in err and "'faults': 0" in err
    import numpy as np

    log = np.load(tmp_path / "log.npz")
    assert len(log["t_s"]) == 21 and np.allclose(log["torque_nm"][1:], 5 * RATED_MNM * 1e-6)


def test_cli_sigusr1_is_a_reset_mid_run():
    """SIGUSR1 to the CLI drive: a power glitch; it sends its boot-up and
    comes back PRE-OPERATIONAL in SwitchOnDisabled (tests/test_rig_faults.py
    resets the drive this way under a running controller)."""
    with cli_drive() as (host, proc):
        host.set_up()
        host.enable()
        host.cycle(0x0F, 5)
        proc.send_signal(signal.SIGUSR1)
        host.expect(0x700 + NODE, lambda d: d == b"\x00")
        host.expect(0x700 + NODE, lambda d: d == b"\x7f")
        sw = struct.unpack_from("<H", host.sdo_read(0x6041), 4)[0]
        assert state_of(sw) == Cia402State.SWITCH_ON_DISABLED
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert "'resets': 1" in err, err


@pytest.mark.parametrize(
    "args, field",
    [(["--node", "0"], "node"), (["--node", "128"], "node"), (["--torque-limit", "40"], "torque_limit_nm"),
     (["--mass", "-1"], "mass"), (["--rated-torque-mnm", "0"], "rated_torque_mnm")],
)
def test_cli_bad_options_exit_2_naming_the_field(args: list[str], field: str):
    proc = _cli(*args)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 2 and field in err, err


# -- a standard drive (no 0x2000) -------------------------------------------------------------


def test_the_standard_eds_is_the_drives_without_0x2000_in_canopens_local_node():
    """The standard drive's dictionary: cia402_drive.eds without the SYNC counter
    echo, loaded by python-canopen's EDS importer into a LocalNode; every other
    object as in the EDS; the TPDOs map the two objects before it."""
    import canopen

    from sensaug_bridge.virtual_cia402 import load_od

    echo, standard = load_od(NODE), load_od(NODE, standard=True)
    assert 0x2000 in echo and 0x2000 not in standard
    assert set(echo.indices) - set(standard.indices) == {0x2000}
    node = canopen.LocalNode(NODE, standard)
    canopen.Network().add_node(node)  # no bus: the PDO maps need a network only to subscribe
    node.tpdo.read(from_od=True)
    assert [v.index for v in node.tpdo[1]] == [0x6041, 0x6064]
    assert [v.index for v in node.tpdo[2]] == [0x606C, 0x6077]
    assert node.tpdo[1].length == node.tpdo[2].length == 48
    for index in set(standard.indices) - {0x1A00, 0x1A01}:
        a, b = echo[index], standard[index]
        subs = getattr(a, "subindices", {0: a})
        for sub, var in subs.items():
            other = getattr(b, "subindices", {0: b})[sub]
            assert (other.name, other.data_type, other.access_type, other.default) == (
                var.name, var.data_type, var.access_type, var.default), (hex(index), sub)


def test_a_standard_drive_aborts_the_echo_read_and_sends_6_byte_tpdos(start_drive):
    """What the Rust master's set-up reads to choose the mode: SDO upload of
    0x2000 aborts "object does not exist"; the TPDOs answer every SYNC without
    a counter, and the feedback is the plant's as on the echo drive."""
    drive = start_drive(standard=True)
    host = drive.host
    resp = host.sdo_read(0x2000)
    assert resp[0] == 0x80 and struct.unpack_from("<I", resp, 4)[0] == 0x06020000
    host.set_up()
    ref = sensaug.Plant(mass=0.0035, damping=0.0, coulomb=0.0, dt_s=1e-3, x0=0.0, v0=0.0)
    for cw in (0x06, 0x07, 0x0F):
        host.send(0x200 + NODE, struct.pack("<Hh", cw, 0))
        host.send(0x080, bytes([1]))
        t1, t2 = host.expect(0x180 + NODE), host.expect(0x280 + NODE)
        assert len(t1) == len(t2) == 6
    ref.step(0.0)
    assert state_of(struct.unpack("<Hi", t1)[0]) == Cia402State.OPERATION_ENABLED
    for k in range(30):
        host.send(0x200 + NODE, struct.pack("<Hh", 0x0F, 5))
        host.send(0x080, bytes([k % SYNC_COUNTER_OVERFLOW + 1]))
        _, pos = struct.unpack("<Hi", host.expect(0x180 + NODE))
        vel, torque = struct.unpack("<ih", host.expect(0x280 + NODE))
        x, v = ref.step(5 * RATED_MNM * 1e-6)
        assert torque == 5 and pos == round(x / RAD_PER_COUNT) and vel == round(v / RAD_PER_COUNT)
