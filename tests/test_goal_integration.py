"""Stage 3, the adaptive partner channel: the core's ``GoalIntegrator``
against the independent numpy oracle ``tests/oracles/adaptive_channel.py``
(the equations of ``docs/model.md``), tick by tick, and the design's
defining properties on synthetic data with a known truth.

Tolerances: the core runs closed-form scalar updates, the oracle stacked
matrix solves, on the same numbers; they differ by round-off only. Over a few
thousand ticks the relative difference stays below 1e-9 (measured ~1e-13), so
every flag (change point, admission) must be identical.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from oracles.adaptive_channel import AdaptiveChannel, Model, Params, channel_grid, steady_state_posterior

import sensaug
from sensaug import experiment, presets

DT = 1e-3
#: A 1 kg handle with some damping; full (correlated) Q, R and P0 so the
#: core's closed-form 2x2 updates are exercised off the diagonal.
MODEL = Model(
    mass=1.0,
    damping=0.3,
    dt_s=DT,
    Q=np.array([[1e-6, 2e-9], [2e-9, 1e-8]]),
    R=np.array([[1e-4, 3e-8], [3e-8, 1e-8]]),
    P0=np.array([[1e-2, 1e-4], [1e-4, 1e-2]]),
)


def core(model: Model, params: Params = Params()) -> sensaug.GoalIntegrator:
    return sensaug.GoalIntegrator(
        mass=model.mass,
        damping=model.damping,
        dt=model.dt_s,
        Q=model.Q,
        R=model.R,
        x0=[0.0, 0.0],
        P0=model.P0,
        gate=params.gate,
        window_n0=params.window_n0,
        hold_max_s=params.hold_max_s,
    )


def streams(ticks: int, *, seed: int, channel_std: float, lag: int, jumps: tuple[int, ...] = (), jump: float = 0.2):
    """Truth ``e``: a random walk of variance ``Q[0, 0]`` plus target jumps;
    own view ``e + N(0, R)``; the channel ``e`` ``lag`` ticks late plus
    ``N(0, channel_std^2)``, NaN on a stretch (no channel); a torque ``u``."""
    rng = np.random.default_rng(seed)
    e = np.cumsum(rng.normal(0.0, math.sqrt(MODEL.Q[0, 0]), ticks))
    for k in jumps:
        e[k:] += jump
    noise = rng.multivariate_normal([0.0, 0.0], MODEL.R, ticks)
    y = np.column_stack([e, np.zeros(ticks)]) + noise
    late = np.concatenate([np.full(lag, e[0]), e[: ticks - lag]])
    c = late + rng.normal(0.0, channel_std, ticks)
    c[ticks // 3 : ticks // 3 + 200] = np.nan
    u = 0.05 * np.sin(np.arange(ticks) * 2e-3)
    return y, c, u, e


def test_the_steady_state_is_the_fixed_point_of_the_scalar_riccati_recursion():
    for q, r in ((1e-6, 1e-4), (1e-2, 9.0), (1e-4, 1e-5), (4e-5, 1e-3)):
        p = 1.0
        for _ in range(200_000):
            pm = p + q
            p = pm * r / (pm + r)
        assert steady_state_posterior(q, r) == pytest.approx(p, rel=1e-9)


def test_the_core_grid_is_the_documented_one():
    gi = core(MODEL)
    A = steady_state_posterior(MODEL.Q[0, 0], MODEL.R[0, 0])
    grid = gi.grid
    assert math.isinf(grid[0])
    np.testing.assert_allclose(grid[1:], channel_grid(MODEL.Q[0, 0], A, Params()), rtol=1e-12)
    assert grid[1] == pytest.approx(min(MODEL.Q[0, 0], A) / 64)
    assert grid[-1] == pytest.approx(16 * A)


@pytest.mark.parametrize(
    ("seed", "channel_std", "lag", "params"),
    [
        (0, 3e-3, 8, Params()),  # a good channel that lags each jump
        (1, 0.3, 0, Params()),  # a useless channel
        (2, 1e-3, 40, Params(gate=3.0, window_n0=40.0, hold_max_s=0.02)),  # short holds expire
    ],
)
def test_the_core_matches_the_oracle_tick_by_tick(seed, channel_std, lag, params):
    """Every tick's mixture, its variance, member 0, every member, the
    weights, the channel's effective variance and both flags; through a phase
    start (new own noise, reset) half way."""
    T = 4000
    y, c, u, _ = streams(T, seed=seed, channel_std=channel_std, lag=lag, jumps=(900, 1700, 2600, 3500))
    ours, ref = core(MODEL, params), AdaptiveChannel(MODEL, params)
    ours.reset(y[0])
    ref.reset(y[0])
    flags = np.zeros((T, 2), dtype=bool)
    for k in range(T):
        if k == T // 2:  # a new phase: the target-view noise grows
            R = MODEL.R + np.diag([4e-4, 0.0])
            ours.set_own_noise(R)
            ref.set_own_noise(R)
            ours.reset(y[k])
            ref.reset(y[k])
        assert ours.update(np.array([y[k, 0], y[k, 1], c[k]])) == sensaug._core.Status.Nominal()
        ref.update(y[k], c[k])
        where = f"tick {k}"
        assert ours.change_point == ref.change_point, where
        assert ours.channel_admitted == ref.admitted, where
        np.testing.assert_allclose(ours.x, ref.estimate, rtol=1e-9, atol=1e-13, err_msg=where)
        np.testing.assert_allclose(ours.var, ref.variance, rtol=1e-9, atol=1e-18, err_msg=where)
        np.testing.assert_allclose(ours.x_own, ref.x[0], rtol=1e-9, atol=1e-13, err_msg=where)
        np.testing.assert_allclose(ours.var_own, np.diag(ref.P[0]), rtol=1e-9, atol=1e-18, err_msg=where)
        np.testing.assert_allclose(ours.members, ref.x[:, 0], rtol=1e-9, atol=1e-13, err_msg=where)
        np.testing.assert_allclose(ours.weights, ref.weights, rtol=1e-8, atol=1e-12, err_msg=where)
        assert ours.partner_variance == pytest.approx(ref.partner_variance, rel=1e-8), where
        flags[k] = ours.change_point, ours.channel_admitted
        ours.predict(u[k])
        ref.predict(u[k])
        np.testing.assert_allclose(ours.members, ref.x[:, 0], rtol=1e-9, atol=1e-13, err_msg=f"{where}, prior")
    # The run exercised every branch: change points, suspensions, a missing channel.
    assert flags[:, 0].sum() >= 4
    assert (~flags[:, 1]).sum() > 200


def test_a_precise_channel_is_followed_and_a_useless_one_ignored():
    def rmse(est, e):
        return float(np.sqrt(np.mean((est[1000:] - e[1000:]) ** 2)))

    for channel_std, better_than, own_weight in ((1e-3, 0.5, (None, 1e-3)), (0.3, 1.01, (0.5, None))):
        y, c, u, e = streams(6000, seed=5, channel_std=channel_std, lag=0)
        c[:] = np.where(np.isnan(c), e + np.random.default_rng(9).normal(0, channel_std, len(e)), c)
        gi = core(MODEL)
        gi.reset(y[0])
        own, mix = np.empty(len(e)), np.empty(len(e))
        for k in range(len(e)):
            gi.update(np.array([y[k, 0], y[k, 1], c[k]]))
            own[k], mix[k] = gi.x_own[0], gi.x[0]
            gi.predict(u[k])
        assert rmse(mix, e) < better_than * rmse(own, e)
        lo, hi = own_weight
        if lo is not None:
            assert gi.weights[0] > lo  # own sensing alone takes the weight
        if hi is not None:
            assert gi.weights[0] < hi  # own sensing alone: no weight


def test_a_jump_suspends_a_lagging_channel_until_it_agrees_again():
    k0, lag = 3000, 15
    y, c, u, _ = streams(3100, seed=3, channel_std=1e-3, lag=lag, jumps=(k0,))
    gi = core(MODEL)
    gi.reset(y[0])
    flags = []
    for k in range(k0 + 40):
        gi.update(np.array([y[k, 0], y[k, 1], c[k]]))
        flags.append((gi.change_point, gi.channel_admitted))
        gi.predict(u[k])
    flags = np.array(flags[k0:])
    assert flags[0, 0] and not flags[1:, 0].any()  # one change point, at the jump
    readmit = int(np.argmax(flags[:, 1]))
    assert lag - 2 <= readmit <= lag + 2  # suspended while it lags
    assert flags[readmit:, 1].all()
    assert math.isinf(gi.partner_variance) is False


def test_bad_input_is_refused_and_changes_nothing():
    gi = core(MODEL)
    gi.reset([0.0, 0.0])
    gi.update(np.array([0.01, 0.0, 0.01]))
    before = gi.members.copy()
    with pytest.raises(sensaug.UkfStepError):
        gi.update(np.array([math.nan, 0.0, 0.0]))
    np.testing.assert_array_equal(gi.members, before)
    with pytest.raises(ValueError, match="^gate: must be finite and > 0"):
        core(MODEL, Params(gate=0.0))
    with pytest.raises(ValueError, match=r"^Q: its \(0, 0\) entry"):
        sensaug.GoalIntegrator(mass=1.0, Q=np.diag([0.0, 1e-8]), R=MODEL.R, x0=[0, 0], P0=MODEL.P0)


def _robot_streams(trial: experiment.Trial):
    """The robot's stage-3 inputs of the integration phase, read back from
    the log: own ``[e_meas, xdot_meas]``, the channel ``x_meas - tau_h^``
    and the known torque ``u + u_h^``; ``u_h^`` from the logged stage-2 gains
    with the own estimate standing in for the stage-2 posterior's own error
    (its gain ``Lhx^`` is ~0, so the stand-in costs far below the tolerance)."""
    d = trial.data
    m = trial.phase_mask(trial.phases_of("integration")[0])
    v = d["xdot_meas"][m]
    c = d["x_meas"][m] - d["tau_h_hat"][m]
    u_h = -(d["Lhx_hat"][m] * d["e_hat_own"][m] + d["Lhv_hat"][m] * v + d["Lhh_hat"][m] * c)
    return np.column_stack([d["e_meas"][m], v]), c, d["u"][m] + u_h, d, m


def test_the_robot_of_a_simulated_trial_runs_the_documented_bank():
    """The controller wires stage 3 as documented: the oracle, fed the
    robot's logged inputs, reproduces the logged own and integrated
    estimates (closed loop: the integrated estimate drove the commands)."""
    cfg = presets.simulation_integration(presets.INFERIOR_R, presets.SUPERIOR_R, seed=21, phase_s=6.0)
    trial = experiment.run(cfg)
    y, c, u, d, m = _robot_streams(trial)
    s3 = cfg.robot.stage3
    sigma = cfg.phases[2].target_noise_std
    model = Model(
        mass=cfg.plant.mass,
        damping=cfg.plant.damping,
        dt_s=cfg.plant.dt_s,
        Q=np.diag(s3.Q),
        R=np.diag(s3.R_sensor) + np.diag([sigma**2, 0.0]),
        P0=np.diag(s3.P0),
    )
    ref = AdaptiveChannel(model)
    ref.reset(y[0])
    fused, own = np.empty(len(u)), np.empty(len(u))
    for k in range(len(u)):
        ref.update(y[k], c[k])
        fused[k], own[k] = ref.estimate[0], ref.x[0, 0]
        ref.predict(u[k])
    truth = (d["x"] - d["tau"])[m]
    scale = float(np.sqrt(np.mean((own - truth) ** 2)))
    assert np.max(np.abs(own - d["e_hat_own"][m])) < 1e-6 * scale
    assert np.max(np.abs(fused - d["e_hat_fused"][m])) < 1e-6 * scale
