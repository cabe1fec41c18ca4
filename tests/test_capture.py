"""The built-in bus capture of a virtual-rig run (sensaug.capture, rig.py).

One short run on the loopback bus with the capture on; the capture is read
back with python-can's LogReader (and with our own candump parser), decoded
with cantools against firmware_bridge/hi5.dbc, and every command and
feedback in the controller's log is found on it. can-utils' ``log2asc`` is
run on it when installed (then the ASC read back with python-can), since
``canplayer`` needs a kernel CAN device this host does not have (the
SocketCAN VM run, scripts/test-socketcan.sh, uses candump's own capture).
Timing is never asserted.
"""

from __future__ import annotations

import math
import shutil
import subprocess
import time
from pathlib import Path

import can
import cantools
import numpy as np
import pytest
from sensaug_bridge.udp_bus import free_port
from test_rig import short_config, stall_tolerant

from sensaug import cli, rig
from sensaug.capture import BusCapture, Decoded, Frame, decode_all, match_commands, match_feedback, read_candump

REPO = Path(__file__).resolve().parents[1]
DBC = REPO / "firmware_bridge" / "hi5.dbc"


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("capture_run")
    port = rig.bus_port(None)
    r = rig.run_virtual_rig(stall_tolerant(short_config()), out=out, port=port, timeout_s=120.0)
    # The subject is the capture: a run that a safety stop ended early (a
    # feedback timeout, or the drive's watchdog or overspeed fault, when this
    # shared machine starves one of the processes) is accounted for the same
    # way, up to its last tick. test_rig.py checks that runs complete.
    assert r.stats["ticks"] >= 500, (r.returncode, r.stats)
    assert r.port == port
    print(f"\nrig run: {r.stats['stop_reason']}, {r.stats['ticks']} ticks")
    return out, r


def test_the_capture_is_complete_and_readable_by_python_can(run):
    out, r = run
    c = r.capture
    assert c is not None and c.path == out / "bus.log"
    assert c.error is None and c.dropped_kernel == 0 and c.dropped_malformed == 0
    with can.LogReader(c.path) as reader:
        messages = list(reader)
    assert len(messages) == c.frames > 0
    assert all(m.channel == f"can{r.port}" for m in messages)
    frames = [Frame.from_message(m) for m in messages]
    # Our own candump parser (used on the VM's candump capture) reads the same frames.
    assert read_candump(c.path) == frames


def test_every_command_and_feedback_in_the_log_is_on_the_bus(run):
    out, r = run
    db = cantools.database.load_file(DBC)
    frames = [Frame.from_message(m) for m in can.LogReader(r.capture.path)]
    node = r.config.rig.node_id
    decoded, other = decode_all(frames, db, node)
    assert other == {"error": 0, "eff": 0, "fd": 0, "rtr": 0, "unknown_id": 0, "undecodable": 0}
    assert len(decoded) == len(frames), "every frame decodes with hi5.dbc"
    # Started before the drive booted: the drive's first frame, Fault(BOOT), is the capture's first.
    assert decoded[0].name == "Fault" and decoded[0].signals["state"] == 0
    # Stopped after both processes exited and the bus was drained: the
    # drive's final Heartbeat (sent on SIGTERM, after the controller exited)
    # is the last frame, after every frame of the controller.
    host = [d for d in decoded if d.sender == "HOST"]
    assert decoded[-1].name == "Heartbeat" and decoded[-1].index > host[-1].index
    stats, log = r.stats, r.log
    assert stats["can"]["bus_sent"] == len(host), "frames the controller sent = host frames captured"

    by_name: dict[str, list] = {}
    for d in decoded:
        by_name.setdefault(d.name, []).append(d)
    commands, feedback = by_name["TorqueCommand"], by_name["Feedback"]
    scale = db.get_message_by_name("TorqueCommand").get_signal_by_name("torque").scale
    ticks = int(stats["ticks"])
    matched = match_commands(commands, log, scale)
    assert len(matched) == ticks == len(log), "every tick's command is on the bus, in order"

    # Each fresh tick k >= 1 used the Feedback answering tick k-1's command.
    answer = match_feedback(commands, matched, feedback)
    unit = math.pi / 180.0 if r.config.rig.position_unit == "deg" else 1.0
    fresh = np.flatnonzero(log["fresh"][1:]) + 1
    # sensaug-rt counts missing feedback in `sense`, which also runs for the
    # last, unrecorded tick (the one that stops the run or finds the protocol
    # done): the counter is the log's stale ticks, or one more.
    stale = ticks - 1 - len(fresh)
    assert stale <= stats["can"]["missing_feedback"] <= stale + 1
    unanswered = [int(k) for k in fresh if answer[k - 1] is None]
    assert not unanswered, (f"fresh ticks with no Feedback on the bus: {unanswered[:10]}; "
                            + around(decoded, commands[matched[unanswered[0] - 1]].index))
    pos = np.array([feedback[answer[k - 1]].signals["position"] for k in fresh])
    vel = np.array([feedback[answer[k - 1]].signals["velocity"] for k in fresh])
    np.testing.assert_allclose(log["x"][fresh] * unit, pos, rtol=0, atol=1e-9)
    np.testing.assert_allclose(log["xdot"][fresh] * unit, vel, rtol=0, atol=1e-9)
    print(f"\ncapture: {len(frames)} frames, {len(commands)} commands, {len(feedback)} feedback; "
          f"{len(fresh)} fresh ticks of {ticks} matched")


def test_an_answer_captured_before_its_command_is_matched():
    """The capture order of a failed full run (tick 1's Feedback queued before
    its TorqueCommand), and the earlier answers that must not be taken: an
    answer is looked for after the previous tick's command, never earlier."""
    frame = Frame(0.0, 0, False, False, False, False, b"")
    bus = [("TorqueCommand", 0), ("Feedback", 0), ("Feedback", 1), ("TorqueCommand", 1),
           ("TorqueCommand", 2), ("Feedback", 2), ("TorqueCommand", 3), ("Feedback", 2), ("TorqueCommand", 4)]
    decoded = [Decoded(frame, name, "", {"sequence": seq}, i) for i, (name, seq) in enumerate(bus)]
    commands = [d for d in decoded if d.name == "TorqueCommand"]
    feedback = [d for d in decoded if d.name == "Feedback"]
    answer = match_feedback(commands, list(range(len(commands))), feedback)
    # Ticks 3 and 4: only a second Feedback(2) comes after their commands.
    assert answer == [0, 1, 2, None, None]


def test_a_missing_answer_at_the_end_does_not_take_a_later_commands_answer():
    """A full run's capture: an answer missing in the run's last 256 ticks,
    its sequence reused by the unrecorded last tick's command (on the bus, not
    in the log), whose answer came later. That answer is not the missing
    one's (it followed a command reusing the sequence), and taking it would
    leave every later tick unanswered."""
    frame = Frame(0.0, 0, False, False, False, False, b"")
    bus = [("TorqueCommand", 5), ("Feedback", 5), ("TorqueCommand", 6), ("TorqueCommand", 7), ("Feedback", 7),
           ("TorqueCommand", 6), ("Feedback", 6)]
    decoded = [Decoded(frame, name, "", {"sequence": seq}, i) for i, (name, seq) in enumerate(bus)]
    commands = [d for d in decoded if d.name == "TorqueCommand"]
    feedback = [d for d in decoded if d.name == "Feedback"]
    # The log's three ticks: the last command on the bus is the unrecorded tick's.
    assert match_feedback(commands, [0, 1, 2], feedback) == [0, None, 1]


def around(decoded, index: int, frames: int = 6) -> str:
    """The bus in capture order around frame ``index`` (name and sequence),
    for a failure message: a Feedback captured before the command it echoes
    (the capture's socket and the drive's see each datagram in their own
    order) reads differently from one missing."""
    lo, hi = max(index - frames, 0), min(index + frames + 1, len(decoded))
    return "bus around it: " + ", ".join(
        f"{'>' if d.index == index else ''}{d.name}({d.signals.get('sequence')})" for d in decoded[lo:hi])


def test_the_output_folder_says_what_is_in_it(run):
    out, r = run
    readme = (out / "README.txt").read_text().splitlines()
    assert f"port {r.port}" in readme[0]
    listed = {line.split()[0] for line in readme[3:] if line.strip()}
    assert listed == {"rig_config.toml", "rig_log.csv", "rig_stats.json", "bus.log"}
    assert all((out / name).is_file() for name in listed)
    assert f"{r.capture.frames} frames" in next(line for line in readme if line.startswith("bus.log"))


@pytest.mark.skipif(shutil.which("log2asc") is None, reason="can-utils not installed (the python-can reader is tested)")
def test_can_utils_log2asc_reads_the_capture(run, tmp_path):
    _, r = run
    asc = tmp_path / "bus.asc"
    subprocess.run(["log2asc", "-I", str(r.capture.path), "-O", str(asc), f"can{r.port}"], check=True, timeout=60)
    ours = [(m.arbitration_id, bytes(m.data)) for m in can.LogReader(r.capture.path)]
    theirs = [(m.arbitration_id, bytes(m.data)) for m in can.ASCReader(asc)]
    assert theirs == ours


@pytest.mark.parametrize("name", ["bus.log", "bus.blf"])
def test_stop_drains_a_burst_sent_just_before_it(tmp_path, name):
    port = free_port()
    cap = BusCapture(port, tmp_path / name)  # bound: frames are queued from here
    sender = can.Bus(interface="sensaug_udp", channel=port)
    try:
        for i in range(300):  # before the thread even starts
            sender.send(can.Message(arbitration_id=0x200 + i % 16, data=i.to_bytes(2, "little"), is_extended_id=False))
        cap.start()
        time.sleep(0.05)
        for i in range(300, 3000):
            sender.send(can.Message(arbitration_id=0x200 + i % 16, data=i.to_bytes(2, "little"), is_extended_id=False))
    finally:
        sender.shutdown()
    stats = cap.stop()  # right after the burst
    assert stats.error is None and stats.dropped_kernel == 0
    got = [int.from_bytes(m.data, "little") for m in can.LogReader(tmp_path / name)]
    assert got == list(range(3000)) and stats.frames == 3000


def test_port_is_checked_with_a_clear_error(tmp_path):
    for bad in (0, 65536, -1, True, "47100"):
        with pytest.raises(ValueError, match=r"port: must be a UDP port 1\.\.=65535"):
            rig.bus_port(bad)
    port = free_port()
    holder = can.Bus(interface="sensaug_udp", channel=port)
    try:
        with pytest.raises(ValueError, match=rf"port: {port} is in use"):
            rig.bus_port(port)
        with pytest.raises(ValueError, match="is in use"):
            rig.run_virtual_rig(short_config(), out=tmp_path, port=port)
    finally:
        holder.shutdown()
    assert rig.bus_port(port) == port  # free again


def test_cli_refuses_a_bad_port_and_capture_name(tmp_path, capsys):
    toml = tmp_path / "c.toml"
    short_config().to_toml(toml)
    assert cli.main(["rig", str(toml), "--out", str(tmp_path), "--port", "70000"]) == 2
    assert "port: must be a UDP port 1..=65535" in capsys.readouterr().err
    assert cli.main(["rig", str(toml), "--out", str(tmp_path), "--capture", "bus.xyz", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "capture: 'bus.xyz'" in err and "use .log (candump -l) or .blf" in err


def test_demo_reports_a_stopped_run_without_crashing(run, monkeypatch, tmp_path, capsys):
    """A run that stopped in the gain phase (as a feedback timeout on an
    overloaded machine does) is reported with its stop reason and exit 1."""
    _, r = run
    log = r.log
    gains_only = np.flatnonzero(log["phase"] == log.phase_code("gains"))[-1]
    stopped = rig.RigRun(
        config=r.config, log=type(log)(data=log.data[: gains_only + 1], meta=log.meta),
        stats={**r.stats, "stop_reason": "feedback timeout (emergency stop sent)"},
        returncode=1, drive_returncode=0, stderr="", port=r.port, capture=r.capture, files=dict(r.files),
    )
    monkeypatch.setattr(rig, "run_virtual_rig", lambda *a, **k: stopped)
    assert cli.rig_demo(r.config, tmp_path, True, progress=False) == 1
    out = capsys.readouterr().out
    assert "Stage 1: partner gains" in out
    assert "Stage 2: not reached (the run stopped: feedback timeout (emergency stop sent))" in out
    assert "Stage 3: not reached" in out and "plots: skipped" in out
