"""Golden CANopen frames for the CiA 402 profile, produced by python-canopen.

python-canopen is the independent oracle for the Rust master
(`firmware_bridge/src/cia402`): its SDO client talks to its SDO server (a
`LocalNode` built from `cia402_drive.eds`), its NMT master sends commands, its
SYNC producer syncs, PDO maps read from the EDS encode RPDO/TPDO payloads, the
EMCY producer and the NMT slave's heartbeat produce their frames. Every frame
is captured in order on an in-process network (no bus, no threads, no
timing), so the output is deterministic.

`tests/cia402_golden.rs` requires the Rust master to produce the same bytes
(requests, PDOs, NMT, SYNC, heartbeats) and to decode canopen's bytes
(responses, TPDOs, EMCY, heartbeats) to canopen's values;
`tests/test_cia402_golden.py` re-runs this script and requires the committed
file to be its exact output.

Usage: python make_cia402_golden.py [OUT.json]   (default: ../golden/cia402_frames.json)
"""

from __future__ import annotations

import json
import random
import sys
from pathlib import Path
from typing import Any

import canopen
from canopen import objectdictionary as odt
from canopen.sdo import SdoAbortedError

HERE = Path(__file__).resolve().parent
EDS_PATH = HERE.parent / "cia402_drive.eds"
DEFAULT_OUT = HERE.parent / "golden" / "cia402_frames.json"

NODES = (1, 42)
MASTER_NODE = 127

#: The objects the Rust master names (src/cia402/od.rs); their EDS entries go
#: into the golden file so the Rust constants are checked against the EDS.
OBJECTS = [
    (0x1000, 0), (0x1016, 1), (0x1017, 0),
    (0x1400, 1), (0x1400, 2), (0x1800, 1), (0x1800, 2), (0x1801, 1), (0x1801, 2),
    (0x1600, 0), (0x1600, 1), (0x1600, 2),
    (0x1A00, 0), (0x1A00, 1), (0x1A00, 2),
    (0x1A01, 0), (0x1A01, 1), (0x1A01, 2),
    (0x6040, 0), (0x6041, 0), (0x6060, 0), (0x6061, 0), (0x6064, 0), (0x606C, 0),
    (0x6071, 0), (0x6072, 0), (0x6076, 0), (0x6077, 0),
    (0x608F, 1), (0x608F, 2), (0x6091, 1), (0x6091, 2),
]

TYPE_NAMES = {
    odt.INTEGER8: "INTEGER8", odt.INTEGER16: "INTEGER16", odt.INTEGER32: "INTEGER32",
    odt.UNSIGNED8: "UNSIGNED8", odt.UNSIGNED16: "UNSIGNED16", odt.UNSIGNED32: "UNSIGNED32",
}


class CaptureNetwork(canopen.Network):
    """A canopen network without a bus: every frame sent is recorded and
    delivered synchronously to the subscribers (so an SDO request's response
    is queued before the client waits for it)."""

    def __init__(self) -> None:
        super().__init__(bus=None)
        self.frames: list[tuple[int, bytes]] = []

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        assert not remote
        payload = bytes(data)
        self.frames.append((can_id, payload))
        self.notify(can_id, bytearray(payload), 0.0)

    def send_periodic(self, can_id: int, data: bytes, period: float, remote: bool = False) -> Any:
        # The heartbeat producer: record its first frame only.
        self.send_message(can_id, bytes(data), remote)
        return _NoTask()

    def take(self, *only: int) -> list[tuple[int, bytes]]:
        """The frames sent since the last take (only those with these ids, if given)."""
        out, self.frames = self.frames, []
        return [f for f in out if not only or f[0] in only]


class _NoTask:
    def stop(self) -> None:
        pass

    def update(self, data: bytes) -> None:
        pass


def _frame(can_id: int, data: bytes) -> dict[str, Any]:
    return {"id": can_id, "data": data.hex()}


def objects() -> list[dict[str, Any]]:
    od = canopen.import_od(str(EDS_PATH), node_id=1)
    out = []
    for index, sub in OBJECTS:
        var = od.get_variable(index, sub)
        assert var is not None, (hex(index), sub)
        out.append(
            {
                "index": index,
                "subindex": sub,
                "name": var.name,
                "data_type": TYPE_NAMES[var.data_type],
                "bits": len(var),
                "access": var.access_type,
                "pdo_mappable": bool(var.pdo_mappable),
                "default": var.default,
            }
        )
    return out


def _sdo_variable(node: canopen.RemoteNode, index: int, sub: int) -> Any:
    if isinstance(node.object_dictionary[index], odt.ODVariable):
        return node.sdo[index]
    return node.sdo[index][sub]


def sdo_cases(node_id: int) -> list[dict[str, Any]]:
    """canopen's SDO client against its SDO server: writes, reads, aborts."""
    net = CaptureNetwork()
    drive = canopen.LocalNode(node_id, canopen.import_od(str(EDS_PATH), node_id))
    master = canopen.RemoteNode(node_id, canopen.import_od(str(EDS_PATH), node_id))
    net.add_node(drive)
    master.associate_network(net)
    cases: list[dict[str, Any]] = []

    writes = [
        (0x6060, 0, 10),
        (0x1017, 0, 100),
        (0x1017, 0, 7),
        (0x1016, 1, (MASTER_NODE << 16) | 100),
        (0x1016, 1, 0),
        (0x6072, 0, 2500),
        (0x6040, 0, 0x000F),
        (0x6071, 0, -1234),
    ]
    for index, sub, value in writes:
        var = _sdo_variable(master, index, sub)
        var.raw = value
        (req, resp) = net.take(0x600 + node_id, 0x580 + node_id)
        cases.append(
            {"kind": "download", "index": index, "subindex": sub, "value": value,
             "data_type": TYPE_NAMES[var.od.data_type], "request": _frame(*req), "response": _frame(*resp)}
        )
    # The last writes set 0x6072 to 2500; reads below see the stored values.
    reads = [(0x1000, 0), (0x6060, 0), (0x6076, 0), (0x6072, 0), (0x608F, 1), (0x608F, 2),
             (0x6091, 1), (0x6091, 2), (0x1400, 1), (0x1400, 2), (0x1800, 1), (0x1801, 1),
             (0x1600, 0), (0x1600, 1), (0x1600, 2), (0x1A00, 1), (0x1A01, 2), (0x1017, 0),
             (0x1016, 1), (0x6071, 0), (0x1018, 1)]
    for index, sub in reads:
        var = _sdo_variable(master, index, sub)
        value = var.raw
        (req, resp) = net.take(0x600 + node_id, 0x580 + node_id)
        cases.append(
            {"kind": "upload", "index": index, "subindex": sub, "value": value,
             "data_type": TYPE_NAMES[var.od.data_type], "request": _frame(*req), "response": _frame(*resp)}
        )
    aborts = [
        ("download", 0x6041, 0, b"\x00\x00"),  # read-only
        ("download", 0x1000, 0, b"\x00\x00\x00\x00"),  # read-only
        ("upload", 0x2000, 0, b""),  # no such object
        ("upload", 0x608F, 3, b""),  # no such sub-index
        ("download", 0x6060, 0, b"\x0a\x00"),  # wrong length for INTEGER8
    ]
    for kind, index, sub, data in aborts:
        try:
            if kind == "download":
                master.sdo.download(index, sub, data)
            else:
                master.sdo.upload(index, sub)
        except SdoAbortedError as err:
            code = err.code
        else:
            raise AssertionError(f"no abort for {kind} {index:#x}:{sub}")
        (req, resp) = net.take(0x600 + node_id, 0x580 + node_id)
        cases.append(
            {"kind": "abort_" + kind, "index": index, "subindex": sub, "code": code,
             "request": _frame(*req), "response": _frame(*resp)}
        )
    return cases


def nmt_sync_heartbeat_cases(node_id: int) -> list[dict[str, Any]]:
    net = CaptureNetwork()
    master = canopen.RemoteNode(node_id, canopen.import_od(str(EDS_PATH), node_id))
    master.associate_network(net)
    cases: list[dict[str, Any]] = []
    for state, command in [("OPERATIONAL", 0x01), ("STOPPED", 0x02), ("PRE-OPERATIONAL", 0x80),
                           ("RESET", 0x81), ("RESET COMMUNICATION", 0x82)]:
        master.nmt.state = state
        (f,) = net.take()
        cases.append({"kind": "nmt", "command": command, "node": node_id, "frame": _frame(*f)})
    net.nmt.send_command(0x01)  # broadcast start (node 0)
    (f,) = net.take()
    cases.append({"kind": "nmt", "command": 0x01, "node": 0, "frame": _frame(*f)})
    net.sync.transmit()
    (f,) = net.take()
    cases.append({"kind": "sync", "frame": _frame(*f)})
    # Heartbeats: a LocalNode's NMT slave (boot-up, then its periodic beat).
    slave = canopen.LocalNode(node_id, canopen.import_od(str(EDS_PATH), node_id))
    net.add_node(slave)
    slave.nmt.state = "INITIALISING"
    (f,) = net.take()
    cases.append({"kind": "heartbeat", "node": node_id, "state": 0x00, "frame": _frame(*f)})
    for state, value in [("PRE-OPERATIONAL", 0x7F), ("OPERATIONAL", 0x05), ("STOPPED", 0x04)]:
        slave.nmt.state = state
        net.take()
        slave.nmt.start_heartbeat(10)
        (f,) = net.take()
        cases.append({"kind": "heartbeat", "node": node_id, "state": value, "frame": _frame(*f)})
    return cases


def pdo_cases(node_id: int, rng: random.Random) -> list[dict[str, Any]]:
    """PDO payloads from maps read out of the EDS (canopen's PdoVariable encoding)."""
    net = CaptureNetwork()
    drive = canopen.LocalNode(node_id, canopen.import_od(str(EDS_PATH), node_id))
    master = canopen.RemoteNode(node_id, canopen.import_od(str(EDS_PATH), node_id))
    net.add_node(drive)
    master.associate_network(net)
    master.rpdo.read(from_od=True)
    drive.tpdo.read(from_od=True)
    cases: list[dict[str, Any]] = []

    rpdo = master.rpdo[1]
    rpdo_values = [(0x0006, 0), (0x0007, 0), (0x000F, 0), (0x000F, 123), (0x000F, -3000),
                   (0x000F, 32767), (0x000F, -32768), (0x0002, 0), (0x0080, 0), (0x0000, 0)]
    rpdo_values += [(rng.choice([0x06, 0x07, 0x0F]), rng.randint(-32768, 32767)) for _ in range(10)]
    for cw, torque in rpdo_values:
        rpdo["Controlword"].raw = cw
        rpdo["Target torque"].raw = torque
        rpdo.transmit()
        (f,) = net.take()
        cases.append({"kind": "rpdo1", "node": node_id, "controlword": cw, "target_torque": torque,
                      "frame": _frame(*f)})

    tpdo1, tpdo2 = drive.tpdo[1], drive.tpdo[2]
    t1_values = [(0x0240, 0), (0x0231, 1), (0x0233, -1), (0x0237, 2**31 - 1), (0x0A37, -(2**31)),
                 (0x0217, 1048576), (0x0208, -524288), (0x021F, 12345)]
    t1_values += [(rng.choice([0x0237, 0x0A37, 0x0208]), rng.randint(-(2**31), 2**31 - 1)) for _ in range(8)]
    for sw, pos in t1_values:
        tpdo1["Statusword"].raw = sw
        tpdo1["Position actual value"].raw = pos
        tpdo1.transmit()
        (f,) = net.take()
        cases.append({"kind": "tpdo1", "node": node_id, "statusword": sw, "position": pos, "frame": _frame(*f)})
    t2_values = [(0, 0), (1, -1), (-(2**31), 32767), (2**31 - 1, -32768), (1398101, 3000)]
    t2_values += [(rng.randint(-(2**31), 2**31 - 1), rng.randint(-32768, 32767)) for _ in range(8)]
    for vel, torque in t2_values:
        tpdo2["Velocity actual value"].raw = vel
        tpdo2["Torque actual value"].raw = torque
        tpdo2.transmit()
        (f,) = net.take()
        cases.append({"kind": "tpdo2", "node": node_id, "velocity": vel, "torque": torque, "frame": _frame(*f)})
    return cases


def emcy_cases(node_id: int) -> list[dict[str, Any]]:
    net = CaptureNetwork()
    drive = canopen.LocalNode(node_id, canopen.import_od(str(EDS_PATH), node_id))
    net.add_node(drive)
    cases = []
    for code, register, data in [(0x8130, 0x11, b""), (0x8400, 0x01, b"\x01\x02\x03\x04\x05"),
                                 (0x8611, 0x01, b"\xff"), (0x0000, 0x00, b""), (0xFFFF, 0xFF, b"\xaa" * 5)]:
        drive.emcy.send(code, register, data)
        (f,) = net.take()
        cases.append({"kind": "emcy", "node": node_id, "code": code, "register": register,
                      "manufacturer": data.ljust(5, b"\x00").hex(), "frame": _frame(*f)})
    return cases


def build() -> dict[str, Any]:
    rng = random.Random(402)
    frames: list[dict[str, Any]] = []
    for node in NODES:
        frames += sdo_cases(node)
        frames += nmt_sync_heartbeat_cases(node)
        frames += pdo_cases(node, rng)
        frames += emcy_cases(node)
    return {
        "about": "CiA 402 golden CANopen frames produced by python-canopen "
        f"{canopen.__version__} from cia402_drive.eds by firmware_bridge/tools/make_cia402_golden.py; "
        "data is hex",
        "objects": objects(),
        "frames": frames,
    }


def render() -> str:
    """The exact text written to cia402_frames.json."""
    return json.dumps(build(), indent=1, sort_keys=True) + "\n"


def main(argv: list[str]) -> int:
    out = Path(argv[1]) if len(argv) > 1 else DEFAULT_OUT
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(render())
    print(f"wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
