"""The Hi5 CAN protocol, read from ``firmware_bridge/hi5.dbc`` with cantools.

The DBC is the one definition; this module adds what a DBC cannot say:

* node addressing: the DBC lists node ``ListedNode``'s ids (a global attribute,
  1); node ``n`` (0..``NodeCount``) uses ``base + n`` with the bases in
  :data:`BASE_IDS` (all derived from the DBC, so they cannot drift);
* the TorqueCommand CRC: bytes 6..8 are CRC-16/IBM-3740 (CCITT-FALSE: poly
  0x1021, init 0xFFFF, not reflected, xorout 0; check value 0x29B1 over
  ``b"123456789"``) over bytes 0..=5 followed by the data id, the frame's CAN id
  as u16 little-endian (not sent), so a command for another node fails it;
* names for the states and fault bits.

The DBC is found by :mod:`sensaug_bridge.resources`: package data in an
installed wheel, ``firmware_bridge/hi5.dbc`` itself in the checkout's editable
install. ``SENSAUG_HI5_DBC`` overrides the path.

Encoding rounds each physical value to the nearest raw step (cantools uses
Python's ``round``, ties to even) and raises :class:`ProtocolError` (a
``ValueError``) when a value is outside the signal's range; callers that want
saturation clamp first (see :func:`saturate`).
"""

from __future__ import annotations

import enum
import functools
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, ClassVar, Final, Optional, Self

import can
import cantools
import crc

from sensaug_bridge import resources

__all__ = [
    "BASE_IDS",
    "DBC_NODE",
    "DLC",
    "NODE_MAX",
    "NODE_MIN",
    "ClearFaults",
    "Decoded",
    "EmergencyStop",
    "Fault",
    "FaultFlag",
    "Feedback",
    "Heartbeat",
    "ProtocolError",
    "SetState",
    "State",
    "TorqueCommand",
    "classify",
    "crc16",
    "crc_ok",
    "torque_crc",
    "dbc_path",
    "decode",
    "frame_id",
    "load_database",
    "saturate",
]


class State(enum.IntEnum):
    """Drive state, as in the ``state`` signals."""

    BOOT = 0
    DISABLED = 1
    ENABLED = 2
    FAULT = 3


class FaultFlag(enum.IntFlag):
    """Bits of ``fault_flags`` (latched until ClearFaults)."""

    NONE = 0
    WATCHDOG = 1 << 0
    EMERGENCY_STOP = 1 << 1
    OVERSPEED = 1 << 2
    INTERNAL = 1 << 3
    #: A valid TorqueCommand out of sequence while ENABLED: a second command
    #: source on the bus, or a lost command.
    SEQUENCE = 1 << 4


#: Lowest node id.
NODE_MIN: Final = 0


class ProtocolError(ValueError):
    """A frame or value that the protocol does not allow.

    ``kind`` is one of ``"crc"``, ``"length"``, ``"range"``, ``"id"``, ``"node"``
    (``"range"``: a value outside its DBC range, or non-zero unused bits of a
    TorqueCommand).
    """

    def __init__(self, kind: str, msg: str) -> None:
        super().__init__(msg)
        self.kind = kind


def dbc_path() -> Path:
    """Where the DBC is read from: ``$SENSAUG_HI5_DBC``, else the package's
    ``hi5.dbc`` (:func:`sensaug_bridge.resources.data_file`)."""
    env = os.environ.get("SENSAUG_HI5_DBC")
    if env:
        return Path(env)
    return resources.data_file("hi5.dbc")


@functools.cache
def load_database() -> cantools.database.can.Database:
    """The parsed DBC (loaded once per process).

    Raises:
        FileNotFoundError: if the DBC is not at :func:`dbc_path` (a broken
            install, or ``SENSAUG_HI5_DBC`` naming a missing file).
    """
    path = dbc_path()
    if not path.is_file():
        raise FileNotFoundError(
            f"hi5.dbc not found at {path} (SENSAUG_HI5_DBC): point SENSAUG_HI5_DBC at the DBC "
            "or unset it to use the one installed with sensaug_bridge"
        )
    return cantools.database.load_file(str(path), strict=True)


def _global_int(name: str) -> int:
    return int(load_database().dbc.attributes[name].value)


#: The node whose ids the DBC lists (its ``ListedNode`` attribute).
DBC_NODE: Final = _global_int("ListedNode")
#: Highest node id (``NodeCount - 1``).
NODE_MAX: Final = _global_int("NodeCount") - 1
#: Base id per message name, in id order; node ``n`` uses ``base + n``.
BASE_IDS: Final[dict[str, int]] = {
    m.name: m.frame_id - DBC_NODE for m in sorted(load_database().messages, key=lambda m: m.frame_id)
}
#: Data length per message name, from the DBC.
DLC: Final[dict[str, int]] = {m.name: m.length for m in load_database().messages}

_CRC: Final = crc.Calculator(crc.Crc16.IBM_3740, optimized=True)

def _check_node(node: int) -> int:
    if not (isinstance(node, int) and NODE_MIN <= node <= NODE_MAX):
        raise ProtocolError("node", f"node: must be an int in {NODE_MIN}..={NODE_MAX}, got {node!r}")
    return node


def frame_id(name: str, node: int) -> int:
    """The 11-bit id of message ``name`` for ``node``."""
    return BASE_IDS[name] + _check_node(node)


def classify(arbitration_id: int) -> Optional[tuple[str, int]]:
    """``(message name, node)`` for a protocol id, or None for an id the protocol does not define."""
    for name, base in BASE_IDS.items():
        node = arbitration_id - base
        if NODE_MIN <= node <= NODE_MAX:
            return name, node
    return None


def crc16(data: bytes) -> int:
    """CRC-16/IBM-3740 (CCITT-FALSE) of ``data``."""
    return int(_CRC.checksum(bytes(data)))


def torque_crc(frame_id: int, data: bytes) -> int:
    """The TorqueCommand's ``crc16``: CRC-16/IBM-3740 of ``data[:6]`` then ``frame_id`` (u16 LE)."""
    return crc16(bytes(data[:6]) + (frame_id & 0xFFFF).to_bytes(2, "little"))


def crc_ok(data: bytes, frame_id: int) -> bool:
    """True when an 8-byte TorqueCommand payload sent as ``frame_id`` carries the right CRC in bytes 6..8."""
    return len(data) == 8 and torque_crc(frame_id, data) == int.from_bytes(data[6:8], "little")


def saturate(name: str, signal: str, value: float) -> float:
    """Clamp ``value`` into the DBC range of ``name.signal`` (NaN becomes 0)."""
    sig = load_database().get_message_by_name(name).get_signal_by_name(signal)
    if math.isnan(value):
        return 0.0
    lo = sig.minimum if sig.minimum is not None else -math.inf
    hi = sig.maximum if sig.maximum is not None else math.inf
    return min(max(value, lo), hi)


def _encode(name: str, node: int, signals: dict[str, Any]) -> can.Message:
    msg_def = load_database().get_message_by_name(name)
    for key, value in signals.items():
        if isinstance(value, float) and not math.isfinite(value):
            raise ProtocolError("range", f"{name}.{key}: must be finite, got {value!r}")
    try:
        data = msg_def.encode(signals, strict=True) if msg_def.signals else b""
    except (cantools.database.EncodeError, KeyError) as err:
        raise ProtocolError("range", f"{name}: {err}") from err
    return can.Message(
        arbitration_id=frame_id(name, node), is_extended_id=False, data=data, dlc=len(data)
    )


def _decode(name: str, data: bytes) -> dict[str, Any]:
    """Every signal's physical value; each must lie in its DBC range (as the Rust codec checks)."""
    msg_def = load_database().get_message_by_name(name)
    if len(data) != msg_def.length:
        raise ProtocolError(
            "length", f"{name}: expected {msg_def.length} data bytes, got {len(data)}"
        )
    if not msg_def.signals:
        return {}
    values = dict(msg_def.decode(bytes(data), decode_choices=False, scaling=True))
    for sig in msg_def.signals:
        value = values[sig.name]
        tol = abs(sig.scale) * 1e-6
        if (sig.minimum is not None and value < sig.minimum - tol) or (
            sig.maximum is not None and value > sig.maximum + tol
        ):
            raise ProtocolError(
                "range", f"{name}.{sig.name}: must be in [{sig.minimum}, {sig.maximum}], got {value}"
            )
    return values


def _raw(value: Any) -> Any:
    """A field's value as the DBC signal takes it (enums and flags as integers)."""
    return int(value) if isinstance(value, (bool, enum.Enum)) else value


class _Signals:
    """A message whose fields are its DBC signals: ``_SIGNALS`` maps each
    field to its signal and the field's type made from the decoded value."""

    __slots__ = ()
    _MESSAGE: ClassVar[str]
    _SIGNALS: ClassVar[dict[str, tuple[str, Callable[[Any], Any]]]]

    def encode(self, node: int) -> can.Message:
        signals = {signal: _raw(getattr(self, name)) for name, (signal, _) in self._SIGNALS.items()}
        return _encode(self._MESSAGE, node, signals)

    @classmethod
    def decode(cls, data: bytes) -> Self:
        s = _decode(cls._MESSAGE, data)
        return cls(**{name: kind(s[signal]) for name, (signal, kind) in cls._SIGNALS.items()})


class _NoData:
    """A command without data, named as its class."""

    __slots__ = ()

    def encode(self, node: int) -> can.Message:
        return _encode(type(self).__name__, node, {})

    @classmethod
    def decode(cls, data: bytes) -> Self:
        _decode(cls.__name__, data)
        return cls()


def _state(value: Any) -> State:
    return State(int(value))


def _fault_flags(value: Any) -> FaultFlag:
    return FaultFlag(int(value))


@dataclass(frozen=True, slots=True)
class TorqueCommand:
    """Host -> drive, every control tick. ``torque_nm`` in N m (1e-6 steps), u8 ``sequence``."""

    torque_nm: float
    sequence: int

    def encode(self, node: int) -> can.Message:
        """The frame for ``node``, CRC (with the frame id as data id) filled in."""
        msg = _encode("TorqueCommand", node, {"torque": self.torque_nm, "sequence": self.sequence, "crc16": 0})
        msg.data[6:8] = torque_crc(msg.arbitration_id, msg.data).to_bytes(2, "little")
        return msg

    @classmethod
    def decode(cls, data: bytes, frame_id: int) -> TorqueCommand:
        """Decode a payload received as ``frame_id``.

        Raises:
            ProtocolError: ``length``; ``crc`` (checked first, with ``frame_id`` as
                data id); ``range`` for non-zero unused bits or a torque outside the
                DBC range.
        """
        if len(data) != DLC["TorqueCommand"]:
            raise ProtocolError("length", f"TorqueCommand: expected 8 data bytes, got {len(data)}")
        if not crc_ok(data, frame_id):
            got = int.from_bytes(data[6:8], "little")
            raise ProtocolError(
                "crc", f"TorqueCommand.crc16: {got:#06x} != {torque_crc(frame_id, data):#06x}"
            )
        if data[5] != 0:
            raise ProtocolError("range", f"TorqueCommand.reserved: byte 5 must be 0, got {data[5]}")
        s = _decode("TorqueCommand", data)
        return cls(torque_nm=float(s["torque"]), sequence=int(s["sequence"]))


@dataclass(frozen=True, slots=True)
class Feedback(_Signals):
    """Drive -> host, one per accepted TorqueCommand, ``sequence`` echoed.

    ``position_rad`` in 1e-6 rad steps, ``velocity_rad_s`` in 1e-6 rad/s steps (int24, hi5.dbc).
    """

    position_rad: float
    velocity_rad_s: float
    sequence: int
    state: State
    torque_limited: bool
    fault_active: bool

    _MESSAGE = "Feedback"
    _SIGNALS = {
        "position_rad": ("position", float),
        "velocity_rad_s": ("velocity", float),
        "sequence": ("sequence", int),
        "state": ("state", _state),
        "torque_limited": ("torque_limited", bool),
        "fault_active": ("fault_active", bool),
    }


@dataclass(frozen=True, slots=True)
class SetState:
    """Host -> drive: ``enable`` (arms the watchdog with ``watchdog_ms``, the DBC's
    5..=200) or disable; ``sequence`` is the next TorqueCommand sequence the drive
    accepts (resync)."""

    enable: bool
    watchdog_ms: int = 100
    sequence: int = 0

    def encode(self, node: int) -> can.Message:
        return _encode(
            "SetState",
            node,
            {"request": int(self.enable), "watchdog_ms": self.watchdog_ms, "sequence": self.sequence},
        )

    @classmethod
    def decode(cls, data: bytes) -> SetState:
        """Raises :class:`ProtocolError` (``length``; ``range`` for a request other than 0/1)."""
        s = _decode("SetState", data)
        request = int(s["request"])
        if request not in (0, 1):
            raise ProtocolError("range", f"SetState.request: must be 0 or 1, got {request}")
        return cls(enable=bool(request), watchdog_ms=int(s["watchdog_ms"]), sequence=int(s["sequence"]))


@dataclass(frozen=True, slots=True)
class ClearFaults(_NoData):
    """Host -> drive: clear latched faults, FAULT -> DISABLED. No data."""


@dataclass(frozen=True, slots=True)
class EmergencyStop(_NoData):
    """Host -> drive: zero torque now, latch FAULT(EMERGENCY_STOP). No data."""


@dataclass(frozen=True, slots=True)
class Fault(_Signals):
    """Drive -> host whenever state or fault flags change; ``counter`` is a wrapping u8."""

    state: State
    fault_flags: FaultFlag
    counter: int

    _MESSAGE = "Fault"
    _SIGNALS = {"state": ("state", _state), "fault_flags": ("fault_flags", _fault_flags), "counter": ("counter", int)}


@dataclass(frozen=True, slots=True)
class Heartbeat(_Signals):
    """Drive -> host at about 10 Hz. Error counters saturate at 255; ``counter`` wraps."""

    state: State
    fault_flags: FaultFlag
    counter: int
    crc_errors: int = 0
    length_errors: int = 0
    sequence_errors: int = 0
    unknown_ids: int = 0
    range_errors: int = 0

    _MESSAGE = "Heartbeat"
    _SIGNALS = {
        **Fault._SIGNALS,
        **{counter: (counter, int) for counter in
           ("crc_errors", "length_errors", "sequence_errors", "unknown_ids", "range_errors")},
    }


_CLASSES: Final[dict[str, Any]] = {
    "EmergencyStop": EmergencyStop,
    "Fault": Fault,
    "TorqueCommand": TorqueCommand,
    "Feedback": Feedback,
    "SetState": SetState,
    "ClearFaults": ClearFaults,
    "Heartbeat": Heartbeat,
}


@dataclass(frozen=True, slots=True)
class Decoded:
    """A decoded frame: message name, node, and the message object."""

    name: str
    node: int
    message: Any


def decode(msg: can.Message) -> Decoded:
    """Decode any protocol frame.

    Raises:
        ProtocolError: ``id`` for an id the protocol does not define (or an
            extended/remote frame), ``length``/``crc``/``range`` as the message's
            ``decode`` does.
    """
    if msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame:
        raise ProtocolError("id", f"not a classic 11-bit data frame: {msg.arbitration_id:#x}")
    found = classify(msg.arbitration_id)
    if found is None:
        raise ProtocolError("id", f"unknown id {msg.arbitration_id:#05x}")
    name, node = found
    data = bytes(msg.data[: msg.dlc])
    if name == "TorqueCommand":
        return Decoded(name, node, TorqueCommand.decode(data, msg.arbitration_id))
    return Decoded(name, node, _CLASSES[name].decode(data))
