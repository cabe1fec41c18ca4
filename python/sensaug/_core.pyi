# --- riccati ---
import numpy as np
import numpy.typing as npt

class RiccatiConvergenceError(RuntimeError):
    """The solver did not converge, or its solution failed the residual or closed-loop check."""

def care(
    a: npt.NDArray[np.float64],
    b: npt.NDArray[np.float64],
    q: npt.NDArray[np.float64],
    r: npt.NDArray[np.float64],
    /,
) -> npt.NDArray[np.float64]:
    """Stabilising CARE solution X of A'X + XA - X B R^-1 B' X + Q = 0.

    Arguments:
        a: (n, n), 1 <= n <= 6. b: (n, m), 1 <= m <= min(n, 3). q: (n, n) PSD. r: (m, m) PD.

    Raises:
        ValueError: bad shape or input, not stabilisable, not detectable.
        RiccatiConvergenceError: no convergence, residual > 1e-10, or not stabilising.

    Returns:
        X, (n, n).
    """

def dare(
    a: npt.NDArray[np.float64],
    b: npt.NDArray[np.float64],
    q: npt.NDArray[np.float64],
    r: npt.NDArray[np.float64],
    /,
) -> npt.NDArray[np.float64]:
    """Stabilising DARE solution X of X = A'XA - A'XB (R + B'XB)^-1 B'XA + Q.

    Arguments, Raises: as `care`.

    Returns:
        X, (n, n).
    """

def lqr(
    a: npt.NDArray[np.float64],
    b: npt.NDArray[np.float64],
    q: npt.NDArray[np.float64],
    r: npt.NDArray[np.float64],
    /,
    *,
    discrete: bool = False,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """LQR gain and Riccati solution (K, X); K = R^-1 B'X, or (R + B'XB)^-1 B'XA if discrete.

    Arguments, Raises: as `care`.

    Returns:
        (K (m, n), X (n, n)).
    """

def agent_gains(*, mass: float, damping: float, q_pos: float, q_vel: float) -> tuple[float, float]:
    """(k_pos, k_vel) of the reduced 2-state LQR on [x - target, xdot], R = 1.

    Raises:
        ValueError: mass <= 0, damping < 0, q_pos <= 0, q_vel < 0, or non-finite.
    """
# --- end riccati ---
