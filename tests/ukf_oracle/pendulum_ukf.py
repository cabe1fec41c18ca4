"""Test only: the generic UKF on the pendulum model, for the filterpy oracle.

`_ukf_oracle` (this directory's test crate) is built with cargo and loaded
from the workspace's target directory on import; it is not part of the shipped
`sensaug` package. `PendulumUKF` is a thin, validating wrapper with
filterpy's names: ``x``, ``P``, ``Q``, ``R``, ``predict``, ``update``,
``x_prior``, ``P_prior``, ``y``, ``S``, ``K``, ``Wm``, ``Wc``. The numbers
reproduce ``filterpy.kalman.UnscentedKalmanFilter`` with
``MerweScaledSigmaPoints`` (see ``docs/ukf.md``).

Model (state ``[theta_rad, omega_radps, bias_nm]``, control torque ``u`` in
N m, measurement tip position ``[l sin(theta), -l cos(theta)]`` in m)::

    alpha = (u + b - c*omega - m*g*l*sin(theta)) / (m*l**2)
    omega+ = omega + dt*alpha ; theta+ = theta + dt*omega+ ; b+ = b
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import json
import subprocess
from pathlib import Path
from types import ModuleType
from typing import Any, Final, final

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["PendulumUKF", "UkfStepError"]

_ROOT: Final = Path(__file__).resolve().parents[2]


def _build_and_load() -> ModuleType:
    """`cargo build` the test crate (a no-op when fresh), then import its library."""
    cargo = ["cargo", "build", "--release", "-q", "-p", "sensaug-ukf-oracle"]
    subprocess.run(cargo, cwd=_ROOT, check=True, timeout=1800)
    meta = subprocess.run(
        ["cargo", "metadata", "--format-version", "1", "--no-deps"],
        cwd=_ROOT, check=True, timeout=120, capture_output=True, text=True,
    )
    library = Path(json.loads(meta.stdout)["target_directory"]) / "release" / "lib_ukf_oracle.so"
    loader = importlib.machinery.ExtensionFileLoader("_ukf_oracle", str(library))
    spec = importlib.util.spec_from_file_location("_ukf_oracle", library, loader=loader)
    assert spec is not None
    module = importlib.util.module_from_spec(spec)
    loader.exec_module(module)
    return module


_core = _build_and_load()

UkfStepError = _core.UkfStepError

_N: Final = 3
_M: Final = 2


def _vector(name: str, value: ArrayLike, n: int) -> NDArray[np.float64]:
    try:
        a = np.ascontiguousarray(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name}: must be a numeric array of shape ({n},): {e}") from None
    if a.shape != (n,):
        raise ValueError(f"{name}: expected shape ({n},), got {a.shape}; pass a flat array of {n} floats")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: must be finite (no NaN or inf), got {a!r}")
    return a


def _matrix(name: str, value: ArrayLike, n: int, *, spd: bool = False) -> NDArray[np.float64]:
    try:
        a = np.ascontiguousarray(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name}: must be a numeric array of shape ({n}, {n}): {e}") from None
    if a.shape != (n, n):
        raise ValueError(f"{name}: expected shape ({n}, {n}), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: must be finite (no NaN or inf)")
    if spd:
        if not np.allclose(a, a.T, rtol=1e-12, atol=0.0):
            raise ValueError(f"{name}: must be symmetric; use ({name} + {name}.T) / 2")
        try:
            np.linalg.cholesky(a)
        except np.linalg.LinAlgError:
            eig = np.linalg.eigvalsh(a).min()
            raise ValueError(
                f"{name}: must be positive definite (smallest eigenvalue {eig:.3g}); "
                "add a small multiple of the identity"
            ) from None
    return a


def _positive(name: str, value: float, *, allow_zero: bool = False) -> float:
    v = float(value)
    ok = np.isfinite(v) and (v >= 0.0 if allow_zero else v > 0.0)
    if not ok:
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name}: must be finite and {bound}, got {value!r}")
    return v


@final
class PendulumUKF:
    """Merwe-scaled UKF for the pendulum demo model (3 states, 2 measurements).

    All arguments are keyword-only.

    Arguments:
        x0: initial state ``[theta_rad, omega_radps, bias_nm]``, shape (3,).
        P0: initial covariance, (3, 3), symmetric positive definite; also the
            covariance ``P`` is reset to if it ever cannot be factored.
        Q: process noise added per step, (3, 3), finite.
        R: measurement noise, (2, 2), symmetric positive definite.
        alpha, beta, kappa: ``MerweScaledSigmaPoints`` parameters
            (``alpha > 0``, ``3 + kappa > 0``).
        dt_s, length_m, mass_kg, damping_nms, gravity_mps2: model parameters.

    Raises:
        ValueError: naming the argument and how to fix it.
    """

    dim_x: Final = _N
    dim_z: Final = _M

    def __init__(
        self,
        *,
        x0: ArrayLike,
        P0: ArrayLike,
        Q: ArrayLike,
        R: ArrayLike,
        alpha: float,
        beta: float = 2.0,
        kappa: float = 0.0,
        dt_s: float = 1e-3,
        length_m: float = 0.5,
        mass_kg: float = 1.0,
        damping_nms: float = 0.1,
        gravity_mps2: float = 9.81,
    ) -> None:
        alpha = _positive("alpha", alpha)
        if not np.isfinite(beta):
            raise ValueError(f"beta: must be finite, got {beta!r}")
        if not (np.isfinite(kappa) and _N + kappa > 0):
            raise ValueError(f"kappa: must be finite with 3 + kappa > 0, got {kappa!r}")
        if not np.isfinite(gravity_mps2):
            raise ValueError(f"gravity_mps2: must be finite, got {gravity_mps2!r}")
        self._core = _core.DemoUkf(
            x0=_vector("x0", x0, _N),
            P0=_matrix("P0", P0, _N, spd=True),
            Q=_matrix("Q", Q, _N),
            R=_matrix("R", R, _M, spd=True),
            alpha=alpha,
            beta=float(beta),
            kappa=float(kappa),
            dt_s=_positive("dt_s", dt_s),
            length_m=_positive("length_m", length_m),
            mass_kg=_positive("mass_kg", mass_kg),
            damping_nms=_positive("damping_nms", damping_nms, allow_zero=True),
            gravity_mps2=float(gravity_mps2),
        )

    def predict(self, u: float = 0.0, *, Q: ArrayLike | None = None) -> str:
        """Propagate one step with torque ``u`` (N m).

        Arguments:
            u: control torque, finite.
            Q: optional process noise for this step only.

        Returns:
            ``"nominal"`` or ``"resymmetrised:<stage>"`` (a counted repair).

        Raises:
            ValueError: bad ``u`` or ``Q``.
            UkfStepError: rejected (state unchanged) or ``P`` reset.
        """
        if not np.isfinite(u):
            raise ValueError(f"u: must be finite, got {u!r}")
        q = None if Q is None else _matrix("Q", Q, _N)
        return self._core.predict(float(u), Q=q)

    def update(self, z: ArrayLike, *, R: ArrayLike | None = None) -> str:
        """Correct with a tip-position measurement ``z`` (shape (2,), m).

        Arguments:
            z: measurement, finite.
            R: optional measurement noise for this update only (SPD).

        Returns:
            ``"nominal"`` or ``"resymmetrised:<stage>"``.

        Raises:
            ValueError: bad ``z`` or ``R``.
            UkfStepError: ``P`` reset (measurement discarded).
        """
        zz = _vector("z", z, _M)
        r = None if R is None else _matrix("R", R, _M, spd=True)
        return self._core.update(zz, R=r)

    def run(self, z: ArrayLike, u: ArrayLike, *, strict: bool = True) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Replay a whole trial in Rust in the estimators' order
        (``sensaug_core::replay``): ``update(z[k])`` then ``predict(u[k])``.

        Arguments:
            z: measurements, shape (T, 2).
            u: torques, shape (T,).
            strict: raise ``UkfStepError`` if any step was rejected or reset P.

        Returns:
            ``(xs, Pdiag)``, each (T, 3): posterior state and ``diag(P)``.

        Raises:
            ValueError: shapes or non-finite values, naming the argument.
        """
        uu = np.ascontiguousarray(u, dtype=np.float64)
        if uu.ndim != 1:
            raise ValueError(f"u: expected shape (T,), got {uu.shape}")
        zz = np.ascontiguousarray(z, dtype=np.float64)
        if zz.shape != (uu.shape[0], _M):
            raise ValueError(f"z: expected shape ({uu.shape[0]}, {_M}) to match u, got {zz.shape}")
        if not np.all(np.isfinite(uu)):
            raise ValueError(f"u: must be finite; first bad index {int(np.argmin(np.isfinite(uu)))}")
        if strict and not np.all(np.isfinite(zz)):
            bad = int(np.argmin(np.all(np.isfinite(zz), axis=1)))
            raise ValueError(f"z: must be finite; first bad row {bad} (or pass strict=False to skip bad rows)")
        return self._core.run(zz, uu, strict=strict)

    def reset(self, x: ArrayLike, P: ArrayLike) -> None:
        """Replace ``x`` and ``P`` (``P`` symmetric positive definite)."""
        self._core.reset(_vector("x", x, _N), _matrix("P", P, _N, spd=True))

    def recoveries(self) -> dict[str, int]:
        """Counters: resymmetrised, covariance_resets, rejected, predicts, updates."""
        return self._core.recoveries()

    @property
    def x(self) -> NDArray[np.float64]:
        """State estimate (copy)."""
        return self._core.x

    @property
    def P(self) -> NDArray[np.float64]:
        """State covariance (copy)."""
        return self._core.P

    @property
    def x_prior(self) -> NDArray[np.float64]:
        """Mean after the last predict."""
        return self._core.x_prior

    @property
    def P_prior(self) -> NDArray[np.float64]:
        """Covariance after the last predict."""
        return self._core.P_prior

    @property
    def Q(self) -> NDArray[np.float64]:
        """Default process noise."""
        return self._core.Q

    @Q.setter
    def Q(self, value: ArrayLike) -> None:
        self._core.Q = _matrix("Q", value, _N)

    @property
    def R(self) -> NDArray[np.float64]:
        """Default measurement noise."""
        return self._core.R

    @R.setter
    def R(self, value: ArrayLike) -> None:
        self._core.R = _matrix("R", value, _M, spd=True)

    @property
    def y(self) -> NDArray[np.float64]:
        """Last innovation ``z - z_bar``."""
        return self._core.y

    @property
    def S(self) -> NDArray[np.float64]:
        """Last innovation covariance."""
        return self._core.S

    @property
    def K(self) -> NDArray[np.float64]:
        """Last Kalman gain."""
        return self._core.K

    @property
    def Wm(self) -> NDArray[np.float64]:
        """Mean weights."""
        return self._core.Wm

    @property
    def Wc(self) -> NDArray[np.float64]:
        """Covariance weights."""
        return self._core.Wc

    def __repr__(self) -> str:
        d: dict[str, Any] = {"x": self.x.tolist(), **self.recoveries()}
        return f"PendulumUKF({d})"
