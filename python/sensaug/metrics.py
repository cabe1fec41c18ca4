"""The paper's headline numbers from a log (simulated trial or rig run).

Simulated trials and rig runs share one log schema (``sensaug.logs``,
``docs/logs.md``): ``data`` is a log, a trial or its structured array, read
by column name (``x``, ``tau``, ``tau_h``, ``Lh*_hat``, ``tau_h_hat``,
``e_meas``, ``e_hat_own``, ``e_hat_fused``); the caller selects the ticks
with a boolean mask.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "gain_estimate",
    "partner_target_rmse",
    "integration_rmse",
    "partner_integration_rmse",
    "tracking_rmse",
]

GAIN_FIELDS = ("Lhx_hat", "Lhv_hat", "Lhh_hat")


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)))


def gain_estimate(data: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Mean estimated partner gains ``[Lhx, Lhv, Lhh]`` over ``mask``."""
    return np.array([data[f][mask].mean() for f in GAIN_FIELDS])


def partner_target_rmse(data: np.ndarray, mask: np.ndarray) -> float:
    """RMSE of ``tau_h^`` against ``tau_h`` over ``mask``."""
    return _rmse(data["tau_h_hat"][mask], data["tau_h"][mask])


def integration_rmse(data: np.ndarray, mask: np.ndarray) -> dict[str, float]:
    """RMSE against ``x - tau`` over ``mask`` of the robot's measured error,
    its own-sensing estimate and its integrated estimate."""
    e = data["x"][mask] - data["tau"][mask]
    return {
        name: _rmse(data[col][mask], e)
        for name, col in (("measured", "e_meas"), ("own", "e_hat_own"), ("integrated", "e_hat_fused"))
    }


def partner_integration_rmse(data: np.ndarray, mask: np.ndarray) -> dict[str, float]:
    """:func:`integration_rmse` for a goal-integrating partner (simulation
    section): against ``x - tau_h``, its measured error, its own-sensing and
    its integrated estimate."""
    e_h = data["x"][mask] - data["tau_h"][mask]
    return {
        name: _rmse(data[col][mask], e_h)
        for name, col in (("measured", "e_h_meas"), ("own", "e_h_hat_own"), ("integrated", "e_h_hat_fused"))
    }


def tracking_rmse(data: np.ndarray, mask: np.ndarray) -> float:
    """RMSE of the handle ``x`` against the robot's target ``tau`` over ``mask``."""
    return _rmse(data["x"][mask], data["tau"][mask])
