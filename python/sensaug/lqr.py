"""Algebraic Riccati equations and LQR gains (eq.LQRrobot, eq.LQRhuman).

numpy in, numpy out. The solvers are the allocation-free Rust core
(``sensaug._core``): any array-like is converted to a float64 array here,
naming the argument when it cannot be (a str, complex or ragged entry,
``sensaug._args``), and the core checks every shape and value itself
(finite, symmetric, definite, stabilisable, detectable). Every error starts with the argument it is about (``"Q: ..."``,
or ``"(A, B): ..."`` when two disagree) and says how to fix it.

Errors
------
``TypeError``
    an argument that is not real numbers (str, None, complex, bool).
``ValueError``
    bad shape, non-finite entry, asymmetric ``Q``/``R``, ``Q`` not PSD, ``R``
    not PD, ``(A, B)`` not stabilisable, ``(Q, A)`` not detectable, bad agent
    parameter.
``RiccatiConvergenceError`` (subclass of ``RuntimeError``)
    the solver did not converge, or its answer failed the residual
    (relative residual <= 1e-10) or closed-loop stability check.

See ``docs/riccati.md`` for the algorithm and tolerances.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from sensaug import _core
from sensaug._args import real, real_array

__all__ = [
    "RiccatiConvergenceError",
    "agent_gains",
    "care",
    "dare",
    "lqr",
    "partner_gain_vector",
    "robot_gain_vector",
]

RiccatiConvergenceError = _core.RiccatiConvergenceError


def _lqr(
    A: npt.ArrayLike, B: npt.ArrayLike, Q: npt.ArrayLike, R: npt.ArrayLike, *, discrete: bool
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    return _core.lqr(*(_matrix(m, name) for m, name in ((A, "A"), (B, "B"), (Q, "Q"), (R, "R"))), discrete=discrete)


def _matrix(value: npt.ArrayLike, name: str) -> npt.NDArray[np.float64]:
    """``value`` as the C-contiguous 2-D float64 array ``_core.lqr`` takes."""
    m = real_array(value, name)
    if m.ndim != 2:
        raise ValueError(f"{name}: expected a 2-D array, got shape {m.shape}")
    return np.ascontiguousarray(m)


def care(
    A: npt.ArrayLike, B: npt.ArrayLike, Q: npt.ArrayLike, R: npt.ArrayLike
) -> npt.NDArray[np.float64]:
    """Stabilising solution of the CARE ``A'X + XA - X B R^-1 B' X + Q = 0``.

    Arguments:
        A: state matrix, shape (n, n), 1 <= n <= 6.
        B: input matrix, shape (n, m), 1 <= m <= n.
        Q: symmetric positive semidefinite state weight, shape (n, n).
        R: symmetric positive definite input weight, shape (m, m).

    Returns:
        X, shape (n, n): symmetric PSD, ``A - B R^-1 B' X`` Hurwitz.

    Raises:
        ValueError: bad input (naming the argument), or (A, B) not
            stabilisable / (Q, A) not detectable.
        RiccatiConvergenceError: the solver failed its own checks.
    """
    return _lqr(A, B, Q, R, discrete=False)[1]


def dare(
    A: npt.ArrayLike, B: npt.ArrayLike, Q: npt.ArrayLike, R: npt.ArrayLike
) -> npt.NDArray[np.float64]:
    """Stabilising solution of the DARE ``X = A'XA - A'XB (R + B'XB)^-1 B'XA + Q``.

    Arguments and errors as for :func:`care`; ``A - B K`` with
    ``K = (R + B'XB)^-1 B'XA`` has spectral radius < 1.
    """
    return _lqr(A, B, Q, R, discrete=True)[1]


def lqr(
    A: npt.ArrayLike,
    B: npt.ArrayLike,
    Q: npt.ArrayLike,
    R: npt.ArrayLike,
    *,
    discrete: bool = False,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """LQR state feedback ``u = -K x``.

    Continuous (default): ``K = R^-1 B' X`` with X from :func:`care`.
    Discrete (``discrete=True``): ``K = (R + B'XB)^-1 B'XA`` with X from
    :func:`dare`.

    Returns:
        ``(K, X)``: K of shape (m, n), X of shape (n, n).

    Raises:
        As :func:`care`.
    """
    return _lqr(A, B, Q, R, discrete=discrete)


def agent_gains(mass: float, damping: float, q_pos: float, q_vel: float) -> tuple[float, float]:
    """One agent's LQR gains ``(k_pos, k_vel)`` (eq.LQRrobot / eq.LQRhuman).

    Solves the reduced 2-state problem on ``[x - target, xdot]``:
    ``A = [[0, 1], [0, -C/M]]``, ``B = [0, 1/M]'``, ``Q = diag(q_pos, q_vel)``,
    ``R = 1``. The paper's 3-state pair is not stabilisable (see
    ``docs/riccati.md``). For ``damping = 0``: ``k_pos = sqrt(q_pos)``,
    ``k_vel = sqrt(q_vel + 2 M sqrt(q_pos))``.

    Arguments:
        mass: M > 0 (kg, or the experiment's inertia unit).
        damping: C >= 0.
        q_pos: position weight > 0.
        q_vel: velocity weight >= 0 (0 is fine).

    Raises:
        ValueError: a parameter is non-finite or out of range (named).
        TypeError: a parameter is not a real number (named).
    """
    given = dict(mass=mass, damping=damping, q_pos=q_pos, q_vel=q_vel)
    return _core.agent_gains(**{name: real(v, name) for name, v in given.items()})


def robot_gain_vector(
    mass: float, damping: float, q_pos: float, q_vel: float
) -> npt.NDArray[np.float64]:
    """The robot's ``L = [k_pos, k_vel, 0]`` on ``[x - tau, xdot, x - tau_h]`` (eq.LQRrobot)."""
    k_pos, k_vel = agent_gains(mass, damping, q_pos, q_vel)
    return np.array([k_pos, k_vel, 0.0])


def partner_gain_vector(
    mass: float, damping: float, q_pos: float, q_vel: float
) -> npt.NDArray[np.float64]:
    """The partner's ``L_h = [0, k_vel, k_pos]`` on ``[x - tau, xdot, x - tau_h]`` (eq.LQRhuman)."""
    k_pos, k_vel = agent_gains(mass, damping, q_pos, q_vel)
    return np.array([0.0, k_vel, k_pos])
