"""Reference implementation of the human-like virtual partner (issue 24),
written from the equations in docs/design/partner_delay.md, section
"The human-like partner". numpy only; one partner, one tick at a time.

Settings (the future ``partner.human.*`` table, times in ms, gains over
``xi = [x - tau, xdot, x - tau_h]``):

* ``visual_delay_ms``  d_v: the target-related terms (the cursor-minus-target
  errors ``x - tau`` and ``x - tau_h``) are those displayed ``d_v`` ago;
* ``proprioceptive_delay_ms``  d_p: the velocity term is ``xdot`` of ``d_p`` ago;
* ``motor_noise_gain``  k_m: the command gets white noise of std
  ``k_m |c|`` (signal-dependent); the constant floor is the world's existing
  ``motor_noise_std`` on the summed torque (one concept, not two);
* ``gain_drift``  (sigma_d, T_d): each gain is ``L_i (1 + delta_i)``,
  ``delta`` a bounded Ornstein-Uhlenbeck walk of stationary relative std
  ``sigma_d`` and time constant ``T_d``, clipped to ``+-3 sigma_d``;
* ``seed``: the partner's own stream (its motor noise and drift), so a
  partner setting changes no other noise draw.

Delays are whole ticks, ``round(ms / 1000 / dt)``. Before the trial's first
tick the partner has seen the first sample (the handle at rest there): the
history index is clamped at 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class HumanSettings:
    gains: tuple[float, float, float]  # nominal L_h = [Lhx, Lhv, Lhh]
    visual_delay_ms: float = 0.0
    proprioceptive_delay_ms: float = 0.0
    motor_noise_gain: float = 0.0
    drift_std: float = 0.0  # relative
    drift_time_constant_s: float = 10.0
    torque_limit: float = 1e3
    seed: int = 0

    def ticks(self, dt: float) -> tuple[int, int]:
        return round(self.visual_delay_ms * 1e-3 / dt), round(self.proprioceptive_delay_ms * 1e-3 / dt)


def delayed_index(k: int, d: int) -> int:
    """``max(k - d, 0)``: the sample the partner perceives at tick ``k``."""
    return max(k - d, 0)


def drift_step(delta: np.ndarray, w: np.ndarray, dt: float, std: float, T: float) -> np.ndarray:
    """``delta[k+1] = clip(rho delta[k] + std sqrt(1 - rho^2) w, -3 std, 3 std)``,
    ``rho = exp(-dt / T)`` (stationary std ``std``, correlation time ``T``)."""
    rho = math.exp(-dt / T)
    return np.clip(rho * delta + std * math.sqrt(1 - rho * rho) * w, -3 * std, 3 * std)


def partner_command(gains: np.ndarray, e_v: float, v_p: float, eh_v: float) -> float:
    """``c = -(Lhx e(k - d_v) + Lhv v(k - d_p) + Lhh e_h(k - d_v))`` (eq.LQRhuman
    on the perceived state)."""
    return -(gains[0] * e_v + gains[1] * v_p + gains[2] * eh_v)


def motor_noise(c: float, gain: float, n: float) -> float:
    """Signal-dependent motor noise: ``k_m |c| n``, ``n ~ N(0, 1)``."""
    return gain * abs(c) * n


def guard(u: float, limit: float) -> float:
    """The core's torque guard: clamp to the limit, non-finite -> 0."""
    if not math.isfinite(u):
        return 0.0
    return min(max(u, -limit), limit)


class HumanPartner:
    """The partner's torque, tick by tick. ``torque(k, x, v, tau, tau_h)`` is
    called once per tick in order with the sample the partner senses (the
    robot's measured sample, as the project's ``acts_on = "measured"``)."""

    def __init__(self, s: HumanSettings, dt: float, ticks: int):
        self.s, self.dt = s, dt
        self.dv, self.dp = s.ticks(dt)
        self.e = np.zeros(ticks)
        self.v = np.zeros(ticks)
        self.eh = np.zeros(ticks)
        self.delta = np.zeros(3)
        rng = np.random.default_rng([s.seed, 24])
        self.noise = rng.standard_normal(ticks)
        self.drift_w = rng.standard_normal((ticks, 3))
        self.gains_now = np.array(s.gains, float)

    def torque(self, k: int, x: float, v: float, tau: float, tau_h: float) -> float:
        self.e[k], self.v[k], self.eh[k] = x - tau, v, x - tau_h
        iv, ip = delayed_index(k, self.dv), delayed_index(k, self.dp)
        self.gains_now = np.asarray(self.s.gains) * (1.0 + self.delta)
        c = partner_command(self.gains_now, self.e[iv], self.v[ip], self.eh[iv])
        u = c + motor_noise(c, self.s.motor_noise_gain, self.noise[k])
        if self.s.drift_std > 0:
            self.delta = drift_step(self.delta, self.drift_w[k], self.dt, self.s.drift_std, self.s.drift_time_constant_s)
        return guard(u, self.s.torque_limit)
