"""The virtual drives' load: the 1-DoF handle ``M xdd + C xd = f``, stepped
with the exact zero-order hold at a fixed period, with optional Coulomb
friction.

The same model as the controller's (``sensaug-core``'s ``plant.rs``,
docs/model.md), written here in the same operations in the same order so
that the bridge does not import ``sensaug`` (which depends on the bridge):
``tests/test_bridge_plant.py`` checks every step against the core's
``sensaug.Plant``, bit for bit. Units are the caller's (the drives use rad,
N m, kg m^2, s).
"""

from __future__ import annotations

import math

__all__ = ["Plant"]


def _damping_ratio(mass: float, damping: float, dt_s: float) -> float:
    """``s = C dt / M``, in another order only where that one overflows."""
    s = damping * dt_s / mass
    if math.isfinite(s):
        return s
    if math.isfinite(damping * (dt_s / mass)):
        return damping * (dt_s / mass)
    return damping / mass * dt_s


def _phi1(s: float) -> float:
    """``(1 - e^-s) / s`` (1 at ``s = 0``)."""
    return 1.0 if s == 0.0 else -math.expm1(-s) / s


def _phi2(s: float) -> float:
    """``(s - 1 + e^-s) / s^2`` (a Taylor series below 1e-3, where the direct form cancels)."""
    if abs(s) < 1e-3:
        return 0.5 - s / 6.0 + s * s / 24.0 - s * s * s / 120.0
    if s > 1e150:
        return (1.0 + math.expm1(-s) / s) / s
    return (s + math.expm1(-s)) / (s * s)


def _sign(v: float) -> float:
    """Rust's ``f64::signum`` for the finite values used here: +1 or -1 (0 counts as +)."""
    return math.copysign(1.0, v)


class Plant:
    """The handle at ``(x0, v0)``; :meth:`step` advances it one period ``dt_s``.

    Parameters are checked by the drive's own config (``DriveConfig.validate``):
    ``mass > 0``, ``damping >= 0``, ``coulomb >= 0``, ``dt_s > 0``, all finite.
    """

    def __init__(self, *, mass: float, damping: float, coulomb: float, dt_s: float, x0: float = 0.0,
                 v0: float = 0.0) -> None:
        self.mass = mass
        self.coulomb = coulomb
        s = _damping_ratio(mass, damping, dt_s)
        self._decay = math.exp(-s)
        self._dt_phi1 = dt_s * _phi1(s)
        self._dt2_phi2 = dt_s * dt_s * _phi2(s)
        self.x = x0
        self.v = v0

    def _friction(self, v: float, applied: float) -> float:
        """Moving: ``-F_c sign(v)``; at rest, stiction cancels the applied torque up to ``F_c``."""
        fc = self.coulomb
        if fc == 0.0:
            return 0.0
        if v != 0.0:
            return -fc * _sign(v)
        if abs(applied) <= fc:
            return -applied
        return -fc * _sign(applied)

    def step(self, torque: float) -> tuple[float, float]:
        """One period with ``torque`` held (ZOH); returns the new ``(x, v)``.

        A non-finite torque, or a step whose state would not be finite, raises
        ValueError and leaves the state unchanged (as the core's)."""
        if not math.isfinite(torque):
            raise ValueError(f"torque: must be finite, got {torque!r}")
        x, v = self.x, self.v
        friction = self._friction(v, torque)
        acc = (torque + friction) / self.mass
        v_next = self._decay * v + self._dt_phi1 * acc
        x_next = x + self._dt_phi1 * v + self._dt2_phi2 * acc
        if friction != 0.0 and v != 0.0 and v_next * v < 0.0 and abs(torque) <= self.coulomb:
            v_next = 0.0
        if not (math.isfinite(x_next) and math.isfinite(v_next)):
            raise ValueError("the step's state is not finite (torque too large for this plant)")
        self.x, self.v = x_next, v_next
        return x_next, v_next
