"""Issue 24 in the product: the human-like partner and the delay-aware
identification, against the independent numpy oracles of tests/oracles
(written from docs/design/partner_delay.md, not from the Rust code).

Seeds here (world, partner and robot: 200-203) were never used while
designing or tuning the method (tuning seeds 0, 1, 2, 3, 7;
docs/design/partner_delay.md).
"""

from __future__ import annotations

import json
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_rig import RIG_TEST_FIFO_PRIORITY, procs, stall_tolerant  # noqa: F401 (procs: a fixture)

from sensaug import experiment, presets
from sensaug import partner_delay as table
from sensaug.config import ScenarioConfig
from sensaug.config_types import HumanConfig
from sensaug.logs import load_log

REPO = Path(__file__).resolve().parents[1]

sys.path.insert(0, str(Path(__file__).resolve().parent / "oracles"))

import delayed_stage1 as oracle  # noqa: E402
import human_partner as human_oracle  # noqa: E402


def one_gain_phase(delay_ms: float, *, lhh: float = 2.0, gain_s: float = 4.0, seed: int = 200):
    cfg = presets.hi5_experiment(lhh, seed=seed, phase_s=gain_s)
    cfg.phases = cfg.phases[:1]
    cfg.robot.gain_window_s = 1.0
    cfg.partner.human = HumanConfig(visual_delay_ms=delay_ms, proprioceptive_delay_ms=delay_ms, seed=seed)
    cfg.robot.partner_delay = delay_ms
    return cfg


@pytest.mark.parametrize("delay_ms", [0.0, 50.0])
def test_delay_aware_stage1_matches_the_oracle_step_by_step(delay_ms):
    """The Rust delay-aware stage 1 (robot.partner_delay = d) against the
    numpy Kalman filter of the same equations, fed the logged measurements,
    commands and targets: the posterior gains at every tick. Tolerance:
    both run the same float64 arithmetic in a different order; 1e-9 relative
    (plus 1e-12 absolute for the near-zero Lhx, Lhv) is 20x the worst seen
    over 4000 ticks (5.2e-11 at d = 50 ms, 2.8e-11 at 0; printed with -s)."""
    cfg = one_gain_phase(delay_ms)
    trial = experiment.run(cfg)
    d = trial.data
    s1 = cfg.robot.stage1
    ticks = round(delay_ms * 1e-3 / cfg.plant.dt_s)
    f = oracle.DelayedStage1(
        cfg.plant.mass, cfg.plant.damping, cfg.plant.dt_s,
        np.diag(s1.Q), np.diag(s1.R), np.r_[0.0, 0.0, 0.0, s1.gains0], np.diag(s1.P0), ticks, ticks,
    )  # fmt: skip
    y = np.column_stack([d["x_meas"] - d["tau"], d["xdot_meas"], d["x_meas"] - d["tau_h"]])
    est = np.column_stack([d["Lhx_hat"], d["Lhv_hat"], d["Lhh_hat"]])
    worst = 0.0
    for k in range(len(d) - 1):
        f.update(y[k])
        np.testing.assert_allclose(f.gains, est[k], rtol=1e-9, atol=1e-12, err_msg=f"tick {k}")
        worst = max(worst, float(np.max(np.abs(f.gains - est[k]) / np.maximum(np.abs(est[k]), 1e-3))))
        f.predict(d["u"][k], d["tau"][k + 1] - d["tau"][k], d["tau_h"][k + 1] - d["tau_h"][k])
    # The logged delay is the configured one, in ms.
    np.testing.assert_array_equal(d["partner_delay_visual_ms"], delay_ms)
    np.testing.assert_array_equal(d["partner_delay_proprioceptive_ms"], delay_ms)
    print(f"\nd = {delay_ms:g} ms: worst relative gain difference {worst:.1e} over {len(d) - 1} ticks")


def test_paper_model_logs_no_delay_and_is_unchanged():
    """Without robot.partner_delay and partner.human: the paper's model, no
    delay in the log; the numbers are the paper figures' (the other tests of
    the suite hold them bit for bit)."""
    cfg = presets.hi5_experiment(2.0, phase_s=2.0)
    cfg.phases = cfg.phases[:1]
    d = experiment.run(cfg).data
    assert np.isnan(d["partner_delay_visual_ms"]).all() and np.isnan(d["partner_delay_margin_nats"]).all()


def test_human_partner_matches_the_oracle_without_noise():
    """The core's human-like partner (delays 73 / 31 ms, no motor noise, no
    drift) against tests/oracles/human_partner.py on the logged sample it
    sensed: u_h to 1e-12 relative at every tick."""
    cfg = presets.hi5_experiment(1.0, seed=201, phase_s=2.0)
    cfg.phases = cfg.phases[:1]
    cfg.partner.gains = [0.05, 0.08, 1.0]
    cfg.partner.human = HumanConfig(visual_delay_ms=73.0, proprioceptive_delay_ms=31.0, seed=201)
    d = experiment.run(cfg).data
    s = human_oracle.HumanSettings(gains=(0.05, 0.08, 1.0), visual_delay_ms=73.0, proprioceptive_delay_ms=31.0)
    h = human_oracle.HumanPartner(s, cfg.plant.dt_s, len(d))
    want = [h.torque(k, d["x_meas"][k], d["xdot_meas"][k], d["tau"][k], d["tau_h"][k]) for k in range(len(d))]
    np.testing.assert_allclose(d["u_h"], want, rtol=1e-12, atol=1e-15)


def test_human_partner_motor_noise_is_signal_dependent():
    """k_m = 0.2: the partner's torque minus its noise-free law has std
    0.2 |c| (the ratio's std within 5% over 4000 ticks: a chi-square of 4000
    draws has a relative std of 1.1%)."""
    cfg = presets.hi5_experiment(1.0, seed=202, phase_s=4.0)
    cfg.phases = cfg.phases[:1]
    cfg.partner.human = HumanConfig(visual_delay_ms=20.0, motor_noise_gain=0.2, seed=202)
    d = experiment.run(cfg).data
    s = human_oracle.HumanSettings(gains=(0.0, 0.0, 1.0), visual_delay_ms=20.0)
    h = human_oracle.HumanPartner(s, cfg.plant.dt_s, len(d))
    c = np.array([h.torque(k, d["x_meas"][k], d["xdot_meas"][k], d["tau"][k], d["tau_h"][k]) for k in range(len(d))])
    ok = np.abs(c) > 1e-3
    ratio = (d["u_h"][ok] - c[ok]) / np.abs(c[ok])
    assert abs(ratio.std() - 0.2) < 0.01, ratio.std()
    assert abs(ratio.mean()) < 0.02


def test_human_partner_gain_drift_is_bounded_and_of_the_stated_size():
    """gain_drift std 0.1, time constant 0.2 s over a 4 s phase (20 time
    constants): u_h / c - 1 is the drift delta of Lhh, clipped at 3 std
    (0.3); its std within 40% of 0.1 (20 independent stretches: the sample
    std's relative error is about 1/sqrt(40) = 16%, 40% is 2.5 of those)."""
    from sensaug.config_types import GainDriftConfig

    cfg = presets.hi5_experiment(1.0, seed=205, phase_s=4.0)
    cfg.phases = cfg.phases[:1]
    cfg.partner.human = HumanConfig(gain_drift=GainDriftConfig(std=0.1, time_constant_s=0.2), seed=205)
    d = experiment.run(cfg).data
    c = -1.0 * (d["x_meas"] - d["tau_h"])
    ok = np.abs(c) > 1e-2
    delta = d["u_h"][ok] / c[ok] - 1.0
    assert np.abs(delta).max() <= 0.3 + 1e-9
    assert 0.06 < delta.std() < 0.14, delta.std()


def test_a_bad_delay_names_the_field():
    cfg = one_gain_phase(50.0)
    cfg.partner.human.visual_delay_ms = 400.0
    with pytest.raises(ValueError, match="partner.human.visual_delay_ms"):
        experiment.run(cfg)
    cfg = one_gain_phase(50.0)
    cfg.robot.partner_delay = "sometimes"
    with pytest.raises(ValueError, match="robot.partner_delay"):
        experiment.run(cfg)


#: The reduced table's stable cells (sensaug.partner_delay; the full table
#: in REPORT.md): unseen seeds 203 and 204, 20 s phases.
STABLE_REDUCED = [c for c in table.REDUCED if table.closed_loop_stable(*c)]


@pytest.mark.parametrize("family,dv,dp,lhh", STABLE_REDUCED)
@pytest.mark.parametrize("seed", [203, 204])
def test_reduced_table_delay_aware_meets_the_goal(family, dv, dp, lhh, seed):
    """The issue's goal in the reduced table on unseen seeds: with
    robot.partner_delay = "auto" every gain within 5% of the truth (the
    absent ones within 5% of the stiffness, docs/design/partner_delay.md
    section 8) and the delay within 10 ms; the paper's model misses it."""
    row = table.run_cell(family, dv, dp, lhh, seed, phase_s=20.0)
    assert row["stable"]
    aware = row["aware"]
    assert aware["goal"], aware
    assert abs(aware["dv_ms"] - dv) <= 10, aware
    if family == "damped":
        assert abs(aware["dp_ms"] - dp) <= 10, aware
    if dv > 0:
        assert not row["paper"]["goal"], row["paper"]


def test_reduced_table_unstable_cell_is_reported_not_averaged():
    """The paper's virtual human with Lhh = 2 at 100 ms: its closed loop with
    the robot is unstable (docs/design/partner_delay.md section 4), the
    table says so."""
    assert not table.closed_loop_stable("paper", 100, 0, 2.0)
    assert table.closed_loop_stable("paper", 50, 0, 2.0)
    assert table.closed_loop_stable("damped", 200, 40, 2.0)
    row = table.run_cell("paper", 100, 0, 2.0, 203)
    assert not row["stable"] and "paper" not in row and "aware" not in row
    assert "unstable closed loop" in table.fmt(row)


def test_committed_person_config_is_the_preset():
    committed = ScenarioConfig.from_toml(REPO / "configs" / "hi5_rig_person.toml")
    assert committed.to_dict() == presets.hi5_person().to_dict()


def _person_on_the_virtual_rig(procs, stall: tuple[float, float] | None = None) -> dict:
    """configs/hi5_rig_person.toml's partner on the virtual Hi5 drive, the
    robot finding the delay online; with ``stall = (stop_s, every_s)`` the
    drive is frozen (SIGSTOP) for ``stop_s`` every ``every_s`` from the
    start of the run: feedback gaps of about ``stop_s`` at a known rate. The
    preset's 10 s gain phase (the search's coarse stage needs a few seconds
    of data: with a 6 s phase one run of three chose a wrong coarse pair
    before the fine grid started), 1 s others; timing margins as
    test_rig's stall_tolerant."""
    cfg = presets.hi5_person(phase_s=10.0)
    cfg.rig.realtime.fifo_priority = RIG_TEST_FIFO_PRIORITY
    cfg.phases[1].duration_s = cfg.phases[2].duration_s = 1.0
    cfg.robot.gain_window_s = 4.0
    pr = procs(stall_tolerant(cfg))
    pr.start_controller()
    if stall is not None:
        stop_s, every_s = stall
        while pr.controller.poll() is None:
            time.sleep(every_s - stop_s)
            pr.drive.send_signal(signal.SIGSTOP)
            try:
                time.sleep(stop_s)
            finally:
                pr.drive.send_signal(signal.SIGCONT)
    assert pr.wait_controller() == 0, pr.controller.stderr.read()
    stats = json.loads(pr.stats.read_text())
    log = load_log(pr.log)
    assert stats["stop_reason"] == "completed" and len(log) == 12000
    gains = log["phase"] == 0
    end = np.flatnonzero(gains)[-1]
    assert np.isfinite(log["u"][log["phase"] >= 0]).all() and np.isfinite(log["u_h"][log["phase"] >= 0]).all()
    # The partner's delays as the robot found them, at the end of the gain
    # phase, and the ones stages 2-3 then kept.
    dv, dp = log["partner_delay_visual_ms"][end], log["partner_delay_proprioceptive_ms"][end]
    assert (log["partner_delay_visual_ms"][end:][log["phase"][end:] >= 1] == dv).all()
    out = {"dv": dv, "dp": dp, "gains": stats["partner_gains_estimate"],
           "missing": stats["can"]["missing_feedback"], "longest_stale_run": stats["longest_stale_run"],
           "margin": log["partner_delay_margin_nats"][end]}
    print(f"\nrig: {out}")
    return out


#: The person preset's partner gains [Lhx, Lhv, Lhh].
PERSON_GAINS = (0.0, 0.08366600265340755, 1.0)


def _assert_person_identified(r: dict) -> None:
    """Delays within 10 ms, gains within 5% of Lhh (the issue's goal).
    Stage 1 predicts without a measurement in a feedback gap and the delay
    history holds the predicted sample there (docs/model.md, "Feedback
    gaps"); with the last measured sample held instead, runs with ~10%
    missing feedback gave Lhx -0.14, Lhh 0.88 (the tolerance was 20% then).
    Not a safety assertion."""
    assert abs(r["dv"] - 120.0) <= 10 and abs(r["dp"] - 40.0) <= 10, r
    est = r["gains"]
    for e, t in zip(est, PERSON_GAINS):
        assert abs(e - t) < 0.05 * PERSON_GAINS[2], r


def test_person_like_partner_on_the_virtual_rig(procs):
    """The demo variant end to end: configs/hi5_rig_person.toml's partner
    (visual 120 ms, proprioceptive 40 ms, 10% motor noise) inside the
    real-time loop on the virtual Hi5 drive, the robot finding the delay
    online; the feedback this loaded machine loses on its own."""
    _assert_person_identified(_person_on_the_virtual_rig(procs))


def test_person_like_partner_through_induced_feedback_gaps_on_the_virtual_rig(procs):
    """As above with the drive frozen for 25 ms every 200 ms: ~12% of the
    ticks without fresh feedback in runs of ~25 (the loaded rig's pattern,
    made certain)."""
    r = _person_on_the_virtual_rig(procs, stall=(0.025, 0.2))
    assert r["missing"] > 800 and r["longest_stale_run"] >= 15, r
    _assert_person_identified(r)
