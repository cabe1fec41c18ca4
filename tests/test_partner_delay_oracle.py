"""Issue 24, phase 1: the numpy oracles of the human-like partner and of the
delay-aware stage 1 (tests/oracles/), checked against independent
references, so phase 2 can test the Rust filter step by step against them.

* the delay-aware stage-1 filter (a linear Kalman filter on measured
  regressors) against filterpy's UKF on the same process: x, P and the
  innovation log-likelihood after every update, 1e-9 relative (they differ by
  rounding only: the unscented transform of an affine process is exact);
* the delay search (lstsq on stacked regressors) against the running-sum
  form of the prototype, and finding the true delays;
* the human-like partner's law: delayed terms, clamped history, motor noise
  proportional to the command, bounded drift.

The recording: a Hi5 gain phase (presets.hi5_experiment's M, dt, robot LQR
gains, rounded square + chirp in degrees) with a delayed partner, simulated
here tick by tick with the oracle partner.
"""
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from sensaug import presets

sys.path.insert(0, str(Path(__file__).resolve().parent / "oracles"))
from delay_search import profile, residual_torque, search  # noqa: E402
from delayed_stage1 import DelayedStage1  # noqa: E402
from human_partner import HumanPartner, HumanSettings, drift_step  # noqa: E402

CFG = presets.hi5_experiment(1.0)
M, DT = CFG.plant.mass, CFG.plant.dt_s
KP = math.sqrt(CFG.robot.q_pos)
KV = math.sqrt(CFG.robot.q_vel + 2 * M * KP)
SENSOR = CFG.world.position_noise_std
MOTOR = CFG.world.motor_noise_std


def record(partner: HumanSettings, ticks: int, seed: int = 3):
    """y_k = [x_m - tau, v_m, x_m - tau_h], the robot's u_k, the targets'
    increments, the partner's torque."""
    rng = np.random.default_rng(seed)
    t = np.arange(ticks + 1) * DT
    tau_h = 8 * np.cbrt(np.sin(0.5 * np.pi * t))
    tau = tau_h + 2 * np.sin(2 * np.pi * (2.0 * t * t / (2 * 20.0)))
    p = HumanPartner(partner, DT, ticks)
    x = v = 0.0
    Y, U, UH = np.zeros((ticks, 3)), np.zeros(ticks), np.zeros(ticks)
    for k in range(ticks):
        xm, vm = x + SENSOR * rng.standard_normal(), v + SENSOR * rng.standard_normal()
        Y[k] = xm - tau[k], vm, xm - tau_h[k]
        U[k] = -(KP * (xm - tau[k]) + KV * vm)
        UH[k] = p.torque(k, xm, vm, tau[k], tau_h[k])
        f = U[k] + UH[k] + MOTOR * rng.standard_normal()
        x, v = x + DT * v + 0.5 * DT * DT * f / M, v + DT * f / M
    return Y, U, np.diff(tau), np.diff(tau_h), UH


@pytest.fixture(scope="module")
def delayed_recording():
    s = HumanSettings((0.0, 0.08, 1.0), visual_delay_ms=120, proprioceptive_delay_ms=40, motor_noise_gain=0.05, seed=9)
    return s, record(s, 6000)


def filterpy_delayed(Q, R, x0, P0):
    def fx(z, dt, u, dtau, dtau_h, phi):
        e, v, eh = z[:3]
        a = (u - z[3:] @ phi) / M
        dx = dt * v + 0.5 * dt * dt * a
        return np.array([e + dx - dtau, v + dt * a, eh + dx - dtau_h, *z[3:]])

    pts = MerweScaledSigmaPoints(6, alpha=1.0, beta=2.0, kappa=0.0)
    fp = UnscentedKalmanFilter(dim_x=6, dim_z=3, dt=DT, fx=fx, hx=lambda z: z[:3], points=pts)
    fp.x, fp.P, fp.Q, fp.R = x0.copy(), P0.copy(), Q, R
    fp.sigmas_f = pts.sigma_points(fp.x, fp.P)
    return fp


def test_delayed_stage1_matches_filterpy_step_by_step(delayed_recording):
    s, (Y, U, dtau, dtau_h, _) = delayed_recording
    dv, dp = s.ticks(DT)
    Q = np.diag(CFG.robot.stage1.Q)
    R = np.diag(CFG.robot.stage1.R)
    P0 = np.diag(CFG.robot.stage1.P0)
    x0 = np.zeros(6)
    ours = DelayedStage1(M, 0.0, DT, Q, R, x0, P0, dv, dp)
    fp = filterpy_delayed(Q, R, x0, P0)
    worst = 0.0
    n = 3000
    for k in range(n):
        l = ours.update(Y[k])
        fp.update(Y[k])
        dx = np.abs(ours.x - fp.x).max() / np.abs(fp.x).max()
        dP = np.abs(ours.P - fp.P).max() / np.abs(fp.P).max()
        dl = abs(l - fp.log_likelihood) / abs(fp.log_likelihood)
        worst = max(worst, dx, dP, dl)
        assert dx <= 1e-9 and dP <= 1e-9 and dl <= 1e-9, f"step {k}: x {dx:.1e}, P {dP:.1e}, loglik {dl:.1e}"
        phi = np.array([Y[max(k - dv, 0), 0], Y[max(k - dp, 0), 1], Y[max(k - dv, 0), 2]])
        ours.predict(U[k], dtau[k], dtau_h[k])
        fp.predict(u=U[k], dtau=dtau[k], dtau_h=dtau_h[k], phi=phi)
    print(f"\nworst relative difference over {n} steps: {worst:.1e}")


def test_delayed_stage1_at_the_true_delay_finds_the_gains(delayed_recording):
    """Gain-process noise 1e-6 per step (the design note's choice for a person):
    the mean over the last 2 s within 3% of Lhh (Lhv: 3% of its truth)."""
    s, (Y, U, dtau, dtau_h, _) = delayed_recording
    dv, dp = s.ticks(DT)
    Q = np.diag(list(CFG.robot.stage1.Q[:3]) + [1e-6] * 3)
    f = DelayedStage1(M, 0.0, DT, Q, np.diag(CFG.robot.stage1.R), np.zeros(6), np.diag(CFG.robot.stage1.P0), dv, dp)
    tail = []
    for k in range(len(Y)):
        f.update(Y[k])
        if k >= len(Y) - 2000:
            tail.append(f.gains)
        f.predict(U[k], dtau[k], dtau_h[k])
    g = np.mean(tail, 0)
    assert abs(g[0]) < 0.03 * s.gains[2] and abs(g[2] - s.gains[2]) < 0.03 * s.gains[2], g
    assert abs(g[1] - s.gains[1]) < 0.03 * s.gains[1], g


def test_delay_search_finds_both_delays(delayed_recording):
    s, (Y, U, _, _, _) = delayed_recording
    dv, dp = s.ticks(DT)
    vm = Y[:, 1]
    r = residual_torque(vm, U, M, DT)
    ks = np.arange(300, len(r))
    pairs = [(a, b) for a in range(dv - 3, dv + 4) for b in range(dp - 3, dp + 4)] + [(0, 0), (dv, dv), (300, 300)]
    best, l, L = search(Y, r, ks, pairs)
    assert best == (dv, dp)
    np.testing.assert_allclose(L, s.gains, atol=0.02 * s.gains[2])
    # a 1 ms error costs far more than the 95% profile-likelihood margin (1.92)
    assert profile(Y, r, ks, dv + 1, dp)[0] < l - 20 and profile(Y, r, ks, dv - 1, dp)[0] < l - 20


def test_running_sums_equal_the_direct_fit(delayed_recording):
    """The prototype's fixed-size accumulators (benches/partner_delay/delay_id.py,
    the form the Rust filter will take) give the direct weighted lstsq profile."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benches" / "partner_delay"))
    from delay_id import Grid

    s, (Y, U, _, _, _) = delayed_recording
    r = residual_torque(Y[:, 1], U, M, DT)
    dvs, dps = np.array([[0, 60, 120, 121]]), np.array([[0, 40, 55]])
    ks = np.arange(300, len(r))
    q = 1.0 / (1e-3 + 0.01 * r[ks] ** 2)  # any positive weights
    g = Grid(dvs, dps, 300)
    for i, j in enumerate(ks):
        g.add(Y[None], j, r[j : j + 1], q[i : i + 1])
    l, L = g.profile()
    for i, dv in enumerate(dvs[0]):
        for jj, dp in enumerate(dps[0]):
            lo, Lo = profile(Y, r, ks, dv, dp, q)
            assert abs(l[0, i, jj] - lo) <= 1e-6 * abs(lo), (dv, dp)
            np.testing.assert_allclose(L[0, i, jj], Lo, rtol=1e-6, atol=1e-9)


def test_partner_acts_on_the_delayed_sample():
    s = HumanSettings((0.3, 0.05, 1.5), visual_delay_ms=70, proprioceptive_delay_ms=25)
    p = HumanPartner(s, DT, 400)
    rng = np.random.default_rng(1)
    xs, vs, ts, ths = rng.normal(size=(4, 400))
    for k in range(400):
        u = p.torque(k, xs[k], vs[k], ts[k], ths[k])
        iv, ip = max(k - 70, 0), max(k - 25, 0)
        want = -(0.3 * (xs[iv] - ts[iv]) + 0.05 * vs[ip] + 1.5 * (xs[iv] - ths[iv]))
        assert u == pytest.approx(want, rel=1e-12, abs=1e-12)


def test_motor_noise_is_proportional_to_the_command():
    s = HumanSettings((0.0, 0.0, 1.0), motor_noise_gain=0.2, seed=4)
    n = 20000
    p = HumanPartner(s, DT, n)
    c = np.where(np.arange(n) % 2 == 0, 1.0, 5.0)  # commands -1 and -5 (x - tau_h = c)
    u = np.array([p.torque(k, c[k], 0.0, 0.0, 0.0) for k in range(n)])
    for level in (1.0, 5.0):
        resid = u[c == level] + level
        assert np.std(resid) == pytest.approx(0.2 * level, rel=0.05)


def test_gain_drift_is_bounded_with_its_stated_std():
    rng = np.random.default_rng(0)
    d = np.zeros(3)
    std, T = 0.1, 0.5
    out = []
    for _ in range(200000):
        d = drift_step(d, rng.standard_normal(3), DT, std, T)
        out.append(d.copy())
    out = np.array(out)
    assert np.abs(out).max() <= 3 * std
    assert out[20000:].std() == pytest.approx(std, rel=0.15)  # 180 s = 360 time constants
    lag = int(T / DT)
    a = out[20000:, 0]
    corr = np.corrcoef(a[:-lag], a[lag:])[0, 1]
    assert corr == pytest.approx(math.exp(-1), abs=0.1)
