"""Reference implementation (numpy) of stage 3's adaptive partner channel.

Written from the equations of ``docs/model.md`` ("Stage 3: the adaptive
partner channel", labels S1-S4, U1-U10, P1), not from the Rust: the
independent oracle of the core's ``GoalIntegrator`` (``sensaug._core``), which
``tests/test_goal_integration.py`` compares tick by tick. Where the core runs
scalar, closed-form updates over arrays of members, this runs one stacked
matrix Kalman update per member (``numpy.linalg.solve``).

One agent's goal integration: the state is ``s = [e, v]`` with
``e = x - tau`` (the agent's own target) and ``v = xdot``; per tick it has its
own measurement ``y = [e_meas, v_meas]`` (covariance ``R``, target-view noise
included), the partner channel ``c = (x - tau_h)^`` (NaN: none) and the known
torque ``u`` for the prediction ``s' = F s + b(u)``, ``P' = F P F' + Q``.
Member 0 uses the own measurement only, member ``i >= 1`` also the channel at
a fixed variance ``r_i``; the members are scored by their one-step
predictions of the own position measurement and mixed by those scores; a
change-point test on member 0's innovation inflates the priors and suspends
the channel until it agrees with the own measurement again.

Units are the caller's (m or deg, N m or model torque units); covariances
are per step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

#: Measurement matrices on ``s = [e, v]``: own ``[e, v]``; own and channel ``[e, v, e]``.
H_OWN = np.array([[1.0, 0.0], [0.0, 1.0]])
H_FUSED = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])


@dataclass(frozen=True)
class Model:
    """The stage-3 model of one agent: handle, process noise ``Q``, own
    measurement noise ``R`` and initial covariance ``P0`` (2x2 each)."""

    mass: float
    damping: float
    dt_s: float
    Q: Array
    R: Array
    P0: Array

    def transition(self, u: float, dtau: float = 0.0) -> tuple[Array, Array]:
        """``F = [[1, dx_v], [0, v_v]]``, ``b = [dx_f u - dtau, v_f u]`` with
        ``dx_f = dt^2 / (2 M)``, ``dx_v = dt - dx_f C``, ``v_f = dt / M``,
        ``v_v = 1 - v_f C`` (``docs/model.md``)."""
        dt, m, c = self.dt_s, self.mass, self.damping
        dx_f, v_f = 0.5 * dt * dt / m, dt / m
        F = np.array([[1.0, dt - dx_f * c], [0.0, 1.0 - v_f * c]])
        b = np.array([dx_f * u - dtau, v_f * u])
        return F, b


@dataclass(frozen=True)
class Params:
    """The channel's settings (``[robot.stage3.channel]``) and the design's constants."""

    gate: float = 4.0
    window_n0: float = 80.0
    hold_max_s: float = 0.25
    members: int = 7
    low: float = 1.0 / 64.0
    high: float = 16.0


def steady_state_posterior(q: float, r: float) -> float:
    """(S1) ``A``: the fixed point of ``Pm = P + q``, ``P = Pm r / (Pm + r)``,
    found by solving the quadratic ``Pm^2 - q Pm - q r = 0``."""
    pm = np.roots([1.0, -q, -q * r]).real.max()
    return float(pm * r / (pm + r))


def channel_grid(q_e: float, A: float, p: Params) -> Array:
    """(S2, S3) ``K`` geometric steps from ``low min(q_e, A)`` to ``high A``."""
    return np.geomspace(p.low * min(q_e, A), p.high * A, p.members)


@dataclass
class AdaptiveChannel:
    """The bank of one agent: ``x[i]``, ``P[i]`` member ``i``'s posterior
    (after :meth:`update`) or prior (after :meth:`predict`), ``score[i]`` its
    score, ``hold`` the ticks left in which the channel is suspended."""

    model: Model
    params: Params = field(default_factory=Params)
    r: Array = field(init=False)
    A: float = field(init=False)
    alpha: float = field(init=False)
    x: Array = field(init=False)
    P: Array = field(init=False)
    score: Array = field(init=False)
    hold: int = field(init=False, default=0)
    # What the last update did.
    weights: Array = field(init=False)
    estimate: Array = field(init=False)
    variance: Array = field(init=False)
    change_point: bool = field(init=False, default=False)
    admitted: bool = field(init=False, default=False)

    def __post_init__(self) -> None:
        n = self.params.members + 1
        self.x = np.zeros((n, 2))
        self.P = np.zeros((n, 2, 2))
        self.score = np.zeros(n)
        self.set_own_noise(self.model.R)

    @property
    def hold_ticks(self) -> int:
        return int(round(self.params.hold_max_s / self.model.dt_s))

    def set_own_noise(self, R: Array) -> None:
        """(S1-S4) ``A`` from ``q_e = Q[0, 0]`` and ``R_e = R[0, 0]``, the
        grid (member 0: infinite variance), ``alpha = 1 / (n0 (1 + R_e / A))``."""
        self.R = np.asarray(R, dtype=float)
        q_e, r_e = self.model.Q[0, 0], self.R[0, 0]
        self.A = steady_state_posterior(q_e, r_e)
        self.r = np.concatenate([[math.inf], channel_grid(q_e, self.A, self.params)])
        self.alpha = 1.0 / (self.params.window_n0 * (1.0 + r_e / self.A))

    def reset(self, x0: Array) -> None:
        """Phase start: every member at ``x0`` with ``P0``; scores 0, no hold."""
        self.x[:] = np.asarray(x0, dtype=float)
        self.P[:] = self.model.P0
        self.score[:] = 0.0
        self.hold = 0

    def update(self, y: Array, c: float) -> None:
        """(U1-U10) One tick's update; sets ``estimate`` (the mixture ``[e, v]``),
        ``variance``, ``weights``, ``change_point``, ``admitted``."""
        p, r_e = self.params, self.R[0, 0]
        g2 = p.gate**2
        y = np.asarray(y, dtype=float)
        nu = y[0] - self.x[:, 0]  # (U1)
        s0 = self.P[0, 0, 0] + r_e
        self.change_point = bool(nu[0] ** 2 > g2 * s0)  # (U2)
        finite = math.isfinite(c)
        if self.change_point:  # (U3)
            self.P[:, 0, 0] += nu[0] ** 2 - g2 * s0
            self.hold = self.hold_ticks
        elif self.hold > 0 and finite and (c - y[0]) ** 2 <= g2 * (r_e + self.A):  # (U4)
            self.hold = 0
        self.admitted = finite and self.hold == 0  # (U5)
        if not self.change_point:  # (U6)
            self.score += self.alpha * (nu * nu / s0 - self.score)
        # (U7) Member 0, and every member while the channel is out: own sensing.
        n = len(self.r)
        own = slice(0, 1) if self.admitted else slice(0, n)
        self.x[own], self.P[own] = kalman_update(self.x[own], self.P[own], y, H_OWN, self.R)
        if self.admitted:
            R = np.zeros((n - 1, 3, 3))
            R[:, :2, :2] = self.R
            R[:, 2, 2] = self.r[1:]
            z = np.array([y[0], y[1], c])
            self.x[1:], self.P[1:] = kalman_update(self.x[1:], self.P[1:], z, H_FUSED, R)
        # (U8) Weights from the scores, (U9) the mixture.
        w = np.exp(-(self.score - self.score.min()) / (2.0 * self.alpha))
        self.weights = w / w.sum()
        self.estimate = self.weights @ self.x
        spread = (self.x - self.estimate) ** 2
        self.variance = self.weights @ (np.diagonal(self.P, axis1=1, axis2=2) + spread)
        if self.hold > 0:  # (U10)
            self.hold -= 1

    def predict(self, u: float, dtau: float = 0.0) -> None:
        """(P1) ``x_i' = F x_i + b``, ``P_i' = F P_i F' + Q``."""
        F, b = self.model.transition(u, dtau)
        self.x = self.x @ F.T + b
        self.P = F @ self.P @ F.T + self.model.Q

    @property
    def partner_variance(self) -> float:
        """``1 / sum_i (w_i / r_i)``; infinite when the channel was not fused."""
        precision = float(np.sum(self.weights / self.r))
        if not self.admitted or precision == 0.0:
            return math.inf
        with np.errstate(over="ignore"):
            return float(np.float64(1.0) / precision)


def kalman_update(x: Array, P: Array, z: Array, H: Array, R: Array) -> tuple[Array, Array]:
    """``S = H P H' + R``, ``K = P H' S^-1``, ``x + K (z - H x)``, ``P - K S K'``;
    ``x``, ``P`` (and ``R``) may carry a leading axis of members."""
    S = H @ P @ H.T + R
    PHt = P @ H.T
    K = np.swapaxes(np.linalg.solve(S, np.swapaxes(PHt, -1, -2)), -1, -2)
    nu = z - x @ H.T
    x = x + (K @ nu[..., None])[..., 0]
    P = P - K @ S @ np.swapaxes(K, -1, -2)
    return x, 0.5 * (P + np.swapaxes(P, -1, -2))
