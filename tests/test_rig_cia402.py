"""The whole experiment on the CiA 402 profile (``[rig] drive = "cia402"``):
the virtual CiA 402 drive (python-canopen) and the real-time binary on the
loopback CAN bus at 1 kHz, with the same outcome checks as the Hi5 rig test
(tests/test_rig.py) and the same outcomes as the Hi5 profile on the same
configuration.

Timing is reported, never asserted; the configuration is stall-tolerant as
in tests/test_rig.py (this VM is shared and loaded).
"""
from __future__ import annotations

import subprocess
import sys
from collections import Counter

import numpy as np
import pytest

from sensaug import experiment, logs, rig
from sensaug.capture import read_candump
from test_rig import presets_gains, short_config, stall_tolerant

NODE = 1
#: CiA 402 COB-IDs of node 1 (docs/cia402.md) and the SYNC.
RPDO1, TPDO1, TPDO2, SYNC = 0x200 + NODE, 0x180 + NODE, 0x280 + NODE, 0x080
#: The log's ``drive_state`` code of an enabled drive, whatever the profile
#: (docs/drive_profiles.md; CiA 402 OperationEnabled, whose own number in
#: CiA 402 table 30 is 4, the log's "fault" code 3 plus one).
ENABLED = 2


#: The CiA 402 runs: the virtual drive with the SYNC counter echo 0x2000
#: (chosen automatically), and a standard one without it
#: (``rig.cia402.freshness = "standard"``: ``sensaug-virtual-cia402 --standard``).
CIA402_RUNS = {"cia402": "sync_counter_echo", "cia402-standard": "standard"}


def experiment_config(drive: str):
    """3 s per phase (the 2 s of settling the metrics skip leave 1 s each)."""
    cfg = stall_tolerant(short_config(gain_s=3.0, other_s=3.0))
    cfg.rig.drive = "hi5" if drive == "hi5" else "cia402"
    if drive == "cia402-standard":
        cfg.rig.cia402.freshness = "standard"
    return cfg


#: The partner gain estimate's goal: within 0.02 of Lhh = 2, and
#: Lhx^, Lhv^ within 0.02 of 0 (the virtual human's gains).
GAIN_GOAL = 0.02

#: Consecutive gain-phase ticks without fresh feedback that can explain a
#: missed goal: in the full run on ae2fba3 the echo-mode run lost 29 (the
#: Python drive descheduled on the loaded VM) just as the partner gain
#: converged, and its Lhh^ ended 1.979; the Hi5 and standard runs lost 33
#: and 28 at other times of the phase and ended 1.999. Gaps of 10-30 ticks
#: are common here (all three runs of an idle rerun had one).
GAIN_PHASE_GAP_TICKS = 10


def gains_within_goal(run: rig.RigRun) -> bool:
    est, true = run.stats["partner_gains_estimate"], run.stats["partner_gains_true"]
    return all(abs(e - t) < GAIN_GOAL for e, t in zip(est, true))


def longest_gain_phase_gap(run: rig.RigRun) -> int:
    """The most consecutive gain-phase ticks without fresh feedback."""
    stale = ~run.log["fresh"][run.log["phase"] == 0]
    longest = current = 0
    for s in stale:
        current = current + 1 if s else 0
        longest = max(longest, current)
    return longest


def run_profile(drive: str, out) -> rig.RigRun:
    """One run of ``drive``, and once more (printed) when it missed the gain
    goal after losing GAIN_PHASE_GAP_TICKS consecutive feedbacks in the gain
    phase: the machine's stall, not the profile. A miss without such a gap,
    or a second miss, fails the outcome test."""
    run = rig.run_virtual_rig(experiment_config(drive), out=out / drive)
    gap = longest_gain_phase_gap(run)
    if not gains_within_goal(run) and gap >= GAIN_PHASE_GAP_TICKS:
        est = run.stats["partner_gains_estimate"]
        print(f"\n{drive}: gains {est} missed the goal after {gap} consecutive lost feedbacks; run again")
        run = rig.run_virtual_rig(experiment_config(drive), out=out / f"{drive}-again")
    return run


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("rig_profiles")
    return {d: run_profile(d, out) for d in ("hi5", *CIA402_RUNS)}


@pytest.mark.parametrize("drive", CIA402_RUNS)
def test_the_whole_experiment_runs_on_cia402_and_logs_every_tick(runs, drive):
    run = runs[drive]
    stats, log = run.stats, run.log
    assert run.returncode == 0 and run.drive_returncode == 0, run.stderr
    assert stats["stop_reason"] == "completed"
    assert stats["ticks"] == 9000 == len(log) == stats["records_written"]
    np.testing.assert_array_equal(log["tick"], np.arange(9000))
    assert stats["ring_overflows"] == 0 and stats["log_error"] is None
    assert log.complete and log.meta["end"]["stop_reason"] == "completed"
    assert log.meta["config"]["rig"]["drive"] == "cia402" and log.meta["loop"]["drive"] == "cia402"
    assert log.meta["resolved"]["robot"]["gains"] == list(presets_gains(run.capture.path.parent / "rig_config.toml"))
    sim = experiment.run(short_config())
    assert log.data.dtype == sim.data.dtype == logs.DTYPE
    assert list(np.unique(log["phase"])) == [0, 1, 2]
    assert set(np.unique(log["drive_state"])) == {ENABLED}
    assert log.meta["end"]["drive_status"] == "enabled"
    # The share of ticks with fresh feedback depends on the machine's
    # scheduling, not on the code (0.86 in a CI run at load 5, ~0.98 idle):
    # more than half (the default rig.max_missing_feedback_fraction). Which ticks are
    # fresh is checked exactly by the link tests (drive_link_virtual.rs).
    assert log["fresh"].mean() > 0.5
    np.testing.assert_array_equal(log["x_meas"], log["x"])
    assert np.isfinite(log["u"]).all() and np.isfinite(log["e_meas"]).all()
    can = stats["can"]
    assert can["decode_errors"] == 0 and can["foreign_commands"] == 0 and can["implausible_feedback"] == 0
    # The statistics say how freshness was judged.
    assert stats["drive"]["freshness"] == CIA402_RUNS[drive]
    if drive == "cia402-standard":
        assert stats["drive"]["feedback_discarded"] == 0  # the echo's counter; none in standard mode
    print(f"\n{drive} {stats['drive']}")
    print(f"\ncia402 loop: wake p50/p99/max {stats['wake_latency']['p50_us']}/{stats['wake_latency']['p99_us']}/"
          f"{stats['wake_latency']['max_us']:.0f} us, missing feedback {can['missing_feedback']}")


@pytest.mark.parametrize("drive", CIA402_RUNS)
def test_the_bus_carries_cia402_frames_one_cycle_per_tick(runs, drive):
    """The capture works on the CiA 402 bus; its frames are counted by
    COB-ID (no DBC applies): one RPDO1 + SYNC per tick (plus the set-up's
    and shut-down's steps), one TPDO1 + TPDO2 per SYNC, no Hi5 command."""
    run = runs[drive]
    assert run.capture is not None and run.capture.error is None
    assert run.capture.dropped_kernel == 0 and run.capture.dropped_malformed == 0
    ids = Counter(f.can_id for f in read_candump(run.capture.path))
    ticks = run.stats["ticks"]
    assert ids[RPDO1] >= ticks and ids[SYNC] >= ticks
    assert ids[RPDO1] == ids[SYNC]
    # A loaded VM may lose a few answers; every lost one shows as missing feedback.
    assert ids[TPDO1] >= ticks - run.stats["can"]["missing_feedback"] - 10
    # No Hi5 command of node 1 (TorqueCommand 0x200, SetState 0x300).
    assert ids[0x200] == 0 and ids[0x300] == 0


# The standard drive too: an answer the bus shows may be late (the first
# after a SYNC without one, or more than half a period after its SYNC) is
# not fresh there (docs/safety.md, "Standard CiA 402 drives"). Before that
# rule its Lhh^ was 2.036 (goal 0.02) in 1 of 2 full runs on main; with it,
# 4 of 4 runs passed here, 2 of them beside a CPU hog (issue 21's report).
@pytest.mark.parametrize("drive", CIA402_RUNS)
def test_cia402_gives_the_hi5_outcomes(runs, drive):
    """Gains, trajectory and integration on both profiles, same configuration
    and seeds. The drives differ in resolution (CiA 402: 1 mN m torque steps,
    4096-count encoder; Hi5: the DBC's scales) and their Python processes in
    timing, so the outcomes agree within tolerances, not bit for bit."""
    runs = {"hi5": runs["hi5"], "cia402": runs[drive]}
    hi5, cia = runs["hi5"], runs["cia402"]
    for run in (hi5, cia):
        assert run.stats["stop_reason"] == "completed", run.stderr
    est = {d: np.array(r.stats["partner_gains_estimate"]) for d, r in runs.items()}
    for d, r in runs.items():
        assert gains_within_goal(r), (d, est[d], f"longest gain-phase gap {longest_gain_phase_gap(r)} ticks")
    np.testing.assert_allclose(est["cia402"], est["hi5"], atol=0.02)
    rmse = {d: r.partner_target_rmse() for d, r in runs.items()}
    integ = {d: r.integration_rmse() for d, r in runs.items()}
    print(f"\ngains {est}\npartner-target RMSE {rmse}\nintegration {integ}")
    assert rmse["cia402"] < 1.5 * rmse["hi5"] + 0.02, rmse
    for d, r in integ.items():
        # The integration's point: the fused estimate beats the robot's own.
        assert r["integrated"] < r["own"] < r["measured"], (d, r)
    assert integ["cia402"]["integrated"] < 1.5 * integ["hi5"]["integrated"] + 0.02, integ


@pytest.mark.parametrize("drive", ("hi5", *CIA402_RUNS))
def test_the_estimators_predict_with_the_torque_the_drive_applies(runs, drive):
    """The drive applies the sum sent rounded to its step (CiA 402: 1 mN m,
    the Hi5: 1 uN m); the rounding is the robot's: its ``u`` (what its
    estimators predicted with) plus the virtual human's exact ``u_h`` is the
    torque sent, so the partner they identify is the virtual human, not its
    torque quantised (docs/cia402.md, "The Lhh difference between the
    profiles"). Rounding the robot's command alone (the drive then applying
    ``u + round(u_h)``) misses by up to half a step: this fails."""
    log = runs[drive].log
    unit = log.meta["resolved"]["rad_per_unit"]
    step_nm = log.meta["end"]["robot_torque_step"] * unit
    assert step_nm == pytest.approx(1e-3 if drive != "hi5" else 1e-6)
    ctl = log.data[(log["phase"] >= 0) & (log["guard"] == 0)]
    assert len(ctl) > 0.99 * len(log)
    sent = ctl["torque_nm"]
    np.testing.assert_allclose(sent / step_nm, np.round(sent / step_nm), rtol=0, atol=1e-6)
    implied = (ctl["u"] + ctl["u_h"]) * unit + ctl["friction_nm"]
    np.testing.assert_allclose(implied, sent, rtol=0, atol=1e-3 * step_nm)
    # The partner's torque is its own: mostly off the grid.
    off_grid = np.abs(ctl["u_h"] * unit / step_nm - np.round(ctl["u_h"] * unit / step_nm)) > 1e-3
    assert off_grid.mean() > 0.5


def test_demo_and_rig_commands_take_the_drive_profile(tmp_path):
    """``sensaug rig --drive cia402`` overrides the file's profile and says
    which drive it runs."""
    cfg = stall_tolerant(short_config(gain_s=1.0, other_s=0.5))
    toml = tmp_path / "hi5.toml"
    cfg.to_toml(toml)
    proc = subprocess.run(
        [sys.executable, "-m", "sensaug", "rig", str(toml), "--drive", "cia402", "--out", str(tmp_path / "out"),
         "--quiet", "--no-capture"],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert "virtual CiA 402 (CANopen) drive" in proc.stdout
    assert "stop: completed" in proc.stdout
    meta = logs.load_log(tmp_path / "out" / "rig_log.csv").meta
    assert meta["config"]["rig"]["drive"] == "cia402"
