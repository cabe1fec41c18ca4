"""A loopback-only virtual CAN bus for python-can: one UDP broadcast per frame on 127.0.0.0/8.

Registered as the python-can interface ``sensaug_udp`` (entry point group
``can.interface``), so ``can.Bus(interface="sensaug_udp", channel=47100)`` opens it;
the channel is the UDP port. Any number of processes on this machine that open
the same port see each other's frames, like nodes on one CAN bus. Nothing is
ever sent outside 127.0.0.0/8: the only destination is the loopback broadcast
address ``127.255.255.255`` and the sender binds ``127.0.0.1``.

Wire format (exactly SocketCAN's ``struct can_frame``, 16 bytes a datagram)::

    offset size  field
    0      4     can_id, u32 little-endian (11-bit id; flag bits must be 0)
    4      1     len, 0..=8
    5      3     zero (__pad, __res0, len8_dlc)
    8      8     data, zero-padded past len

A received datagram that is not exactly that (size != 16, len > 8, any of the
EFF/RTR/ERR flags, an id above 0x7FF, non-zero reserved bytes) is dropped and
counted in :attr:`UdpLoopbackBus.dropped_malformed` (per reason in
:attr:`UdpLoopbackBus.drop_reasons`); it never raises.

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
from typing import Any, Final, Optional

import can
from can import BusABC, CanProtocol, Message
from can.typechecking import AutoDetectedConfig, CanFilters

__all__ = [
    "BROADCAST_ADDR",
    "DEFAULT_PORT",
    "FRAME_SIZE",
    "SEND_ADDR",
    "UdpLoopbackBus",
    "free_port",
    "pack_frame",
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

CAN_EFF_FLAG: Final = 0x8000_0000
CAN_RTR_FLAG: Final = 0x4000_0000
CAN_ERR_FLAG: Final = 0x2000_0000
CAN_SFF_MASK: Final = 0x7FF

# can_id u32 LE, len u8, 3 reserved bytes, 8 data bytes.
_FRAME: Final = struct.Struct("<IB3s8s")
_ZERO3: Final = b"\x00\x00\x00"


def pack_frame(arbitration_id: int, data: bytes) -> bytes:
    """Pack one classic 11-bit frame into the 16-byte wire layout.

    Raises:
        ValueError: if the id is not an 11-bit id or the data is longer than 8 bytes.
    """
    if not 0 <= arbitration_id <= CAN_SFF_MASK:
        raise ValueError(f"arbitration_id: must be an 11-bit id (0..=0x7FF), got {arbitration_id:#x}")
    if len(data) > 8:
        raise ValueError(f"data: at most 8 bytes for classic CAN, got {len(data)}")
    return _FRAME.pack(arbitration_id, len(data), _ZERO3, bytes(data).ljust(8, b"\x00"))


def unpack_frame(datagram: bytes) -> tuple[int, bytes] | str:
    """Unpack one datagram into ``(arbitration_id, data)``, or return why it is malformed.

    Returns a string (the drop reason) instead of raising, so the receive path
    never throws on garbage.
    """
    if len(datagram) != FRAME_SIZE:
        return "size"
    can_id, length, reserved, payload = _FRAME.unpack(datagram)
    if can_id & CAN_EFF_FLAG:
        return "extended"
    if can_id & CAN_RTR_FLAG:
        return "rtr"
    if can_id & CAN_ERR_FLAG:
        return "error_frame"
    if can_id > CAN_SFF_MASK:
        return "id"
    if length > 8:
        return "len"
    if reserved != _ZERO3:
        return "reserved"
    return can_id, payload[:length]


class UdpLoopbackBus(BusABC):
    """Virtual classic-CAN bus between processes on this machine, over loopback UDP broadcast.

    :param channel: the UDP port (int, or a string of digits as given on a
        command line). Defaults to :data:`DEFAULT_PORT`.
    :param receive_own_messages: deliver this peer's own frames back to it
        (with ``is_rx=False``), like SocketCAN's ``recv_own_msgs``.
    :param can_filters: see :meth:`can.BusABC.set_filters` (applied in Python).

    Only classic CAN with 11-bit ids: :meth:`send` raises
    :class:`can.CanOperationError` for extended, remote, error or FD frames.

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
        #: Drop count per reason (``size``, ``len``, ``extended``, ``rtr``,
        #: ``error_frame``, ``id``, ``reserved``).
        self.drop_reasons: collections.Counter[str] = collections.Counter()
        self._rx: Optional[socket.socket] = None
        self._tx: Optional[socket.socket] = None
        try:
            rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._rx = rx
            rx.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            rx.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
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
        if msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame or msg.is_fd:
            raise can.CanOperationError(
                "sensaug_udp carries classic data frames with 11-bit ids only"
            )
        data = bytes(msg.data)
        if msg.dlc < len(data):
            data = data[: msg.dlc]
        elif msg.dlc > len(data):
            data = data.ljust(msg.dlc, b"\x00")
        try:
            datagram = pack_frame(msg.arbitration_id, data)
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
                datagram, source = rx.recvfrom(2048)
            except (socket.timeout, BlockingIOError):
                return None, False
            except OSError as err:
                raise can.CanOperationError(f"sensaug_udp: receive failed: {err}") from err
            stamp = time.time()
            own = source == self._own_addr
            if own and not self.receive_own_messages:
                continue
            frame = unpack_frame(datagram)
            if isinstance(frame, str):
                self.dropped_malformed += 1
                self.drop_reasons[frame] += 1
                continue
            arbitration_id, data = frame
            msg = Message(
                timestamp=stamp,
                arbitration_id=arbitration_id,
                is_extended_id=False,
                dlc=len(data),
                data=data,
                channel=self.port,
                is_rx=not own,
            )
            return msg, False

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
