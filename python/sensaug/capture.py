"""The rig's bus traffic: a built-in capture, and reading it back against
the controller's log (``docs/virtual_hi5.md``, "Bus capture").

:class:`BusCapture` records every frame on a ``sensaug_udp`` port into a
file python-can and can-utils read: candump's ``-l`` log format
(``bus.log``, python-can's ``CanutilsLogWriter``) or any other format
python-can writes, chosen by the suffix (``.blf``, ``.asc``, ...). It runs
in a thread of the Python launcher, never in the real-time process: its
socket is bound before the drive boots (the kernel queues every frame from
then on, even before the thread reads it), and :meth:`BusCapture.stop`,
called once both processes have exited, drains the socket before closing
the file, so the run's last frames are kept.

Reading back: :func:`read_candump` parses a candump ``-l`` log itself
(error frames keep their class bits, which python-can's reader drops);
:meth:`Frame.from_message` takes python-can's messages (``can.LogReader``).
:func:`decode_all` decodes frames with cantools against the DBC;
:func:`match_commands`, :func:`subsequence` and :func:`match_feedback` put
the controller's logged commands and feedback beside the frames on the bus.
``scripts/vcan/check.py`` (the SocketCAN VM run) and ``tests/test_capture.py``
(the loopback rig) use the same functions.
"""

from __future__ import annotations

import re
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

__all__ = [
    "BusCapture",
    "CaptureStats",
    "Decoded",
    "Frame",
    "decode_all",
    "match_commands",
    "match_feedback",
    "read_candump",
    "subsequence",
]

CAN_EFF_FLAG, CAN_RTR_FLAG, CAN_ERR_FLAG = 0x80000000, 0x40000000, 0x20000000
CAN_EFF_MASK = 0x1FFFFFFF

#: How long the drain waits for one more frame once both processes exited.
DRAIN_QUIET_S = 0.1


# -- recording --------------------------------------------------------------------------


@dataclass(frozen=True)
class CaptureStats:
    """What a capture recorded, and what the receive path lost (both should be 0)."""

    path: Path
    frames: int
    dropped_kernel: int
    dropped_malformed: int
    error: Optional[str]
    #: CPU time the capture thread used, s (``time.thread_time``).
    cpu_s: float = 0.0


class BusCapture:
    """Every frame on the loopback bus at ``port`` into ``path`` (format by suffix).

    The socket is bound in the constructor: frames sent from then on are
    queued by the kernel. :meth:`start` begins writing them in a daemon
    thread; :meth:`stop` drains the socket (until it has been quiet for
    :data:`DRAIN_QUIET_S`), closes the file and the bus. A write failure
    ends the thread and is reported by :meth:`stop`, never raised into the
    run.

    Raises:
        ValueError: ``path``'s suffix is no format python-can writes.
        ConfigError: ``path`` is not a regular file or a new one (a FIFO, a
            device, a folder, a link: ``docs/safety.md``, "Output paths");
            checked before anything is opened, so a FIFO never blocks it.
        can.CanInitializationError: the bus cannot be opened.
    """

    def __init__(self, port: int, path: str | Path) -> None:
        import can

        from sensaug import _core

        self.path = Path(path)
        _core.check_output_paths([("capture", str(self.path))])
        self._bus = can.Bus(interface="sensaug_udp", channel=port)
        try:
            self._writer = can.Logger(self.path)
        except ValueError as err:
            self._bus.shutdown()
            raise ValueError(f"capture: {self.path.name!r}: {err}; use .log (candump -l) or .blf") from None
        except Exception:
            self._bus.shutdown()
            raise
        self._stop = threading.Event()
        self._frames = 0
        self._error: Optional[str] = None
        self._cpu_s = 0.0
        self._thread = threading.Thread(target=self._run, name=f"sensaug-capture-{port}", daemon=True)

    def start(self) -> "BusCapture":
        self._thread.start()
        return self

    def _run(self) -> None:
        bus, writer = self._bus, self._writer
        try:
            while True:
                msg = bus.recv(timeout=DRAIN_QUIET_S)
                if msg is not None:
                    writer.on_message_received(msg)
                    self._frames += 1
                elif self._stop.is_set():
                    # Quiet for DRAIN_QUIET_S after stop(): everything the
                    # (exited) processes sent has been read.
                    return
        except Exception as err:  # noqa: BLE001 - reported by stop(), the run goes on
            self._error = f"{type(err).__name__}: {err}"
        finally:
            self._cpu_s = time.thread_time()

    def stop(self) -> CaptureStats:
        """Drain, close, and report. Call after both processes have exited."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        try:
            self._writer.stop()
        except Exception as err:  # noqa: BLE001
            self._error = self._error or f"{type(err).__name__}: {err}"
        stats = CaptureStats(
            path=self.path,
            frames=self._frames,
            dropped_kernel=int(getattr(self._bus, "dropped_kernel", 0)),
            dropped_malformed=int(getattr(self._bus, "dropped_malformed", 0)),
            error=self._error,
            cpu_s=self._cpu_s,
        )
        self._bus.shutdown()
        return stats


# -- reading back -----------------------------------------------------------------------


@dataclass(frozen=True)
class Frame:
    """One captured classic or FD CAN frame."""

    t: float
    can_id: int  # without flag bits
    eff: bool
    rtr: bool
    err: bool
    fd: bool
    data: bytes

    @classmethod
    def from_message(cls, msg: Any) -> "Frame":
        """From a python-can ``Message`` (e.g. from ``can.LogReader``)."""
        return cls(
            t=float(msg.timestamp),
            can_id=int(msg.arbitration_id) & CAN_EFF_MASK,
            eff=bool(msg.is_extended_id) and not msg.is_error_frame,
            rtr=bool(msg.is_remote_frame),
            err=bool(msg.is_error_frame),
            fd=bool(msg.is_fd),
            data=b"" if msg.is_remote_frame else bytes(msg.data),
        )


# ``(t) iface ID#DATA``, ``ID#R[len]``, ``ID##F DATA`` (FD), with python-can's
# optional direction `` R``/`` T`` at the end.
_LINE = re.compile(r"^\((?P<t>[0-9.]+)\)\s+\S+\s+(?P<id>[0-9A-Fa-f]+)#(?P<rest>\S*)(?:\s+[RT])?$")


def read_candump(path: Path) -> list[Frame]:
    """Parse candump's log format (``candump -l``, python-can's ``.log``)."""
    frames = []
    for line in Path(path).read_text().splitlines():
        if not line.strip():
            continue
        m = _LINE.match(line.strip())
        if m is None:
            raise ValueError(f"{path}: not a candump log line: {line!r}")
        raw_id = int(m["id"], 16)
        rest = m["rest"]
        eight = len(m["id"]) == 8
        err = eight and bool(raw_id & CAN_ERR_FLAG)
        eff = eight and not err
        fd = rest.startswith("#")
        rtr = rest.startswith("R")
        if fd:
            data = bytes.fromhex(rest[2:])  # one flags nibble, then the data
        elif rtr:
            data = b""
        else:
            data = bytes.fromhex(rest)
        frames.append(Frame(float(m["t"]), raw_id & CAN_EFF_MASK, eff, rtr, err, fd, data))
    return frames


@dataclass
class Decoded:
    """A frame decoded against the DBC; ``index`` is its position in the capture."""

    frame: Frame
    name: str
    sender: str
    signals: dict[str, Any]
    index: int = -1


def decode_all(frames: list[Frame], db: Any, node: int) -> tuple[list[Decoded], dict[str, int]]:
    """Every classic data frame with a DBC id decoded by cantools; counts of the rest.

    The DBC's ids are node 1's; node ``n`` uses ``id + n - 1``.
    """
    out: list[Decoded] = []
    counts = {"error": 0, "eff": 0, "fd": 0, "rtr": 0, "unknown_id": 0, "undecodable": 0}
    for i, f in enumerate(frames):
        if f.err:
            counts["error"] += 1
        elif f.fd:
            counts["fd"] += 1
        elif f.eff:
            counts["eff"] += 1
        elif f.rtr:
            counts["rtr"] += 1
        else:
            try:
                msg = db.get_message_by_frame_id(f.can_id - node + 1)
            except KeyError:
                counts["unknown_id"] += 1
                continue
            try:
                signals = msg.decode(f.data, decode_choices=False) if msg.length else {}
                if len(f.data) != msg.length:
                    raise ValueError("length")
            except Exception:  # noqa: BLE001 - cantools raises several types; all mean "not this message"
                counts["undecodable"] += 1
                continue
            out.append(Decoded(f, msg.name, msg.senders[0], signals, i))
    return out, counts


def match_commands(torque: list[Decoded], log: Any, scale: float) -> list[int]:
    """In bus order, the index of the frame carrying each tick's command
    (sequence ``k mod 256``, torque equal to the log's within half a raw step);
    stops at the first tick with no such frame. Other frames (set-up,
    shut-down, fuzz) are skipped."""
    found: list[int] = []
    j = 0
    for k, t_nm in zip(log["tick"].astype(int), log["torque_nm"]):
        while j < len(torque):
            s = torque[j].signals
            if s["sequence"] == k % 256 and abs(s["torque"] - t_nm) <= 0.5 * scale + 1e-12:
                break
            j += 1
        if j == len(torque):
            break
        found.append(j)
        j += 1
    return found


def subsequence(commands: list[Decoded], seq: list[int], torque: np.ndarray, tol: float) -> Optional[list[int]]:
    """Indices of ``commands`` (in order) carrying these sequences and torques; None if they are not there."""
    out: list[int] = []
    j = 0
    for sq, t in zip(seq, torque):
        while j < len(commands) and not (commands[j].signals["sequence"] == sq and abs(commands[j].signals["torque"] - t) <= tol):
            j += 1
        if j == len(commands):
            return None
        out.append(j)
        j += 1
    return out


def match_feedback(commands: list[Decoded], matched: list[int], feedback: list[Decoded]) -> list[Optional[int]]:
    """For each tick's command (``commands[matched[k]]``), the index in
    ``feedback`` of the Feedback answering it: the first one echoing its
    sequence after the previous tick's command on the bus, before the next
    command on the bus reuses that sequence; None when there is none.

    From the previous command, not from this one: the capture is one more
    receiver of the bus and can queue the drive's answer before the command
    it answers (seen on the loopback UDP bus in a full test run:
    ``Feedback(1)`` captured before ``TorqueCommand(1)``; presumably the
    drive, woken by the command's datagram, answered while the kernel was
    still handing that datagram to the other sockets)."""
    # The bus index of the next command with each command's sequence: the
    # bus's own, not the log's tick k + 256, which a run's last 256 ticks
    # lack while the bus still has the unrecorded last tick's command (an
    # answer missing there must not take a later command's answer).
    reused: list[Optional[int]] = [None] * len(commands)
    seen: dict[int, int] = {}
    for pos in range(len(commands) - 1, -1, -1):
        seq = commands[pos].signals["sequence"]
        reused[pos] = seen.get(seq)
        seen[seq] = commands[pos].index
    out: list[Optional[int]] = []
    j = 0
    for k, ci in enumerate(matched):
        seq = commands[ci].signals["sequence"]
        bound = reused[ci]
        start = commands[matched[k - 1]].index if k > 0 else -1
        while j < len(feedback) and feedback[j].index < start:
            j += 1
        i = j
        while i < len(feedback) and (bound is None or feedback[i].index < bound) and feedback[i].signals["sequence"] != seq:
            i += 1
        if i < len(feedback) and (bound is None or feedback[i].index < bound):
            out.append(i)
            j = i + 1
        else:
            out.append(None)
    return out
