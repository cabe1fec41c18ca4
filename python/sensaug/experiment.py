"""Run whole trials and read their logs as numpy arrays.

``run(config)`` resolves a validated :class:`~sensaug.config.ScenarioConfig`
(LQR weights to gains, covariances to matrices), crosses into Rust once for
the whole trial, and returns a :class:`Trial` whose ``data`` is a numpy
structured array with one named field per logged quantity.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sensaug import _core, metrics
from sensaug.config import PHASE_KINDS, ScenarioConfig, _shape_to_dict
from sensaug.lqr import agent_gains

__all__ = ["Trial", "run", "resolve", "FIELDS"]

FIELDS: tuple[str, ...] = tuple(_core.RECORD_FIELDS)


def _robot_gains(cfg: ScenarioConfig) -> list[float]:
    k_pos, k_vel = agent_gains(cfg.plant.mass, cfg.plant.damping, cfg.robot.q_pos, cfg.robot.q_vel)
    return [k_pos, k_vel, 0.0]


def _partner_gains(cfg: ScenarioConfig) -> list[float]:
    p = cfg.partner
    if p.gains is not None:
        return list(p.gains)
    k_pos, k_vel = agent_gains(cfg.plant.mass, cfg.plant.damping, p.q_pos, p.q_vel)
    return [0.0, k_vel, k_pos]


def resolve(cfg: ScenarioConfig) -> dict[str, Any]:
    """The plain dict the compiled runner takes: gains computed, matrices as arrays."""
    cfg.validate()
    r = cfg.robot
    a = np.asarray

    def extended(fc: Any) -> dict[str, Any]:
        x0 = np.zeros(6)
        x0[3:] = fc.gains0
        return {"x0": x0, "P0": a(fc.P0), "Q": a(fc.Q), "R": a(fc.R)}

    return {
        "plant": vars(cfg.plant).copy(),
        "world": vars(cfg.world).copy(),
        "robot": {
            "gains": a(_robot_gains(cfg), dtype=float),
            "model": {"mass": cfg.plant.mass, "damping": cfg.plant.damping},
            "integrate": r.integrate,
            "gain_window_s": r.gain_window_s,
            "torque_limit": r.torque_limit,
            "seed": r.seed,
            "prior_partner_gains": None if r.prior_partner_gains is None else a(r.prior_partner_gains, dtype=float),
            "sigma": vars(r.sigma).copy(),
            "stage1": extended(r.stage1),
            "stage2": extended(r.stage2),
            "stage3": {
                "Q": a(r.stage3.Q),
                "R_sensor": a(r.stage3.R_sensor),
                "P0": a(r.stage3.P0),
                "partner_window_s": r.stage3.partner_window_s,
            },
        },
        "partner": {
            "gains": a(_partner_gains(cfg), dtype=float),
            "torque_limit": cfg.partner.torque_limit,
            "estimates_robot": cfg.partner.estimates_robot,
        },
        "phases": [
            {
                "kind": p.kind,
                "duration_s": p.duration_s,
                "target_noise_std": p.target_noise_std,
                "robot_target": [_shape_to_dict(s) for s in p.robot_target],
                "partner_target": [_shape_to_dict(s) for s in p.partner_target],
            }
            for p in cfg.phases
        ],
    }


@dataclass
class Trial:
    """One trial's log and the configuration that produced it.

    ``data`` is a structured array (one record per tick) with the fields in
    :data:`FIELDS`; ``trial["x"]`` is a column. Phase codes: 0 gains,
    1 trajectory, 2 integration. Estimates a phase does not produce are NaN.
    """

    config: ScenarioConfig
    data: np.ndarray
    summary: dict[str, int]
    robot_gains: np.ndarray = field(default_factory=lambda: np.zeros(3))
    partner_gains: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __getitem__(self, name: str) -> np.ndarray:
        return self.data[name]

    def __len__(self) -> int:
        return len(self.data)

    def phase_mask(self, index: int, *, last_s: float | None = None, skip_s: float = 0.0) -> np.ndarray:
        """Ticks of phase ``index`` (position in ``config.phases``), optionally
        only its last ``last_s`` seconds or without its first ``skip_s``."""
        if not 0 <= index < len(self.config.phases):
            raise ValueError(f"index: phase {index} does not exist (trial has {len(self.config.phases)})")
        t = self.data["t"]
        dt = self.config.plant.dt_s
        start = sum(p.duration_s for p in self.config.phases[:index])
        end = start + self.config.phases[index].duration_s
        lo = start + skip_s if last_s is None else end - last_s
        return (t >= lo - dt / 2) & (t < end - dt / 2)

    def phases_of(self, kind: str) -> list[int]:
        """Indices of the phases of ``kind`` ('gains', 'trajectory', 'integration')."""
        if kind not in PHASE_KINDS:
            raise ValueError(f"kind: must be one of {PHASE_KINDS}, got {kind!r}")
        return [i for i, p in enumerate(self.config.phases) if p.kind == kind]

    # --- the paper's headline numbers --------------------------------------

    def gain_estimate(self, index: int | None = None, *, last_s: float = 8.0) -> np.ndarray:
        """Mean estimated partner gains ``[Lhx, Lhv, Lhh]`` over the last
        ``last_s`` of a gain phase (the paper reports the final 8 s)."""
        return metrics.gain_estimate(self.data, self.phase_mask(self._default(index, "gains"), last_s=last_s))

    def partner_target_rmse(self, index: int | None = None, *, skip_s: float = 2.0) -> float:
        """RMSE of ``tau_h^`` against ``tau_h`` in a trajectory phase, after ``skip_s``."""
        return metrics.partner_target_rmse(self.data, self.phase_mask(self._default(index, "trajectory"), skip_s=skip_s))

    def integration_rmse(self, index: int | None = None, *, skip_s: float = 2.0) -> dict[str, float]:
        """RMSE of the robot's ``(x - tau)^`` against the true ``x - tau`` in an
        integration phase: raw measurement, own sensing only, integrated."""
        return metrics.integration_rmse(self.data, self.phase_mask(self._default(index, "integration"), skip_s=skip_s))

    def _default(self, index: int | None, kind: str) -> int:
        if index is not None:
            return index
        found = self.phases_of(kind)
        if not found:
            raise ValueError(f"index: this trial has no {kind!r} phase")
        return found[0]


def run(config: ScenarioConfig) -> Trial:
    """Runs one whole trial in the compiled core and returns its log."""
    resolved = resolve(config)
    rows, summary = _core.run_scenario(resolved)
    data = np.rec.fromarrays(rows.T, names=list(FIELDS))
    return Trial(
        config=config,
        data=np.asarray(data),
        summary=dict(summary),
        robot_gains=resolved["robot"]["gains"],
        partner_gains=resolved["partner"]["gains"],
    )
