"""Type stubs for the compiled module `sensaug._core` (Rust, pyo3)."""
from typing import Any, Self, final

import numpy as np
import numpy.typing as npt
from numpy.typing import NDArray
from typing_extensions import disjoint_base

__all__ = [
    "Config",
    "GainEstimator",
    "GoalIntegrator",
    "Plant",
    "RiccatiConvergenceError",
    "Status",
    "TrajectoryEstimator",
    "UkfStepError",
    "agent_gains",
    "available_memory",
    "check_output_paths",
    "config_schema",
    "config_sha256",
    "git_commit",
    "log_schema",
    "lqr",
    "replay_robot",
    "resolve_count",
    "run_scenario",
    "write_log",
]

# --- riccati ---

class RiccatiConvergenceError(RuntimeError):
    """The solver did not converge, or its solution failed the residual or closed-loop check."""

def lqr(
    a: NDArray[np.float64],
    b: NDArray[np.float64],
    q: NDArray[np.float64],
    r: NDArray[np.float64],
    /,
    *,
    discrete: bool,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(K, X)`` of ``sensaug.lqr`` (its docs); each matrix a 2-D float64
    array (another ndim or dtype: pyo3's ``TypeError``), C-contiguous (else a
    ``ValueError`` naming it)."""

def agent_gains(*, mass: float, damping: float, q_pos: float, q_vel: float) -> tuple[float, float]:
    """``(k_pos, k_vel)`` of ``sensaug.agent_gains`` (its docs)."""
# --- end riccati ---

# --- errors ---

class UkfStepError(RuntimeError):
    """A UKF predict/update was rejected (state unchanged) or reset P (state valid)."""
# --- end errors ---

@disjoint_base
class Status:
    """How a UKF step went: ``Status.Nominal()``, or
    ``Status.Resymmetrised(stage=...)`` naming the stage whose covariance was
    repaired (a counted repair). ``str()``: ``nominal`` / ``resymmetrised:<stage>``."""

    @final
    class Nominal(Status):
        __match_args__ = ()
        def __new__(cls) -> Status.Nominal: ...

    @final
    class Resymmetrised(Status):
        __match_args__ = ("stage",)
        def __new__(cls, stage: str) -> Status.Resymmetrised: ...
        @property
        def stage(self) -> str: ...


# --- plant and estimators: the compiled halves of ``sensaug.estimators``'
# classes (their docs); every keyword required, floats and float64 arrays. ---

@disjoint_base
class Plant:
    def __new__(cls, *, mass: float, damping: float, coulomb: float, dt_s: float, x0: float, v0: float) -> Self: ...
    @property
    def x(self) -> float: ...
    @property
    def v(self) -> float: ...
    def step(self, torque: float) -> tuple[float, float]: ...
    def run(self, torques: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...

class _ExtendedEstimator:
    """What the two 6-state estimators share (stub only: each compiled class has its own)."""

    def __new__(
        cls, *, mass: float, Q: NDArray[np.float64], R: NDArray[np.float64], x0: NDArray[np.float64],
        P0: NDArray[np.float64], damping: float, dt_s: float, alpha: float, beta: float, kappa: float,
    ) -> Self: ...
    def update(self, y: NDArray[np.float64]) -> Status: ...
    def predict(self, u: float, dtau: float = 0.0, dtau_h: float = 0.0) -> Status: ...
    def run(
        self,
        y: NDArray[np.float64],
        u: NDArray[np.float64],
        dtau: NDArray[np.float64],
        dtau_h: NDArray[np.float64],
        *,
        strict: bool = True,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...
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

@disjoint_base
class GainEstimator(_ExtendedEstimator): ...

@disjoint_base
class TrajectoryEstimator(_ExtendedEstimator):
    def partner_target(self, x: float) -> float: ...

@disjoint_base
class GoalIntegrator:
    def __new__(
        cls, *, mass: float, Q: NDArray[np.float64], R: NDArray[np.float64], x0: NDArray[np.float64],
        P0: NDArray[np.float64], damping: float, dt_s: float, gate: float, window_n0: float, hold_max_s: float,
    ) -> Self: ...
    def update(self, y: NDArray[np.float64]) -> Status: ...
    def predict(self, u: float, dtau: float) -> Status: ...
    def set_own_noise(self, R: NDArray[np.float64]) -> None: ...
    def reset(self, x0: NDArray[np.float64]) -> None: ...
    def run(
        self,
        y: NDArray[np.float64],
        u: NDArray[np.float64],
        dtau: NDArray[np.float64],
        *,
        strict: bool = True,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...
    @property
    def x(self) -> NDArray[np.float64]: ...
    @property
    def var(self) -> NDArray[np.float64]: ...
    @property
    def x_own(self) -> NDArray[np.float64]: ...
    @property
    def var_own(self) -> NDArray[np.float64]: ...
    @property
    def weights(self) -> NDArray[np.float64]: ...
    @property
    def members(self) -> NDArray[np.float64]: ...
    @property
    def grid(self) -> NDArray[np.float64]: ...
    @property
    def change_point(self) -> bool: ...
    @property
    def channel_admitted(self) -> bool: ...
    @property
    def partner_variance(self) -> float: ...

# --- scenario ---

# ``ConfigError`` and ``TrialTooLargeError`` are Python classes
# (``sensaug.config``, ``sensaug.experiment``): the module raises them with
# ``(field, message)``.

@final
class Config:
    """A configuration resolved once: the file's values (every default filled
    in) and everything derived from them (gains, period, unit, the rig loop's
    settings). Immutable; ``run_scenario``, ``replay_robot`` and the rig
    launcher take it.

    Raises:
        ConfigError: naming the first bad field and how to fix it.
    """

    def __new__(cls, tables: dict[str, Any]) -> Config: ...
    @staticmethod
    def from_file(path: str, /, *, check_outputs: bool) -> Config:
        """Reads and resolves a file (TOML, or JSON by extension); with
        ``check_outputs`` also its rig output paths, as ``sensaug-rt --check``."""
    @staticmethod
    def from_text(text: str, /, *, format: str) -> Config:
        """Parses and resolves text in ``format`` (``"toml"`` or ``"json"``)."""
    def to_dict(self) -> dict[str, Any]:
        """The file's values, every default filled in, as plain dicts and lists."""
    def to_text(self, *, format: str) -> str:
        """The file's values as text in ``format``: ``"json"`` (compact) or
        ``"toml"`` (with each field's description and unit as a comment)."""
    def metadata(self) -> dict[str, Any]:
        """``{"config", "resolved", "loop"}`` as a log's metadata records them."""
    def trial_memory(self, *, memory_budget: int | None) -> tuple[int, int]:
        """``(ticks, log_bytes)`` of its trial.

        Raises:
            TrialTooLargeError: ``memory_budget`` is given and the log needs more.
        """
    def __copy__(self) -> Config: ...
    def __deepcopy__(self, memo: Any, /) -> Config: ...
    def __reduce__(self) -> tuple[Any, ...]: ...

def run_scenario(
    config: Config, /, *, memory_budget: int | None, git_commit: str | None
) -> tuple[NDArray[np.uint8], dict[str, int], dict[str, Any]]:
    """One whole simulated trial of a resolved configuration.

    Returns ``(records, summary, meta)``: the log's rows as the bytes of
    packed records in the log schema's column order (``log_schema()``; int64
    and float64 native-endian, bool one byte),
    ``records.view(sensaug.logs.DTYPE)``; the run's counters; the log's
    metadata (the metadata line's object), built in Rust inside the run.

    Raises:
        TrialTooLargeError: the log needs more than ``memory_budget`` bytes
            (``None``: ``available_memory()``), before anything runs.
        ConfigError: the core rejected the resolved configuration (a bug).
    """

def resolve_count() -> int:
    """Configurations resolved so far on the calling thread (for tests)."""

def config_schema() -> str:
    """The JSON Schema of a configuration file."""

def available_memory() -> int | None:
    """Half the memory available to this process (bytes), or ``None`` where unknown."""

def replay_robot(
    config: Config, records: NDArray[np.uint8], /, *, applied_u: bool
) -> tuple[NDArray[np.uint8], dict[str, int]]:
    """Re-runs the robot's controller over a recorded trial's rows (packed
    records, ``sensaug.logs.to_records``): tick ``k`` fuses the recorded
    ``(x_meas, xdot_meas)`` when ``fresh``, else only predicts, exactly as
    online; with ``applied_u`` the estimators predict with the recorded
    ``u`` (a rig log's: the torque the drive applied for the robot), else
    with the replayed command.

    Returns ``(records, counters)``: the rows as packed records, as
    ``run_scenario`` returns them (``sensaug.logs.from_records``; the
    controller's columns plus ``tick``, ``t``, ``x_meas``, ``xdot_meas``,
    ``fresh``; the rest unknown) and the robot's counters.

    Raises:
        ValueError: ``records`` is not whole packed rows or not C-contiguous.
    """

# --- log (the one log schema, docs/logs.md) ---

def log_schema() -> dict[str, Any]:
    """The schema: ``format_line``, ``format_version``, ``columns`` as
    ``(name, unit, kind, description)`` tuples (kind ``int``/``float``/``bool``),
    ``sources`` (column name -> who fills it: ``time``, ``controller``,
    ``world``, ``rig``), ``phase_names``, ``unknown_int``, ``units`` as ``(symbol, meaning)``,
    ``checksum_field`` and ``json_checksum_key`` (docs/logs.md, "Checksums")."""

def config_sha256(config_json: str) -> str:
    """SHA-256 (hex) of a configuration's canonical JSON: what a log records
    as ``meta["config_sha256"]``.

    Raises:
        ValueError: ``config_json`` is not valid JSON.
    """

def check_output_paths(outputs: list[tuple[str, str]]) -> None:
    """Checks ``(name, path)`` outputs as sensaug-rt checks its own: regular
    files or absent (their ``.partial`` too), no two the same file.

    Raises:
        ConfigError: ``<name>: ...`` at the first refused one.
    """

def git_commit(dir: str) -> str | None:
    """``git rev-parse HEAD`` of the checkout containing ``dir`` (``-dirty`` if
    modified), or ``None``."""

def write_log(path: str, records: NDArray[np.uint8], /, *, meta_json: str, end_json: str | None) -> None:
    """Writes a log file: metadata line, one line per row of ``records`` (the
    bytes of packed records, ``sensaug.logs.to_records``), then the end status
    (none when ``end_json`` is ``None``).

    Raises:
        ValueError: not whole records, a value its column does not take
            (``data.<column>: ... (row k)``); bad JSON.
        ConfigError: ``path`` is not a regular file or a new one (a device,
            a FIFO, a folder, a link).
        OSError: the file cannot be written.
    """
