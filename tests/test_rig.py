"""The virtual rig end to end: the virtual Hi5 drive (Python process) and the
real-time binary (Rust process) on the loopback CAN bus.

Each test starts both processes for a few seconds on its own free port.
These VMs are noisy: timing is reported by the binary, never asserted here;
margins on watchdog reactions are generous and stated.
"""
from __future__ import annotations

import json
import signal
import socket
import struct
import subprocess
import time
from pathlib import Path

import can
import numpy as np
import pytest
from sensaug_bridge import protocol as p
from sensaug_bridge.protocol import FaultFlag, State
from sensaug_bridge.udp_bus import BROADCAST_ADDR, free_port

from sensaug import experiment, logs, presets, rig
from sensaug.config import ScenarioConfig
from sensaug.logs import load_log

NODE = 1
REPO = Path(__file__).resolve().parents[1]


#: SCHED_FIFO priority of the loop and the virtual drive in these tests
#: (rig.realtime.fifo_priority; CI runs as root). A simulated drive held off
#: the CPU by the machine's other work answered tens of ms late, and the
#: estimators' predict-only stretches moved the converged stage-1 gains by
#: 10-30% (2.11 and 2.19 for Lhh = 2 in a CI run; 168-782 ticks without fresh
#: feedback per 5 s run at load 7 here, 0-95 under SCHED_FIFO). Refused
#: (not root): both warn and run as before.
RIG_TEST_FIFO_PRIORITY = 20


def short_config(gain_s: float = 3.0, other_s: float = 1.0) -> ScenarioConfig:
    cfg = presets.hi5_rig(phase_s=gain_s)
    cfg.rig.realtime.fifo_priority = RIG_TEST_FIFO_PRIORITY
    cfg.phases[0].duration_s = gain_s
    cfg.phases[0].robot_target[1] = type(cfg.phases[0].robot_target[1])(
        amplitude=2.0, f0_hz=0.0, f1_hz=2.0, duration_s=gain_s
    )
    cfg.phases[1].duration_s = other_s
    cfg.phases[2].duration_s = other_s
    cfg.robot.gain_window_s = 0.5
    return cfg


class Processes:
    """A virtual drive and a controller on one port; always cleaned up."""

    def __init__(self, tmp: Path, cfg: ScenarioConfig, *, drive_args: list[str] | None = None):
        self.port = free_port()
        self.tmp = tmp
        self.toml = tmp / "trial.toml"
        cfg.to_toml(self.toml)
        self.log, self.stats = tmp / "log.csv", tmp / "stats.json"
        self.monitor = can.Bus(interface="sensaug_udp", channel=self.port)
        self.drive = rig.start_drive(self.port, duration_s=120, extra=drive_args, drive=cfg.rig.drive,
                                     fifo_priority=cfg.rig.realtime.fifo_priority,
                                     standard=rig.standard_drive(cfg))
        self.controller: subprocess.Popen | None = None

    def start_controller(self) -> subprocess.Popen:
        self.controller = subprocess.Popen(
            [str(rig.find_binary()), str(self.toml), "--can", f"udp:{self.port}",
             "--log", str(self.log), "--stats", str(self.stats)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        return self.controller

    def wait_controller(self, timeout: float = 60) -> int:
        assert self.controller is not None
        self.controller.wait(timeout=timeout)
        return self.controller.returncode

    def frames(self, seconds: float):
        """Decoded protocol frames seen on the bus for ``seconds`` (others skipped)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            msg = self.monitor.recv(timeout=0.05)
            if msg is None:
                continue
            try:
                yield p.decode(msg)
            except p.ProtocolError:
                continue

    def heartbeats(self, seconds: float) -> list[p.Heartbeat]:
        return [d.message for d in self.frames(seconds) if d.name == "Heartbeat"]

    def close(self) -> None:
        for proc in (self.controller, self.drive):
            if proc is not None:
                rig.stop_process(proc, timeout_s=10.0)
        self.monitor.shutdown()


@pytest.fixture
def procs(tmp_path):
    made: list[Processes] = []

    def make(cfg: ScenarioConfig, **kw) -> Processes:
        pr = Processes(tmp_path, cfg, **kw)
        made.append(pr)
        time.sleep(0.5)  # the drive boots and starts its heartbeat
        return pr

    yield make
    for pr in made:
        pr.close()


def stall_tolerant(cfg: ScenarioConfig) -> ScenarioConfig:
    """Feedback timeout 300 ms and drive watchdog 200 ms (the bounds of the
    schema and the protocol): on this loaded 2-core VM
    the loop or the Python drive stalls for tens of ms now and then, which
    the preset's 20 ms / 50 ms turn into a stopped run (seen with the
    unchanged binary too). Likewise the degraded-run thresholds: 300 stale
    ticks (as the timeout), no limit on the missing fraction (a run at load 9
    lost 501 of its first 831 feedbacks) nor on estimator errors (2 of 5
    runs at load 8 passed the default 10). For the tests whose subject is
    not those limits. CiA 402: the drive's heartbeat is declared lost after
    600 ms (3 watchdogs, the bound), not the default 100 ms."""
    cfg.rig.feedback_timeout_ms, cfg.rig.watchdog_ms = 300.0, 200
    cfg.rig.cia402.heartbeat_timeout_ms = 600
    cfg.rig.max_stale_feedback_ticks, cfg.rig.max_missing_feedback_fraction = 300, 1.0
    cfg.rig.max_estimator_errors = 1_000_000
    return cfg


def test_short_trial_converges_and_logs_every_tick(procs):
    pr = procs(stall_tolerant(short_config()))
    pr.start_controller()
    assert pr.wait_controller() == 0, pr.controller.stderr.read()
    stats = json.loads(pr.stats.read_text())
    log = load_log(pr.log)
    assert stats["stop_reason"] == "completed"
    assert stats["ticks"] == 5000 == len(log) == stats["records_written"]
    np.testing.assert_array_equal(log["tick"], np.arange(5000))
    assert stats["ring_overflows"] == 0
    assert stats["log_write_errors"] == 0 and stats["log_records_lost"] == 0 and stats["log_error"] is None
    # The end-status line, and the metadata a replay needs.
    assert log.complete and log.meta["end"]["stop_reason"] == "completed"
    assert log.meta["end"]["records_written"] == 5000
    assert log.meta["source"] == "rig" and log.meta["loop"]["dt_s"] == 1e-3
    # The configuration the loop ran: the file with the command line's overrides.
    expected = ScenarioConfig.from_toml(pr.toml)
    expected.rig.can, expected.rig.log, expected.rig.stats = f"udp:{pr.port}", str(pr.log), str(pr.stats)
    assert ScenarioConfig.from_dict(log.meta["config"]).to_dict() == expected.to_dict()
    assert log.meta["resolved"]["robot"]["gains"] == list(presets_gains(pr.toml))
    # Same schema as a simulated trial: same columns, same dtypes.
    sim = experiment.run(short_config())
    assert log.data.dtype == sim.data.dtype == logs.DTYPE
    assert sim.columns == log.columns
    # Integers are integers; the phases run in order; the controller got
    # fresh feedback on most ticks (how many depends on the machine's
    # scheduling: more than half, as rig.max_missing_feedback_fraction's default) and logged
    # what it received.
    assert list(np.unique(log["phase"])) == [0, 1, 2]
    assert np.all(np.diff(log["phase"]) >= 0)
    assert set(np.unique(log["drive_state"])) == {2}  # ENABLED throughout
    assert log["fresh"].dtype == np.bool_ and log["fresh"].mean() > 0.5
    np.testing.assert_array_equal(log["x_meas"], log["x"])
    assert np.isfinite(log["u"]).all() and np.isfinite(log["e_meas"]).all()
    # Simulated without noise the 3 s gain phase (0.5 s window) gives
    # Lhh = 1.9993 (tests/../crates/sensaug-rt/tests/rig_loop.rs); 0.02 leaves
    # room for the ticks a loaded VM loses feedback (predict-only there).
    est = stats["partner_gains_estimate"]
    assert abs(est[2] - 2.0) < 0.02, est
    assert abs(est[0]) < 0.02 and abs(est[1]) < 0.02, est
    print(f"\nloop: wake p50/p99/max {stats['wake_latency']['p50_us']}/{stats['wake_latency']['p99_us']}/"
          f"{stats['wake_latency']['max_us']:.0f} us, missing feedback {stats['can']['missing_feedback']}")


def test_a_spin_before_each_deadline_logs_both_latencies_every_tick(procs):
    """rig.realtime.spin_us: each tick sleeps until 100 us before its
    deadline and spins on the clock for the rest. Every tick logs both the
    wake-up latency (the tick's start after its deadline) and the sleep's
    own (the OS timer's); no timing is asserted."""
    cfg = stall_tolerant(short_config(gain_s=1.0, other_s=0.5))
    cfg.rig.realtime.spin_us = 100
    pr = procs(cfg)
    pr.start_controller()
    assert pr.wait_controller() == 0, pr.controller.stderr.read()
    stats = json.loads(pr.stats.read_text())
    log = load_log(pr.log)
    assert stats["ticks"] == 2000 == len(log)
    assert np.isfinite(log["sleep_latency_us"]).all() and (log["sleep_latency_us"] >= 0).all()
    assert np.isfinite(log["wake_latency_us"]).all() and (log["wake_latency_us"] >= 0).all()
    # One sample per wake-up: each tick's and the last, which found the protocol done.
    assert stats["sleep_latency"]["count"] == stats["wake_latency"]["count"] == stats["ticks"] + 1
    assert "spin 100 us before each deadline" in stats["realtime"]
    assert log.meta["loop"]["spin_us"] == 100 and log.meta["config"]["rig"]["realtime"]["spin_us"] == 100
    print(f"\nspin 100 us: wake p50/p99 {stats['wake_latency']['p50_us']}/{stats['wake_latency']['p99_us']} us, "
          f"sleep p50/p99 {stats['sleep_latency']['p50_us']}/{stats['sleep_latency']['p99_us']} us")


def test_killing_the_controller_trips_the_drive_watchdog(procs):
    """SIGKILL: no ramp, no disable. The drive must zero its torque and latch
    FAULT(WATCHDOG) after its 50 ms watchdog; we allow 1 s for a loaded VM
    (the drive's own loop can be descheduled; see docs/virtual_hi5.md)."""
    cfg = short_config(gain_s=10.0)
    pr = procs(cfg)
    pr.start_controller()
    time.sleep(2.0)
    assert pr.controller.poll() is None, "controller died early"
    pr.controller.kill()
    killed = time.monotonic()
    fault_at = None
    for d in pr.frames(3.0):
        if d.name in ("Fault", "Heartbeat") and d.message.state == State.FAULT:
            assert d.message.fault_flags & FaultFlag.WATCHDOG
            fault_at = time.monotonic()
            break
    assert fault_at is not None, "no FAULT(WATCHDOG) within 3 s of killing the controller"
    delay = fault_at - killed
    print(f"\nwatchdog fault {1000 * delay:.0f} ms after SIGKILL (watchdog 50 ms)")
    assert delay < 1.05


def presets_gains(toml: Path) -> list[float]:
    """The robot gains the simulation resolves for the same file."""
    cfg = ScenarioConfig.from_toml(toml)
    cfg.phases = cfg.phases[:1]
    cfg.phases[0].duration_s = 0.01
    return [float(g) for g in experiment.run(cfg).robot_gains]


def _kill_mid_run(pr: Processes) -> int | None:
    """Starts the controller, SIGKILLs it ~2.5 s into the run and returns the
    tick it had reached (from the bus), or None if the run ended by itself
    first (a loaded VM can stall the loop or the drive into a fault)."""
    torque_id = p.frame_id("TorqueCommand", NODE)
    pr.start_controller()
    t0 = last_seq = None
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        msg = pr.monitor.recv(timeout=0.05)
        if msg is None or msg.arbitration_id != torque_id:
            continue
        seq = p.TorqueCommand.decode(bytes(msg.data), msg.arbitration_id).sequence
        if t0 is None:
            if seq == 0:
                t0 = time.monotonic()
            continue
        last_seq = seq
        if time.monotonic() - t0 > 2.5:
            break
    assert t0 is not None and last_seq is not None, "no torque commands seen"
    # Catch up with the bus, then kill right away.
    while (msg := pr.monitor.recv(timeout=0)) is not None:
        if msg.arbitration_id == torque_id:
            last_seq = p.TorqueCommand.decode(bytes(msg.data), msg.arbitration_id).sequence
    killed = time.monotonic()
    if pr.controller.poll() is not None:
        return None
    pr.controller.kill()
    pr.controller.wait()
    estimate = (killed - t0) / 1e-3
    return last_seq + 256 * round((estimate - last_seq) / 256)


def test_sigkill_leaves_every_record_older_than_200_ms_readable(procs):
    """After a SIGKILL at an arbitrary moment, the log loads (the partial
    last line ignored), its ticks run from 0 without a gap, and it holds every
    record the loop produced until 200 ms before the kill.

    The loop's progress at the kill is read off the bus: the torque command
    of tick k (sequence k mod 256) is sent just before record k is queued.
    The wall clock since tick 0's command resolves k from k mod 256 (valid
    while the loop lags the wall clock by < 128 ms). Feedback timeout and
    drive watchdog are raised, and the run is retried (3 attempts) if it
    ended by itself before the kill: this VM's stalls can fault the drive."""
    cfg = stall_tolerant(short_config(gain_s=20.0))
    for attempt in range(3):
        pr = procs(cfg)
        k_bus = _kill_mid_run(pr)
        if k_bus is not None:
            break
        print(f"\nattempt {attempt}: the run ended before the kill ({pr.controller.returncode}); retrying")
    assert k_bus is not None, "the run ended by itself before the kill in all 3 attempts"
    log = load_log(pr.log)
    assert not log.complete, "a killed run has no end-status line"
    assert log.meta["source"] == "rig" and "config" in log.meta
    n = len(log)
    np.testing.assert_array_equal(log["tick"], np.arange(n))
    missing = k_bus - (n - 1)
    print(f"\nSIGKILL at tick ~{k_bus}: log holds ticks 0..{n - 1} ({missing} ticks = {missing} ms not on disk)")
    assert n - 1 >= k_bus - 200, (n, k_bus)


def _garbage(port: int) -> None:
    """Malformed traffic on the bus: short and long datagrams, bad flags,
    a bad-CRC and a wrong-DLC torque command, an unknown id (5 rounds)."""
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    raw.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
    dest = (BROADCAST_ADDR, port)
    torque_id = p.frame_id("TorqueCommand", NODE)
    frames = [
        b"\x01\x02\x03",
        b"\x00" * 40,
        struct.pack("<IB3x8s", 0x80000123, 8, b"\0" * 8),  # extended id: carried, not the protocol's
        struct.pack("<IB3x8s", torque_id, 8, b"\x10\x00\x00\x00\x05\x00\x00\x99"),  # bad CRC
        struct.pack("<IB3x8s", torque_id, 3, b"\x10\x00\x00"),  # wrong DLC
        struct.pack("<IB3x8s", 0x555, 2, b"\x01\x02"),  # unknown id
    ]
    for _ in range(5):
        for f in frames:
            raw.sendto(f, dest)
        time.sleep(0.05)
    raw.close()


def _stale_commands(pr: Processes, count: int = 5) -> None:
    """Valid torque commands (good CRC, zero torque) whose sequence is 64
    behind the controller's latest: the drive must reject them as stale."""
    # Drop what the monitor buffered since it opened: only a command seen
    # now tells the controller's current sequence (an old one could make
    # "64 behind" land ahead of the controller and lock it out).
    while pr.monitor.recv(timeout=0) is not None:
        pass
    latest = None
    for d in pr.frames(1.0):
        if d.name == "TorqueCommand":
            latest = d.message.sequence
            break
    assert latest is not None, "no torque command seen on the bus"
    for i in range(count):
        pr.monitor.send(p.TorqueCommand(0.0, (latest - 64 - i) % 256).encode(NODE))


def test_malformed_frames_are_dropped_and_counted_on_both_sides(procs):
    pr = procs(stall_tolerant(short_config()))  # the subject is the frames, not the stall limits
    pr.start_controller()
    time.sleep(1.0)
    _garbage(pr.port)
    assert pr.wait_controller() == 0, pr.controller.stderr.read()
    stats = json.loads(pr.stats.read_text())
    assert stats["stop_reason"] == "completed"
    assert stats["can"]["bus_malformed_dropped"] >= 10  # 2 malformed datagrams x 5
    # The bus carries extended frames; the protocol rejects them.
    assert stats["can"]["decode_errors"] >= 15  # extended id + wrong DLC + unknown id, x 5
    assert stats["can"]["bus_kernel_dropped"] == 0
    beats = pr.heartbeats(0.5)
    assert beats, "the drive stopped sending heartbeats"
    last = beats[-1]
    assert last.crc_errors >= 5 and last.length_errors >= 5 and last.unknown_ids >= 5, last
    assert pr.drive.poll() is None, "the drive crashed"
    np.testing.assert_array_equal(load_log(pr.log)["tick"], np.arange(stats["ticks"]))


def test_a_second_command_source_faults_the_drive(procs):
    """Valid torque commands from a second host (good CRC, sequence 64 behind the
    controller's): the drive latches FAULT(SEQUENCE), and the controller stops
    on whichever it sees first: the drive's fault (exit 1) or the foreign
    command itself (exit 4, tests/test_rig_faults.py)."""
    pr = procs(stall_tolerant(short_config(gain_s=10.0)))
    pr.start_controller()
    time.sleep(1.0)
    _stale_commands(pr, count=1)
    code = pr.wait_controller(timeout=20)
    stats = json.loads(pr.stats.read_text())
    reason = stats["stop_reason"]
    assert (code == 1 and reason.startswith("drive fault")) or (code == 4 and reason.startswith("foreign command")), (
        code, reason)
    beats = pr.heartbeats(0.5)
    assert beats and beats[-1].fault_flags & FaultFlag.SEQUENCE, beats[-1:]
    assert beats[-1].sequence_errors >= 1
    assert beats[-1].state == State.FAULT


def test_sigterm_brakes_disables_and_flushes_the_log(procs):
    pr = procs(stall_tolerant(short_config(gain_s=10.0)))
    pr.start_controller()
    time.sleep(2.0)
    pr.controller.send_signal(signal.SIGTERM)
    code = pr.wait_controller(timeout=20)
    assert code == 1  # not completed
    stats = json.loads(pr.stats.read_text())
    assert stats["stop_reason"] == "signal SIGTERM (controlled stop, drive disabled)"
    assert stats["stop"]["kind"] == "controlled" and stats["stop"]["brake_end"] in ("at_rest", "time_limit")
    log = load_log(pr.log)
    assert len(log) == stats["ticks"] == stats["records_written"]
    np.testing.assert_array_equal(log["tick"], np.arange(len(log)))
    assert log.complete and log.meta["end"]["stop_reason"] == stats["stop_reason"]
    stop = log.data[log["ramp"]]
    assert len(stop) == stats["stop"]["braking_ticks"]
    # The brake opposes the measured motion (log units: deg/s), within its bound.
    assert np.all(stop["torque_nm"] * stop["xdot"] <= 0.0), stop[["xdot", "torque_nm"]]
    assert np.abs(stop["torque_nm"]).max(initial=0.0) <= 3.0
    # Stop ticks are outside the protocol: unknown phase and guard.
    assert np.all(stop["phase"] == logs.UNKNOWN_INT) and np.all(stop["guard"] == logs.UNKNOWN_INT)
    beats = pr.heartbeats(0.5)
    assert beats and beats[-1].state == State.DISABLED, beats[-1:]


def test_a_dead_drive_stops_the_controller_with_an_emergency_stop(procs):
    pr = procs(short_config(gain_s=10.0))
    pr.start_controller()
    time.sleep(1.5)
    pr.drive.kill()
    pr.drive.wait()
    code = pr.wait_controller(timeout=20)
    assert code == 1
    stats = json.loads(pr.stats.read_text())
    assert stats["stop_reason"].startswith("feedback timeout")
    assert len(load_log(pr.log)) == stats["ticks"]


def test_bad_configuration_is_rejected_before_anything_moves(tmp_path):
    cfg = short_config()
    text = cfg.to_toml().replace("node_id = 1", "node_id = 42")
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    proc = subprocess.run([str(rig.find_binary()), str(bad)], capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2
    assert "rig.node_id" in proc.stderr


def test_committed_rig_config_is_the_preset():
    committed = ScenarioConfig.from_toml(REPO / "configs" / "hi5_rig.toml")
    assert committed.to_dict() == presets.hi5_rig().to_dict()
