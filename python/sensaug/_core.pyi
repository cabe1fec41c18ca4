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
        a: (n, n), 1 <= n <= 6. b: (n, m), 1 <= m <= n. q: (n, n) PSD. r: (m, m) PD.

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

# --- plant ---

@final
class Plant:
    """The handle ``M xdd + C xd = torque``, exact zero-order hold over ``dt_s``."""

    def __init__(
        self, *, mass: float, damping: float = 0.0, coulomb: float = 0.0, dt_s: float = 1e-3, x0: float = 0.0, v0: float = 0.0
    ) -> None:
        """Raises:
        ValueError: a parameter out of range (the message names it).
        """
    @property
    def x(self) -> float: ...
    @property
    def v(self) -> float: ...
    def step(self, torque: float) -> tuple[float, float]:
        """One period with ``torque`` held; returns ``(x, v)``.

        Raises:
            ValueError: non-finite torque (state unchanged).
        """
    def run(self, torques: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Every torque in turn; positions and velocities after each step."""

# --- estimators ---

@final
class GainEstimator:
    """Stage 1: the partner's gains from ``y1 = [x - tau, xdot, x - tau_h]`` (6 states, 3 measurements)."""

    def __init__(
        self,
        *,
        mass: float,
        Q: NDArray[np.float64],
        R: NDArray[np.float64],
        x0: NDArray[np.float64],
        P0: NDArray[np.float64],
        damping: float = 0.0,
        dt: float = 1e-3,
        alpha: float = 1.0,
        beta: float = 2.0,
        kappa: float = 0.0,
    ) -> None: ...
    def update(self, y: NDArray[np.float64]) -> str:
        """Fuse one measurement; returns "nominal" or "resymmetrised:<stage>".

        Raises:
            UkfStepError: non-finite input or a covariance reset (see docs/ukf.md).
        """
    def predict(self, u: float, dtau: float = 0.0, dtau_h: float = 0.0) -> str: ...
    def run(
        self,
        y: NDArray[np.float64],
        u: NDArray[np.float64],
        dtau: NDArray[np.float64],
        dtau_h: NDArray[np.float64],
        *,
        strict: bool = True,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """update(y[k]) then predict(u[k], dtau[k], dtau_h[k]) for every k; posteriors ``(xs, Pdiag)``."""
    @property
    def x(self) -> NDArray[np.float64]: ...
    @property
    def P(self) -> NDArray[np.float64]: ...
    @property
    def x_prior(self) -> NDArray[np.float64]: ...
    @property
    def P_prior(self) -> NDArray[np.float64]: ...
    @property
    def gains(self) -> NDArray[np.float64]: ...
    def recoveries(self) -> dict[str, int]: ...

@final
class TrajectoryEstimator:
    """Stage 2: the partner's target from ``y2 = [x - tau, xdot, Lhx^, Lhv^, Lhh^]`` (same keywords as GainEstimator)."""

    def __init__(
        self,
        *,
        mass: float,
        Q: NDArray[np.float64],
        R: NDArray[np.float64],
        x0: NDArray[np.float64],
        P0: NDArray[np.float64],
        damping: float = 0.0,
        dt: float = 1e-3,
        alpha: float = 1.0,
        beta: float = 2.0,
        kappa: float = 0.0,
    ) -> None: ...
    def update(self, y: NDArray[np.float64]) -> str: ...
    def predict(self, u: float, dtau: float = 0.0, dtau_h: float = 0.0) -> str: ...
    def run(
        self,
        y: NDArray[np.float64],
        u: NDArray[np.float64],
        dtau: NDArray[np.float64],
        dtau_h: NDArray[np.float64],
        *,
        strict: bool = True,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...
    def partner_target(self, x: float) -> float:
        """``tau_h^ = x - (x - tau_h)^``."""
    @property
    def x(self) -> NDArray[np.float64]: ...
    @property
    def P(self) -> NDArray[np.float64]: ...
    @property
    def x_prior(self) -> NDArray[np.float64]: ...
    @property
    def P_prior(self) -> NDArray[np.float64]: ...
    @property
    def gains(self) -> NDArray[np.float64]: ...
    def recoveries(self) -> dict[str, int]: ...

@final
class GoalIntegrator:
    """Stage 3: ``[x - tau, xdot]`` with and without the partner channel ``x - tau_h^``."""

    def __init__(
        self,
        *,
        mass: float,
        Q: NDArray[np.float64],
        R: NDArray[np.float64],
        x0: NDArray[np.float64],
        P0: NDArray[np.float64],
        damping: float = 0.0,
        dt: float = 1e-3,
        partner_window_s: float = 0.2,
        alpha: float = 1.0,
        beta: float = 2.0,
        kappa: float = 0.0,
    ) -> None: ...
    def update(self, y: NDArray[np.float64], partner_floor: float = 0.0) -> str:
        """``y`` = ``[x - tau, xdot]`` or ``[x - tau, xdot, x - tau_h^]``."""
    def predict(self, u: float, dtau: float = 0.0, dtau_h: float = 0.0) -> str:
        """``u``: all known torque (own plus estimated partner); ``dtau_h`` must be 0."""
    @property
    def x(self) -> NDArray[np.float64]: ...
    @property
    def P(self) -> NDArray[np.float64]: ...
    @property
    def x_own(self) -> NDArray[np.float64]: ...
    @property
    def P_own(self) -> NDArray[np.float64]: ...
    @property
    def partner_variance(self) -> float: ...

# --- scenario ---

RECORD_FIELDS: list[str]

def run_scenario(config: dict) -> tuple[NDArray[np.float64], dict[str, int]]:
    """One whole simulated trial from the resolved dict of ``sensaug.experiment.resolve``.

    Returns ``(records (ticks, len(RECORD_FIELDS)), summary)``.

    Raises:
        ValueError: a setting out of range (the message names its path).
    """
