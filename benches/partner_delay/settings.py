"""The Hi5 experiment's numbers, read from ``sensaug.presets.hi5_experiment``
(so the prototype measures exactly the project's settings: M, dt, the robot's
LQR gains, Q_k, R, P0, the targets in degrees, the noise levels)."""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sensaug import presets

# The handle's step is the oracles' (tests/oracles), one definition for the
# prototype and the tests.
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests" / "oracles"))
from delayed_stage1 import step_coefficients  # noqa: E402


@dataclass(frozen=True)
class Hi5:
    M: float  # inertia (model units: N m s^2 / deg)
    C: float
    dt: float  # s
    kp: float  # robot position gain (N m / deg)
    kv: float  # robot velocity gain (N m s / deg)
    motor_std: float  # world motor noise on the summed torque (N m)
    sensor_std: float  # position (deg) and velocity (deg/s) sensor noise std
    torque_limit: float
    phase_s: float
    gain_window_s: float
    rounded_amp: float
    rounded_period: float
    chirp_amp: float
    chirp_f0: float
    chirp_f1: float
    chirp_T: float
    Q1: np.ndarray
    R1: np.ndarray
    P01: np.ndarray
    Q2: np.ndarray
    R2: np.ndarray
    P02: np.ndarray
    Q3: np.ndarray
    R3: np.ndarray
    P03: np.ndarray
    partner_window_s: float
    target_noise_std: float  # robot's view of its own target in stage 3 (deg)

    @property
    def ticks(self) -> int:
        return int(round(self.phase_s / self.dt))

    @property
    def step(self) -> tuple[float, float, float, float]:
        """``(dx_v, dx_f, v_v, v_f)``: ``dx = dx_v v + dx_f f``, ``v' = v_v v + v_f f``."""
        return step_coefficients(self.M, self.C, self.dt)


def hi5(phase_s: float = 20.0) -> Hi5:
    cfg = presets.hi5_experiment(2.0, phase_s=phase_s)
    cfg.validate()
    rounded, chirp = cfg.phases[0].robot_target
    M, C = cfg.plant.mass, cfg.plant.damping
    q_pos, q_vel = cfg.robot.q_pos, cfg.robot.q_vel
    # Reduced 2-state LQR (docs/model.md), closed form for C = 0.
    assert C == 0.0
    kp = math.sqrt(q_pos)
    kv = math.sqrt(q_vel + 2 * M * math.sqrt(q_pos))
    s1, s2, s3 = cfg.robot.stage1, cfg.robot.stage2, cfg.robot.stage3
    assert cfg.world.position_noise_std == cfg.world.velocity_noise_std
    return Hi5(
        M=M,
        C=C,
        dt=cfg.plant.dt_s,
        kp=kp,
        kv=kv,
        motor_std=cfg.world.motor_noise_std,
        sensor_std=cfg.world.position_noise_std,
        torque_limit=cfg.robot.torque_limit,
        phase_s=phase_s,
        gain_window_s=cfg.robot.gain_window_s,
        rounded_amp=rounded.amplitude,
        rounded_period=rounded.period_s,
        chirp_amp=chirp.amplitude,
        chirp_f0=chirp.f0_hz,
        chirp_f1=chirp.f1_hz,
        chirp_T=chirp.duration_s,
        Q1=np.diag(s1.Q),
        R1=np.diag(s1.R),
        P01=np.diag(s1.P0),
        Q2=np.diag(s2.Q),
        R2=np.diag(s2.R),
        P02=np.diag(s2.P0),
        Q3=np.diag(s3.Q),
        R3=np.diag(s3.R_sensor),
        P03=np.diag(s3.P0),
        # Retired from the schema after the prototype (issue 22's adaptive
        # channel); the prototype's stage 3 keeps the old rule's 0.5 s.
        partner_window_s=getattr(s3, "partner_window_s", 0.5),
        target_noise_std=cfg.phases[2].target_noise_std,
    )


def rounded_square(h: Hi5, t: np.ndarray) -> np.ndarray:
    """``A cbrt(sin(2 pi t / T))`` (eqn:human_trajectory), degrees."""
    return h.rounded_amp * np.cbrt(np.sin(2 * np.pi * t / h.rounded_period))


def chirp(h: Hi5, t: np.ndarray) -> np.ndarray:
    """Linear chirp f0 -> f1 over T, continuing at f1 (target.rs), degrees."""
    f0, f1, T = h.chirp_f0, h.chirp_f1, h.chirp_T
    ph = np.where(t <= T, f0 * t + (f1 - f0) * t * t / (2 * T), (f0 + f1) * T / 2 + f1 * (t - T))
    return h.chirp_amp * np.sin(2 * np.pi * ph)
