"""The Hi5 trial with the human-like partner, batched over seeds (numpy).

Same equations as ``tests/oracles/human_partner.py`` (checked against it in
``check_world.py``) and the project's world: per tick, sense (robot's
measurement ``x + n_x``, ``v + n_v``), robot command (LQR on the measurement
and its known target; in the integration phase a caller-supplied command),
partner torque on its delayed view of that same measured sample, world motor
noise, exact ZOH plant step (C = 0).

Noise streams per seed: world ``default_rng([seed, 0])`` (n_x, n_v, eps per
tick), partner ``default_rng([seed, 24])`` (motor noise, drift), robot's
target view ``default_rng([seed, 2])``. Changing the partner's delays changes
no draw.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from settings import Hi5, chirp, rounded_square

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests" / "oracles"))
from human_partner import HumanSettings  # noqa: E402

PHASES = ("gains", "trajectory", "integration")


def targets(h: Hi5) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``tau``, ``tau_h`` at every tick of the three phases, their increments
    to the next tick (from the phase of the tick), and the phase index."""
    T = h.ticks
    k = np.arange(3 * T)
    t = k * h.dt
    t1 = (k + 1) * h.dt
    phase = k // T
    rs, rs1 = rounded_square(h, t), rounded_square(h, t1)
    gains = phase == 0
    tau = rs + np.where(gains, chirp(h, t), 0.0)
    tau1 = rs1 + np.where(gains, chirp(h, t1), 0.0)
    return tau, rs, tau1 - tau, rs1 - rs, phase


@dataclass
class World:
    """Batched world state and its records (B seeds x 3T ticks)."""

    h: Hi5
    partners: list[HumanSettings]
    seeds: list[int]
    B: int = 0
    k: int = 0
    rec: dict = field(default_factory=dict)

    def __post_init__(self):
        h, B, N = self.h, len(self.seeds), 3 * self.h.ticks
        self.B = B
        self.tau, self.tau_h, self.dtau, self.dtau_h, self.phase = targets(h)
        w = [np.random.default_rng([s, 0]).standard_normal((3, N)) for s in self.seeds]
        self.n_x = np.stack([a[0] for a in w])
        self.n_v = np.stack([a[1] for a in w])
        self.n_eps = np.stack([a[2] for a in w])
        self.n_view = np.stack([np.random.default_rng([s, 2]).standard_normal(N) for s in self.seeds])
        # The partner's own stream, drawn as the oracle draws it.
        pn, pw = [], []
        for p in self.partners:
            rng = np.random.default_rng([p.seed, 24])
            pn.append(rng.standard_normal(N))
            pw.append(rng.standard_normal((N, 3)))
        self.p_noise, self.p_drift_w = np.stack(pn), np.stack(pw)
        self.L0 = np.array([p.gains for p in self.partners], float)  # (B, 3)
        dvp = np.array([p.ticks(h.dt) for p in self.partners])
        self.dv, self.dp = dvp[:, 0], dvp[:, 1]
        self.km = np.array([p.motor_noise_gain for p in self.partners])
        self.drift_std = np.array([p.drift_std for p in self.partners])
        self.drift_rho = np.array([math.exp(-h.dt / p.drift_time_constant_s) for p in self.partners])
        self.limit = np.array([p.torque_limit for p in self.partners])
        self.delta = np.zeros((B, 3))
        self.x = np.zeros(B)
        self.v = np.zeros(B)
        for name in ("x", "v", "xm", "vm", "u", "u_h", "e_meas"):
            self.rec[name] = np.full((B, N), np.nan)
        self.rec["gains"] = np.full((B, N, 3), np.nan)
        self.rows = np.arange(B)

    def sense(self) -> tuple[np.ndarray, np.ndarray]:
        k, h = self.k, self.h
        xm = self.x + h.sensor_std * self.n_x[:, k]
        vm = self.v + h.sensor_std * self.n_v[:, k]
        self.rec["x"][:, k], self.rec["v"][:, k] = self.x, self.v
        self.rec["xm"][:, k], self.rec["vm"][:, k] = xm, vm
        return xm, vm

    def robot_lqr(self, xm, vm) -> np.ndarray:
        """``u = guard(-(kp (x_m - tau) + kv v_m))`` (targets known)."""
        h = self.h
        return np.clip(-(h.kp * (xm - self.tau[self.k]) + h.kv * vm), -h.torque_limit, h.torque_limit)

    def partner(self) -> np.ndarray:
        """The human-like partner on its delayed view of the measured samples."""
        k, r = self.k, self.rec
        iv, ip = np.maximum(k - self.dv, 0), np.maximum(k - self.dp, 0)
        xm_v, vm_p = r["xm"][self.rows, iv], r["vm"][self.rows, ip]
        L = self.L0 * (1.0 + self.delta)
        c = -(L[:, 0] * (xm_v - self.tau[iv]) + L[:, 1] * vm_p + L[:, 2] * (xm_v - self.tau_h[iv]))
        u = c + self.km * np.abs(c) * self.p_noise[:, k]
        u = np.where(np.isfinite(u), np.clip(u, -self.limit, self.limit), 0.0)
        r["gains"][:, k] = L
        sd = self.drift_std[:, None]
        rho = self.drift_rho[:, None]
        self.delta = np.where(
            sd > 0, np.clip(rho * self.delta + sd * np.sqrt(1 - rho * rho) * self.p_drift_w[:, k], -3 * sd, 3 * sd), 0.0
        )
        return u

    def step(self, u: np.ndarray) -> np.ndarray:
        """Partner torque, motor noise, plant; returns the partner's torque."""
        h, k = self.h, self.k
        u_h = self.partner()
        f = u + u_h + h.motor_std * self.n_eps[:, k]
        self.rec["u"][:, k], self.rec["u_h"][:, k] = u, u_h
        self.x, self.v = self.x + h.dt * self.v + 0.5 * h.dt * h.dt * f / h.M, self.v + h.dt * f / h.M
        self.k += 1
        return u_h

    def run_open(self, ticks: int) -> None:
        """Ticks in which the robot's command needs no estimate (gain and
        trajectory phases)."""
        for _ in range(ticks):
            xm, vm = self.sense()
            self.rec["e_meas"][:, self.k] = xm - self.tau[self.k]
            self.step(self.robot_lqr(xm, vm))

    def copy(self) -> "World":
        import copy

        return copy.deepcopy(self)
