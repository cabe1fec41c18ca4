"""The virtual rig under the faults a lab bus sees (issue 9, part 2;
docs/safety.md): a second controller, foreign command frames, forged or
stale feedback, unwritable outputs, a log that fails mid-run, and the gap
between the enable and the first tick.

Each test starts the virtual drive and sensaug-rt on its own free loopback
port (tests/test_rig.py's helpers), injects the fault from a third socket on
the same bus, bounded in time, and stops every process it started. Each
scenario is a function returning its measured figures, so that
``scripts/measure_safety.py`` repeats the same code and quotes median and
maximum. Timing is reported, never asserted tightly: these VMs are noisy.

Every scenario runs on both drive profiles (``[rig] drive``, the
``drive`` parameter). On CiA 402 the frames the tests watch and forge are
PDOs and SDOs by COB-ID (node 1), the drive's state is its statusword
0x6041 read over SDO from the test's socket.
"""
from __future__ import annotations

import json
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
from test_virtual_cia402 import SYNC_COUNTER_OVERFLOW

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

#: Exit codes (docs/realtime.md).
EXIT_SETUP, EXIT_OTHER_CONTROLLER, EXIT_FOREIGN, EXIT_IMPLAUSIBLE, EXIT_DEGRADED, EXIT_LOG = 2, 3, 4, 5, 6, 7


def rig_processes(tmp: Path, cfg: ScenarioConfig, drive: str = "hi5") -> Processes:
    """A virtual drive of profile ``drive`` on a free port, booted (its
    heartbeat runs)."""
    cfg.rig.drive = drive
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
        if drive == "cia402":
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


def forge_jump(pr: Processes, drive: str, jump_rad: float) -> float:
    """Sends a feedback ``jump_rad`` away from the latest one (Hi5: a
    Feedback with the next sequence; CiA 402: TPDO1 with the position moved,
    then TPDO2 as last sent, both echoing the SYNC just seen, sent right
    after each of the next 20 SYNCs: the master takes only the TPDOs of the
    newest SYNC, first come, so a forgery must beat the drive's answer to a
    SYNC, which one of them does); returns when the first was sent."""
    if drive == "hi5":
        fb = latest_feedback(pr)
        forged = p.Feedback(fb.position_rad + jump_rad, fb.velocity_rad_s, (fb.sequence + 1) % 256, fb.state,
                            False, False)
        sent = time.monotonic()
        pr.monitor.send(forged.encode(NODE))
        return sent
    from sensaug_bridge.virtual_cia402 import Cia402Config

    _drain(pr)
    last = latest_tpdos(pr)
    counts = Cia402Config().encoder_counts_per_rev
    position = int.from_bytes(last[TPDO1][2:6], "little", signed=True) + round(jump_rad * counts / (2 * np.pi))
    sent: list[float] = []
    for msg in cia_frames(pr, 1.0):
        if msg.arbitration_id != SYNC:
            continue
        echo = bytes(msg.data[:1])
        tpdo1 = last[TPDO1][0:2] + position.to_bytes(4, "little", signed=True) + echo
        sent.append(time.monotonic())
        pr.monitor.send(can.Message(arbitration_id=TPDO1, data=tpdo1, is_extended_id=False))
        pr.monitor.send(can.Message(arbitration_id=TPDO2, data=last[TPDO2][:-1] + echo, is_extended_id=False))
        if len(sent) == 20:
            break
    assert sent, "no SYNC on the bus"
    return sent[0]


def latest_tpdos(pr: Processes, last: dict[int, bytes] | None = None) -> dict[int, bytes]:
    """The latest TPDO1 and TPDO2 payloads the monitor has (draining its
    queue; waiting up to 1 s for both when ``last`` has none)."""
    last = dict(last or {})
    while (msg := pr.monitor.recv(timeout=0)) is not None:
        if msg.arbitration_id in (TPDO1, TPDO2):
            last[msg.arbitration_id] = bytes(msg.data)
    for msg in cia_frames(pr, 0.0 if len(last) == 2 else 1.0):
        if msg.arbitration_id in (TPDO1, TPDO2):
            last[msg.arbitration_id] = bytes(msg.data)
        if len(last) == 2:
            break
    assert len(last) == 2, "no TPDOs on the bus"
    return last


def with_old_sync_counter(tpdo: bytes, behind: int) -> bytes:
    """A TPDO payload whose SYNC counter echo (its last byte, 0x2000) is
    ``behind`` SYNCs older (counters run 1..240, docs/cia402.md)."""
    return tpdo[:-1] + bytes([(tpdo[-1] - 1 - behind) % SYNC_COUNTER_OVERFLOW + 1])


def scenario_forged_jump(tmp: Path, drive: str = "hi5") -> dict:
    """A forged feedback 0.5 rad away from the last one: the controller
    never acts on it; the torque ramps down from the last command (never
    above it), the drive is disabled, exit 5."""
    pr = rig_processes(tmp, stall_tolerant(short_config(gain_s=10.0)), drive)
    try:
        pr.start_controller()
        wait_running(pr, drive=drive)
        time.sleep(1.0)
        sent = forge_jump(pr, drive, 0.5)
        disabled_at = first_command(pr, drive, 5.0, emergency=False)
        assert disabled_at is not None, "the controller did not disable the drive within 5 s"
        code, stats, err = end_of_run(pr)
        assert code == EXIT_IMPLAUSIBLE, err
        assert stats["stop_reason"].startswith("implausible feedback: position step"), stats["stop_reason"]
        assert "implausible feedback" in err and stats["can"]["implausible_feedback"] >= 1
        log = load_log(pr.log)
        assert log.complete and len(log) == stats["ticks"]
        ramp = log["ramp"]
        assert ramp.any() and ramp[-1] and not ramp[0]
        first = int(np.argmax(ramp))
        assert ramp[first:].all()
        before = abs(log["torque_nm"][first - 1])
        # Never above the last command before the forged feedback.
        assert np.abs(log["torque_nm"][first:]).max() <= before + 1e-12, (before, log["torque_nm"][first:].max())
        # The controller never ran on the jump: no running tick saw it (deg).
        running_x = log["x"][:first]
        assert np.abs(np.diff(running_x)).max() < np.degrees(0.1)
        assert_drive_disabled(pr, drive)
        return {
            "disabled_after_ms": 1e3 * (disabled_at - sent),
            "ramp_ticks": int(ramp.sum()),
            "torque_before_nm": float(before),
        }
    finally:
        pr.close()


# --- 3. degraded runs ---------------------------------------------------------


def scenario_stale_flood(tmp: Path, drive: str = "hi5", flood_s: float = 5.0) -> dict:
    """A bounded flood of stale feedback frames (plausible values, a
    sequence 100 behind; CiA 402: the latest TPDO1 and TPDO2 replayed with a
    SYNC counter echo 100 behind). Hi5: ticks lose their fresh feedback; past
    rig.max_stale_feedback_ticks or rig.max_missing_feedback_fraction (at
    their defaults, 100 and 0.5) the run ramps down and ends as "degraded", exit 6, and says
    why. CiA 402: every replayed TPDO is discarded (older SYNC counter) and
    counted; the run completes (with stall_tolerant's thresholds: the
    flood's 4 kHz of frames load this 2-core VM, and the feedback the load
    delays is not the subject; 2 of 5 runs at load 9.7 crossed the default
    thresholds that way)."""
    cfg = stall_tolerant(short_config(gain_s=10.0))
    # The thresholds under test: the defaults. The estimator-error threshold
    # is lifted (stall_tolerant) so that the stop can only come from the
    # feedback thresholds: with its default of 10, the starved filters'
    # recoveries crossed it first in one CI run (the run still ended
    # "degraded", exit 6, but for the other reason).
    if drive == "hi5":
        cfg.rig.max_stale_feedback_ticks, cfg.rig.max_missing_feedback_fraction = 100, 0.5
    pr = rig_processes(tmp, cfg, drive)
    try:
        pr.start_controller()
        wait_running(pr, drive=drive)
        # Past the start of the gain phase: a flood right there once drove
        # the motor into the drive's OVERSPEED first (docs/safety.md).
        time.sleep(1.0)
        assert pr.controller.poll() is None, pr.controller.stderr.read()
        sent = 0
        start = time.monotonic()
        if drive == "hi5":
            fb = latest_feedback(pr)
        else:
            last = latest_tpdos(pr)
        while time.monotonic() - start < flood_s and pr.controller.poll() is None:
            if drive == "hi5":
                fb = latest_feedback(pr, fb)
                stale = p.Feedback(fb.position_rad, fb.velocity_rad_s, (fb.sequence - 100) % 256, fb.state,
                                   False, False)
                replay = [stale.encode(NODE)] * 2
            else:
                last = latest_tpdos(pr, last)
                replay = [can.Message(arbitration_id=i, data=with_old_sync_counter(last[i], 100), is_extended_id=False)
                          for i in (TPDO1, TPDO2)]
            for msg in replay:
                pr.monitor.send(msg)
            sent += len(replay)
            time.sleep(0.0003)
        code, stats, err = end_of_run(pr)
        flood_to_stop_s = time.monotonic() - start
        assert sent > 100, sent
        if drive == "cia402":
            # The master keeps the TPDO of the newest SYNC and discards older
            # ones (docs/cia402.md, "Freshness"): the flood is counted and
            # changes nothing; the run completes.
            assert code == 0 and stats["stop_reason"] == "completed", (stats["stop_reason"], err)
            assert stats["drive"]["feedback_discarded"] >= 0.9 * sent, (stats["drive"], sent)
            return {"stale_frames_sent": sent, "discarded": stats["drive"]["feedback_discarded"],
                    "missing_feedback": stats["can"]["missing_feedback"]}
        assert code == EXIT_DEGRADED, (stats["stop_reason"], err)
        assert stats["stop_reason"].startswith("degraded: "), stats["stop_reason"]
        assert "without fresh feedback" in stats["stop_reason"] and "rig.max_" in stats["stop_reason"]
        assert "degraded" in err and stats["exit_code"] == EXIT_DEGRADED
        log = load_log(pr.log)
        assert log.complete and log.meta["end"]["stop_reason"] == stats["stop_reason"]
        assert log["ramp"][-1]
        assert_drive_disabled(pr, drive)
        return {"stale_frames_sent": sent, "missing_feedback": stats["can"]["missing_feedback"],
                "flood_to_exit_ms": 1e3 * flood_to_stop_s}
    finally:
        pr.close()


@pytest.mark.parametrize("drive", PROFILES)
def test_a_second_controller_refuses_to_start_and_the_first_runs_on(tmp_path, drive):
    figures = scenario_second_controller(tmp_path, drive)
    print(f"\nsecond controller refused after {figures['refused_after_ms']:.0f} ms")


@pytest.mark.parametrize("drive", PROFILES)
def test_a_foreign_command_frame_stops_a_running_controller_with_an_emergency_stop(tmp_path, drive):
    figures = scenario_foreign_command(tmp_path, drive)
    print(f"\nforeign command -> emergency stop on the bus after {figures['emergency_stop_after_ms']:.1f} ms")


@pytest.mark.parametrize("drive", PROFILES)
def test_a_forged_feedback_jump_ramps_down_and_never_raises_the_torque(tmp_path, drive):
    figures = scenario_forged_jump(tmp_path, drive)
    print(f"\nforged 0.5 rad jump -> drive disabled after {figures['disabled_after_ms']:.0f} ms "
          f"({figures['ramp_ticks']} ramp ticks from {figures['torque_before_nm']:.4f} N m)")


@pytest.mark.parametrize("drive", PROFILES)
def test_a_flood_of_stale_feedback_ends_the_run_as_degraded(tmp_path, drive):
    figures = scenario_stale_flood(tmp_path, drive)
    print(f"\nstale flood: {figures}")


# --- 4. outputs ----------------------------------------------------------------


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
def test_a_log_write_failure_ramps_down_and_keeps_what_was_written(tmp_path, drive):
    figures = scenario_log_failure(tmp_path, drive=drive)
    print(f"\nlog failed: {figures}")


# --- 5. the first tick after the enable ------------------------------------------


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
    register (0x8400, 0x01), Hi5 its fault flags (OVERSPEED), exit 1."""
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
