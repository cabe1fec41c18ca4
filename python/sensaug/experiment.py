"""Run whole trials and read their logs as numpy arrays.

``run(config)`` hands a :class:`~sensaug.config.ScenarioConfig` to Rust,
where the one configuration schema resolves it (LQR weights to gains,
covariances to matrices) and the core runs the whole trial in one call; it
returns a :class:`Trial` whose ``data`` is a numpy structured array with one
named field per logged quantity.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sensaug import _core, metrics
from sensaug.config import ScenarioConfig

__all__ = ["Trial", "run", "FIELDS"]

FIELDS: tuple[str, ...] = tuple(_core.RECORD_FIELDS)

#: The phase kinds, in the order of their codes in logs.
PHASE_KINDS: tuple[str, ...] = ("gains", "trajectory", "integration")


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
    summary: dict[str, Any]
    rows, summary = _core.run_scenario(config._toml())
    data = np.rec.fromarrays(rows.T, names=list(FIELDS))
    robot_gains = np.asarray(summary.pop("robot_gains"))
    partner_gains = np.asarray(summary.pop("partner_gains"))
    return Trial(
        config=config,
        data=np.asarray(data),
        summary=summary,
        robot_gains=robot_gains,
        partner_gains=partner_gains,
    )
