"""The paper's three estimators and the handle, with filterpy's conventions:
step-wise ``update`` / ``predict``, and ``run`` over a whole recording in one
core call.

Each class is a subclass of its compiled one (``sensaug._core``): the
constructor takes any array-like of real numbers and real numbers
(``sensaug._args``), fills the optional keywords from the configuration
schema's defaults (``sensaug.config_types``) and calls the core once; the
per-tick methods are the compiled ones, with no Python in between. Every
error names the argument first and says how to fix it: ``TypeError`` for
what is not real numbers, ``ValueError`` for a bad shape or value (``Q`` and
``R`` must be symmetric positive semidefinite, ``P0`` symmetric positive
definite).
"""

from __future__ import annotations

from collections.abc import Generator
from contextlib import contextmanager
from typing import Any, Self

import numpy.typing as npt

from sensaug import _core
from sensaug._args import real, real_array
from sensaug.config_types import ChannelConfig, PlantConfig, SigmaConfig, WorldConfig

__all__ = ["GainEstimator", "GoalIntegrator", "Plant", "TrajectoryEstimator"]

_PLANT, _SIGMA, _CHANNEL, _WORLD = PlantConfig(), SigmaConfig(), ChannelConfig(), WorldConfig()


@contextmanager
def _dt_named_dt() -> Generator[None]:
    """The core calls the model's step ``dt_s``; the estimators' keyword is ``dt``."""
    try:
        yield
    except ValueError as e:
        if not str(e).startswith("dt_s:"):
            raise
        raise ValueError("dt:" + str(e).removeprefix("dt_s:")) from None


def _filter_args(
    mass: float, Q: npt.ArrayLike, R: npt.ArrayLike, x0: npt.ArrayLike, P0: npt.ArrayLike, damping: float, dt: float
) -> dict[str, Any]:
    """The arguments every estimator's core constructor takes."""
    arrays = {name: real_array(v, name) for name, v in (("Q", Q), ("R", R), ("x0", x0), ("P0", P0))}
    return dict(mass=real(mass, "mass"), **arrays, damping=real(damping, "damping"), dt_s=real(dt, "dt"))


class _Extended:
    """The constructor of both estimators of the 6-state extended model
    (before the compiled class in the MRO, whose ``__new__`` it calls)."""

    __slots__ = ()

    def __new__(
        cls, *, mass: float, Q: npt.ArrayLike, R: npt.ArrayLike, x0: npt.ArrayLike, P0: npt.ArrayLike,
        damping: float = _PLANT.damping, dt: float = _PLANT.dt_s,
        alpha: float = _SIGMA.alpha, beta: float = _SIGMA.beta, kappa: float = _SIGMA.kappa,
    ) -> Self:  # fmt: skip
        sigma = dict(alpha=real(alpha, "alpha"), beta=real(beta, "beta"), kappa=real(kappa, "kappa"))
        with _dt_named_dt():
            return super().__new__(cls, **_filter_args(mass, Q, R, x0, P0, damping, dt), **sigma)


class GainEstimator(_Extended, _core.GainEstimator):
    """Stage 1: the partner's gains from ``y1 = [x - tau, xdot, x - tau_h]``
    (6 states ``[x - tau, xdot, x - tau_h, Lhx, Lhv, Lhh]``, 3 measurements).

    Keywords:
        - mass: the handle's inertia M (``[plant]``, as every default here).
        - Q: the process noise (6 x 6), per step.
        - R: the measurement noise (3 x 3), per step.
        - x0: the initial state (6 entries).
        - P0: the initial covariance (6 x 6).
        - damping: the handle's viscous damping C.
        - dt: the step (s).
        - alpha: Merwe's sigma-point spread (``[robot.sigma]``).
        - beta: Merwe's prior-knowledge parameter (2 for Gaussians).
        - kappa: Merwe's secondary scaling; 6 + kappa must be > 0.

    Methods:
        update(y): fuse one measurement (a float64 array of 3); returns the
            step's :class:`sensaug._core.Status`. Raises ``UkfStepError`` for
            a non-finite input or a covariance reset (docs/ukf.md).
        predict(u, dtau=0.0, dtau_h=0.0): propagate with the own torque and
            both targets' increments over the coming step.
        run(y, u, dtau, dtau_h, *, strict=True): ``update(y[k])`` then
            ``predict(u[k], dtau[k], dtau_h[k])`` for every k in one core call;
            ``y`` (T, 3) C-contiguous, the others (T,). Returns ``(xs, Pdiag)``,
            each (T, 6): the posterior after each update and its diagonal.
            A shape or length that does not fit is a ``ValueError`` naming the
            argument; with ``strict``, the first step error is raised after
            the run (the filter has handled it) as ``UkfStepError``.
        recoveries(): the filter's counters (resymmetrised, covariance_resets,
            rejected, predicts, updates).

    Attributes:
        x: the posterior mean.
        P: the posterior covariance.
        x_prior: the prior mean of the last predict.
        P_prior: the prior covariance of the last predict.
        gains: the estimated ``[Lhx, Lhv, Lhh]`` (``x[3:]``).
    """

class TrajectoryEstimator(_Extended, _core.TrajectoryEstimator):
    """Stage 2: the partner's target from ``y2 = [x - tau, xdot, Lhx^, Lhv^, Lhh^]``
    (6 states as :class:`GainEstimator`, 5 measurements; ``R`` is 5 x 5).

    The keywords, methods and attributes are :class:`GainEstimator`'s, with
    ``y`` of 5 entries (``run``: (T, 5)), and ``partner_target(x)``: the
    estimated partner target ``tau_h^ = x - (x - tau_h)^`` at handle
    position ``x``.
    """

class GoalIntegrator(_core.GoalIntegrator):
    """Stage 3: ``[x - tau, xdot]`` with the adaptive partner channel
    ``x - tau_h^`` (a bank of Kalman filters over the channel's variance,
    docs/model.md).

    Keywords:
        - mass: the handle's inertia M (``[plant]``, as every default here).
        - Q: the process noise (2 x 2), per step.
        - R: the own measurement's noise (2 x 2).
        - x0: the initial state of every member (2 entries).
        - P0: the initial covariance of every member (2 x 2).
        - damping: the handle's viscous damping C.
        - dt: the step (s).
        - gate: the change-point and readmission threshold (standard
          deviations of the own position innovation,
          ``[robot.stage3.channel]``).
        - window_n0: the scale of the score window (ticks).
        - hold_max_s: the longest suspension of the channel after a target
          jump (s).

    Methods:
        update(y): ``y`` = ``[x - tau, xdot]`` or ``[x - tau, xdot, x - tau_h^]``
            (a float64 array; a NaN channel: none).
        run(y, u, dtau, *, strict=True): ``update(y[k])`` then
            ``predict(u[k], dtau[k])`` for every k in one core call; ``y`` (T, 2)
            own measurements or (T, 3) with the channel. Returns ``(xs, var)``,
            each (T, 2), of the mixture; errors as ``GainEstimator.run``.

    Attributes:
        x: the mixture's mean (goal integration with the partner), as of
            the last update.
        var: the mixture's variances.
        x_own: member 0's mean (own sensing only).
        var_own: member 0's variances.
        weights: the bank's weights.
        members: the bank's means.
        grid: the bank's channel variances.
        change_point: whether the last update saw a target jump.
        channel_admitted: whether the partner channel is fused.
        partner_variance: the channel's estimated variance.
    """

    def __new__(
        cls, *, mass: float, Q: npt.ArrayLike, R: npt.ArrayLike, x0: npt.ArrayLike, P0: npt.ArrayLike,
        damping: float = _PLANT.damping, dt: float = _PLANT.dt_s,
        gate: float = _CHANNEL.gate, window_n0: float = _CHANNEL.window_n0, hold_max_s: float = _CHANNEL.hold_max_s,
    ) -> Self:  # fmt: skip
        given = dict(gate=gate, window_n0=window_n0, hold_max_s=hold_max_s)
        channel: dict[str, Any] = {name: real(v, name) for name, v in given.items()}
        with _dt_named_dt():
            return super().__new__(cls, **_filter_args(mass, Q, R, x0, P0, damping, dt), **channel)

    def predict(self, u: float, dtau: float = 0.0, dtau_h: float = 0.0) -> _core.Status:
        """``u``: all known torque (own plus estimated partner); ``dtau``: the
        own target's increment; ``dtau_h`` must be 0 (the state is ``[x - tau, xdot]``)."""
        if dtau_h != 0.0:
            raise ValueError("dtau_h: must be 0 for GoalIntegrator (its state is [x - tau, xdot])")
        return super().predict(u, dtau)

    def set_own_noise(self, R: npt.ArrayLike) -> None:
        """Phase start: the own measurement's covariance (sets the grid and the score window)."""
        super().set_own_noise(real_array(R, "R"))

    def reset(self, x0: npt.ArrayLike) -> None:
        """Phase start: every member at ``x0`` with ``P0``, scores 0."""
        super().reset(real_array(x0, "x0"))


class Plant(_core.Plant):
    """The handle ``M xdd + C xd = torque`` (plus Coulomb friction), exact
    zero-order hold over ``dt_s``; the defaults are ``[plant]``'s and
    ``[world]``'s.

    Raises:
        TypeError: a parameter that is not a real number (named).
        ValueError: a parameter out of range, or one that makes the step
            overflow (too small a mass for ``dt_s``, ...); the message names it.

    Methods:
        step(torque): one period with ``torque`` held; returns ``(x, v)``. A
            non-finite torque, or a new state that would overflow, is a
            ``ValueError`` (state unchanged).
        run(torques): every torque in turn (a C-contiguous float64 array);
            positions and velocities after each step. ``torques[k]`` non-finite
            (nothing stepped) or its step's state overflowing (the steps before
            it ran) is a ``ValueError``.

    Attributes:
        x: the position.
        v: the velocity.
    """

    def __new__(
        cls,
        *,
        mass: float,
        damping: float = _PLANT.damping,
        coulomb: float = _PLANT.coulomb,
        dt_s: float = _PLANT.dt_s,
        x0: float = _WORLD.x0,
        v0: float = _WORLD.v0,
    ) -> Self:
        given = dict(mass=mass, damping=damping, coulomb=coulomb, dt_s=dt_s, x0=x0, v0=v0)
        return super().__new__(cls, **{name: real(v, name) for name, v in given.items()})
