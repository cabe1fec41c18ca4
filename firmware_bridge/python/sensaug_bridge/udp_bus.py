"""A loopback-only virtual CAN bus for python-can: one UDP broadcast per frame on 127.0.0.0/8.

Registered as the python-can interface ``sensaug_udp`` (entry point group
``can.interface``), so ``can.Bus(interface="sensaug_udp", channel=47100)`` opens it;
the channel is the UDP port. Any number of processes on this machine that open
the same port see each other's frames, like nodes on one CAN bus. Nothing is
ever sent outside 127.0.0.0/8: the only destination is the loopback broadcast
address ``127.255.255.255`` and the sender binds ``127.0.0.1``.

Wire format (exactly SocketCAN's ``struct can_frame``, 16 bytes a datagram)::

    offset size  field
    0      4     can_id, u32 little-endian: the 11- or 29-bit id | flags
                 0x80000000 EFF (29-bit id), 0x40000000 RTR, 0x20000000 ERR
    4      1     len, 0..=8
    5      3     zero (__pad, __res0, len8_dlc)
    8      8     data, zero-padded past len (all zero in a remote frame)

Every classic CAN frame travels: standard and extended ids, data, remote and
error frames, exactly as python-can's ``socketcan`` interface packs them
(``arbitration_id`` is the low 29 bits of ``can_id``). CAN FD frames do not
fit the format and :meth:`UdpLoopbackBus.send` refuses them.

A received datagram that is not a frame (size != 16, len > 8, a standard id
above 0x7FF, non-zero reserved bytes) is dropped and counted in
:attr:`UdpLoopbackBus.dropped_malformed` (per reason in
:attr:`UdpLoopbackBus.drop_reasons`); it never raises.

Bursts: the receive socket asks for :data:`RECEIVE_BUFFER_BYTES` of buffer
(``SO_RCVBUFFORCE`` when allowed, else ``SO_RCVBUF``, capped by
``net.core.rmem_max``; the grant is :attr:`UdpLoopbackBus.receive_buffer_bytes`).
Datagrams the kernel drops because the buffer is full are counted from
``SO_RXQ_OVFL`` in :attr:`UdpLoopbackBus.dropped_kernel`.

Self-filter: each peer sends from its own socket bound to ``127.0.0.1:0``; a
received datagram whose source ``(address, port)`` equals that socket's
``getsockname()`` is this peer's own frame and is skipped, or delivered with
``is_rx=False`` when ``receive_own_messages=True``.
"""

from __future__ import annotations

import collections
import socket
import struct
import time
from typing import Any, Final, NamedTuple, Optional

import can
from can import BusABC, CanProtocol, Message
from can.typechecking import AutoDetectedConfig, CanFilters

__all__ = [
    "BROADCAST_ADDR",
    "DEFAULT_PORT",
    "FRAME_SIZE",
    "RECEIVE_BUFFER_BYTES",
    "SEND_ADDR",
    "UdpLoopbackBus",
    "free_port",
    "pack_frame",
    "WireFrame",
    "unpack_frame",
]

#: Where every frame is sent, and the address each receive socket binds.
BROADCAST_ADDR: Final = "127.255.255.255"
#: Address each send socket binds (port chosen by the kernel).
SEND_ADDR: Final = "127.0.0.1"
#: Port used when no channel is given.
DEFAULT_PORT: Final = 47100
#: Size of one datagram: SocketCAN ``struct can_frame``.
FRAME_SIZE: Final = 16

#: Receive buffer each peer asks for: 4 MiB, about 5000 queued frames (a
#: 16-byte datagram costs ~800 bytes of buffer on loopback).
RECEIVE_BUFFER_BYTES: Final = 4 << 20

CAN_EFF_FLAG: Final = 0x8000_0000
CAN_RTR_FLAG: Final = 0x4000_0000
CAN_ERR_FLAG: Final = 0x2000_0000
CAN_SFF_MASK: Final = 0x7FF
CAN_EFF_MASK: Final = 0x1FFF_FFFF

# Linux socket options Python's socket module may not name.
_SO_RXQ_OVFL: Final = getattr(socket, "SO_RXQ_OVFL", 40)
_SO_RCVBUFFORCE: Final = getattr(socket, "SO_RCVBUFFORCE", 33)
_ANCILLARY_BYTES: Final = socket.CMSG_SPACE(4)

# can_id u32 LE, len u8, 3 reserved bytes, 8 data bytes.
_FRAME: Final = struct.Struct("<IB3s8s")
_ZERO3: Final = b"\x00\x00\x00"
_U32: Final = struct.Struct("=I")


def pack_frame(
    arbitration_id: int,
    data: bytes,
    *,
    is_extended_id: bool = False,
    is_remote_frame: bool = False,
    is_error_frame: bool = False,
    dlc: Optional[int] = None,
) -> bytes:
    """Pack one classic CAN frame into the 16-byte wire layout.

    ``dlc`` defaults to ``len(data)``; a remote frame sends ``dlc`` and no data.

    Raises:
        ValueError: if the id does not fit 11 bits (29 if extended or an error
            frame), the data is longer than 8 bytes or ``dlc`` is not 0..=8.
    """
    wide = is_extended_id or is_error_frame
    limit = CAN_EFF_MASK if wide else CAN_SFF_MASK
    if not 0 <= arbitration_id <= limit:
        kind = "a 29-bit id (0..=0x1FFFFFFF)" if wide else "an 11-bit id (0..=0x7FF; set is_extended_id for 29 bits)"
        raise ValueError(f"arbitration_id: must be {kind}, got {arbitration_id:#x}")
    if len(data) > 8:
        raise ValueError(f"data: at most 8 bytes for classic CAN, got {len(data)}")
    length = len(data) if dlc is None else dlc
    if not 0 <= length <= 8:
        raise ValueError(f"dlc: must be 0..=8 for classic CAN, got {length}")
    can_id = arbitration_id
    if is_extended_id:
        can_id |= CAN_EFF_FLAG
    if is_remote_frame:
        can_id |= CAN_RTR_FLAG
        data = b""
    if is_error_frame:
        can_id |= CAN_ERR_FLAG
    return _FRAME.pack(can_id, length, _ZERO3, bytes(data).ljust(8, b"\x00"))


class WireFrame(NamedTuple):
    """One unpacked datagram: python-can's view of a SocketCAN ``can_frame``."""

    arbitration_id: int
    data: bytes
    dlc: int
    is_extended_id: bool
    is_remote_frame: bool
    is_error_frame: bool


def unpack_frame(datagram: bytes) -> WireFrame | str:
    """Unpack one datagram, or return why it is malformed.

    Returns a string (the drop reason) instead of raising, so the receive path
    never throws on garbage.
    """
    if len(datagram) != FRAME_SIZE:
        return "size"
    can_id, length, reserved, payload = _FRAME.unpack(datagram)
    if length > 8:
        return "len"
    if reserved != _ZERO3:
        return "reserved"
    extended = bool(can_id & CAN_EFF_FLAG)
    remote = bool(can_id & CAN_RTR_FLAG)
    error = bool(can_id & CAN_ERR_FLAG)
    arbitration_id = can_id & CAN_EFF_MASK
    if not (extended or error) and arbitration_id > CAN_SFF_MASK:
        return "id"
    data = b"" if remote else payload[:length]
    return WireFrame(arbitration_id, data, length, extended, remote, error)


class UdpLoopbackBus(BusABC):
    """Virtual classic-CAN bus between processes on this machine, over loopback UDP broadcast.

    :param channel: the UDP port (int, or a string of digits as given on a
        command line). Defaults to :data:`DEFAULT_PORT`.
    :param receive_own_messages: deliver this peer's own frames back to it
        (with ``is_rx=False``), like SocketCAN's ``recv_own_msgs``.
    :param can_filters: see :meth:`can.BusABC.set_filters` (applied in Python).

    Every classic CAN frame (11- or 29-bit id; data, remote or error);
    :meth:`send` raises :class:`can.CanOperationError` for CAN FD frames.

    :raises ValueError: if the port is not in 1..=65535.
    :raises can.CanInitializationError: if a socket cannot be opened or bound.
    """

    def __init__(
        self,
        channel: Any = DEFAULT_PORT,
        receive_own_messages: bool = False,
        can_filters: Optional[CanFilters] = None,
        **kwargs: Any,
    ) -> None:
        port = _port_from_channel(channel)
        self.port: int = port
        self.receive_own_messages = receive_own_messages
        #: Datagrams dropped as malformed (never raised).
        self.dropped_malformed: int = 0
        #: Drop count per reason (``size``, ``len``, ``id``, ``reserved``).
        self.drop_reasons: collections.Counter[str] = collections.Counter()
        #: Datagrams the kernel dropped because the receive buffer was full
        #: (``SO_RXQ_OVFL``; learnt with the next datagram received).
        self.dropped_kernel: int = 0
        #: Receive buffer the kernel granted, bytes.
        self.receive_buffer_bytes: int = 0
        self._kernel_drops_seen = 0
        self._rx: Optional[socket.socket] = None
        self._tx: Optional[socket.socket] = None
        try:
            rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._rx = rx
            rx.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            rx.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            try:
                rx.setsockopt(socket.SOL_SOCKET, _SO_RCVBUFFORCE, RECEIVE_BUFFER_BYTES)
            except OSError:  # needs CAP_NET_ADMIN; SO_RCVBUF is capped by rmem_max
                rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)
            self.receive_buffer_bytes = rx.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
            rx.setsockopt(socket.SOL_SOCKET, _SO_RXQ_OVFL, 1)
            rx.bind((BROADCAST_ADDR, port))
            tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._tx = tx
            tx.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
            tx.bind((SEND_ADDR, 0))
            self._own_addr: tuple[str, int] = tx.getsockname()
        except OSError as err:
            self._close_sockets()
            raise can.CanInitializationError(
                f"sensaug_udp: cannot open loopback bus on port {port}: {err}"
            ) from err
        self._dest = (BROADCAST_ADDR, port)
        self._rx_timeout: Optional[float] = -1.0  # forces the first settimeout
        self.channel_info = f"sensaug_udp loopback port {port} (tx {self._own_addr[0]}:{self._own_addr[1]})"
        self._can_protocol = CanProtocol.CAN_20
        super().__init__(channel=port, can_filters=can_filters, **kwargs)

    # -- sending -----------------------------------------------------------------

    def send(self, msg: Message, timeout: Optional[float] = None) -> None:
        """Send one frame to every peer on the port (UDP never blocks here; ``timeout`` is unused).

        :raises can.CanOperationError: for frames this format cannot carry, or a socket error.
        """
        if msg.is_fd:
            raise can.CanOperationError(
                "sensaug_udp carries classic CAN frames (SocketCAN can_frame); CAN FD does not fit"
            )
        data = bytes(msg.data)
        if not msg.is_remote_frame:
            if msg.dlc < len(data):
                data = data[: msg.dlc]
            elif msg.dlc > len(data):
                data = data.ljust(msg.dlc, b"\x00")
        try:
            datagram = pack_frame(
                msg.arbitration_id,
                data,
                is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame,
                is_error_frame=msg.is_error_frame,
                dlc=msg.dlc,
            )
        except ValueError as err:
            raise can.CanOperationError(f"sensaug_udp: {err}") from err
        tx = self._tx
        if tx is None:
            raise can.CanOperationError("sensaug_udp: bus is shut down")
        try:
            tx.sendto(datagram, self._dest)
        except OSError as err:
            raise can.CanOperationError(f"sensaug_udp: send failed: {err}") from err

    # -- receiving ---------------------------------------------------------------

    def _set_rx_timeout(self, timeout: Optional[float]) -> None:
        # settimeout costs a syscall; skip it when the value is unchanged.
        if timeout != self._rx_timeout:
            assert self._rx is not None
            self._rx.settimeout(timeout)
            self._rx_timeout = timeout

    def _recv_internal(self, timeout: Optional[float]) -> tuple[Optional[Message], bool]:
        rx = self._rx
        if rx is None:
            raise can.CanOperationError("sensaug_udp: bus is shut down")
        deadline = None if timeout is None else time.monotonic() + max(timeout, 0.0)
        while True:
            if deadline is None:
                self._set_rx_timeout(None)
            else:
                self._set_rx_timeout(max(deadline - time.monotonic(), 0.0))
            try:
                datagram, ancillary, _flags, source = rx.recvmsg(2048, _ANCILLARY_BYTES)
            except (socket.timeout, BlockingIOError):
                return None, False
            except OSError as err:
                raise can.CanOperationError(f"sensaug_udp: receive failed: {err}") from err
            stamp = time.time()
            self._count_kernel_drops(ancillary)
            own = source == self._own_addr
            if own and not self.receive_own_messages:
                continue
            frame = unpack_frame(datagram)
            if isinstance(frame, str):
                self.dropped_malformed += 1
                self.drop_reasons[frame] += 1
                continue
            msg = Message(
                timestamp=stamp,
                arbitration_id=frame.arbitration_id,
                is_extended_id=frame.is_extended_id,
                is_remote_frame=frame.is_remote_frame,
                is_error_frame=frame.is_error_frame,
                dlc=frame.dlc,
                data=frame.data,
                channel=self.port,
                is_rx=not own,
            )
            return msg, False

    def _count_kernel_drops(self, ancillary: list[tuple[int, int, bytes]]) -> None:
        # SO_RXQ_OVFL: the socket's drop count (a wrapping u32) when the
        # datagram was queued.
        for level, kind, data in ancillary:
            if level == socket.SOL_SOCKET and kind == _SO_RXQ_OVFL and len(data) >= 4:
                drops = _U32.unpack_from(data)[0]
                self.dropped_kernel += (drops - self._kernel_drops_seen) % (1 << 32)
                self._kernel_drops_seen = drops

    def fileno(self) -> int:
        """The receive socket's file descriptor (for select/asyncio), or -1 after shutdown."""
        return self._rx.fileno() if self._rx is not None else -1

    # -- lifetime ----------------------------------------------------------------

    def _close_sockets(self) -> None:
        for sock in (self._rx, self._tx):
            if sock is not None:
                try:
                    sock.close()
                except OSError:
                    pass
        self._rx = None
        self._tx = None

    def shutdown(self) -> None:
        """Close both sockets. Idempotent, never raises."""
        super().shutdown()
        self._close_sockets()

    @staticmethod
    def _detect_available_configs() -> list[AutoDetectedConfig]:
        return [{"interface": "sensaug_udp", "channel": DEFAULT_PORT}]


def free_port() -> int:
    """A port no socket has bound on the loopback broadcast address right now (for tests).

    Binds ``127.255.255.255:0`` without SO_REUSEPORT, so the kernel skips ports
    that other buses hold; racy by nature, but two tests asking at once get
    different ports.
    """
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind((BROADCAST_ADDR, 0))
        return int(sock.getsockname()[1])


def _port_from_channel(channel: Any) -> int:
    if channel is None:
        return DEFAULT_PORT
    if isinstance(channel, bool):
        raise ValueError(f"channel: must be a UDP port 1..=65535, got {channel!r}")
    try:
        port = int(channel)
    except (TypeError, ValueError):
        raise ValueError(f"channel: must be a UDP port 1..=65535, got {channel!r}") from None
    if not 1 <= port <= 65535:
        raise ValueError(f"channel: must be a UDP port 1..=65535, got {channel!r}")
    return port
