"""The handle's range of motion and speed on the virtual rig (``rig.range``,
docs/safety.md, "Range of motion"), and the experimenter's stop key.

A virtual human drives the handle into the soft end stop (the wall holds it
where its spring balances the push, a closed form), past the hard limit (the
controlled stop, its reason naming the limit and the position), and fast
(the speed damping bounds the speed, the hard speed stops the run); the
launcher's stop key is pressed through a pseudo-terminal mid-trial. Loop and
drive run under SCHED_FIFO where allowed (``RIG_TEST_FIFO_PRIORITY``, as
tests/test_rig.py), with the stall-tolerant limits of tests/test_rig.py: the
subject here is the range, not the machine's load.
"""
from __future__ import annotations

import fcntl
import json
import math
import os
import pty
import select
import subprocess
import sys
import termios
import time
from pathlib import Path

import numpy as np
import pytest
from sensaug_bridge import protocol as p
from sensaug_bridge.protocol import State
from test_rig import Processes, procs, short_config, stall_tolerant  # noqa: F401 (procs: a fixture)

from sensaug import rig
from sensaug.config import ScenarioConfig
from sensaug.config_types import Sampled, Square
from sensaug.logs import load_log

C = math.pi / 180  # rad (and N m per model torque unit) per degree


def pushing_config(lhh: float, *, soft_max: float, hard_max: float, ramp_s: float = 3.0,
                   target_deg: float = 30.0, hold_s: float = 2.0) -> ScenarioConfig:
    """One gain phase: robot and virtual human both aim at a target that
    ramps from 0 to ``target_deg`` over ``ramp_s`` and holds there, beyond
    the soft end stop ``soft_max``; the virtual human's gain ``lhh``
    (model units, N m/deg x 180/pi) with a critically damped velocity gain."""
    cfg = stall_tolerant(short_config(gain_s=ramp_s + hold_s))
    cfg.phases = cfg.phases[:1]
    ramp = Sampled(samples=[0.0, target_deg], dt_s=ramp_s)
    cfg.phases[0].robot_target = [ramp]
    cfg.phases[0].partner_target = [Sampled(samples=[0.0, target_deg], dt_s=ramp_s)]
    cfg.partner.gains = [0.0, 2.0 * math.sqrt(cfg.plant.mass * lhh), lhh]
    r = cfg.rig.range
    r.soft_max_deg, r.hard_max_deg = soft_max, hard_max
    return cfg


def run_to_end(pr: Processes) -> tuple[int, dict, object]:
    pr.start_controller()
    code = pr.wait_controller(timeout=60)
    stats = json.loads(pr.stats.read_text())
    log = load_log(pr.log)
    # The log is complete whatever the stop: every tick run, in order, and
    # its end line says why the run stopped.
    assert len(log) == stats["ticks"] == stats["records_written"]
    np.testing.assert_array_equal(log["tick"], np.arange(len(log)))
    assert log.complete and log.meta["end"]["stop_reason"] == stats["stop_reason"]
    return code, stats, log


def wall_rest_deg(lhh: float, target_deg: float, soft_max: float, stiffness_nm_per_deg: float) -> float:
    """Where the virtual human's spring Lhh (tau_h - x) C N m balances the
    wall's K (x - soft_max): the controller's own push toward the stop is
    ramped to zero there, so only these two act at rest."""
    k_h = lhh * C
    return (k_h * target_deg + stiffness_nm_per_deg * soft_max) / (k_h + stiffness_nm_per_deg)


def test_the_wall_holds_a_virtual_human_pushing_past_the_soft_end_stop(procs):
    # Lhh = 5: 1.6 N m at rest in the wall, inside the 3 N m limit.
    cfg = pushing_config(5.0, soft_max=10.0, hard_max=20.0)
    pr = procs(cfg)
    code, stats, log = run_to_end(pr)
    assert code == 0, stats["stop_reason"]
    k = stats_loop_stiffness_nm_per_deg(log)
    expected = wall_rest_deg(5.0, 30.0, 10.0, k)
    last = log["x"][log["t"] > log["t"][-1] - 1.0]
    print(f"\nwall: K {k:.4f} N m/deg, rest {expected:.3f} deg (closed form), "
          f"measured {last.mean():.3f} +- {last.std():.4f} deg, peak {log['x'].max():.3f} deg")
    # Held in the wall: at the spring balance within 0.05 deg (the
    # encoder's and the robot's noise are far below it), never near the
    # hard limit, and at rest.
    assert abs(last.mean() - expected) < 0.05, (last.mean(), expected)
    assert 10.0 < last.min() and log["x"].max() < 15.0
    assert np.abs(log["xdot"][log["t"] > log["t"][-1] - 1.0]).max() < 1.0
    # Never a command beyond the limit nor a NaN.
    assert np.isfinite(log["torque_nm"]).all() and np.abs(log["torque_nm"]).max() <= 3.0


def stats_loop_stiffness_nm_per_deg(log) -> float:
    """The wall's stiffness the loop ran with (its metadata, N m/rad)."""
    return log.meta["loop"]["range_wall_stiffness_nm_per_rad"] * C


def test_a_push_past_the_hard_limit_stops_the_run_with_the_controlled_stop(procs):
    # The same push rests at 11.67 deg in the wall: a hard limit at 11 deg
    # is crossed.
    cfg = pushing_config(5.0, soft_max=10.0, hard_max=11.0)
    pr = procs(cfg)
    code, stats, log = run_to_end(pr)
    reason = stats["stop_reason"]
    assert code == 9, reason
    assert reason.startswith("range limit: the handle at 11.") and reason.endswith(
        "deg, beyond rig.range.hard_max_deg = 11 deg (controlled stop, drive disabled)"), reason
    assert stats["stop"]["kind"] == "controlled"
    assert stats["stop"]["brake_end"] in ("at_rest", "time_limit")
    # The stop came at the first tick past the limit, and braked.
    over = np.flatnonzero(log["x"] > 11.0)
    assert len(over) and stats["stop"]["tick"] == log["tick"][over[0]]
    braking = log.data[log["ramp"]]
    assert len(braking) == stats["stop"]["braking_ticks"] > 0
    assert np.all(braking["torque_nm"] * braking["xdot"] <= 0.0)
    beats = pr.heartbeats(0.5)
    assert beats and beats[-1].state == State.DISABLED, beats[-1:]


def test_a_handle_outside_the_soft_window_at_the_start_is_not_driven(procs):
    # The window moved so that the handle's rest position, 0, lies beyond
    # its low soft end stop: the first tick stops the run.
    cfg = pushing_config(5.0, soft_max=30.0, hard_max=40.0)
    cfg.rig.range.soft_min_deg, cfg.rig.range.hard_min_deg = 5.0, -10.0
    pr = procs(cfg)
    code, stats, log = run_to_end(pr)
    assert code == 9 and "starts at 0.00 deg, outside the soft window (rig.range.soft_min_deg = 5 deg)" \
        in stats["stop_reason"], stats["stop_reason"]
    assert stats["stop"]["tick"] == 0


def step_config(lhh: float, torque_limit_nm: float) -> ScenarioConfig:
    """A 30 deg target step at t = 0 (a square of period 20 s) for robot and
    virtual human, 1.5 s."""
    cfg = stall_tolerant(short_config(gain_s=1.5))
    cfg.phases = cfg.phases[:1]
    cfg.phases[0].robot_target = [Square(amplitude=30.0, period_s=20.0)]
    cfg.phases[0].partner_target = [Square(amplitude=30.0, period_s=20.0)]
    cfg.partner.gains = [0.0, 0.0, lhh]
    cfg.rig.torque_limit_nm = torque_limit_nm
    return cfg


def test_the_speed_damping_bounds_a_saturated_push_below_the_hard_speed(procs):
    # 1 N m pushing the bare handle over 30 deg would reach 12 rad/s (the
    # drive's OVERSPEED is 8); above the soft speed (200 deg/s) the damping
    # B (|v| - v_soft) bounds it at v_soft + limit / B, 331 deg/s, below the
    # hard speed (400 deg/s): the run completes.
    cfg = step_config(lhh=20.0, torque_limit_nm=1.0)
    pr = procs(cfg)
    code, stats, log = run_to_end(pr)
    assert code == 0, stats["stop_reason"]
    b = log.meta["loop"]["range_speed_damping_nm_s_per_rad"]
    bound = 200.0 + (1.0 / b) / C
    peak = np.abs(log["xdot"]).max()
    print(f"\nspeed: peak {peak:.1f} deg/s, terminal bound {bound:.1f} deg/s")
    assert 200.0 < peak <= bound + 5.0, (peak, bound)
    # Where faster than the soft speed (fresh feedback: the command's own
    # view), the push along the motion is the limit less the damping.
    fast = log.data[(np.abs(log["xdot"]) > 260.0) & (log["fresh"] == 1)]
    along = fast["torque_nm"] * np.sign(fast["xdot"])
    allowed = 1.0 - b * (np.abs(fast["xdot"]) - 200.0) * C
    # The logged torque is what the drive applies: the range's command
    # rounded (ties to even) to the drive's step, so up to half a step over.
    half_step_nm = 0.5 * log.meta["end"]["robot_torque_step"] * C
    assert 0.0 < half_step_nm < 1e-3, half_step_nm
    assert len(fast) and np.all(along <= allowed + half_step_nm + 1e-12), np.max(along - allowed)


def test_a_handle_faster_than_the_hard_speed_stops_the_run_before_the_drive_overspeed(procs):
    # 3 N m: the damping cannot hold it (terminal 650 deg/s): the hard speed
    # (400 deg/s = 6.98 rad/s) stops the run, before the drive's 8 rad/s.
    cfg = step_config(lhh=20.0, torque_limit_nm=3.0)
    pr = procs(cfg)
    code, stats, log = run_to_end(pr)
    reason = stats["stop_reason"]
    assert code == 9, reason
    assert "deg/s, faster than rig.range.hard_speed_deg_s = 400 deg/s (controlled stop" in reason, reason
    assert stats["stop"]["kind"] == "controlled"
    assert np.abs(log["xdot"]).max() < 8.0 / C  # never the drive's overspeed
    beats = pr.heartbeats(0.5)
    assert beats and beats[-1].state == State.DISABLED, beats[-1:]


# --- the stop key, through a pseudo-terminal ------------------------------------------


def launch_in_pty(args: list[str], cwd: Path) -> tuple[subprocess.Popen, int]:
    """``sensaug`` with a pseudo-terminal as its controlling terminal and
    stdin/stdout/stderr (the experimenter's terminal); the master side."""
    master, slave = pty.openpty()

    def controlling_tty() -> None:
        fcntl.ioctl(0, termios.TIOCSCTTY, 0)

    proc = subprocess.Popen([sys.executable, "-m", "sensaug", *args], stdin=slave, stdout=slave, stderr=slave,
                            cwd=cwd, start_new_session=True, preexec_fn=controlling_tty)
    os.close(slave)
    return proc, master


class Screen:
    """What the launcher wrote to its terminal, read as it comes."""

    def __init__(self, master: int) -> None:
        self.master, self.text = master, ""

    def read(self, timeout: float) -> None:
        ready, _, _ = select.select([self.master], [], [], timeout)
        if ready:
            try:
                self.text += os.read(self.master, 65536).decode(errors="replace")
            except OSError:  # the launcher closed its side
                pass

    def wait_for(self, needle: str, timeout: float) -> float:
        end = time.monotonic() + timeout
        while needle not in self.text:
            assert time.monotonic() < end, f"{needle!r} not seen; the terminal says:\n{self.text[-3000:]}"
            self.read(0.05)
        return time.monotonic()


def stop_key_run(tmp: Path, key: bytes = b" ", after_s: float = 1.5) -> dict:
    """`sensaug rig` of a 10 s trial in a pseudo-terminal; ``key`` typed
    ``after_s`` after the hint; the launcher's end and the run's files.
    Returns the ms from the key written to the terminal to the drive's
    disable on the bus (its SetState(disable) frame, seen by a monitor on
    the bus), and the run's statistics and log."""
    import can

    cfg = stall_tolerant(short_config(gain_s=10.0))
    cfg.rig.watchdog_ms = 50  # the preset's: the stop must reach the safe state within it
    toml = tmp / "trial.toml"
    cfg.to_toml(toml)
    port = rig.bus_port(None)
    proc, master = launch_in_pty(["rig", str(toml), "--out", str(tmp / "out"), "--port", str(port), "--quiet"], tmp)
    screen = Screen(master)
    monitor = None
    try:
        screen.wait_for(rig.STOP_KEY_HINT, 60)
        # On the bus once the launcher holds its port (it refuses a taken one).
        monitor = can.Bus(interface="sensaug_udp", channel=port)
        time.sleep(after_s)
        while monitor.recv(timeout=0) is not None:
            pass
        t_key = time.monotonic()
        os.write(master, key)
        disabled_ms = None
        end = time.monotonic() + 5.0
        while time.monotonic() < end and disabled_ms is None:
            msg = monitor.recv(timeout=0.05)
            if msg is None:
                continue
            try:
                d = p.decode(msg)
            except p.ProtocolError:
                continue
            if d.name == "SetState" and not d.message.enable:
                disabled_ms = 1e3 * (time.monotonic() - t_key)
        deadline = time.monotonic() + 60
        while proc.poll() is None and time.monotonic() < deadline:
            screen.read(0.1)
        screen.read(0.2)
        assert proc.poll() is not None, "the launcher did not end"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
        if monitor is not None:
            monitor.shutdown()
    stats = json.loads((tmp / "out" / "rig_stats.json").read_text())
    return {"disabled_after_ms": disabled_ms, "stats": stats, "log": load_log(tmp / "out" / "rig_log.csv"),
            "terminal": screen.text, "returncode": proc.returncode}


def test_the_stop_key_in_the_terminal_ends_the_trial_with_the_controlled_stop(tmp_path):
    r = stop_key_run(tmp_path)
    stats, log, text = r["stats"], r["log"], r["terminal"]
    print(f"\nstop key -> drive disabled on the bus: {r['disabled_after_ms']} ms")
    assert stats["stop_reason"] == "signal SIGTERM (controlled stop, drive disabled)", stats["stop_reason"]
    assert stats["stop"]["kind"] == "controlled"
    assert "STOPPED by the stop key (SPACE)" in text, text[-2000:]
    # The trial ran about as long as the key waited (1.5 s after the hint),
    # not to its 10 s end; the log is complete.
    assert 1.0 < stats["ticks"] / 1000 < 8.0, stats["ticks"]
    assert len(log) == stats["ticks"] == stats["records_written"] and log.complete
    # The drive's safe state, disabled on the bus, within one watchdog
    # period (rig.watchdog_ms = 50) of the key.
    assert r["disabled_after_ms"] is not None and r["disabled_after_ms"] < 50.0, r["disabled_after_ms"]


def test_other_keys_do_not_stop_the_trial(tmp_path):
    """A key that is not a stop key (``x``) leaves the trial running to its
    end (a 1.5 s trial)."""
    cfg = stall_tolerant(short_config(gain_s=1.0, other_s=0.25))
    toml = tmp_path / "trial.toml"
    cfg.to_toml(toml)
    proc, master = launch_in_pty(["rig", str(toml), "--out", str(tmp_path / "out"), "--quiet"], tmp_path)
    screen = Screen(master)
    try:
        screen.wait_for(rig.STOP_KEY_HINT, 60)
        os.write(master, b"x")
        deadline = time.monotonic() + 60
        while proc.poll() is None and time.monotonic() < deadline:
            screen.read(0.1)
        screen.read(0.2)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
    stats = json.loads((tmp_path / "out" / "rig_stats.json").read_text())
    assert stats["stop_reason"] == "completed", stats["stop_reason"]
    assert "STOPPED by the stop key" not in screen.text


@pytest.mark.parametrize("stream", ["pipe", "devnull"])
def test_the_stop_key_is_not_armed_without_a_terminal(stream):
    """A launcher whose stdin is no terminal (CI, a pipe) reads no keys and
    prints no hint: nothing to arm."""
    proc = subprocess.Popen(["sleep", "5"])
    try:
        if stream == "pipe":
            r, w = os.pipe()
            with os.fdopen(r) as f:
                assert rig.StopKey.arm(proc, f) is None
            os.close(w)
        else:
            with open(os.devnull) as f:
                assert rig.StopKey.arm(proc, f) is None
    finally:
        proc.kill()
        proc.wait()
