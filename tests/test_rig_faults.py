"""The virtual rig under the faults a lab bus sees (issue 9, part 2; issue
17; docs/safety.md): a second controller, foreign command frames, forged
positions and velocities, replayed and copied feedback, a stalled drive, the
controlled stop at the worst moment (the handle's travel on the drive's own
record), every terminating signal, unwritable outputs, a log that fails
mid-run, and the gap between the enable and the first tick.

Each test starts the virtual drive and sensaug-rt on its own free loopback
port (tests/test_rig.py's helpers), injects the fault from a third socket on
the same bus, bounded in time, and stops every process it started. Each
scenario is a function returning its measured figures, so that
``scripts/measure_safety.py`` repeats the same code and quotes median and
maximum. Timing is reported, never asserted tightly: these VMs are noisy.

Every scenario runs on both drive profiles (``[rig] drive``, the
``drive`` parameter; the signals all on the Hi5, SIGHUP on both: the
handling is the binary's, the same for both). On CiA 402 the frames the tests watch and forge are
PDOs and SDOs by COB-ID (node 1), the drive's state is its statusword
0x6041 read over SDO from the test's socket.
"""
from __future__ import annotations

import json
import math
import resource
import signal
import socket
import struct
import subprocess
import threading
import time
from pathlib import Path

import can
import numpy as np
import pytest
from sensaug_bridge import protocol as p
from sensaug_bridge.protocol import FaultFlag, State
from sensaug_bridge.udp_bus import BROADCAST_ADDR, unpack_frame
from test_rig import NODE, Processes, short_config, stall_tolerant

from sensaug import rig
from sensaug.config import ScenarioConfig
from sensaug.logs import load_log

#: CiA 402 COB-IDs of node 1 (docs/cia402.md).
RPDO1, TPDO1, TPDO2, SDO_RX, SDO_TX, SYNC, NMT = 0x201, 0x181, 0x281, 0x601, 0x581, 0x080, 0x000
#: CiA 402 controlwords the controller sends at its stops.
CW_QUICK_STOP, CW_SHUTDOWN = 0x0002, 0x0006
#: The frames only a controller (master) sends, per profile.
COMMAND_IDS = {"cia402": {RPDO1, SDO_RX, SYNC, NMT}}

#: Both profiles, for the scenarios that apply to both.
PROFILES = ["hi5", "cia402"]
#: The standard CiA 402 drive (no SYNC counter echo 0x2000: the virtual drive
#: with --standard, rig.cia402.freshness = "standard"), for the scenarios whose
#: outcome its freshness rule could change (docs/safety.md, "Standard CiA 402
#: drives").
STANDARD = "cia402-standard"

#: Exit codes (docs/realtime.md).
EXIT_SETUP, EXIT_OTHER_CONTROLLER, EXIT_FOREIGN, EXIT_IMPLAUSIBLE, EXIT_DEGRADED, EXIT_LOG = 2, 3, 4, 5, 6, 7
#: sensaug-rt's exit code of a feedback timeout (and of a signal or a drive fault).
EXIT_FEEDBACK_TIMEOUT = 1


def rig_processes(tmp: Path, cfg: ScenarioConfig, drive: str = "hi5") -> Processes:
    """A virtual drive of profile ``drive`` on a free port, booted (its
    heartbeat runs); :data:`STANDARD`: the CiA 402 one without 0x2000."""
    cfg.rig.drive = "cia402" if drive == STANDARD else drive
    if drive == STANDARD:
        cfg.rig.cia402.freshness = "standard"
    pr = Processes(tmp, cfg)
    time.sleep(0.5)
    return pr


def _drain(pr: Processes) -> None:
    while pr.monitor.recv(timeout=0) is not None:
        pass


def cia_frames(pr: Processes, seconds: float):
    """Raw frames seen on the bus for ``seconds``."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        msg = pr.monitor.recv(timeout=0.05)
        if msg is not None:
            yield msg


def cia_controlword(msg: can.Message) -> int | None:
    """The controlword of an RPDO1 frame, else None."""
    return int.from_bytes(msg.data[0:2], "little") if msg.arbitration_id == RPDO1 and len(msg.data) >= 2 else None


def cia_statusword(pr: Processes) -> int:
    """The drive's statusword 0x6041, read over SDO (expedited upload)."""
    _drain(pr)
    pr.monitor.send(can.Message(arbitration_id=SDO_RX, data=[0x40, 0x41, 0x60, 0, 0, 0, 0, 0], is_extended_id=False))
    for msg in cia_frames(pr, 1.0):
        d = msg.data
        if msg.arbitration_id == SDO_TX and len(d) == 8 and d[0] & 0xE0 == 0x40 and bytes(d[1:4]) == b"\x41\x60\x00":
            return int.from_bytes(d[4:6], "little")
    raise AssertionError("the drive did not answer an SDO read of 0x6041")


def cia_state(statusword: int) -> str:
    """The CiA 402 state of a statusword (table 30)."""
    for mask, value, name in [(0x4F, 0x00, "NotReadyToSwitchOn"), (0x4F, 0x40, "SwitchOnDisabled"),
                              (0x6F, 0x21, "ReadyToSwitchOn"), (0x6F, 0x23, "SwitchedOn"),
                              (0x6F, 0x27, "OperationEnabled"), (0x6F, 0x07, "QuickStopActive"),
                              (0x4F, 0x0F, "FaultReactionActive"), (0x4F, 0x08, "Fault")]:
        if statusword & mask == value:
            return name
    raise AssertionError(f"statusword {statusword:#06x} is no CiA 402 state")


def assert_drive_disabled(pr: Processes, drive: str) -> None:
    """The drive applies no torque and is not faulted (Hi5 DISABLED; CiA 402
    ReadyToSwitchOn or SwitchOnDisabled)."""
    if drive == "hi5":
        assert drive_state(pr).state == State.DISABLED
    else:
        assert cia_state(cia_statusword(pr)) in ("ReadyToSwitchOn", "SwitchOnDisabled")


def assert_drive_latched_off(pr: Processes, drive: str) -> None:
    """After an emergency stop the drive applies no torque until a
    controller sets it up again: Hi5 FAULT(EMERGENCY_STOP) (cleared only by
    ClearFaults); CiA 402 QuickStopActive (torque 0, left only on a
    controlword from a master; the virtual drive faults on a lost master
    heartbeat only in OperationEnabled), still so after the watchdog."""
    if drive == "hi5":
        beat = drive_state(pr)
        assert beat.state == State.FAULT and beat.fault_flags & FaultFlag.EMERGENCY_STOP, beat
        return
    time.sleep(0.5)  # > rig.watchdog_ms (200 ms here): the master's silence changes nothing
    assert cia_state(cia_statusword(pr)) == "QuickStopActive"


def first_command(pr: Processes, drive: str, seconds: float, *, emergency: bool) -> float | None:
    """Monotonic time of the first stop command seen within ``seconds``:
    the emergency stop (Hi5 EmergencyStop; CiA 402 controlword quick stop) or
    the disable (Hi5 SetState(disable); CiA 402 controlword shutdown)."""
    if drive == "hi5":
        seen = (first_frame(pr, {"EmergencyStop"}, seconds) if emergency
                else first_frame(pr, {"SetState"}, seconds, lambda d: not d.message.enable))
        return None if seen is None else seen[0]
    want = CW_QUICK_STOP if emergency else CW_SHUTDOWN
    for msg in cia_frames(pr, seconds):
        if cia_controlword(msg) == want:
            return time.monotonic()
    return None


def controller(pr: Processes, log: Path, stats: Path, **kw) -> subprocess.Popen:
    """One more sensaug-rt on the processes' bus and node."""
    return subprocess.Popen(
        [str(rig.find_binary()), str(pr.toml), "--can", f"udp:{pr.port}", "--log", str(log), "--stats", str(stats)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw,
    )


def wait_running(pr: Processes, timeout: float = 10.0, drive: str = "hi5") -> p.Feedback | None:
    """Waits until the controller's loop runs (feedback on the bus) and
    returns the latest feedback (Hi5; CiA 402: None)."""
    end = time.monotonic() + timeout
    ticks = 0
    while time.monotonic() < end:
        assert pr.controller.poll() is None, pr.controller.stderr.read()
        if drive in ("cia402", STANDARD):
            # The loop's ticks: enable-operation RPDO1s past the set-up's few steps.
            ticks += sum(cia_controlword(m) == 0x000F for m in cia_frames(pr, 0.05))
            if ticks > 100:
                return None
            continue
        for d in pr.frames(0.05):
            if d.name == "Feedback":
                return latest_feedback(pr, d.message)
    raise AssertionError("the loop did not start")


def latest_feedback(pr: Processes, fb: p.Feedback | None = None) -> p.Feedback:
    """The most recent feedback the monitor has (draining its queue)."""
    while (msg := pr.monitor.recv(timeout=0)) is not None:
        try:
            d = p.decode(msg)
        except p.ProtocolError:
            continue
        if d.name == "Feedback":
            fb = d.message
    if fb is None:
        for d in pr.frames(1.0):
            if d.name == "Feedback":
                return d.message
        raise AssertionError("no feedback on the bus")
    return fb


def first_frame(pr: Processes, names: set[str], seconds: float, pred=lambda d: True) -> tuple[float, p.Decoded] | None:
    """(monotonic time, frame) of the first frame named in ``names`` seen within ``seconds``."""
    for d in pr.frames(seconds):
        if d.name in names and pred(d):
            return time.monotonic(), d
    return None


def stats_of(pr: Processes) -> dict:
    return json.loads(pr.stats.read_text())


def end_of_run(pr: Processes) -> tuple[int, dict, str]:
    code = pr.wait_controller(timeout=30)
    return code, stats_of(pr), pr.controller.stderr.read()


def drive_state(pr: Processes) -> p.Heartbeat:
    """The drive's latest heartbeat: what the monitor buffered during the
    run is dropped first (it may hold seconds of frames)."""
    while pr.monitor.recv(timeout=0) is not None:
        pass
    beats = pr.heartbeats(0.5)
    assert beats, "the drive stopped sending heartbeats"
    return beats[-1]


# --- 1. a second controller -------------------------------------------------


def scenario_second_controller(tmp: Path, drive: str = "hi5") -> dict:
    """A second sensaug-rt on the same port and node while one runs: it
    refuses to start (exit 3) without sending anything; the first runs on."""
    pr = rig_processes(tmp, stall_tolerant(short_config(gain_s=10.0)), drive)
    try:
        pr.start_controller()
        wait_running(pr, drive=drive)
        log2, stats2 = tmp / "second_log.csv", tmp / "second_stats.json"
        t0 = time.monotonic()
        second = controller(pr, log2, stats2)
        second.wait(timeout=30)
        refused_s = time.monotonic() - t0
        err = second.stderr.read()
        assert second.returncode == EXIT_OTHER_CONTROLLER, err
        assert "another controller" in err and "sensaug-rt" in err and "rig.node_id" in err, err
        # It never ran: no log, no statistics, no partial files left.
        assert not log2.exists() and not stats2.exists(), list(tmp.iterdir())
        assert not list(tmp.glob("second_*.partial")), list(tmp.iterdir())
        # The first one was not disturbed.
        assert pr.controller.poll() is None, pr.controller.stderr.read()
        pr.controller.send_signal(signal.SIGTERM)
        code, stats, _ = end_of_run(pr)
        assert code == 1 and stats["stop_reason"].startswith("signal"), stats["stop_reason"]
        assert stats["can"]["foreign_commands"] == 0
        return {"refused_after_ms": 1e3 * refused_s}
    finally:
        pr.close()


def scenario_foreign_command(tmp: Path, drive: str = "hi5") -> dict:
    """A foreign command frame for the node (Hi5: a SetState with another
    watchdog: valid, and ignored by the drive while ENABLED; CiA 402: an SDO
    read of the statusword, which the drive just answers; so only the
    controller reacts): the controller stops at once with an emergency stop
    (exit 4), which leaves the drive off until set up again (Hi5 FAULT;
    CiA 402 QuickStopActive)."""
    cfg = stall_tolerant(short_config(gain_s=10.0))
    pr = rig_processes(tmp, cfg, drive)
    try:
        pr.start_controller()
        wait_running(pr, drive=drive)
        _drain(pr)  # drop what the monitor buffered
        sent = time.monotonic()
        if drive == "hi5":
            pr.monitor.send(p.SetState(True, cfg.rig.watchdog_ms - 1, 0).encode(NODE))
        else:
            pr.monitor.send(can.Message(arbitration_id=SDO_RX, data=[0x40, 0x41, 0x60, 0, 0, 0, 0, 0],
                                        is_extended_id=False))
        seen_at = first_command(pr, drive, 5.0, emergency=True)
        assert seen_at is not None, "no emergency stop within 5 s"
        code, stats, err = end_of_run(pr)
        assert code == EXIT_FOREIGN, err
        assert stats["stop_reason"].startswith("foreign command"), stats["stop_reason"]
        assert "another controller" in stats["stop_reason"] and "foreign command" in err
        assert stats["can"]["foreign_commands"] >= 1 and stats["exit_code"] == EXIT_FOREIGN
        assert_drive_latched_off(pr, drive)
        log = load_log(pr.log)
        assert log.complete and len(log) == stats["ticks"]
        return {"emergency_stop_after_ms": 1e3 * (seen_at - sent)}
    finally:
        pr.close()


# --- 2. feedback plausibility -----------------------------------------------


#: CiA 402 position increments per rad of the virtual drive (velocity:
#: increments/s per rad/s).
def _increments_per_rad() -> float:
    from sensaug_bridge.virtual_cia402 import Cia402Config

    return Cia402Config().encoder_counts_per_rev / (2 * np.pi)


class Forger:
    """A third node on the bus building feedback frames for the drive's node
    out of what it sees: the latest real feedback (Hi5 Feedback; CiA 402
    TPDO1 and TPDO2) and the commands (Hi5 TorqueCommand; CiA 402 SYNC)."""

    def __init__(self, pr: Processes, drive: str):
        self.pr, self.drive = pr, drive
        #: The standard drive's TPDOs carry no SYNC counter (6 bytes).
        self.standard = drive == STANDARD
        self.fb: p.Feedback | None = None
        self.tpdo: dict[int, bytes] = {}
        #: Every real feedback seen, as its frames' (id, payload).
        self.seen: list[list[tuple[int, bytes]]] = []
        self.torque_id = p.frame_id("TorqueCommand", NODE)
        self.sent = 0

    def next_event(self, timeout: float = 0.05) -> tuple[str, int] | None:
        """Reads one frame: ("feedback", its sequence) for a real feedback
        (CiA 402: its TPDO2), ("command", its sequence) for a command
        (CiA 402: a SYNC's counter), ("disable", 0) for the controller's
        disable (Hi5 SetState(disable); CiA 402 controlword shutdown), else
        None."""
        msg = self.pr.monitor.recv(timeout=timeout)
        if msg is None:
            return None
        i, data = msg.arbitration_id, bytes(msg.data)
        if self.drive == "hi5":
            if i == self.torque_id:
                return "command", p.TorqueCommand.decode(data, i).sequence
            try:
                d = p.decode(msg)
            except p.ProtocolError:
                return None
            if d.name == "Feedback":
                self.fb = d.message
                self.seen.append([(i, data)])
                return "feedback", d.message.sequence
            if d.name == "SetState" and not d.message.enable:
                return "disable", 0
            return None
        if i in (TPDO1, TPDO2):
            self.tpdo[i] = data
            if i == TPDO2 and TPDO1 in self.tpdo:
                self.seen.append([(TPDO1, self.tpdo[TPDO1]), (TPDO2, data)])
                return "feedback", 0 if self.standard else data[-1]
            return None
        if i == SYNC and data:
            return "command", data[0]
        if cia_controlword(msg) == CW_SHUTDOWN:
            return "disable", 0
        return None

    def ready(self) -> bool:
        return self.fb is not None if self.drive == "hi5" else len(self.tpdo) == 2

    def velocity(self) -> float:
        """The latest real velocity (rad/s)."""
        if self.drive == "hi5":
            return self.fb.velocity_rad_s
        return int.from_bytes(self.tpdo[TPDO2][0:4], "little", signed=True) / _increments_per_rad()

    def send(self, seq: int, *, dx_rad: float = 0.0, velocity_rad_s: float | None = None) -> float:
        """A feedback for command ``seq`` from the latest real one: its
        position moved by ``dx_rad``, its velocity replaced; returns when
        it was sent."""
        v = self.velocity() if velocity_rad_s is None else velocity_rad_s
        if self.drive == "hi5":
            fb = self.fb
            frames = [p.Feedback(fb.position_rad + dx_rad, v, seq, fb.state, False, False).encode(NODE)]
        else:
            per_rad = _increments_per_rad()
            t1, t2 = self.tpdo[TPDO1], self.tpdo[TPDO2]
            position = int.from_bytes(t1[2:6], "little", signed=True) + round(dx_rad * per_rad)
            # The echo drive's TPDOs end with the SYNC counter; the standard one's have none.
            echo = b"" if self.standard else bytes([seq])
            tpdo1 = t1[0:2] + position.to_bytes(4, "little", signed=True) + echo
            tpdo2 = round(v * per_rad).to_bytes(4, "little", signed=True) + t2[4:6] + echo
            frames = [can.Message(arbitration_id=i, data=d, is_extended_id=False)
                      for i, d in ((TPDO1, tpdo1), (TPDO2, tpdo2))]
        at = time.monotonic()
        for f in frames:
            self.pr.monitor.send(f)
        self.sent += len(frames)
        return at

    def replay(self, behind: int) -> None:
        """A real feedback again, exactly as it was: the latest (``behind``
        0) or the one ``behind`` feedbacks before it (the oldest seen if
        fewer)."""
        for i, data in self.seen[max(len(self.seen) - 1 - behind, 0)]:
            self.pr.monitor.send(can.Message(arbitration_id=i, data=data, is_extended_id=False))
            self.sent += 1

    def next_command(self, timeout: float = 2.0) -> int:
        """The sequence of the next command on the bus (what the monitor had
        buffered dropped first, so it is the controller's latest)."""
        _drain(self.pr)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            e = self.next_event()
            if e is not None:
                kind, seq = e
                if kind == "command" and self.ready():
                    return seq
        ended = self.pr.controller.poll()
        raise AssertionError(f"no command on the bus; the controller's exit: {ended}"
                             + (f", {self.pr.controller.stderr.read()}" if ended is not None else ""))


def forging_on_a_running_controller(pr: Processes, drive: str) -> Forger:
    """Starts the controller, lets it run 1 s, and returns a forger on the
    bus with everything received so far drained."""
    pr.start_controller()
    wait_running(pr, drive=drive)
    time.sleep(1.0)
    forger = Forger(pr, drive)
    _drain(pr)
    return forger


def forge_jump(pr: Processes, drive: str, jump_rad: float, commands: int = 50) -> tuple[float, float | None, int]:
    """Sends a feedback ``jump_rad`` away from the latest one answering
    each of the controller's next ``commands`` commands, as soon as the
    monitor sees it (Hi5: a Feedback of its sequence; CiA 402: TPDO1 with
    the position moved and TPDO2 as last sent, both echoing the SYNC's
    counter), until the controller disables the drive (5 s at most).
    Returns when the first was sent, when the disable was seen (None: not
    within 5 s) and how many were sent. Each races the drive's own answer:
    first, it is a position step; second, a conflict with the drive's; later
    still (a monitor descheduled on a loaded machine: its answer older than
    the newest), discarded."""
    forger = Forger(pr, drive)
    first = forger.send(forger.next_command(), dx_rad=jump_rad)
    sent = 1
    end = first + 5.0
    while time.monotonic() < end:
        event = forger.next_event()
        if event is None:
            continue
        if event[0] == "disable":
            return first, time.monotonic(), sent
        if event[0] == "command" and sent < commands:
            forger.send(event[1], dx_rad=jump_rad)
            sent += 1
    return first, None, sent


#: What an implausible feedback's stop reason says after "implausible feedback: ".
IMPLAUSIBLE_KINDS = ("position step", "two different feedbacks answer command", "velocity inconsistent")


def implausible_kind(reason: str) -> str:
    """Which check refused the feedback (one of IMPLAUSIBLE_KINDS)."""
    prefix = "implausible feedback: "
    assert reason.startswith(prefix) and reason.endswith("(torque off at once, drive disabled)"), reason
    kinds = [k for k in IMPLAUSIBLE_KINDS if reason[len(prefix):].startswith(k)]
    assert kinds, reason
    return kinds[0]


def assert_torque_off_at_once(log, stats: dict) -> None:
    """The stop turned the torque off at once: no braking tick, the log holds
    the controller's ticks up to the stop, and the controller never ran on
    a refused feedback (no position jump in its log, deg)."""
    assert log.complete and len(log) == stats["ticks"]
    assert not log["ramp"].any()
    assert stats["stop"]["kind"] == "torque_off" and stats["stop"]["braking_ticks"] == 0, stats["stop"]
    assert np.abs(np.diff(log["x"])).max() < np.degrees(0.1)


def scenario_forged_jump(tmp: Path, drive: str = "hi5") -> dict:
    """Forged feedback 0.5 rad away from the last one, answering the
    controller's next commands (``forge_jump``): the controller never acts
    on it; whether one arrives before the drive's answer (a position step)
    or after it (two different feedbacks for one command), the torque goes
    off at once, the drive is disabled, exit 5."""
    pr = rig_processes(tmp, stall_tolerant(short_config(gain_s=10.0)), drive)
    try:
        pr.start_controller()
        wait_running(pr, drive=drive)
        time.sleep(1.0)
        sent, disabled_at, forged_frames = forge_jump(pr, drive, 0.5)
        if drive == STANDARD and disabled_at is None:
            return standard_forgeries_discarded(pr, forged_frames)
        assert disabled_at is not None, "the controller did not disable the drive within 5 s"
        code, stats, err = end_of_run(pr)
        assert code == EXIT_IMPLAUSIBLE, err
        kind = implausible_kind(stats["stop_reason"])
        # Standard mode: no counter, so no conflict; a forged answer alone in
        # its SYNC's window is refused by physics (a step, or its velocity).
        allowed = (IMPLAUSIBLE_KINDS[0], IMPLAUSIBLE_KINDS[2]) if drive == STANDARD else IMPLAUSIBLE_KINDS[:2]
        assert kind in allowed, stats["stop_reason"]
        assert "implausible feedback" in err and stats["can"]["implausible_feedback"] >= 1
        assert_torque_off_at_once(load_log(pr.log), stats)
        assert_drive_disabled(pr, drive)
        return {
            "disabled_after_ms": 1e3 * (disabled_at - sent),
            "forged_answers": forged_frames,
            "refused_as_step": float(kind == "position step"),
            "speed_at_stop_rad_s": stats["stop"]["speed_at_stop_rad_s"],
        }
    finally:
        pr.close()


def standard_forgeries_discarded(pr: Processes, forged_frames: int) -> dict:
    """Standard CiA 402, forged answers that each came with the drive's own
    answer to the same SYNC: every such window is ambiguous (duplicated),
    neither answer taken, so the run went on on the drive's answers alone:
    ended here by SIGTERM, the forged ones counted as duplicated, none used
    (the log never jumps)."""
    assert pr.controller.poll() is None, pr.controller.stderr.read()
    pr.controller.send_signal(signal.SIGTERM)
    code, stats, err = end_of_run(pr)
    assert code == 1 and stats["stop_reason"].startswith("signal SIGTERM"), (stats["stop_reason"], err)
    can_ = stats["can"]
    assert can_["implausible_feedback"] == 0, can_
    assert stats["drive"]["feedback_duplicated"] >= forged_frames - can_["bus_kernel_dropped"] - 10, stats["drive"]
    log = load_log(pr.log)
    running = ~log["ramp"]
    assert np.abs(np.diff(log["x"][running])).max() < np.degrees(0.05)
    return {"disabled_after_ms": math.nan, "forged_answers": forged_frames, "refused_as_step": 0.0,
            "speed_at_stop_rad_s": math.nan, "all_duplicated": 1.0}


def forged(mode: str, v: float, n: int) -> float:
    """The forger's velocity from the real ``v`` (its ``n``-th forgery):
    scaled by 1.5, doubled, or the real one plus a 1 rad/s, 50 Hz
    oscillation (at 1 kHz)."""
    if mode == "scaled":
        return 1.5 * v
    if mode == "doubled":
        return 2.0 * v
    return v + np.sin(2 * np.pi * n / 20)


def scenario_forged_velocity(tmp: Path, drive: str = "hi5", mode: str = "doubled", race: bool = False,
                             forge_s: float = 5.0) -> dict:
    """A third node copying the drive's real position and changing only the
    velocity (``forged``) for ``forge_s``: after each real feedback, with
    its sequence (CiA 402: SYNC counter), or, with ``race``, answering each
    command before the drive does. The controller stops the run (exit 5:
    two feedbacks for one command, or a velocity inconsistent with the
    position's change) with the torque off at once, before the drive's
    own OVERSPEED; no run completes on forged velocity."""
    record_path = tmp / "drive_record.npz"
    cfg = stall_tolerant(short_config(gain_s=10.0))
    cfg.rig.drive = "cia402" if drive == STANDARD else drive
    if drive == STANDARD:
        cfg.rig.cia402.freshness = "standard"
    pr = Processes(tmp, cfg, drive_args=["--log", str(record_path)])
    try:
        time.sleep(0.5)
        forger = forging_on_a_running_controller(pr, drive)
        start = time.monotonic()
        n = 0
        while time.monotonic() - start < forge_s and pr.controller.poll() is None:
            event = forger.next_event()
            if event is None or not forger.ready():
                continue
            kind, seq = event
            if kind == ("command" if race else "feedback"):
                forger.send(seq, velocity_rad_s=forged(mode, forger.velocity(), n))
                n += 1
        code, stats, err = end_of_run(pr)
        stopped_s = time.monotonic() - start
        assert n > 0, ("nothing forged", code, stats["stop_reason"])
        log = load_log(pr.log)
        if drive == STANDARD and code in (EXIT_DEGRADED, EXIT_FEEDBACK_TIMEOUT):
            # Standard mode: each forged answer in the window of the drive's
            # own makes it ambiguous, so no feedback is taken: the run ends
            # as degraded (rig.max_stale_feedback_ticks, torque off at once)
            # or, as both limits are 300 ms here and the loop has taken no
            # feedback, on the feedback timeout (emergency stop) in the same
            # tick range; a third case, one forged answer alone in a window,
            # is refused as implausible below. The log's position may jump:
            # the handle moved while the loop went without fresh feedback.
            degraded = code == EXIT_DEGRADED
            expected = "consecutive ticks without fresh feedback" if degraded else "feedback timeout"
            assert expected in stats["stop_reason"], stats["stop_reason"]
            assert stats["drive"]["feedback_duplicated"] > 0, stats["drive"]
            assert log.complete and len(log) == stats["ticks"] and not log["ramp"].any()
            stop_kind = "torque_off" if degraded else "emergency_stop"
            assert stats["stop"]["kind"] == stop_kind and stats["stop"]["braking_ticks"] == 0, stats["stop"]
            kind = "degraded"
        else:
            assert code == EXIT_IMPLAUSIBLE, (stats["stop_reason"], err)
            kind = implausible_kind(stats["stop_reason"])
            assert_torque_off_at_once(log, stats)
        if code == EXIT_FEEDBACK_TIMEOUT:
            assert_drive_latched_off(pr, drive)
        else:
            assert_drive_disabled(pr, drive)
        record = drive_record(pr, record_path, coast_s=0.0)
        if drive == STANDARD:
            # The fresh velocities the loop used are the drive's own (the
            # forger copies positions, not velocities), except where a forged
            # answer arrived alone in a SYNC's window, the drive's own late:
            # standard mode takes it (docs/safety.md, what it cannot detect).
            # Seen: 0 such ticks in most runs, 2 in one; a few at most.
            per_rad = _increments_per_rad()
            real = set(np.round(record["velocity_rad_s"] * per_rad).astype(int))
            used = np.round(np.radians(log["xdot_meas"][log["fresh"]]) * per_rad).astype(int)
            forged_used = [int(u) for u in used if u not in real]
            print(f"\nstandard mode: {len(forged_used)} fresh ticks used a forged velocity")
            assert len(forged_used) <= 10, forged_used[:10]
        # The drive never reached its own overspeed (8 rad/s): it stopped
        # because the controller did.
        assert np.abs(record["velocity_rad_s"]).max() < 8.0
        return {
            "forged_frames": forger.sent,
            "forgery_to_exit_ms": 1e3 * stopped_s,
            "refused_as_conflict": float(kind == IMPLAUSIBLE_KINDS[1]),
            "refused_as_inconsistent": float(kind == IMPLAUSIBLE_KINDS[2]),
            "ended_as_degraded": float(kind == "degraded"),
            "peak_speed_rad_s": float(np.abs(record["velocity_rad_s"]).max()),
        }
    finally:
        pr.close()


def scenario_misscaled_velocity(tmp: Path, drive: str = "hi5", scale: float = 1.5) -> dict:
    """A drive whose velocity disagrees with its own position (reported
    ``scale`` times the plant's: a faulty drive, or a master reading the
    wrong velocity unit): the consistency check refuses it as soon as the
    handle moves (exit 5, "velocity inconsistent"), with the torque off at
    once, far below the drive's OVERSPEED; the run never completes."""
    record_path = tmp / "drive_record.npz"
    cfg = stall_tolerant(short_config(gain_s=10.0))
    cfg.rig.drive = drive
    pr = Processes(tmp, cfg, drive_args=["--log", str(record_path), "--velocity-report-scale", str(scale)])
    try:
        time.sleep(0.5)
        pr.start_controller()
        code, stats, err = end_of_run(pr)
        assert code == EXIT_IMPLAUSIBLE, (stats["stop_reason"], err)
        assert implausible_kind(stats["stop_reason"]) == "velocity inconsistent", stats["stop_reason"]
        assert_torque_off_at_once(load_log(pr.log), stats)
        assert_drive_disabled(pr, drive)
        record = drive_record(pr, record_path, coast_s=0.0)
        assert np.abs(record["velocity_rad_s"]).max() < 8.0
        return {"ticks_run": stats["ticks"], "speed_at_stop_rad_s": stats["stop"]["speed_at_stop_rad_s"],
                "peak_speed_rad_s": float(np.abs(record["velocity_rad_s"]).max())}
    finally:
        pr.close()


def scenario_replayed_feedback(tmp: Path, drive: str = "hi5", replay_s: float = 2.0) -> dict:
    """After every fourth real feedback, a third node sends two real
    feedbacks again, exactly as they were: that one (a copy) and the one 100
    feedbacks before it (a late replay). Both are discarded and counted, never used: the run goes
    on with fresh feedback until SIGTERM, and its log never jumps back."""
    pr = rig_processes(tmp, stall_tolerant(short_config(gain_s=10.0)), drive)
    try:
        forger = forging_on_a_running_controller(pr, drive)
        start = time.monotonic()
        n = 0
        while time.monotonic() - start < replay_s and pr.controller.poll() is None:
            event = forger.next_event()
            if event is not None and event[0] == "feedback" and forger.ready():
                # Every fourth feedback: every frame on the bus costs the
                # Python CiA 402 drive time, and on this loaded machine
                # every one replayed made it too late (degraded).
                if n % 4 == 0:
                    forger.replay(0)
                    forger.replay(100)
                n += 1
        if drive == STANDARD and pr.controller.poll() is not None:
            # Standard mode: a replay that reached the controller alone in a
            # SYNC's window (the drive's answer after the drain) passes as the
            # answer (undetectable by the bus: docs/safety.md); physics then
            # refuses the old position or the copy's velocity: the run stops
            # as implausible, the torque off at once, never acting on it.
            code, stats, err = end_of_run(pr)
            assert code == EXIT_IMPLAUSIBLE, (stats["stop_reason"], err)
            assert implausible_kind(stats["stop_reason"]) in (IMPLAUSIBLE_KINDS[0], IMPLAUSIBLE_KINDS[2])
            assert_torque_off_at_once(load_log(pr.log), stats)
            return {"replayed_frames": forger.sent, "discarded": stats["can"]["feedback_discarded"],
                    "stopped_as_implausible": 1.0}
        assert pr.controller.poll() is None, pr.controller.stderr.read()
        pr.controller.send_signal(signal.SIGTERM)
        code, stats, err = end_of_run(pr)
        assert code == 1 and stats["stop_reason"].startswith("signal SIGTERM"), (stats["stop_reason"], err)
        can_ = stats["can"]
        assert forger.sent > 100, forger.sent
        assert can_["implausible_feedback"] == 0, can_
        # Every replayed frame the controller received was discarded (the
        # loopback may drop a few under load: bus_kernel_dropped). Standard
        # mode: a replay after a SYNC's answer is a duplicate (discarded,
        # and that SYNC's answer not used); one that arrives after the next
        # SYNC, before its answer, answers it (undetectable; then the real
        # answer is the duplicate), so the count is the same.
        assert can_["feedback_discarded"] >= forger.sent - can_["bus_kernel_dropped"] - 10, (forger.sent, can_)
        if drive == STANDARD:
            assert stats["drive"]["freshness"] == "standard"
            # A replay received before the next SYNC but read after it is late, not duplicated.
            dropped = stats["drive"]["feedback_duplicated"] + stats["drive"]["feedback_late"]
            assert dropped >= forger.sent - can_["bus_kernel_dropped"] - 10, stats["drive"]
        log = load_log(pr.log)
        assert log.complete
        running = ~log["ramp"]
        assert np.abs(np.diff(log["x"][running])).max() < np.degrees(0.05)
        return {"replayed_frames": forger.sent, "discarded": can_["feedback_discarded"],
                "missing_feedback_fraction": can_["missing_feedback"] / stats["ticks"], "stopped_as_implausible": 0.0}
    finally:
        pr.close()


# --- 3. degraded runs ---------------------------------------------------------


def assert_drive_off(pr: Processes, drive: str) -> None:
    """The drive applies no torque: Hi5 DISABLED or FAULT; CiA 402 any state
    but OperationEnabled."""
    if drive == "hi5":
        assert drive_state(pr).state in (State.DISABLED, State.FAULT)
    else:
        assert cia_state(cia_statusword(pr)) != "OperationEnabled"


def scenario_stalled_drive(tmp: Path, drive: str = "hi5", stall_s: float = 0.25) -> dict:
    """The drive stalls (SIGSTOP for ``stall_s``): ticks lose their fresh
    feedback; past rig.max_stale_feedback_ticks (its default, 100) the run
    ends as "degraded", exit 6, says why, and turns the torque off at once
    (no braking on feedback it no longer has), before the feedback timeout
    (300 ms here). The drive, resumed, may find its own 200 ms watchdog
    expired (FAULT) or take the disable first: either way it applies no
    torque. A run that this loaded machine's own stalls end so before the
    drive is stopped takes the same path and is reported
    (``before_the_stall``)."""
    cfg = stall_tolerant(short_config(gain_s=10.0))
    # The threshold under test; the missing fraction and the estimator
    # errors are lifted (stall_tolerant): this loaded machine's CiA 402
    # runs lose up to half their feedbacks on their own.
    cfg.rig.max_stale_feedback_ticks = 100
    pr = rig_processes(tmp, cfg, drive)
    try:
        pr.start_controller()
        wait_running(pr, drive=drive)
        time.sleep(1.0)
        start = time.monotonic()
        before_the_stall = pr.controller.poll() is not None
        disabled_at = None
        if not before_the_stall:
            _drain(pr)
            pr.drive.send_signal(signal.SIGSTOP)
            try:
                # The controller's disable, seen on the bus while the drive is stopped.
                disabled_at = first_command(pr, drive, stall_s, emergency=False)
                time.sleep(max(start + stall_s - time.monotonic(), 0.0))
            finally:
                pr.drive.send_signal(signal.SIGCONT)
        code, stats, err = end_of_run(pr)
        assert code == EXIT_DEGRADED, (stats["stop_reason"], err)
        reason = stats["stop_reason"]
        assert reason.startswith("degraded: ") and "consecutive ticks without fresh feedback" in reason, reason
        assert "rig.max_stale_feedback_ticks" in reason and reason.endswith("(torque off at once, drive disabled)")
        assert "degraded" in err and stats["exit_code"] == EXIT_DEGRADED
        log = load_log(pr.log)
        assert log.complete and log.meta["end"]["stop_reason"] == reason
        assert not log["ramp"].any() and stats["stop"]["kind"] == "torque_off"
        assert_drive_off(pr, drive)
        return {"longest_stale_run": stats["longest_stale_run"], "before_the_stall": float(before_the_stall),
                "stall_to_disable_ms": math.nan if disabled_at is None else 1e3 * (disabled_at - start)}
    finally:
        pr.close()


#: The bus faults run on every profile, the standard CiA 402 drive too
#: (replayed feedback has its own outcome there when a replay lands alone in
#: a SYNC's window: scenario_replayed_feedback; docs/safety.md's fault
#: table): what each shows, its scenario, and the line it prints.
BUS_FAULTS = {
    "a_second_controller_refuses_to_start_and_the_first_runs_on": (
        scenario_second_controller, lambda f: f"second controller refused after {f['refused_after_ms']:.0f} ms"),
    "a_foreign_command_frame_stops_a_running_controller_with_an_emergency_stop": (
        scenario_foreign_command,
        lambda f: f"foreign command -> emergency stop on the bus after {f['emergency_stop_after_ms']:.1f} ms"),
    "a_forged_feedback_jump_turns_the_torque_off_at_once": (
        scenario_forged_jump, lambda f: f"forged 0.5 rad jump -> drive disabled after {f['disabled_after_ms']:.0f} ms "
                                        f"(refused as a position step: {bool(f['refused_as_step'])})"),
    "replayed_and_copied_feedback_is_discarded_counted_and_never_used": (
        scenario_replayed_feedback, lambda f: f"replayed feedback: {f}"),
    "a_stalled_drive_ends_the_run_as_degraded_with_the_torque_off": (
        scenario_stalled_drive, lambda f: f"stalled drive: {f}"),
}


@pytest.mark.parametrize("drive", [*PROFILES, STANDARD])
@pytest.mark.parametrize("fault", BUS_FAULTS)
def test_a_bus_fault_ends_safely(tmp_path, fault, drive):
    scenario, line = BUS_FAULTS[fault]
    print("\n" + line(scenario(tmp_path, drive)))


@pytest.mark.parametrize("drive", [*PROFILES, STANDARD])
@pytest.mark.parametrize("mode, race", [("scaled", False), ("doubled", False), ("oscillating", False),
                                        ("doubled", True)])
def test_a_forged_velocity_stops_the_run_before_the_drives_overspeed(tmp_path, drive, mode, race):
    figures = scenario_forged_velocity(tmp_path, drive, mode, race)
    print(f"\nforged velocity ({mode}, {'racing the drive' if race else 'after the drive'}): {figures}")


@pytest.mark.parametrize("drive", PROFILES)
@pytest.mark.parametrize("scale", [1.5, 0.5])
def test_a_velocity_inconsistent_with_the_position_is_refused_before_overspeed(tmp_path, drive, scale):
    figures = scenario_misscaled_velocity(tmp_path, drive, scale)
    print(f"\nvelocity reported x{scale}: {figures}")


# --- 4. the controlled stop ----------------------------------------------------

#: The tick of the gain phase's first target step: the rounded square
#: (period 4 s) crosses zero at 2 s, its steepest (docs/safety.md).
STEP_TICK = 2000


def step_config(amplitude_deg: float, virtual_human: bool) -> ScenarioConfig:
    """A 4 s gain phase (then 0.5 s phases) whose rounded squares have
    ``amplitude_deg``, the virtual human on or off."""
    cfg = stall_tolerant(short_config(gain_s=4.0, other_s=0.5))
    phase = cfg.phases[0]
    for target in (phase.robot_target[0], phase.partner_target[0]):
        target.amplitude = amplitude_deg
    cfg.rig.virtual_human = virtual_human
    return cfg


def tick0_time(pr: Processes, drive: str, timeout: float = 20.0) -> float:
    """Monotonic time of the loop's tick 0, seen on the bus (to ~1 ms): Hi5
    the first TorqueCommand of sequence 0; CiA 402 the first TPDO1 reporting
    OperationEnabled (tick 0 follows the enable's answer at once)."""
    torque_id = p.frame_id("TorqueCommand", NODE)
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        msg = pr.monitor.recv(timeout=0.05)
        if msg is None:
            assert pr.controller.poll() is None, pr.controller.stderr.read()
            continue
        now = time.monotonic()
        if drive == "hi5" and msg.arbitration_id == torque_id:
            if p.TorqueCommand.decode(bytes(msg.data), msg.arbitration_id).sequence == 0:
                return now
        elif drive == "cia402" and msg.arbitration_id == TPDO1 and len(msg.data) >= 2:
            if cia_state(int.from_bytes(msg.data[0:2], "little")) == "OperationEnabled":
                return now
    raise AssertionError("the loop did not start")


def drive_record(pr: Processes, path: Path, coast_s: float = 0.5) -> dict[str, np.ndarray]:
    """The drive's own record of the handle (``--log``): the drive keeps
    simulating the handle for ``coast_s`` after the controller exited, then
    is stopped (SIGTERM saves the record). ``t`` is monotonic time."""
    time.sleep(coast_s)
    pr.drive.send_signal(signal.SIGTERM)
    pr.drive.wait(timeout=10)
    data = dict(np.load(path))
    data["t"] = data["t_s"] + float(data["t0_monotonic_s"])
    return data


def stop_figures(record: dict[str, np.ndarray], log, stats: dict, t_request: float, drive: str) -> dict:
    """The handle's motion after a stop requested at ``t_request``
    (monotonic), on the drive's record: travel (the largest distance from
    where the handle was at the request), its speed then and its peak
    after, and the same from the stop's first brake command (the request
    reaches the loop at its next tick: a command of the controller sent
    before may still be applied after it, more when the drive lags:
    ``controller_steps_after_request``); the braking ticks without fresh
    feedback (zero torque, the handle coasts: ``stale_braking_ticks``), from
    the controller's log."""
    t, x, v = record["t"], record["position_rad"], record["velocity_rad_s"]
    at = int(np.searchsorted(t, t_request, side="right")) - 1
    assert at >= 0, "no record before the request"
    after = slice(at + 1, None)
    # The first brake command's row: commanded rows are the loop's ticks in
    # order; the last one is the stop's zero command (Hi5: tick `ticks`) or
    # the last tick (CiA 402: its shutdown SYNC steps nothing).
    commanded = np.flatnonzero(~record["free"])
    k_stop = int(np.argmax(log["ramp"]))
    last_tick = stats["ticks"] if drive == "hi5" else stats["ticks"] - 1
    brake_row = int(commanded[len(commanded) - 1 - (last_tick - k_stop)])
    if drive == "hi5":
        assert record["sequence"][brake_row] == k_stop % 256, "the record and the log disagree"
    # The state the brake acts on is the one before its step.
    brake_from = slice(brake_row, None)
    v_brake = abs(v[brake_row - 1])
    disabled = int(commanded[-1])
    braking = log.data[log["ramp"]]
    stale = ~braking["fresh"].astype(bool)
    # A tick without fresh feedback commands zero: the handle coasts for a
    # step at no more than the newest feedback's speed (the brake never
    # speeds it up).
    rad_per_unit = log.meta["loop"]["rad_per_unit"]
    coast_allowance_rad = float(np.abs(braking["xdot"][stale]).sum() * rad_per_unit * log.meta["loop"]["dt_s"])
    return {
        "controller_steps_after_request": int(np.count_nonzero((commanded > at) & (commanded < brake_row))),
        "stale_braking_ticks": int(np.count_nonzero(stale)),
        "coast_allowance_rad": coast_allowance_rad,
        "request_after_step_ms": float(k_stop - STEP_TICK),
        "speed_at_request_rad_s": float(abs(v[at])),
        "peak_speed_after_request_rad_s": float(np.abs(v[after]).max()),
        "speed_at_brake_rad_s": float(v_brake),
        "peak_speed_after_brake_rad_s": float(np.abs(v[brake_from]).max()),
        "rise_after_request_rad_s": float(np.abs(v[after]).max() - abs(v[at])),
        "rise_after_brake_rad_s": float(np.abs(v[brake_from]).max() - v_brake),
        "travel_rad": float(np.abs(x[after] - x[at]).max()),
        "travel_from_brake_rad": float(np.abs(x[brake_from] - x[brake_row - 1]).max()),
        "travel_brake_to_disable_rad": float(np.abs(x[brake_row:disabled + 1] - x[brake_row - 1]).max()),
        "braking_ms": float(1e3 * (t[disabled] - t[brake_row])),
        "speed_at_disable_rad_s": float(abs(v[disabled])),
        "coast_after_disable_rad": float(abs(x[-1] - x[disabled])),
        "brake_end": stats["stop"]["brake_end"],
    }


def clean_stop(f: dict) -> bool:
    """The loop ran the stop as designed: it reacted within a tick on the
    drive's clock and had fresh feedback on every braking tick."""
    return f["stale_braking_ticks"] == 0 and f["controller_steps_after_request"] <= 1


def scenario_controlled_stop(tmp: Path, drive: str = "hi5", amplitude_deg: float = 8.0, virtual_human: bool = True,
                             after_step_ms: float = 10.0, sig: int = signal.SIGTERM) -> dict:
    """A stop requested at the worst moment, ``after_step_ms`` after a
    target step (the controller pushes hardest): the controlled stop brakes
    the handle to rest and disables the drive; measured on the drive's own
    record of the handle."""
    cfg = step_config(amplitude_deg, virtual_human)
    cfg.rig.drive = drive
    tmp.mkdir(parents=True, exist_ok=True)
    record_path = tmp / "drive_record.npz"
    pr = Processes(tmp, cfg, drive_args=["--log", str(record_path)])
    try:
        time.sleep(0.5)
        _drain(pr)
        pr.start_controller()
        t0 = tick0_time(pr, drive)
        wait = t0 + (STEP_TICK + after_step_ms) * 1e-3 - time.monotonic()
        assert wait > 0, "tick 0 was seen too late"
        time.sleep(wait)
        pr.controller.send_signal(sig)
        t_request = time.monotonic()
        code, stats, err = end_of_run(pr)
        name = signal.Signals(sig).name
        assert code == 1, (stats["stop_reason"], err)
        assert stats["stop_reason"] == f"signal {name} (controlled stop, drive disabled)", stats["stop_reason"]
        assert stats["stop"]["kind"] == "controlled" and stats["stop"]["brake_end"] in ("at_rest", "time_limit")
        log = load_log(pr.log)
        assert log.complete and log.meta["end"]["stop_reason"] == stats["stop_reason"]
        # Each braking tick: zero torque without fresh feedback, else a
        # torque against the measured velocity.
        braking = log.data[log["ramp"]]
        fresh = braking["fresh"].astype(bool)
        assert np.all(braking["torque_nm"][~fresh] == 0.0)
        assert np.all(braking["torque_nm"][fresh] * braking["xdot"][fresh] <= 0.0)
        assert_drive_disabled(pr, drive)
        record = drive_record(pr, record_path, coast_s=0.2)
        figures = stop_figures(record, log, stats, t_request, drive)
        # The brake only takes energy out: never faster than when it began
        # (the plant's exact velocity; 1e-9 for rounding), however late the
        # feedback.
        assert figures["rise_after_brake_rad_s"] <= 1e-9, figures
        return figures
    finally:
        pr.close()


@pytest.mark.parametrize("drive", PROFILES)
@pytest.mark.parametrize("amplitude_deg, virtual_human", [(8.0, True), (30.0, False)])
def test_a_stop_just_after_a_target_step_brakes_the_handle_to_rest(tmp_path, drive, amplitude_deg, virtual_human):
    """The issue's worst cases: 10 ms after a target step, the default 8 deg
    with the virtual human, and 30 deg without it (a person's setting, and
    nobody holding the handle). In every stop the handle never speeds up
    once the brake acts, and moves under the brake at most 0.05 rad plus
    the coasting of the ticks without fresh feedback (zero torque). In a
    stop the loop ran as designed (it reacted within a tick on the drive's
    clock and had fresh feedback on every braking tick) the handle moves at
    most 0.05 rad after the request (the goal, coasting after the disable
    included) and is at rest at the disable; this loaded machine's stalls
    (a drive late by tens of ms) break that now and then, so up to 3
    attempts are made for one (docs/safety.md has the figures of every
    stop, clean or not: scripts/measure_safety.py)."""
    clean = None
    for attempt in range(3):
        f = scenario_controlled_stop(tmp_path / str(attempt), drive, amplitude_deg, virtual_human)
        print(f"\n{drive} {amplitude_deg} deg, virtual human {virtual_human}, attempt {attempt}: {f}")
        # The scenario checks the brake never sped the handle up, and zero
        # torque on the ticks without fresh feedback. The brake's own travel is within the goal; beyond it only the
        # coasting of the ticks without fresh feedback.
        assert f["travel_brake_to_disable_rad"] <= 0.05 + f["coast_allowance_rad"], f
        if clean_stop(f):
            clean = f
            break
    if clean is None:
        print("no stop of the 3 had fresh feedback on every braking tick and a one-tick reaction "
              "(this machine's load): the goal checked with the coasting allowance only")
        return
    assert clean["brake_end"] == "at_rest" and clean["speed_at_disable_rad_s"] < 0.01, clean
    assert clean["travel_rad"] <= 0.05, clean


#: The signals that stop the run as SIGTERM does (crates/sensaug-rt/src/os.rs).
STOP_SIGNALS = [signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT, signal.SIGUSR1, signal.SIGUSR2,
                signal.SIGPIPE]


def scenario_signal(tmp: Path, drive: str = "hi5", sig: int = signal.SIGTERM, session_gone: bool = False) -> dict:
    """A terminating signal mid-run: the controlled stop, the drive
    disabled, the statistics and the log's end line written, exit 1, the
    stop reason naming the signal. With ``session_gone`` the controller's
    stdout and stderr are closed first (a dropped SSH session: its end
    prints fail), which changes none of that."""
    pr = rig_processes(tmp, stall_tolerant(short_config(gain_s=10.0)), drive)
    try:
        pr.start_controller()
        wait_running(pr, drive=drive)
        time.sleep(0.5)
        if session_gone:
            pr.controller.stdout.close()
            pr.controller.stderr.close()
        _drain(pr)
        sent = time.monotonic()
        pr.controller.send_signal(sig)
        disabled_at = first_command(pr, drive, 5.0, emergency=False)
        assert disabled_at is not None, "no disable within 5 s"
        code = pr.wait_controller(timeout=30)
        stats = stats_of(pr)
        reason = f"signal {signal.Signals(sig).name} (controlled stop, drive disabled)"
        assert code == 1 and stats["exit_code"] == 1, (code, stats["stop_reason"])
        assert stats["stop_reason"] == reason and stats["stop"]["kind"] == "controlled", stats["stop"]
        log = load_log(pr.log)
        assert log.complete and log.meta["end"]["stop_reason"] == reason and log.meta["end"]["exit_code"] == 1
        assert len(log) == stats["ticks"]
        assert_drive_disabled(pr, drive)
        return {"disabled_after_ms": 1e3 * (disabled_at - sent)}
    finally:
        pr.close()


@pytest.mark.parametrize("sig", STOP_SIGNALS, ids=lambda s: signal.Signals(s).name)
def test_every_terminating_signal_stops_with_the_controlled_stop(tmp_path, sig):
    figures = scenario_signal(tmp_path, "hi5", sig)
    print(f"\n{signal.Signals(sig).name}: drive disabled {figures['disabled_after_ms']:.0f} ms after it")


@pytest.mark.parametrize("drive", PROFILES)
def test_sighup_of_a_dropped_session_stops_safely_and_reports(tmp_path, drive):
    figures = scenario_signal(tmp_path, drive, signal.SIGHUP, session_gone=True)
    print(f"\nSIGHUP, session gone: drive disabled {figures['disabled_after_ms']:.0f} ms after it")


# --- 5. outputs ----------------------------------------------------------------


@pytest.mark.parametrize("drive", PROFILES)
@pytest.mark.parametrize("which", ["log", "stats"])
def test_an_unwritable_output_refuses_to_start_and_never_enables_the_drive(tmp_path, which, drive):
    pr = rig_processes(tmp_path, short_config(), drive)
    try:
        blocker = tmp_path / "not_a_dir"
        blocker.write_text("a file, so nothing can be created under it (even by root)\n")
        if which == "log":
            pr.log = blocker / "log.csv"
        else:
            pr.stats = blocker / "stats.json"
        proc = pr.start_controller()
        code = pr.wait_controller(timeout=30)
        err = proc.stderr.read()
        assert code == EXIT_SETUP, err
        assert f"rig.{which}: cannot write" in err and f"--{which}" in err, err
        # Nothing for the drive came from the controller; the drive stayed disabled.
        if drive == "hi5":
            commands = [d for d in pr.frames(0.5) if d.name in ("SetState", "TorqueCommand")]
        else:
            commands = [m for m in cia_frames(pr, 0.5) if m.arbitration_id in COMMAND_IDS["cia402"]]
        assert commands == []
        assert_drive_disabled(pr, drive)
        assert not list(tmp_path.glob("*.partial"))
    finally:
        pr.close()


@pytest.mark.parametrize("drive", PROFILES)
def test_an_old_log_is_kept_when_the_run_never_starts(tmp_path, drive):
    """No drive on the bus: set-up times out (exit 2) and leaves the old log
    and statistics as they were."""
    from sensaug_bridge.udp_bus import free_port

    toml = tmp_path / "trial.toml"
    cfg = short_config()
    cfg.rig.drive = drive
    cfg.to_toml(toml)
    log, stats = tmp_path / "log.csv", tmp_path / "stats.json"
    log.write_text("the previous run's log\n")
    stats.write_text("{}\n")
    proc = subprocess.run(
        [str(rig.find_binary()), str(toml), "--can", f"udp:{free_port()}", "--log", str(log), "--stats", str(stats)],
        capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == EXIT_SETUP, proc.stderr
    assert "is the drive on the bus?" in proc.stderr
    assert log.read_text() == "the previous run's log\n" and stats.read_text() == "{}\n"
    assert sorted(f.name for f in tmp_path.iterdir()) == ["log.csv", "stats.json", "trial.toml"]


def _file_size_limit(limit: int):
    def pre() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return pre


def scenario_log_failure(tmp: Path, limit_bytes: int = 1_000_000, drive: str = "hi5") -> dict:
    """A full disk, as a file-size limit on the controller (RLIMIT_FSIZE):
    the write fails (EFBIG), the loop ramps down and stops (exit 7); the log
    holds a readable prefix from tick 0."""
    pr = rig_processes(tmp, stall_tolerant(short_config(gain_s=10.0)), drive)
    try:
        pr.controller = controller(pr, pr.log, pr.stats, preexec_fn=_file_size_limit(limit_bytes))
        code, stats, err = end_of_run(pr)
        assert code == EXIT_LOG, (stats["stop_reason"], err)
        assert stats["stop_reason"].startswith("log write failed"), stats["stop_reason"]
        assert stats["log_write_errors"] >= 1 and "too large" in stats["log_error"].lower(), stats["log_error"]
        assert stats["ticks"] < 10_000
        log = load_log(pr.log)
        # The failed write may have put some whole lines before the partial one.
        assert not log.complete and 0 < stats["records_written"] <= len(log)
        assert len(log) <= stats["records_written"] + stats["log_records_lost"]
        np.testing.assert_array_equal(log["tick"], np.arange(len(log)))
        assert pr.log.stat().st_size <= limit_bytes
        assert_drive_disabled(pr, drive)
        return {"records_kept": len(log), "ticks_after_last_record": stats["ticks"] - len(log)}
    finally:
        pr.close()


@pytest.mark.parametrize("drive", PROFILES)
def test_a_log_write_failure_stops_with_the_controlled_stop_and_keeps_what_was_written(tmp_path, drive):
    figures = scenario_log_failure(tmp_path, drive=drive)
    print(f"\nlog failed: {figures}")


# --- 6. the first tick after the enable ------------------------------------------


@pytest.mark.parametrize("drive", PROFILES)
def test_the_drive_is_fed_from_the_enable_to_the_first_tick(tmp_path, drive):
    """The statistics report both gaps the drive's watchdog sees at the
    start; each is far below the watchdog (50 ms) on an idle machine; here
    only that they are measured and below the watchdog we ran with."""
    pr = rig_processes(tmp_path, stall_tolerant(short_config(gain_s=0.5, other_s=0.2)), drive)
    try:
        pr.start_controller()
        code, stats, err = end_of_run(pr)
        assert code == 0, err
        gap = stats["start"]
        assert 0 <= gap["enable_to_first_command_us"] < 200e3, gap
        assert 0 <= gap["first_command_to_tick0_us"] < 200e3, gap
        print(f"\nstart gaps: {gap}")
    finally:
        pr.close()


# --- 6. the drive's own reports: resets, EMCYs, faults, heartbeat, 0x6072 (issue 17) ---------

#: sensaug-rt's exit code for a drive reset (docs/realtime.md).
EXIT_DRIVE_RESET = 8

_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)  # Linux's value; Python does not name it


class KernelTimedFrames:
    """Every frame on a loopback bus port with the kernel's time of its
    arrival (``SO_TIMESTAMPNS``: stamped when the sender's datagram is
    queued, so it is the send time on loopback), read by a thread: the
    reaction times below are differences of these stamps, free of the
    reading process's own scheduling."""

    def __init__(self, port: int) -> None:
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self._sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
        self._sock.bind((BROADCAST_ADDR, port))
        self._sock.settimeout(0.05)
        self._stop = threading.Event()
        self.frames: list[tuple[float, int, bytes]] = []
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                datagram, ancillary, _, _ = self._sock.recvmsg(64, 64)
            except socket.timeout:
                continue
            frame = unpack_frame(datagram)
            stamps = [d for level, kind, d in ancillary if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS]
            if isinstance(frame, str) or not stamps:
                continue
            sec, ns = struct.unpack("qq", stamps[0][:16])
            self.frames.append((sec + ns * 1e-9, frame.arbitration_id, bytes(frame.data)))

    def first(self, pred, after: float = 0.0) -> float | None:
        """Kernel time of the first frame ``pred(can_id, data)`` after ``after``."""
        return next((t for t, i, d in list(self.frames) if t > after and pred(i, d)), None)

    def last(self, pred, before: float) -> float | None:
        """Kernel time of the last frame ``pred(can_id, data)`` before ``before``."""
        return next((t for t, i, d in reversed(list(self.frames)) if t < before and pred(i, d)), None)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self._sock.close()


def _hi5(can_id: int, data: bytes) -> p.Decoded | None:
    try:
        return p.decode(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
    except p.ProtocolError:
        return None


def is_reset_report(drive: str):
    """``pred(can_id, data)`` for the drive's report of a reset: CiA 402 its
    boot-up message (0x701, NMT state 0x00); Hi5 a Fault or Heartbeat frame
    with state BOOT."""
    if drive == "cia402":
        return lambda i, d: i == 0x700 + NODE and d == b"\x00"

    def hi5(i: int, d: bytes) -> bool:
        m = _hi5(i, d)
        return m is not None and m.name in ("Fault", "Heartbeat") and m.message.state == State.BOOT

    return hi5


def is_emergency_stop(drive: str):
    """``pred(can_id, data)`` for the controller's emergency stop: CiA 402
    controlword quick stop; Hi5 EmergencyStop."""
    if drive == "cia402":
        return lambda i, d: i == RPDO1 and len(d) >= 2 and int.from_bytes(d[:2], "little") == CW_QUICK_STOP
    return lambda i, d: (m := _hi5(i, d)) is not None and m.name == "EmergencyStop"


def wait_for(frames: KernelTimedFrames, pred, after: float = 0.0, seconds: float = 5.0) -> float | None:
    """Kernel time of the first frame ``pred`` after ``after``, waiting up to ``seconds``."""
    end = time.monotonic() + seconds
    while (t := frames.first(pred, after)) is None and time.monotonic() < end:
        time.sleep(0.01)
    return t


def scenario_drive_reset(tmp: Path, drive: str = "hi5", how: str = "restart") -> dict:
    """The drive resets mid-run (``restart``: SIGUSR1 to the virtual drive,
    a power glitch: CiA 402 boot-up, pre-operational, SwitchOnDisabled; Hi5
    BOOT then DISABLED), or a third node forges its reset report
    (``forged``: the boot-up message; a Fault frame saying BOOT): the
    controller stops at once with an emergency stop and "drive reset"
    (exit 8), never waiting for the feedback timeout."""
    pr = rig_processes(tmp, stall_tolerant(short_config(gain_s=10.0)), drive)
    frames = KernelTimedFrames(pr.port)
    try:
        pr.start_controller()
        wait_running(pr, drive=drive)
        acted = time.time()  # the kernel's stamps are CLOCK_REALTIME too
        if how == "restart":
            pr.drive.send_signal(signal.SIGUSR1)
        elif drive == "cia402":
            pr.monitor.send(can.Message(arbitration_id=0x700 + NODE, data=b"\x00", is_extended_id=False))
        else:
            pr.monitor.send(p.Fault(State.BOOT, FaultFlag.NONE, 0).encode(NODE))
        reported = wait_for(frames, is_reset_report(drive), after=acted)
        assert reported is not None, "no reset report on the bus"
        stopped = wait_for(frames, is_emergency_stop(drive), after=reported)
        assert stopped is not None, "no emergency stop after the reset report"
        code, stats, err = end_of_run(pr)
        assert code == EXIT_DRIVE_RESET and stats["exit_code"] == EXIT_DRIVE_RESET, (stats["stop_reason"], err)
        reason = stats["stop_reason"]
        assert reason.startswith("drive reset: ") and "emergency stop sent" in reason, reason
        assert ("boot-up message" if drive == "cia402" else "reports Boot") in reason, reason
        assert reason in err
        # Long before the feedback timeout (300 ms here): the tick after the report.
        log = load_log(pr.log)
        assert log.complete and len(log) == stats["ticks"]
        if how == "restart" and drive == "cia402":
            assert_drive_disabled(pr, drive)  # rebooted: SwitchOnDisabled, pre-operational
        elif how == "restart":
            assert_drive_latched_off(pr, drive)  # the emergency stop latched FAULT
        return {"report_to_emergency_stop_ms": 1e3 * (stopped - reported), "ticks": stats["ticks"]}
    finally:
        frames.close()
        pr.close()


@pytest.mark.parametrize("how", ["restart", "forged"])
@pytest.mark.parametrize("drive", PROFILES)
def test_a_drive_reset_stops_the_run_at_once_with_its_own_reason(tmp_path, drive, how):
    figures = scenario_drive_reset(tmp_path, drive, how)
    print(f"\n{drive} {how}: reset report -> emergency stop on the bus in {figures['report_to_emergency_stop_ms']:.1f} ms")


def third_canopen_node(pr: Processes):
    """python-canopen as a third node on the processes' bus: a network on
    its own socket with the drive as a RemoteNode (the project's EDS)."""
    import canopen
    from sensaug_bridge.virtual_cia402 import EDS_PATH

    network = canopen.Network()
    network.connect(interface="sensaug_udp", channel=pr.port)
    node = canopen.RemoteNode(NODE, str(EDS_PATH))
    network.add_node(node)
    node.sdo.RESPONSE_TIMEOUT = 2.0  # the Python drive may answer late on a loaded VM
    node.nmt.wait_for_heartbeat(timeout=10.0)  # the drive is up
    return network, node


@pytest.mark.parametrize("max_torque", [32767, 50])
def test_a_max_torque_another_node_wrote_is_refused_at_set_up(tmp_path, max_torque):
    """Before the run a third node (python-canopen's SDO client) writes the
    drive's max torque 0x6072: 32767 (32.8 N m, 11x the configured 3 N m) or
    50 (0.05 N m). The controller reads it at set-up, refuses to start
    (exit 2) naming 0x6072, both values and the fix, and never enables the
    drive: no RPDO1 and no SYNC on the bus, the drive still SwitchOnDisabled
    in PRE-OPERATIONAL."""
    pr = rig_processes(tmp_path, stall_tolerant(short_config()), "cia402")
    network, node = third_canopen_node(pr)
    try:
        node.sdo["Max torque"].raw = max_torque
        assert node.sdo["Max torque"].raw == max_torque
        _drain(pr)
        proc = pr.start_controller()
        code = pr.wait_controller(timeout=30)
        err = proc.stderr.read()
        assert code == EXIT_SETUP, err
        for part in ["0x6072", f"is {max_torque} per-mille", "rig.torque_limit_nm is 3 N m", "3000 per-mille",
                     "not starting"]:
            assert part in err, (part, err)
        sent = list(cia_frames(pr, 0.3))  # every frame since the controller started
        assert not [m for m in sent if m.arbitration_id in (RPDO1, SYNC)], "the controller cycled the drive"
        assert not [m for m in sent if m.arbitration_id == NMT], "the controller sent an NMT command"
        assert cia_state(cia_statusword(pr)) == "SwitchOnDisabled"
        assert node.nmt.wait_for_heartbeat(timeout=1.0) == "PRE-OPERATIONAL"
    finally:
        network.disconnect()
        pr.close()


def test_emcy_warnings_and_forged_emcys_are_listed_with_code_register_and_time(tmp_path):
    """A third node sends EMCYs built by python-canopen's EmcyProducer while
    the drive runs normally: a temperature warning (0x4210, register 0x09)
    and a forged overspeed (0x8400, register 0x01). The statusword stays
    OperationEnabled, so the run goes on (only a latched Fault stops it);
    both are in the statistics (code, error register, manufacturer bytes,
    time after tick 0, tick) and one line each on stderr."""
    import canopen

    cfg = stall_tolerant(short_config(gain_s=1.0, other_s=0.5))
    pr = rig_processes(tmp_path, cfg, "cia402")
    network, _ = third_canopen_node(pr)
    try:
        pr.start_controller()
        wait_running(pr, drive="cia402")
        emcy = canopen.emcy.EmcyProducer(0x080 + NODE)
        emcy.network = network
        emcy.send(0x4210, 0x09, b"\x01\x02")
        time.sleep(0.2)
        emcy.send(0x8400, 0x01)
        code, stats, err = end_of_run(pr)
        assert code == 0 and stats["stop_reason"] == "completed", (stats["stop_reason"], err)
        listed = stats["drive"]["emcy"]
        assert stats["drive"]["emcy_received"] == 2 == len(listed), stats["drive"]
        warning, forged = listed
        assert (warning["code"], warning["error_register"], warning["manufacturer"]) == ("0x4210", "0x09", "0102000000")
        assert warning["meaning"] == "temperature"
        assert (forged["code"], forged["error_register"]) == ("0x8400", "0x01")
        assert 0 < warning["t_s"] < forged["t_s"] <= stats["ticks"] * 1e-3
        assert forged["tick"] == pytest.approx(forged["t_s"] * 1e3, abs=1)
        assert "drive EMCY 0x4210 (temperature), error register 0x09" in err, err
        assert "drive EMCY 0x8400 (velocity speed controller (overspeed)), error register 0x01" in err, err
    finally:
        network.disconnect()
        pr.close()


@pytest.mark.parametrize("drive", PROFILES)
def test_a_latched_drive_fault_stops_the_run_with_the_profiles_own_code(tmp_path, drive):
    """The drive's own overspeed limit set low (--max-velocity 0.05 rad/s):
    it latches its fault at the first fast move; the controller stops at once
    and says why in the drive's terms: CiA 402 the EMCY code and error
    register (0x8400, 0x01), Hi5 its fault flags (OVERSPEED), exit 1. The
    log says so in the profile-neutral status: every row logged "enabled"
    (code 2), the end line's drive_status "fault"."""
    cfg = stall_tolerant(short_config(gain_s=10.0))
    cfg.rig.drive = drive
    pr = Processes(tmp_path, cfg, drive_args=["--max-velocity", "0.05"])
    try:
        time.sleep(0.5)
        pr.start_controller()
        code, stats, err = end_of_run(pr)
        reason = stats["stop_reason"]
        assert code == 1 and reason.startswith("drive fault: "), (reason, err)
        if drive == "cia402":
            assert "CiA 402 Fault, EMCY 0x8400 (velocity speed controller (overspeed)), error register 0x01" in reason
            assert stats["drive"]["emcy"][0]["code"] == "0x8400"
            assert "FaultFlags" not in reason
        else:
            assert "Hi5 FAULT" in reason and "OVERSPEED" in reason, reason
        log = load_log(pr.log)
        assert len(log) == stats["ticks"] > 0
        assert set(np.unique(log["drive_state"])) == {2}, np.unique(log["drive_state"])
        assert log.meta["end"]["drive_status"] == "fault", log.meta["end"]
        print(f"\n{drive}: {reason} at tick {stats['ticks']}")
    finally:
        pr.close()


def scenario_heartbeat_lost(tmp: Path, drive: str = "cia402") -> dict:
    """The drive process frozen (SIGSTOP: no heartbeat, no TPDO) with the
    feedback timeout at 300 ms and rig.cia402.heartbeat_timeout_ms at its
    default 100: the heartbeat consumer stops the run first, with an
    emergency stop, "the drive's heartbeat lost" (exit 1). Measured on the
    bus from the drive's last heartbeat to the quick stop."""
    cfg = stall_tolerant(short_config(gain_s=10.0))
    cfg.rig.cia402.heartbeat_timeout_ms = 100
    pr = rig_processes(tmp, cfg, drive)
    frames = KernelTimedFrames(pr.port)
    try:
        pr.start_controller()
        wait_running(pr, drive=drive)
        acted = time.time()
        pr.drive.send_signal(signal.SIGSTOP)
        try:
            stopped = wait_for(frames, is_emergency_stop(drive), after=acted, seconds=3.0)
            code, stats, err = end_of_run(pr)
        finally:
            pr.drive.send_signal(signal.SIGCONT)
        assert stopped is not None, "no quick stop within 3 s"
        reason = stats["stop_reason"]
        assert code == 1 and reason.startswith("drive fault: the drive's heartbeat lost"), (reason, err)
        assert "100 ms" in reason and "rig.cia402.heartbeat_timeout_ms" in reason, reason
        last_beat = frames.last(lambda i, d: i == 0x700 + NODE, before=stopped)
        last_tpdo = frames.last(lambda i, d: i == TPDO2, before=stopped)
        assert last_beat is not None and last_tpdo is not None
        # The consumer time at least, and before the 300 ms feedback timeout
        # counted from the last TPDO (the drive's last sign of life).
        after_ms = 1e3 * (stopped - last_beat)
        assert 100 <= after_ms, after_ms
        assert 1e3 * (stopped - last_tpdo) < 300
        return {"last_heartbeat_to_quick_stop_ms": after_ms, "last_tpdo_to_quick_stop_ms": 1e3 * (stopped - last_tpdo)}
    finally:
        frames.close()
        pr.close()


def test_a_lost_drive_heartbeat_stops_the_run_after_the_consumer_time(tmp_path):
    figures = scenario_heartbeat_lost(tmp_path)
    print(f"\ndrive heartbeat lost: {figures} (consumer 100 ms, beats every 50 ms)")
