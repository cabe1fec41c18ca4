"""Run whole trials and read their logs as numpy arrays.

``run(config)`` resolves a validated :class:`~sensaug.config.ScenarioConfig`
(LQR weights to gains, covariances to matrices), crosses into Rust once for
the whole trial, and returns a :class:`Trial`: a log of the one schema
(``sensaug.logs``, ``docs/logs.md``) plus the configuration that produced it.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sensaug import _core, logs, metrics
from sensaug.config import PHASE_KINDS, ScenarioConfig, _shape_to_dict
from sensaug.lqr import agent_gains

__all__ = ["Trial", "run", "resolve", "FIELDS"]

#: Column names of ``Trial.data`` (the one log schema, ``sensaug.logs``).
FIELDS: tuple[str, ...] = logs.COLUMNS


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


@dataclass(repr=False)
class Trial(logs.Log):
    """One trial's log and the configuration that produced it.

    ``data`` is a structured array (one record per tick) with the columns of
    the one log schema (:data:`FIELDS`, ``docs/logs.md``); ``trial["x"]`` is a
    column; ``meta`` holds the configuration, versions and units. ``phase``
    is an integer code, its names in ``meta["phase_names"]`` (0 gains,
    1 trajectory, 2 integration). Estimates a phase does not produce are NaN.
    ``save(path)`` writes the log file, ``Trial.load(path)`` reads it back.
    """

    config: ScenarioConfig = None  # type: ignore[assignment]
    summary: dict[str, Any] = field(default_factory=dict)
    robot_gains: np.ndarray = field(default_factory=lambda: np.zeros(3))
    partner_gains: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def load(cls, path: str | Path) -> "Trial":
        """A trial from a log file (``Trial.save`` or a rig log): the
        configuration rebuilt from its metadata, the summary from its end line."""
        log = logs.load_log(path)
        try:
            config = ScenarioConfig.from_dict(log.meta["config"])
        except (KeyError, TypeError) as e:
            raise ValueError(f"{path}: metadata has no usable configuration ({e})") from None
        resolved = log.meta.get("resolved") or {}
        return cls(
            data=log.data,
            meta=log.meta,
            config=config,
            summary=dict(log.meta.get("end") or {}),
            robot_gains=np.asarray(resolved.get("robot", {}).get("gains", np.zeros(3)), dtype=float),
            partner_gains=np.asarray(resolved.get("partner", {}).get("gains", np.zeros(3)), dtype=float),
        )

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


@functools.lru_cache(maxsize=1)
def _git_commit() -> str | None:
    """The git commit of this package's checkout (looked up once per process)."""
    return _core.git_commit(str(Path(__file__).resolve().parent))


def run(config: ScenarioConfig) -> Trial:
    """Runs one whole trial in the compiled core and returns its log."""
    resolved = resolve(config)
    meta = _core.simulation_meta(
        config_json=logs.to_json(config.to_dict()),
        resolved_json=logs.to_json(resolved),
        git_commit=_git_commit(),
    )
    columns, summary = _core.run_scenario(resolved)
    summary = dict(summary)
    meta = json.loads(meta)
    meta["end"] = summary
    return Trial(
        data=logs.from_columns(columns),
        meta=meta,
        config=config,
        summary=summary,
        robot_gains=resolved["robot"]["gains"],
        partner_gains=resolved["partner"]["gains"],
    )
