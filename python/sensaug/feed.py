"""Reading the live feed of a rig run (``sensaug-rt --feed 127.0.0.1:PORT``).

The real-time binary's log writer thread sends every row of the log, batched
per writer pass (~10 ms), as UDP datagrams to each ``--feed`` address on
loopback; wire format in ``docs/live.md`` and ``crates/sensaug-rt/src/feed.rs``.
A subscriber binds its port (before or after the run starts: datagrams to a
port nobody holds are dropped) and reads :class:`Batch` es::

    with FeedReader(9870) as feed:
        for batch in feed.batches(timeout_s=5.0):
            rows = batch.rows            # numpy structured array, sensaug.logs.DTYPE
            if batch.end is not None:    # the run's end status (stop_reason, ticks, ...)
                break

The feed is best effort: a slow reader loses datagrams (counted in
:attr:`FeedReader.lost` from the sequence numbers), the sender never waits.
"""

from __future__ import annotations

import json
import socket
import struct
import time
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from sensaug.logs import DTYPE

__all__ = ["Batch", "FeedReader", "HEADER", "MAGIC", "WIRE_VERSION", "parse"]

MAGIC = b"SAFD"
WIRE_VERSION = 1
#: magic, wire version, log format version, row bytes, rows, flags, reserved, seq, start ns.
HEADER = struct.Struct("<4sHHHHHHQQ")
FLAG_END = 1
#: Receive buffer asked of the kernel: ~1 s of rows at 1 kHz.
RECV_BUFFER_BYTES = 1 << 19


@dataclass(frozen=True)
class Batch:
    """One datagram: the rows of one writer pass, or the run's end status."""

    #: Datagram number in its run, from 0 (a gap: datagrams lost).
    seq: int
    #: The run's start (ns since the Unix epoch); a new value is a new run.
    start_unix_ns: int
    #: Rows (``sensaug.logs.DTYPE``), empty in the last datagram.
    rows: np.ndarray
    #: The run's end status (the log's end line) in its last datagram, else None.
    end: dict | None

    @property
    def start_unix_s(self) -> float:
        return self.start_unix_ns * 1e-9


def parse(datagram: bytes) -> Batch:
    """One datagram as a :class:`Batch`; ``ValueError`` says what is wrong."""
    if len(datagram) < HEADER.size:
        raise ValueError(f"feed datagram: {len(datagram)} bytes, shorter than the {HEADER.size}-byte header")
    magic, version, _log_format, row_bytes, rows, flags, _reserved, seq, start = HEADER.unpack_from(datagram)
    if magic != MAGIC or version != WIRE_VERSION:
        raise ValueError(f"feed datagram: magic {magic!r} version {version}, expected {MAGIC!r} version {WIRE_VERSION}")
    if row_bytes != DTYPE.itemsize:
        raise ValueError(
            f"feed datagram: rows of {row_bytes} bytes, this sensaug reads {DTYPE.itemsize} "
            "(sensaug-rt and the Python package are from different versions)"
        )
    body = datagram[HEADER.size :]
    if flags & FLAG_END:
        end = json.loads(body.decode("utf-8")) if body else {}
        return Batch(seq, start, np.empty(0, dtype=DTYPE), end)
    if len(body) != rows * row_bytes:
        raise ValueError(f"feed datagram: {len(body)} bytes of rows, header says {rows} x {row_bytes}")
    return Batch(seq, start, np.frombuffer(body, dtype=DTYPE), None)


class FeedReader:
    """A subscriber: a UDP socket bound to ``host:port`` (loopback by default;
    port 0 picks a free one, see :attr:`port`)."""

    def __init__(self, port: int = 0, host: str = "127.0.0.1") -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECV_BUFFER_BYTES)
        try:
            self.sock.bind((host, port))
        except OSError as e:
            self.sock.close()
            raise ValueError(f"feed port {host}:{port}: cannot bind ({e}); choose another port") from None
        self.port: int = self.sock.getsockname()[1]
        #: Datagrams lost, from gaps in the sequence numbers (per run).
        self.lost = 0
        #: Datagrams that were not feed datagrams (ignored).
        self.invalid = 0
        self._run: int | None = None
        self._next_seq = 0

    @property
    def address(self) -> str:
        """What to give ``sensaug-rt --feed``."""
        return f"127.0.0.1:{self.port}"

    def recv(self, timeout_s: float | None = None) -> Batch | None:
        """The next valid datagram, or None when ``timeout_s`` passes first."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            remaining = None if deadline is None else max(0.0, deadline - time.monotonic())
            self.sock.settimeout(remaining)
            try:
                data = self.sock.recv(65536)
            except (TimeoutError, socket.timeout, BlockingIOError):  # BlockingIOError: timeout_s 0
                return None
            try:
                batch = parse(data)
            except ValueError:
                self.invalid += 1
                continue
            if batch.start_unix_ns != self._run:
                self._run, self._next_seq = batch.start_unix_ns, 0
            self.lost += max(0, batch.seq - self._next_seq)
            self._next_seq = batch.seq + 1
            return batch

    def batches(self, timeout_s: float | None = None) -> Iterator[Batch]:
        """Batches until none arrives for ``timeout_s``."""
        while (b := self.recv(timeout_s)) is not None:
            yield b

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> "FeedReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
