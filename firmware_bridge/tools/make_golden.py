"""Golden CAN frames for the Hi5 protocol, encoded by cantools from hi5.dbc.

The Rust crate (`tests/golden.rs`) encodes and decodes every entry and must
agree byte for byte; `tests/test_bridge_golden.py` re-runs this script and
checks that the committed `golden/frames.json` is exactly its output.

The list of messages is fixed and deterministic (hand-picked extremes,
negative values and rounding ties, plus a seeded `random.Random`). The DBC
gives node 1's ids; node n uses `frame_id - 1 + n`. The TorqueCommand's
`crc16` is CRC-16/IBM-3740 over bytes 0..=5 followed by the data id (the
frame's CAN id, u16 little-endian), computed with the PyPI `crc` package (an
implementation independent of the Rust `crc` crate).

Usage: python make_golden.py [OUT.json]   (default: ../golden/frames.json)
"""

from __future__ import annotations

import random
import sys
from pathlib import Path
from typing import Any

import cantools
from crc import Calculator, Crc16

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import golden_file  # noqa: E402  (beside this script)

DBC_PATH = HERE.parent / "hi5.dbc"
DEFAULT_OUT = HERE.parent / "golden" / "frames.json"

CRC16 = Calculator(Crc16.IBM_3740)  # CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, xorout 0



def _range(message: str, signal: str) -> tuple[float, float]:
    """A signal's ``[min|max]``, read from the DBC (never copied here)."""
    sig = cantools.database.load_file(str(DBC_PATH)).get_message_by_name(message).get_signal_by_name(signal)
    return float(sig.minimum), float(sig.maximum)


TORQUE_MIN, TORQUE_MAX = _range("TorqueCommand", "torque")
POSITION_MIN, POSITION_MAX = _range("Feedback", "position")
VELOCITY_MIN, VELOCITY_MAX = _range("Feedback", "velocity")
SEED = 20240611

Case = tuple[str, str, int, dict[str, Any]]  # (label, message, node, physical signals)


def cases() -> list[Case]:
    """The fixed list of messages to encode."""
    rng = random.Random(SEED)
    out: list[Case] = []

    # TorqueCommand: extremes, signs, 1 LSB, rounding ties (ties-to-even:
    # 0.5e-6 N m -> 0, 1.5e-6 -> 2, 2.5e-6 -> 2), off-grid values.
    torques = [
        ("zero", 0.0),
        ("+1lsb", 1e-6),
        ("-1lsb", -1e-6),
        ("max", TORQUE_MAX),
        ("min", TORQUE_MIN),
        ("+1", 1.0),
        ("-1", -1.0),
        ("tie 0.5lsb", 0.5e-6),
        ("tie -0.5lsb", -0.5e-6),
        ("tie 1.5lsb", 1.5e-6),
        ("tie 2.5lsb", 2.5e-6),
        ("tie -1.5lsb", -1.5e-6),
        ("round down", 1.2345674),
        ("round up", 1.2345676),
        ("neg round", -2.3456789),
        ("0.4lsb", 0.4e-6),
        ("-0.6lsb", -0.6e-6),
        ("typical", 0.8),
        ("typical neg", -2.75),
        ("big", 9.5),
    ]
    for i, (label, t) in enumerate(torques):
        out.append((f"torque {label}", "TorqueCommand", 1, {"torque": t, "sequence": i * 13 % 256}))
    for seq in (0, 1, 127, 128, 254, 255):
        out.append((f"torque seq {seq}", "TorqueCommand", 1, {"torque": 0.25, "sequence": seq}))
    for node in range(16):
        out.append((f"torque node {node}", "TorqueCommand", node, {"torque": -0.5, "sequence": node}))
    for k in range(40):
        t = rng.uniform(TORQUE_MIN, TORQUE_MAX) if k % 2 else rng.uniform(-3.0, 3.0)
        out.append(
            (f"torque random {k}", "TorqueCommand", rng.randrange(16), {"torque": t, "sequence": rng.randrange(256)})
        )

    # Feedback.
    fb_fixed = [
        ("zero", 0.0, 0.0),
        ("max", POSITION_MAX, VELOCITY_MAX),
        ("min", POSITION_MIN, VELOCITY_MIN),
        ("mixed", POSITION_MAX, VELOCITY_MIN),
        ("1lsb", 1e-6, 1e-6),
        ("-1lsb", -1e-6, -1e-6),
        ("tie 0.5lsb", 0.5e-6, 0.5e-6),
        ("tie -0.5lsb", -0.5e-6, -0.5e-6),
        ("tie 1.5lsb", 1.5e-6, 1.5e-6),
        ("tie 2.5lsb", 2.5e-6, 2.5e-6),
        ("pi", 3.141592653589793, -3.141592653589793),
        ("round", 1.23456789, 4.56789012),
    ]
    for i, (label, pos, vel) in enumerate(fb_fixed):
        out.append(
            (
                f"feedback {label}",
                "Feedback",
                1,
                {
                    "position": pos,
                    "velocity": vel,
                    "sequence": i * 29 % 256,
                    "state": i % 4,
                    "torque_limited": i % 2,
                    "fault_active": (i // 2) % 2,
                },
            )
        )
    for state in range(4):
        for limited in (0, 1):
            for fault in (0, 1):
                out.append(
                    (
                        f"feedback state {state} limited {limited} fault {fault}",
                        "Feedback",
                        state + 4 * limited + 8 * fault,
                        {
                            "position": -1.0,
                            "velocity": 2.0,
                            "sequence": 255,
                            "state": state,
                            "torque_limited": limited,
                            "fault_active": fault,
                        },
                    )
                )
    for k in range(40):
        out.append(
            (
                f"feedback random {k}",
                "Feedback",
                rng.randrange(16),
                {
                    "position": rng.uniform(POSITION_MIN, POSITION_MAX),
                    "velocity": rng.uniform(VELOCITY_MIN, VELOCITY_MAX),
                    "sequence": rng.randrange(256),
                    "state": rng.randrange(4),
                    "torque_limited": rng.randrange(2),
                    "fault_active": rng.randrange(2),
                },
            )
        )

    # Heartbeat and Fault: states, every named flag, reserved bits, counters.
    flag_sets = [0, 1, 2, 4, 8, 16, 0b11111, 0b0011, 0x80, 0xFF, 0x34]
    for i, flags in enumerate(flag_sets):
        state = i % 4
        out.append(
            (
                f"heartbeat flags {flags:#06x}",
                "Heartbeat",
                i,
                {
                    "state": state,
                    "fault_flags": flags,
                    "counter": (i * 37) % 256,
                    "crc_errors": i,
                    "length_errors": 255 - i,
                    "sequence_errors": (i * 7) % 256,
                    "unknown_ids": 255 if i % 2 else 0,
                    "range_errors": (i * 13) % 256,
                },
            )
        )
        out.append(
            (
                f"fault flags {flags:#06x}",
                "Fault",
                15 - i,
                {"state": state, "fault_flags": flags, "counter": (i * 91) % 256},
            )
        )
    out.append(
        (
            "heartbeat saturated",
            "Heartbeat",
            15,
            {
                "state": 3,
                "fault_flags": 0xFF,
                "counter": 255,
                "crc_errors": 255,
                "length_errors": 255,
                "sequence_errors": 255,
                "unknown_ids": 255,
                "range_errors": 255,
            },
        )
    )
    for k in range(20):
        out.append(
            (
                f"heartbeat random {k}",
                "Heartbeat",
                rng.randrange(16),
                {
                    "state": rng.randrange(4),
                    "fault_flags": rng.randrange(256),
                    "counter": rng.randrange(256),
                    "crc_errors": rng.randrange(256),
                    "length_errors": rng.randrange(256),
                    "sequence_errors": rng.randrange(256),
                    "unknown_ids": rng.randrange(256),
                    "range_errors": rng.randrange(256),
                },
            )
        )
        out.append(
            (
                f"fault random {k}",
                "Fault",
                rng.randrange(16),
                {"state": rng.randrange(4), "fault_flags": rng.randrange(256), "counter": rng.randrange(256)},
            )
        )

    # SetState: both requests, watchdog extremes, resync sequences.
    for request in (0, 1):
        for i, wd in enumerate((5, 6, 10, 20, 50, 100, 199, 200)):
            seq = (0, 1, 127, 128, 254, 255, 37, 200)[i]
            out.append(
                (
                    f"setstate {request} {wd} ms seq {seq}",
                    "SetState",
                    wd % 16,
                    {"request": request, "watchdog_ms": wd, "sequence": seq},
                )
            )

    # Zero-length frames on every node.
    for node in range(16):
        out.append((f"estop node {node}", "EmergencyStop", node, {}))
        out.append((f"clear node {node}", "ClearFaults", node, {}))
    return out


def encode_case(db: cantools.database.can.Database, case: Case) -> dict[str, Any]:
    """One golden entry: cantools' bytes, its decode, and the frame id."""
    label, name, node, signals = case
    msg = db.get_message_by_name(name)
    signals = dict(signals)
    frame_id = msg.frame_id - 1 + node
    if name == "TorqueCommand":
        body = msg.encode({**signals, "crc16": 0}, strict=True)
        assert body[5] == 0, label
        signals["crc16"] = CRC16.checksum(body[:6] + frame_id.to_bytes(2, "little"))
    data = msg.encode(signals, strict=True)
    assert len(data) == msg.length, label
    decoded = msg.decode(data, decode_choices=False, scaling=True)
    return {
        "label": label,
        "message": name,
        "node": node,
        "signals": signals,
        "decoded": {k: decoded[k] for k in signals},
        "id": frame_id,
        "data": data.hex(),
    }


def build() -> dict[str, Any]:
    """The whole golden file as a JSON-ready dict."""
    db = cantools.database.load_file(str(DBC_PATH))
    # Self-check of the CRC definition: the catalogue check value.
    assert CRC16.checksum(b"123456789") == 0x29B1
    return {
        "about": "Hi5 CAN golden frames, encoded by cantools from hi5.dbc by firmware_bridge/tools/make_golden.py; "
        "id = DBC id - 1 + node; data is hex; signals are the physical inputs, decoded is cantools' decode",
        "frames": [encode_case(db, c) for c in cases()],
    }


def render() -> str:
    """The exact text written to frames.json."""
    return golden_file.render(build())


def main(argv: list[str]) -> int:
    return golden_file.write(argv, DEFAULT_OUT, render())


if __name__ == "__main__":
    sys.exit(main(sys.argv))
