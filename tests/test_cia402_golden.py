"""The CiA 402 EDS loads in python-canopen, and the committed golden frames are
exactly python-canopen's output.

`firmware_bridge/golden/cia402_frames.json` is what the Rust master is tested
against (`firmware_bridge/tests/cia402_golden.rs`). Here it is regenerated
with python-canopen into a temporary file and compared byte for byte, so a
hand edit of the JSON, or an EDS change without regenerating, fails.

Regenerate with: python firmware_bridge/tools/make_cia402_golden.py
"""

from __future__ import annotations

import json
from pathlib import Path

import canopen
from bridge_tools import ROOT, load_tool, regenerated
from canopen import objectdictionary as odt

COMMITTED = ROOT / "firmware_bridge" / "golden" / "cia402_frames.json"
EDS = ROOT / "firmware_bridge" / "cia402_drive.eds"


def test_eds_loads_with_canopens_importer() -> None:
    od = canopen.import_od(str(EDS), node_id=5)
    assert od[0x1000].default & 0xFFFF == 402
    assert od[0x1000].default >> 16 == 0x0002  # servo drive
    # Heartbeat producer and consumer.
    assert od[0x1017].data_type == odt.UNSIGNED16 and od[0x1017].writable
    assert od[0x1016][1].data_type == odt.UNSIGNED32 and od[0x1016][1].writable
    # Controlword/statusword and the process data are PDO-mappable.
    for index in (0x6040, 0x6041, 0x6064, 0x606C, 0x6071, 0x6077, 0x2000):
        assert od[index].pdo_mappable, hex(index)
    # The SYNC counter echo: one read-only byte (docs/cia402.md, "Freshness").
    assert od[0x2000].data_type == odt.UNSIGNED8 and not od[0x2000].writable
    assert not od[0x6041].writable and od[0x6040].writable
    assert od[0x6071].data_type == odt.INTEGER16 and od[0x6064].data_type == odt.INTEGER32
    # $NODEID in the COB-IDs.
    assert od[0x1400][1].default == 0x205
    assert od[0x1800][1].default == 0x185 and od[0x1801][1].default == 0x285
    assert od[0x1014].default == 0x85
    # A LocalNode's PDO maps come out of it as documented.
    node = canopen.LocalNode(5, od)
    canopen.Network().add_node(node)  # no bus: reading maps only subscribes
    node.tpdo.read(from_od=True)
    node.rpdo.read(from_od=True)
    assert [v.name for v in node.rpdo[1]] == ["Controlword", "Target torque"]
    assert [v.name for v in node.tpdo[1]] == ["Statusword", "Position actual value", "SYNC counter echo"]
    assert [v.name for v in node.tpdo[2]] == ["Velocity actual value", "Torque actual value", "SYNC counter echo"]
    assert node.rpdo[1].trans_type == 1 and node.tpdo[1].trans_type == 1


def test_committed_golden_frames_are_canopens_output(tmp_path: Path) -> None:
    fresh, committed = regenerated("make_cia402_golden", COMMITTED, tmp_path)
    if fresh != committed:
        a = json.loads(fresh)
        b = json.loads(committed)
        diff = [(x.get("kind"), x, y) for x, y in zip(a["frames"], b["frames"]) if x != y]
        raise AssertionError(
            f"golden/cia402_frames.json differs from python-canopen's output ({len(a['frames'])} vs "
            f"{len(b['frames'])} frames, objects equal: {a['objects'] == b['objects']}, about equal: "
            f"{a['about'] == b['about']}; first differences: {diff[:3]}); "
            "run python firmware_bridge/tools/make_cia402_golden.py"
        )


def test_golden_frames_cover_every_kind() -> None:
    doc = json.loads(COMMITTED.read_text())
    kinds = {f["kind"] for f in doc["frames"]}
    assert kinds == {
        "download", "upload", "abort_download", "abort_upload", "nmt", "sync",
        "heartbeat", "rpdo1", "tpdo1", "tpdo2", "emcy", "pdo_remap",
    }
    assert {f.get("node") for f in doc["frames"] if "node" in f} == {0, 1, 42}


def test_docs_object_table_is_the_eds() -> None:
    """docs/cia402.md's object table equals what the tool renders from the EDS."""
    tool = load_tool("make_cia402_golden")
    doc = tool.DOC.read_text()
    assert tool.BEGIN in doc and tool.END in doc
    if tool.spliced_doc(doc) != doc:
        raise AssertionError(
            "docs/cia402.md's object table differs from cia402_drive.eds; "
            "run python firmware_bridge/tools/make_cia402_golden.py --docs"
        )
