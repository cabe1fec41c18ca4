"""Type stubs for the compiled module `sensaug._core` (Rust, pyo3)."""
from typing import final

import numpy as np
import numpy.typing as npt
from numpy.typing import NDArray

# --- riccati ---

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

# --- ukf ---


class UkfStepError(RuntimeError):
    """A UKF predict/update was rejected (state unchanged) or reset P (state valid)."""

@final
class DemoUkf:
    """Merwe-scaled UKF on the built-in pendulum model (N = 3, M = 2).

    Arguments are float64 numpy arrays; the Python wrapper
    `sensaug.ukf.PendulumUKF` converts and validates them first.

    Raises:
        ValueError: an argument is malformed; the message starts with its name.
    """

    def __init__(
        self,
        *,
        x0: NDArray[np.float64],
        P0: NDArray[np.float64],
        Q: NDArray[np.float64],
        R: NDArray[np.float64],
        alpha: float,
        beta: float,
        kappa: float,
        dt_s: float = 1e-3,
        length_m: float = 0.5,
        mass_kg: float = 1.0,
        damping_nms: float = 0.1,
        gravity_mps2: float = 9.81,
    ) -> None: ...
    def predict(self, u: float, *, Q: NDArray[np.float64] | None = None) -> str:
        """One predict with torque `u`.

        Returns:
            "nominal" or "resymmetrised:<stage>".

        Raises:
            UkfStepError: rejected (state unchanged) or P reset.
        """
    def update(self, z: NDArray[np.float64], *, R: NDArray[np.float64] | None = None) -> str:
        """One update with measurement `z` of shape (2,).

        Returns:
            "nominal" or "resymmetrised:<stage>".

        Raises:
            UkfStepError: rejected (state unchanged) or P reset.
        """
    def run(
        self, u: NDArray[np.float64], z: NDArray[np.float64], *, strict: bool = True
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """predict(u[k]) then update(z[k]) for all k, in Rust.

        Returns:
            (xs, Pdiag), each of shape (T, 3).

        Raises:
            ValueError: shape mismatch or non-contiguous input.
            UkfStepError: with strict, if any step errored (after the run).
        """
    def reset(self, x: NDArray[np.float64], P: NDArray[np.float64]) -> None: ...
    def recoveries(self) -> dict[str, int]: ...
    @property
    def x(self) -> NDArray[np.float64]: ...
    @property
    def P(self) -> NDArray[np.float64]: ...
    @property
    def x_prior(self) -> NDArray[np.float64]: ...
    @property
    def P_prior(self) -> NDArray[np.float64]: ...
    @property
    def x_post(self) -> NDArray[np.float64]: ...
    @property
    def P_post(self) -> NDArray[np.float64]: ...
    @property
    def Q(self) -> NDArray[np.float64]: ...
    @Q.setter
    def Q(self, value: NDArray[np.float64]) -> None: ...
    @property
    def R(self) -> NDArray[np.float64]: ...
    @R.setter
    def R(self, value: NDArray[np.float64]) -> None: ...
    @property
    def P_reset(self) -> NDArray[np.float64]: ...
    @P_reset.setter
    def P_reset(self, value: NDArray[np.float64]) -> None: ...
    @property
    def y(self) -> NDArray[np.float64]: ...
    @property
    def S(self) -> NDArray[np.float64]: ...
    @property
    def K(self) -> NDArray[np.float64]: ...
    @property
    def Wm(self) -> NDArray[np.float64]: ...
    @property
    def Wc(self) -> NDArray[np.float64]: ...
# --- end ukf ---
