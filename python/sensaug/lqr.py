"""Algebraic Riccati equations and LQR gains (eq.LQRrobot, eq.LQRhuman).

numpy in, numpy out. The solvers are the allocation-free Rust core
(``sensaug._core``), which checks every value itself (finite, symmetric,
definite, stabilisable, detectable) and names the argument. This module only
converts to 2-D float arrays before the call; when the core rejects the input,
it re-runs its own, slower checks to say how to fix it (the eigenvalue checks
cost a valid call several times the solve, so they run only on failure).

Errors
------
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

from typing import Callable, TypeVar

import numpy as np
import numpy.typing as npt

from sensaug import _core

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

MAX_STATES = 6
_SYMMETRY_TOL = 1e-10
_T = TypeVar("_T")


def _as_2d(name: str, value: npt.ArrayLike) -> npt.NDArray[np.float64]:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected a 2-D array of real numbers ({exc})") from None
    if arr.ndim != 2:
        raise ValueError(f"{name}: expected a 2-D array, got {arr.ndim}-D with shape {arr.shape}")
    return arr


def _check_finite(name: str, arr: npt.NDArray[np.float64]) -> None:
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains NaN or infinite entries; pass finite values")


def _check_weight(name: str, w: npt.NDArray[np.float64], *, definite: bool) -> None:
    scale = np.linalg.norm(w)
    if np.linalg.norm(w - w.T) > _SYMMETRY_TOL * scale:
        raise ValueError(f"{name}: must be symmetric; pass ({name} + {name}.T) / 2")
    eig = np.linalg.eigvalsh((w + w.T) / 2)
    if definite and not eig[0] > 0:
        raise ValueError(
            f"{name}: must be positive definite, smallest eigenvalue is {eig[0]:.3g}"
        )
    if not definite and eig[0] < -1e-10 * scale:
        raise ValueError(
            f"{name}: must be positive semidefinite, smallest eigenvalue is {eig[0]:.3g}"
        )


def _check_values(
    a: npt.NDArray[np.float64],
    b: npt.NDArray[np.float64],
    q: npt.NDArray[np.float64],
    r: npt.NDArray[np.float64],
) -> None:
    """The full checks, in order, raising a ``ValueError`` that says how to fix
    the first problem; run only after the core has rejected the input."""
    for name, arr in (("A", a), ("B", b), ("Q", q), ("R", r)):
        _check_finite(name, arr)
    n = a.shape[0]
    if a.shape[0] != a.shape[1] or not 1 <= n <= MAX_STATES:
        raise ValueError(
            f"A: expected a square shape (n, n) with 1 <= n <= {MAX_STATES}, got {a.shape}"
        )
    if b.shape[0] != n or not 1 <= b.shape[1] <= n:
        raise ValueError(
            f"B: expected shape (n, m) = ({n}, m) with 1 <= m <= {n}, got {b.shape}"
        )
    m = b.shape[1]
    if q.shape != (n, n):
        raise ValueError(f"Q: expected shape (n, n) = ({n}, {n}), got {q.shape}")
    if r.shape != (m, m):
        raise ValueError(f"R: expected shape (m, m) = ({m}, {m}), got {r.shape}")
    _check_weight("Q", q, definite=False)
    _check_weight("R", r, definite=True)


def _solve(
    fn: Callable[..., _T],
    A: npt.ArrayLike,
    B: npt.ArrayLike,
    Q: npt.ArrayLike,
    R: npt.ArrayLike,
    **kwargs: bool,
) -> _T:
    """Converts, calls the core ``fn``; on a ``ValueError`` from the core,
    raises the more helpful message of :func:`_check_values` if it finds the
    problem, else the core's own."""
    args = (_as_2d("A", A), _as_2d("B", B), _as_2d("Q", Q), _as_2d("R", R))
    try:
        return fn(*args, **kwargs)
    except ValueError:
        try:
            _check_values(*args)
        except ValueError as detailed:
            raise detailed from None
        raise


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
    return _solve(_core.lqr, A, B, Q, R, discrete=False)[1]


def dare(
    A: npt.ArrayLike, B: npt.ArrayLike, Q: npt.ArrayLike, R: npt.ArrayLike
) -> npt.NDArray[np.float64]:
    """Stabilising solution of the DARE ``X = A'XA - A'XB (R + B'XB)^-1 B'XA + Q``.

    Arguments and errors as for :func:`care`; ``A - B K`` with
    ``K = (R + B'XB)^-1 B'XA`` has spectral radius < 1.
    """
    return _solve(_core.lqr, A, B, Q, R, discrete=True)[1]


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
    return _solve(_core.lqr, A, B, Q, R, discrete=discrete)


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
    """
    for name, value in (("mass", mass), ("damping", damping), ("q_pos", q_pos), ("q_vel", q_vel)):
        if not np.isfinite(value):
            raise ValueError(f"{name}: must be finite, got {value!r}")
    if not mass > 0:
        raise ValueError(f"mass: must be > 0, got {mass!r}")
    if not damping >= 0:
        raise ValueError(f"damping: must be >= 0, got {damping!r}")
    if not q_pos > 0:
        raise ValueError(f"q_pos: must be > 0 (the position weight makes the problem detectable), got {q_pos!r}")
    if not q_vel >= 0:
        raise ValueError(f"q_vel: must be >= 0, got {q_vel!r}")
    return _core.agent_gains(
        mass=float(mass), damping=float(damping), q_pos=float(q_pos), q_vel=float(q_vel)
    )


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
