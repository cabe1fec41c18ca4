"""Reference implementation of the delay-aware stage 1 (issue 24), written
from the equations in docs/design/partner_delay.md, section "Delay-aware
stage 1"; the independent oracle of the future step-by-step test of the
Rust filter. numpy only, one filter, one tick at a time, no batching.

State ``z = [e, v, e_h, Lhx, Lhv, Lhh]`` at tick ``k`` (``e = x - tau``,
``v = xdot``, ``e_h = x - tau_h``). The partner's torque is modelled on the
robot's own *measured* sample delayed by ``d_v`` ticks (the target-related
terms) and ``d_p`` ticks (the velocity):

    phi_k = [y_e[k - d_v], y_v[k - d_p], y_eh[k - d_v]]      (index clamped at 0)
    u_h   = -(Lhx phi_1 + Lhv phi_2 + Lhh phi_3)

so the process is *linear* in ``z`` (the regressor is data, not state):

    z' = F_k z + b_k,
    F_k = I6 except rows 0..2:
        e'   : [1, dx_v, 0, -dx_f phi_1, -dx_f phi_2, -dx_f phi_3]
        v'   : [0, v_v,  0, -v_f  phi_1, -v_f  phi_2, -v_f  phi_3]
        e_h' : [0, dx_v, 1, -dx_f phi_1, -dx_f phi_2, -dx_f phi_3]
    b_k = [dx_f u - dtau, v_f u, dx_f u - dtau_h, 0, 0, 0]

with the handle model's step ``dx_f = dt^2/(2M)``, ``dx_v = dt - dx_f C``,
``v_f = dt/M``, ``v_v = 1 - v_f C``. The unscented transform of an affine map
is exact, so the UKF of this process *is* this Kalman filter (checked against
filterpy's UKF in tests/test_partner_delay_oracle.py):

    predict:  z- = F z + b,  P- = F P F' + Q
    update:   nu = y - H z-,  S = H P- H' + R,  K = P- H' S^-1,
              z+ = z- + K nu,  P+ = P- - K S K'           (H = [I3 0])
    evidence: l_k = -(nu' S^-1 nu + ln det S + 3 ln 2 pi) / 2

Per tick, as the project's identifier: ``update(y_k)`` (which also stores
``y_k`` in the history), then ``predict(u_k, dtau_k, dtau_h_k)`` using
``phi_k`` from that history. At ``d_v = d_p = 0`` the regressor is the
current measurement.
"""

from __future__ import annotations

import math

import numpy as np

H = np.hstack([np.eye(3), np.zeros((3, 3))])


def step_coefficients(M: float, C: float, dt: float) -> tuple[float, float, float, float]:
    """``(dx_v, dx_f, v_v, v_f)`` of ``dx = dx_v v + dx_f f``, ``v' = v_v v + v_f f``."""
    dx_f, v_f = 0.5 * dt * dt / M, dt / M
    return dt - dx_f * C, dx_f, 1.0 - v_f * C, v_f


def regressor(history: list[np.ndarray], k: int, dv: int, dp: int) -> np.ndarray:
    """``phi_k = [y_e[k - d_v], y_v[k - d_p], y_eh[k - d_v]]``, index clamped at 0."""
    yv, yp = history[max(k - dv, 0)], history[max(k - dp, 0)]
    return np.array([yv[0], yp[1], yv[2]])


def transition(coef, phi: np.ndarray, u: float, dtau: float, dtau_h: float) -> tuple[np.ndarray, np.ndarray]:
    """``(F_k, b_k)`` of the delayed process."""
    dx_v, dx_f, v_v, v_f = coef
    F = np.eye(6)
    F[0, 1], F[1, 1], F[2, 1] = dx_v, v_v, dx_v
    F[0, 3:] = -dx_f * phi
    F[1, 3:] = -v_f * phi
    F[2, 3:] = -dx_f * phi
    b = np.array([dx_f * u - dtau, v_f * u, dx_f * u - dtau_h, 0.0, 0.0, 0.0])
    return F, b


class DelayedStage1:
    """One delay-aware stage-1 filter at delays ``(dv, dp)`` ticks."""

    def __init__(self, M, C, dt, Q, R, x0, P0, dv: int, dp: int):
        self.coef = step_coefficients(M, C, dt)
        self.Q, self.R = np.asarray(Q, float), np.asarray(R, float)
        self.x, self.P = np.array(x0, float), np.array(P0, float)
        self.P0 = self.P.copy()
        self.dv, self.dp = dv, dp
        self.history: list[np.ndarray] = []
        self.k = -1
        self.loglik = 0.0
        self.last_loglik = 0.0
        self.resets = 0

    def update(self, y) -> float:
        """Fuse ``y_k = [x_m - tau, v_m, x_m - tau_h]``; returns ``l_k``."""
        y = np.asarray(y, float)
        self.k += 1
        self.history.append(y.copy())
        nu = y - H @ self.x
        S = H @ self.P @ H.T + self.R
        try:
            Lc = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            # The core's repair path: measurement dropped, P reset.
            self.P = self.P0.copy()
            self.resets += 1
            self.last_loglik = -math.inf
            return self.last_loglik
        K = np.linalg.solve(S, H @ self.P).T  # P H' S^-1 (S symmetric)
        self.x = self.x + K @ nu
        self.P = self.P - K @ S @ K.T
        w = np.linalg.solve(Lc, nu)
        self.last_loglik = -0.5 * (w @ w + 2 * np.log(np.diag(Lc)).sum() + 3 * math.log(2 * math.pi))
        self.loglik += self.last_loglik
        return self.last_loglik

    def predict(self, u: float, dtau: float, dtau_h: float) -> None:
        phi = regressor(self.history, self.k, self.dv, self.dp)
        F, b = transition(self.coef, phi, u, dtau, dtau_h)
        self.x = F @ self.x + b
        self.P = F @ self.P @ F.T + self.Q

    @property
    def gains(self) -> np.ndarray:
        return self.x[3:].copy()
