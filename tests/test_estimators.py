"""The paper's estimators, step by step, against filterpy on the same model.

Oracle: filterpy's UnscentedKalmanFilter with MerweScaledSigmaPoints, given
the reference discrete model of docs/model.md written independently in numpy,
fed the same recorded Hi5 data (a simulated trial). Both run update(y_k)
then predict(u_k, dtau_k, dtau_h_k). filterpy's first update would use its
zero-initialised sigma points, so its `sigmas_f` is set from (x0, P0) first
(docs/ukf.md). Tolerance 1e-9 relative to each quantity's scale: the two
differ only by rounding (filterpy inverts S, we solve with Cholesky).
"""
import numpy as np
import pytest
from filterpy.kalman import KalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter

import sensaug
from sensaug import experiment, presets

M, DT = 0.0035, 1e-3


def reference_fx(z, dt, u, dtau, dtau_h):
    e, v, eh, lx, lv, lh = z
    a = (u - lx * e - lv * v - lh * eh) / M
    dx = dt * v + 0.5 * dt * dt * a
    return np.array([e + dx - dtau, v + dt * a, eh + dx - dtau_h, lx, lv, lh])


@pytest.fixture(scope="module")
def recorded():
    """Stage-1 inputs from a simulated Hi5 gain phase (Lhh = 1.5)."""
    trial = experiment.run(presets.hi5_experiment(1.5, seed=4, phase_s=10.0))
    m = trial.phase_mask(0)
    rng = np.random.default_rng(7)
    x, v, tau, tau_h, u = (trial[f][m] for f in ("x", "xdot", "tau", "tau_h", "u"))
    y = np.column_stack([x - tau, v, x - tau_h]) + rng.normal(0, np.sqrt(1e-7), (len(x), 3))
    dtau = np.append(np.diff(tau), 0.0)
    dtau_h = np.append(np.diff(tau_h), 0.0)
    return y, u, dtau, dtau_h


def assert_steps_match_filterpy(ours, fp, y, u, dtau, dtau_h):
    """update(y[k]) then predict(u[k], dtau[k], dtau_h[k]) in both; after each
    update, x and P within 1e-9 of filterpy's, relative to their scale."""
    worst_x = worst_p = 0.0
    for k in range(len(y)):
        ours.update(y[k])
        fp.update(y[k])
        dx = np.abs(ours.x - fp.x).max() / np.abs(fp.x).max()
        dp = np.abs(ours.P - fp.P).max() / np.abs(fp.P).max()
        worst_x, worst_p = max(worst_x, dx), max(worst_p, dp)
        assert dx <= 1e-9 and dp <= 1e-9, f"step {k}: x rel {dx:.2e}, P rel {dp:.2e}"
        ours.predict(u[k], dtau[k], dtau_h[k])
        fp.predict(u=u[k], dtau=dtau[k], dtau_h=dtau_h[k])
    print(f"\nworst relative difference over {len(y)} steps: x {worst_x:.1e}, P {worst_p:.1e}")


@pytest.mark.parametrize("alpha,beta,kappa", [(1.0, 2.0, 0.0), (0.5, 2.0, 1.0)])
def test_gain_estimator_matches_filterpy_step_by_step(recorded, alpha, beta, kappa):
    y, u, dtau, dtau_h = recorded
    Q, R = 1e-2 * np.eye(6), 1e-7 * np.eye(3)
    P0 = np.diag([1e-4] * 3 + [1.0] * 3)
    x0 = np.zeros(6)
    ours = sensaug.GainEstimator(mass=M, dt=DT, Q=Q, R=R, x0=x0, P0=P0, alpha=alpha, beta=beta, kappa=kappa)
    pts = MerweScaledSigmaPoints(6, alpha=alpha, beta=beta, kappa=kappa)
    fp = UnscentedKalmanFilter(dim_x=6, dim_z=3, dt=DT, fx=reference_fx, hx=lambda z: z[:3], points=pts)
    fp.x, fp.P, fp.Q, fp.R = x0.copy(), P0.copy(), Q, R
    fp.sigmas_f = pts.sigma_points(fp.x, fp.P)
    assert_steps_match_filterpy(ours, fp, y, u, dtau, dtau_h)


def test_batch_run_equals_stepping(recorded):
    y, u, dtau, dtau_h = recorded
    kw = dict(mass=M, dt=DT, Q=1e-2 * np.eye(6), R=1e-7 * np.eye(3), x0=np.zeros(6), P0=np.diag([1e-4] * 3 + [1.0] * 3))
    a, b = sensaug.GainEstimator(**kw), sensaug.GainEstimator(**kw)
    xs, pd = a.run(y[:500], u[:500], dtau[:500], dtau_h[:500])
    for k in range(500):
        b.update(y[k])
        np.testing.assert_array_equal(xs[k], b.x)
        np.testing.assert_array_equal(pd[k], np.diag(b.P))
        b.predict(u[k], dtau[k], dtau_h[k])


@pytest.mark.parametrize("alpha,beta,kappa", [(1.0, 2.0, 0.0), (0.1, 2.0, 0.0)])
def test_trajectory_estimator_matches_filterpy_step_by_step(recorded, alpha, beta, kappa):
    """Stage 2: the partner's target unknown (the process gets dtau_h = 0),
    the gains measured as pseudo-measurements, y2 = [e, v, Lhx, Lhv, Lhh];
    the partner-target error e_h is observed only through the dynamics."""
    y, u, dtau, _ = recorded
    gains = np.array([0.02, 0.0, 1.5])
    y2 = np.column_stack([y[:, :2], np.tile(gains, (len(y), 1))])
    Q = np.diag([1e-8, 1e-6, 1e-5, 1e-8, 1e-8, 1e-8])
    R = np.diag([1e-7, 1e-7, 1e-4, 1e-4, 1e-4])
    P0 = np.diag([1e-4] * 3 + [1e-2] * 3)
    x0 = np.concatenate([np.zeros(3), gains])
    ours = sensaug.TrajectoryEstimator(mass=M, dt=DT, Q=Q, R=R, x0=x0, P0=P0, alpha=alpha, beta=beta, kappa=kappa)
    pts = MerweScaledSigmaPoints(6, alpha=alpha, beta=beta, kappa=kappa)
    fp = UnscentedKalmanFilter(dim_x=6, dim_z=5, dt=DT, fx=reference_fx, hx=lambda z: z[[0, 1, 3, 4, 5]], points=pts)
    fp.x, fp.P, fp.Q, fp.R = x0.copy(), P0.copy(), Q, R
    fp.sigmas_f = pts.sigma_points(fp.x, fp.P)
    assert_steps_match_filterpy(ours, fp, y2, u, dtau, np.zeros_like(dtau))


def test_trajectory_estimator_partner_target_is_x_minus_state():
    est = sensaug.TrajectoryEstimator(
        mass=M, Q=1e-2 * np.eye(6), R=1e-7 * np.eye(5), x0=np.array([0.1, 0, -0.2, 0, 0, 2]), P0=np.eye(6)
    )
    assert est.partner_target(3.0) == pytest.approx(3.2)
    assert est.x.shape == (6,) and est.P.shape == (6, 6)


def reference_error_fx(s, dt, u, dtau, damping):
    e, v = s
    a = (u - damping * v) / M
    dx = dt * v + 0.5 * dt * dt * a
    return np.array([e + dx - dtau, v + dt * a])


@pytest.mark.parametrize("damping", [0.0, 0.02])
def test_goal_integrator_own_sensing_matches_filterpy_step_by_step(recorded, damping):
    """Stage 3 without the partner channel and with the change-point test
    off (an unreachable gate): every member of the bank, so the mixture and
    member 0, is the linear Kalman filter of the model of docs/model.md;
    filterpy's KalmanFilter with the same F, B, Q, R. The full bank with the
    channel is checked against its own oracle in test_goal_integration.py."""
    y, u, dtau, _ = recorded
    Q, R = np.diag([1e-2, 1e-8]), np.diag([1e-4, 1e-7])
    x0, P0 = np.zeros(2), np.eye(2)
    ours = sensaug.GoalIntegrator(mass=M, dt=DT, damping=damping, Q=Q, R=R, x0=x0, P0=P0, gate=1e9)
    ours.reset(x0)
    dx_f, v_f = 0.5 * DT * DT / M, DT / M
    kf = KalmanFilter(dim_x=2, dim_z=2, dim_u=2)
    kf.F = np.array([[1.0, DT - dx_f * damping], [0.0, 1.0 - v_f * damping]])
    kf.B = np.array([[dx_f, -1.0], [v_f, 0.0]])  # b = B [u, dtau]
    kf.H, kf.Q, kf.R = np.eye(2), Q, R
    kf.x, kf.P = x0.copy(), P0.copy()
    worst = 0.0
    for k in range(len(y)):
        ours.update(y[k, :2])
        kf.update(y[k, :2])
        for x, var in ((ours.x, ours.var), (ours.x_own, ours.var_own)):
            dx = np.abs(x - kf.x).max() / np.abs(kf.x).max()
            dp = np.abs(var - np.diag(kf.P)).max() / np.abs(np.diag(kf.P)).max()
            worst = max(worst, dx, dp)
            assert dx <= 1e-9 and dp <= 1e-9, f"step {k}: x rel {dx:.2e}, P rel {dp:.2e}"
        assert not ours.change_point
        ours.predict(u[k], dtau[k])
        kf.predict(u=np.array([u[k], dtau[k]]))
    print(f"\nworst relative difference over {len(y)} steps: {worst:.1e}")


def test_goal_integrator_argument_errors():
    kw = dict(mass=M, Q=1e-2 * np.eye(2), R=np.diag([1.0, 1e-7]), x0=np.zeros(2), P0=np.eye(2))
    gi = sensaug.GoalIntegrator(**kw)
    with pytest.raises(ValueError, match="dtau_h"):
        gi.predict(0.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="y: expected 2 entries"):
        gi.update(np.zeros(4))
    with pytest.raises(ValueError, match="^window_n0: must be finite and > 0"):
        sensaug.GoalIntegrator(**kw, window_n0=-1.0)


@pytest.mark.parametrize(
    "change,field",
    [
        (dict(mass=-1.0), "mass"),
        (dict(dt=0.0), "dt"),
        (dict(Q=np.eye(5)), "Q"),
        (dict(R=np.eye(4)), "R"),
        (dict(x0=np.zeros(5)), "x0"),
        (dict(P0=-np.eye(6)), "P0"),
        (dict(P0=np.full((6, 6), np.nan)), "P0"),
        (dict(alpha=0.0), "alpha"),
    ],
)
def test_gain_estimator_bad_arguments_name_the_field(change, field):
    kw = dict(mass=M, dt=DT, Q=1e-2 * np.eye(6), R=1e-7 * np.eye(3), x0=np.zeros(6), P0=np.eye(6))
    kw.update(change)
    with pytest.raises(ValueError, match=field):
        sensaug.GainEstimator(**kw)


def test_non_finite_measurement_is_rejected_and_state_kept():
    est = sensaug.GainEstimator(mass=M, Q=1e-2 * np.eye(6), R=1e-7 * np.eye(3), x0=np.zeros(6), P0=np.eye(6))
    x_before = est.x.copy()
    with pytest.raises(sensaug.UkfStepError, match="z"):
        est.update(np.array([np.nan, 0.0, 0.0]))
    np.testing.assert_array_equal(est.x, x_before)
    with pytest.raises(ValueError, match="u, dtau, dtau_h"):
        est.predict(np.inf)


@pytest.mark.parametrize("columns", [2, 3])
def test_goal_integrator_run_equals_stepping(recorded, columns):
    """`run` is update(y[k]) then predict(u[k], dtau[k]) per k, with and
    without the partner channel; posteriors are the mixture's."""
    y, u, dtau, _ = recorded
    T = 500
    channel = y[:T, 0] + 0.02 * np.sin(np.arange(T) * 0.05)
    yk = np.ascontiguousarray(np.column_stack([y[:T, :2], channel])[:, :columns])
    kw = dict(mass=M, dt=DT, Q=1e-2 * np.eye(2), R=np.diag([1e-4, 1e-7]), x0=np.zeros(2), P0=np.eye(2))
    a, b = sensaug.GoalIntegrator(**kw), sensaug.GoalIntegrator(**kw)
    xs, pd = a.run(yk, u[:T], dtau[:T])
    assert xs.shape == pd.shape == (T, 2)
    for k in range(T):
        b.update(yk[k])
        np.testing.assert_array_equal(xs[k], b.x)
        np.testing.assert_array_equal(pd[k], b.var)
        b.predict(u[k], dtau[k])
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.x_own, b.x_own)
    if columns == 3:
        assert not np.array_equal(a.x, a.x_own), "the channel was used"


def test_run_arguments_and_step_errors_name_the_field(recorded):
    y, u, dtau, dtau_h = recorded
    kw = dict(mass=M, dt=DT, Q=1e-2 * np.eye(2), R=np.diag([1e-4, 1e-7]), x0=np.zeros(2), P0=np.eye(2))
    gi = sensaug.GoalIntegrator(**kw)
    with pytest.raises(ValueError, match="^y: expected 2 entries"):
        gi.run(np.zeros((10, 4)), np.zeros(10), np.zeros(10))
    with pytest.raises(ValueError, match="^dtau: expected 10 values"):
        gi.run(np.zeros((10, 3)), np.zeros(10), np.zeros(9))
    with pytest.raises(ValueError, match="^y: must be C-contiguous"):
        gi.run(np.zeros((10, 6))[:, ::2], np.zeros(10), np.zeros(10))
    # A Fortran-ordered y (as pandas' to_numpy() often returns) is contiguous
    # too, but its data read row-major would be its transpose's: refused.
    with pytest.raises(ValueError, match="^y: must be C-contiguous"):
        gi.run(np.asfortranarray(y[:10, :3]), np.zeros(10), np.zeros(10))
    kw6 = dict(mass=M, dt=DT, Q=1e-2 * np.eye(6), R=1e-7 * np.eye(3), x0=np.zeros(6), P0=np.eye(6))
    with pytest.raises(ValueError, match=r"^y: expected shape \(T, 3\)"):
        sensaug.GainEstimator(**kw6).run(y[:10, :2].copy(), u[:10], dtau[:10], dtau_h[:10])
    with pytest.raises(ValueError, match="^y: must be C-contiguous"):
        sensaug.GainEstimator(**kw6).run(np.asfortranarray(y[:10]), u[:10], dtau[:10], dtau_h[:10])
    with pytest.raises(ValueError, match=r"^y: expected 27 values \(one row per tick of u\), got 30"):
        sensaug.GainEstimator(**kw6).run(y[:10], u[:9], dtau[:10], dtau_h[:10])
    bad = y[:200].copy()
    bad[50, 1] = np.nan
    est = sensaug.GainEstimator(**kw6)
    with pytest.raises(sensaug.UkfStepError, match=r"^1 step error\(s\); first at step 50 \(update\): z: must be finite"):
        est.run(bad, u[:200], dtau[:200], dtau_h[:200])
    est = sensaug.GainEstimator(**kw6)
    xs, pd = est.run(bad, u[:200], dtau[:200], dtau_h[:200], strict=False)
    assert np.all(np.isfinite(xs)) and np.all(np.isfinite(pd))
    assert est.recoveries()["rejected"] == 1
