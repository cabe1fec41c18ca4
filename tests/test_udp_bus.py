"""One transport suite, run on the sensaug_udp loopback bus and on python-can's `virtual` bus.

`TransportSuite` holds the behaviour every bus must show; each subclass only
says how to open a peer on a fresh channel. The sensaug_udp subclass adds what
only a socket transport has: the exact wire format, garbage datagrams, the
entry point, and `python -m can.logger` in another process.

Every test picks its own port (`free_port`), so parallel runs don't collide.
All traffic goes to 127.255.255.255 / 127.0.0.1.
"""

from __future__ import annotations

import os
import queue
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import uuid
from typing import Any

import can
import pytest

from sensaug_bridge.udp_bus import BROADCAST_ADDR, FRAME_SIZE, UdpLoopbackBus, free_port  # noqa: E402

RECV_S = 2.0  # generous: a frame on loopback arrives in well under 1 ms


def _msg(arbitration_id: int, data: bytes | list[int]) -> can.Message:
    return can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False)


def _same(a: can.Message, b: can.Message) -> bool:
    return a.arbitration_id == b.arbitration_id and bytes(a.data) == bytes(b.data) and a.dlc == b.dlc


class TransportSuite:
    """Behaviour common to every bus. Subclasses implement `open_bus` and `new_channel`."""

    def new_channel(self) -> Any:
        raise NotImplementedError

    def open_bus(self, channel: Any, **kwargs: Any) -> can.BusABC:
        raise NotImplementedError

    @pytest.fixture(autouse=True)
    def _buses(self):
        self.channel = self.new_channel()
        self.buses: list[can.BusABC] = []
        yield
        for bus in self.buses:
            bus.shutdown()

    def peer(self, **kwargs: Any) -> can.BusABC:
        bus = self.open_bus(self.channel, **kwargs)
        self.buses.append(bus)
        return bus

    def test_two_peers_both_directions(self):
        a, b = self.peer(), self.peer()
        a.send(_msg(0x201, [1, 2, 3, 4, 5, 6, 7, 8]))
        got = b.recv(RECV_S)
        assert got is not None and got.arbitration_id == 0x201
        assert bytes(got.data) == bytes(range(1, 9)) and got.dlc == 8
        assert not got.is_extended_id and got.is_rx
        b.send(_msg(0x281, [9]))
        back = a.recv(RECV_S)
        assert back is not None and _same(back, _msg(0x281, [9]))

    def test_three_peers_everyone_else_receives(self):
        a, b, c = self.peer(), self.peer(), self.peer()
        sent = _msg(0x701, [0xAA, 0x55])
        a.send(sent)
        for bus in (b, c):
            got = bus.recv(RECV_S)
            assert got is not None and _same(got, sent)
        assert a.recv(0.05) is None  # not its own frame
        c.send(_msg(0x010, []))
        for bus in (a, b):
            got = bus.recv(RECV_S)
            assert got is not None and got.arbitration_id == 0x010 and got.dlc == 0

    def test_no_own_frames(self):
        a = self.peer()
        a.send(_msg(0x123, [1]))
        assert a.recv(0.1) is None

    def test_receive_own_messages(self):
        a, b = self.peer(receive_own_messages=True), self.peer()
        a.send(_msg(0x124, [2]))
        own = a.recv(RECV_S)
        assert own is not None and _same(own, _msg(0x124, [2]))
        assert not own.is_rx
        got = b.recv(RECV_S)
        assert got is not None and got.is_rx

    def test_every_length_and_order_kept(self):
        a, b = self.peer(), self.peer()
        sent = [_msg(0x300 + n, bytes(range(n))) for n in range(9)] * 10
        for m in sent:
            a.send(m)
        got = [b.recv(RECV_S) for _ in sent]
        assert all(g is not None for g in got)
        assert all(_same(g, m) for g, m in zip(got, sent))

    def test_timeouts(self):
        a = self.peer()
        t0 = time.monotonic()
        assert a.recv(0.05) is None
        waited = time.monotonic() - t0
        assert waited >= 0.045  # waited for (about) the timeout, not less
        print(f"recv(0.05) on an idle bus returned None after {waited * 1e3:.1f} ms")
        assert a.recv(0) is None  # non-blocking poll

    def test_filters(self):
        a = self.peer()
        b = self.peer(can_filters=[{"can_id": 0x280, "can_mask": 0x7F0}])
        a.send(_msg(0x201, [1]))
        a.send(_msg(0x281, [2]))
        got = b.recv(RECV_S)
        assert got is not None and got.arbitration_id == 0x281


    def test_every_classic_frame_kind(self):
        """python-can's Message() defaults to a 29-bit id; remote and error frames travel too."""
        a, b = self.peer(), self.peer()
        sent = [
            can.Message(),
            can.Message(arbitration_id=0x1ABCDEF0, is_extended_id=True, data=bytes(range(8))),
            can.Message(arbitration_id=0x123, is_extended_id=False, is_remote_frame=True, dlc=4),
            can.Message(arbitration_id=0x1234567, is_extended_id=True, is_remote_frame=True, dlc=8),
            can.Message(arbitration_id=0x4, is_error_frame=True, is_extended_id=False, data=bytes([0, 0x10] + [0] * 6)),
        ]
        for msg in sent:
            a.send(msg)
            got = b.recv(RECV_S)
            assert got is not None, msg
            assert (got.arbitration_id, got.is_extended_id, got.is_remote_frame, got.is_error_frame, got.dlc) == (
                msg.arbitration_id,
                msg.is_extended_id,
                msg.is_remote_frame,
                msg.is_error_frame,
                msg.dlc,
            ), (got, msg)
            if not msg.is_remote_frame:
                assert bytes(got.data) == bytes(msg.data)


class TestVirtualBus(TransportSuite):
    """python-can's own in-process `virtual` interface, for comparison."""

    def new_channel(self) -> Any:
        return f"sensaug-test-{uuid.uuid4()}"

    def open_bus(self, channel: Any, **kwargs: Any) -> can.BusABC:
        return can.Bus(interface="virtual", channel=channel, **kwargs)


def _raw_sender() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
    sock.bind(("127.0.0.1", 0))
    return sock


def _raw_listener(port: int) -> socket.socket:
    """A plain UDP socket that sees every datagram on the bus, as bytes."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
    rx.bind((BROADCAST_ADDR, port))
    rx.settimeout(RECV_S)
    return rx


class TestSensaugUdp(TransportSuite):
    """The loopback plugin, opened through python-can's entry point."""

    def new_channel(self) -> Any:
        return free_port()

    def open_bus(self, channel: Any, **kwargs: Any) -> can.BusABC:
        return can.Bus(interface="sensaug_udp", channel=channel, **kwargs)

    def test_entry_point_and_string_channel(self):
        bus = self.peer()
        assert isinstance(bus, UdpLoopbackBus)
        other = self.open_bus(str(self.channel))  # as a command line gives it
        self.buses.append(other)
        assert other.port == self.channel
        assert other.fileno() >= 0
        with pytest.raises(ValueError):
            can.Bus(interface="sensaug_udp", channel=70000)

    def test_exact_wire_format(self):
        a = self.peer()
        rx = _raw_listener(self.channel)
        try:
            a.send(_msg(0x201, [1, 2, 3]))
            datagram, source = rx.recvfrom(64)
        finally:
            rx.close()
        assert datagram == struct.pack("<IB3x8s", 0x201, 3, bytes([1, 2, 3, 0, 0, 0, 0, 0]))
        assert len(datagram) == FRAME_SIZE
        assert source[0] == "127.0.0.1"
        # And a foreign sender in the same format is received.
        tx = _raw_sender()
        try:
            tx.sendto(struct.pack("<IB3x8s", 0x7FF, 8, bytes(range(8))), (BROADCAST_ADDR, self.channel))
        finally:
            tx.close()
        got = a.recv(RECV_S)
        assert got is not None and got.arbitration_id == 0x7FF and bytes(got.data) == bytes(range(8))

    def test_unsendable_frames_raise(self):
        a = self.peer()
        for bad in (
            can.Message(arbitration_id=0x800, is_extended_id=False, data=[1]),
            can.Message(arbitration_id=0x2000_0000, is_extended_id=True, data=[1]),
            can.Message(arbitration_id=0x123, is_extended_id=False, is_fd=True, data=bytes(12)),
        ):
            with pytest.raises(can.CanOperationError):
                a.send(bad)

    def test_flag_bits_on_the_wire_are_socketcans(self):
        a = self.peer()
        rx = _raw_listener(self.channel)
        try:
            a.send(can.Message(arbitration_id=0x1ABCDEF0, is_extended_id=True, data=b"\x07"))
            a.send(can.Message(arbitration_id=0x123, is_extended_id=False, is_remote_frame=True, dlc=4))
            a.send(can.Message(arbitration_id=0x4, is_error_frame=True, is_extended_id=False, data=bytes(8)))
            got = [rx.recvfrom(64)[0] for _ in range(3)]
        finally:
            rx.close()
        assert got[0] == struct.pack("<IB3x8s", 0x8000_0000 | 0x1ABCDEF0, 1, b"\x07" + bytes(7))
        assert got[1] == struct.pack("<IB3x8s", 0x4000_0123, 4, bytes(8))
        assert got[2] == struct.pack("<IB3x8s", 0x2000_0004, 8, bytes(8))

    def test_garbage_datagrams_dropped_and_counted(self):
        a = self.peer()
        good = struct.pack("<IB3x8s", 0x201, 2, b"\x01\x02" + bytes(6))
        garbage = {
            "size": [b"", b"\x00" * 15, b"\x00" * 17, b"x" * 1000],
            "len": [struct.pack("<IB3x8s", 0x201, 9, bytes(8))],
            "id": [struct.pack("<IB3x8s", 0x800, 1, bytes(8))],
            "reserved": [struct.pack("<IBBBB8s", 0x201, 2, 0, 0, 1, bytes(8))],
        }
        tx = _raw_sender()
        try:
            for datagrams in garbage.values():
                for datagram in datagrams:
                    tx.sendto(datagram, (BROADCAST_ADDR, self.channel))
            tx.sendto(good, (BROADCAST_ADDR, self.channel))
        finally:
            tx.close()
        got = a.recv(RECV_S)
        assert got is not None and got.arbitration_id == 0x201 and bytes(got.data) == b"\x01\x02"
        assert isinstance(a, UdpLoopbackBus)
        assert a.dropped_malformed == sum(len(v) for v in garbage.values())
        assert dict(a.drop_reasons) == {k: len(v) for k, v in garbage.items()}

    def test_kernel_drops_of_a_full_receive_buffer_are_counted(self):
        a = self.peer()
        assert isinstance(a, UdpLoopbackBus)
        granted = a.receive_buffer_bytes
        assert granted >= 200_000, granted
        # Far more than the buffer holds (a queued datagram costs ~800 bytes
        # of it), nobody reading: the kernel drops the rest. One more frame
        # after draining carries the final SO_RXQ_OVFL count.
        sent = granted // 128 + 1000
        datagram = struct.pack("<IB3x8s", 0x123, 1, bytes(8))
        tx = _raw_sender()
        try:
            for _ in range(sent):
                tx.sendto(datagram, (BROADCAST_ADDR, self.channel))
            received = 0
            while a.recv(0) is not None:
                received += 1
            tx.sendto(datagram, (BROADCAST_ADDR, self.channel))
            assert a.recv(RECV_S) is not None
            received += 1
        finally:
            tx.close()
        assert a.dropped_kernel > 0
        assert a.dropped_kernel + received == sent + 1, (a.dropped_kernel, received, sent)
        print(f"\nbuffer {granted} B: {received} frames queued, {a.dropped_kernel} dropped by the kernel")

    def test_opening_the_bus_needs_no_dbc(self):
        """can.Bus(interface="sensaug_udp") in a process where hi5.dbc cannot be found
        (as in a non-editable install): the bus opens; only the protocol asks for the DBC."""
        code = (
            "import can, sys\n"
            f"bus = can.Bus(interface='sensaug_udp', channel={self.channel})\n"
            "bus.send(can.Message(arbitration_id=1, data=[1]))\n"
            "bus.shutdown()\n"
            "assert 'sensaug_bridge.protocol' not in sys.modules\n"
            "try:\n"
            "    import sensaug_bridge.protocol\n"
            "except FileNotFoundError as err:\n"
            "    assert 'SENSAUG_HI5_DBC' in str(err), err\n"
            "    print('protocol needs the DBC')\n"
        )
        env = dict(os.environ, SENSAUG_HI5_DBC="/nonexistent/hi5.dbc")
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        assert out.stdout.strip() == "protocol needs the DBC"

    def test_can_logger_subprocess_captures_frames(self):
        a = self.peer()
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        proc = subprocess.Popen(
            [sys.executable, "-m", "can.logger", "-i", "sensaug_udp", "-c", str(self.channel)],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
        )
        lines: queue.Queue[str] = queue.Queue()

        def pump() -> None:
            assert proc.stdout is not None
            for line in proc.stdout:
                lines.put(line)

        threading.Thread(target=pump, daemon=True).start()
        try:
            # The logger needs a moment to import and bind; resend until it shows a frame.
            seen = []
            deadline = time.monotonic() + 15.0
            while time.monotonic() < deadline and not any("5a5a5a" in s.replace(" ", "").lower() for s in seen):
                a.send(_msg(0x321, [0x5A, 0x5A, 0x5A]))
                try:
                    seen.append(lines.get(timeout=0.1))
                except queue.Empty:
                    pass
            assert any("321" in s for s in seen), seen
            a.send(_msg(0x7AB, [0xDE, 0xAD, 0xBE, 0xEF]))
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and not any("deadbeef" in s.replace(" ", "").lower() for s in seen):
                try:
                    seen.append(lines.get(timeout=0.1))
                except queue.Empty:
                    pass
            assert any("7ab" in s.lower() and "deadbeef" in s.replace(" ", "").lower() for s in seen), seen
        finally:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
