"""The committed Hi5 golden CAN frames are exactly cantools' output.

`firmware_bridge/golden/frames.json` is what the Rust codec is tested
against (`firmware_bridge/tests/golden.rs`). Here it is regenerated from
hi5.dbc with cantools (and the PyPI `crc` package for the TorqueCommand
CRC-8) into a temporary file and compared byte for byte, so a hand edit of
the JSON or a DBC change without regenerating fails.

Regenerate with: python firmware_bridge/tools/make_golden.py
"""

from __future__ import annotations

import json
from pathlib import Path

from bridge_tools import ROOT, load_tool, regenerated

COMMITTED = ROOT / "firmware_bridge" / "golden" / "frames.json"


def test_committed_golden_frames_are_cantools_output(tmp_path: Path) -> None:
    fresh, committed = regenerated("make_golden", COMMITTED, tmp_path)
    if fresh != committed:
        a = json.loads(fresh)["frames"]
        b = json.loads(committed)["frames"]
        diff = [(x["label"], x["data"], y["data"]) for x, y in zip(a, b) if x != y]
        raise AssertionError(
            f"golden/frames.json differs from cantools' output ({len(a)} vs {len(b)} frames; "
            f"first differences (label, cantools, committed): {diff[:5]}); "
            "run python firmware_bridge/tools/make_golden.py"
        )


def test_golden_frames_cover_every_message_and_node() -> None:
    frames = json.loads(COMMITTED.read_text())["frames"]
    assert len(frames) >= 200
    messages = {f["message"] for f in frames}
    assert messages == {
        "EmergencyStop",
        "Fault",
        "TorqueCommand",
        "Feedback",
        "SetState",
        "ClearFaults",
        "Heartbeat",
    }
    assert {f["node"] for f in frames} == set(range(16))


def test_torque_crc_is_crc16_with_the_frame_id() -> None:
    """Bytes 6..8 of every TorqueCommand are CRC-16/IBM-3740 of bytes 0..=5 followed by
    the frame id (u16 LE), checked with a bitwise reference here (poly 0x1021, init
    0xFFFF, not reflected, xorout 0)."""

    def crc16(data: bytes) -> int:
        reg = 0xFFFF
        for byte in data:
            reg ^= byte << 8
            for _ in range(8):
                reg = ((reg << 1) ^ 0x1021) & 0xFFFF if reg & 0x8000 else (reg << 1) & 0xFFFF
        return reg

    assert crc16(b"123456789") == 0x29B1
    frames = json.loads(COMMITTED.read_text())["frames"]
    checked = 0
    for f in frames:
        if f["message"] == "TorqueCommand":
            data = bytes.fromhex(f["data"])
            assert data[5] == 0, f["label"]
            assert int.from_bytes(data[6:8], "little") == crc16(data[:6] + f["id"].to_bytes(2, "little")), f["label"]
            checked += 1
    assert checked >= 50


def test_protocol_doc_tables_are_generated_from_the_dbc() -> None:
    """docs/can_protocol.md's frame tables equal what make_doc_tables.py makes
    from hi5.dbc with cantools (so the docs cannot drift from the DBC)."""
    module = load_tool("make_doc_tables")
    doc_path = ROOT / "docs" / "can_protocol.md"
    doc = doc_path.read_text()
    import cantools

    generated = module.tables(cantools.database.load_file(str(ROOT / "firmware_bridge" / "hi5.dbc"), strict=True))
    # The tables carry every message and signal of the DBC.
    for name in ("TorqueCommand", "Feedback", "Heartbeat", "SetState", "Fault"):
        assert f"**{name}** (DLC" in generated
    assert "| position | int24 | 1e-06 |" in generated
    fresh = module.render(doc, generated)
    assert fresh == doc, (
        "docs/can_protocol.md's frame tables differ from hi5.dbc; "
        "run python firmware_bridge/tools/make_doc_tables.py"
    )


def test_python_state_and_fault_names_are_the_dbcs() -> None:
    """protocol.State is every `state` signal's VAL_ table and protocol.FaultFlag
    the `fault_flags` comment's `bitN NAME` list (the Rust side generates both)."""
    from sensaug_bridge import protocol as p

    db = p.load_database()
    states = {name: int(v) for name, v in p.State.__members__.items()}
    faults = {name: int(v) for name, v in p.FaultFlag.__members__.items() if v}
    seen = 0
    for msg in db.messages:
        for sig in msg.signals:
            if sig.name == "state":
                assert {str(v): int(k) for k, v in sig.choices.items()} == states, msg.name
                seen += 1
            if sig.name == "fault_flags":
                parsed = {}
                for item in sig.comment.split(","):
                    bit, name = item.split()
                    parsed[name] = 1 << int(bit.removeprefix("bit"))
                assert parsed == faults, msg.name
                seen += 1
    assert seen == 5
    assert p.DBC_NODE == 1 and p.NODE_MAX == 15
    assert list(p.BASE_IDS) == [m.name for m in sorted(db.messages, key=lambda m: m.frame_id)]
