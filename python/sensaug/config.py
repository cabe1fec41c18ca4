"""Typed, validated trial configuration, round-tripping through TOML.

Every dataclass validates itself on construction and raises ``ValueError``
naming the field by its dotted path (``robot.stage1.Q``) and saying how to fix
it. ``ScenarioConfig.to_toml`` / ``ScenarioConfig.from_toml`` write and read
the same files the real-time binary reads.

Covariances are given either as a list of diagonal entries or as a full
nested list; both must be symmetric positive definite.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Literal, Union

import numpy as np
import tomli_w

__all__ = [
    "Constant",
    "Square",
    "RoundedSquare",
    "Chirp",
    "Harmonics",
    "Sampled",
    "Shape",
    "PlantConfig",
    "WorldConfig",
    "SigmaConfig",
    "FilterConfig",
    "IntegratorConfig",
    "RobotConfig",
    "PartnerConfig",
    "PhaseConfig",
    "RealtimeConfig",
    "RigConfig",
    "ScenarioConfig",
    "PHASE_KINDS",
]

PHASE_KINDS = ("gains", "trajectory", "integration")


def _fail(path: str, msg: str) -> ValueError:
    return ValueError(f"{path}: {msg}")


def _finite(path: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise _fail(path, f"must be a number, got {v!r}")
    if not math.isfinite(v):
        raise _fail(path, f"must be finite, got {v!r}")
    return float(v)


def _positive(path: str, v: Any) -> float:
    v = _finite(path, v)
    if v <= 0:
        raise _fail(path, f"must be > 0, got {v!r}")
    return v


def _non_negative(path: str, v: Any) -> float:
    v = _finite(path, v)
    if v < 0:
        raise _fail(path, f"must be >= 0, got {v!r}")
    return v


def _covariance(path: str, value: Any, n: int) -> np.ndarray:
    """A list of n diagonal entries or an n x n nested list -> SPD matrix."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise _fail(path, f"must be {n} diagonal entries or an {n}x{n} nested list of numbers") from None
    if a.shape == (n,):
        a = np.diag(a)
    if a.shape != (n, n):
        raise _fail(path, f"expected {n} diagonal entries or shape ({n}, {n}), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise _fail(path, "must be finite (no NaN or inf)")
    if not np.allclose(a, a.T, rtol=1e-12, atol=0.0):
        raise _fail(path, "must be symmetric")
    try:
        np.linalg.cholesky(a)
    except np.linalg.LinAlgError:
        raise _fail(
            path,
            f"must be positive definite (smallest eigenvalue {np.linalg.eigvalsh(a).min():.3g}); "
            "raise the diagonal",
        ) from None
    return a


def _as_toml_cov(a: np.ndarray) -> list:
    if np.count_nonzero(a - np.diag(np.diag(a))) == 0:
        return [float(v) for v in np.diag(a)]
    return [[float(v) for v in row] for row in a]


# --- target shapes ---------------------------------------------------------


@dataclass(frozen=True)
class Constant:
    """A constant offset."""

    value: float
    kind: ClassVar[str] = "constant"

    def validate(self, path: str) -> None:
        _finite(f"{path}.value", self.value)


@dataclass(frozen=True)
class Square:
    """``+amplitude`` for the first half of each period, ``-amplitude`` after."""

    amplitude: float
    period_s: float
    kind: ClassVar[str] = "square"

    def validate(self, path: str) -> None:
        _finite(f"{path}.amplitude", self.amplitude)
        _positive(f"{path}.period_s", self.period_s)


@dataclass(frozen=True)
class RoundedSquare:
    """``amplitude * cbrt(sin(2 pi t / period))``: the Hi5 target (8 deg, 4 s)."""

    amplitude: float
    period_s: float
    kind: ClassVar[str] = "rounded_square"

    def validate(self, path: str) -> None:
        _finite(f"{path}.amplitude", self.amplitude)
        _positive(f"{path}.period_s", self.period_s)


@dataclass(frozen=True)
class Chirp:
    """Linear chirp from ``f0_hz`` to ``f1_hz`` over ``duration_s``, then at ``f1_hz``."""

    amplitude: float
    f0_hz: float
    f1_hz: float
    duration_s: float
    kind: ClassVar[str] = "chirp"

    def validate(self, path: str) -> None:
        _finite(f"{path}.amplitude", self.amplitude)
        _non_negative(f"{path}.f0_hz", self.f0_hz)
        _non_negative(f"{path}.f1_hz", self.f1_hz)
        _positive(f"{path}.duration_s", self.duration_s)


@dataclass(frozen=True)
class Harmonics:
    """``amplitude * sum_{k=1..harmonics} sin(k omega t)`` (``cos`` if ``cosine``)."""

    amplitude: float
    omega_rad_s: float
    harmonics: int = 3
    cosine: bool = False
    kind: ClassVar[str] = "harmonics"

    def validate(self, path: str) -> None:
        _finite(f"{path}.amplitude", self.amplitude)
        _finite(f"{path}.omega_rad_s", self.omega_rad_s)
        if isinstance(self.harmonics, bool) or not isinstance(self.harmonics, int) or self.harmonics < 1:
            raise _fail(f"{path}.harmonics", f"must be an integer >= 1, got {self.harmonics!r}")
        if not isinstance(self.cosine, bool):
            raise _fail(f"{path}.cosine", f"must be true or false, got {self.cosine!r}")


@dataclass(frozen=True)
class Sampled:
    """Samples every ``dt_s`` from t = 0, linearly interpolated, held at the ends."""

    samples: tuple[float, ...]
    dt_s: float
    kind: ClassVar[str] = "sampled"

    def validate(self, path: str) -> None:
        if len(self.samples) == 0:
            raise _fail(f"{path}.samples", "needs at least one sample")
        arr = np.asarray(self.samples, dtype=np.float64)
        if not np.all(np.isfinite(arr)):
            raise _fail(f"{path}.samples", f"must be finite; first bad index {int(np.argmin(np.isfinite(arr)))}")
        _positive(f"{path}.dt_s", self.dt_s)


Shape = Union[Constant, Square, RoundedSquare, Chirp, Harmonics, Sampled]
_SHAPES: dict[str, type] = {c.kind: c for c in (Constant, Square, RoundedSquare, Chirp, Harmonics, Sampled)}
MAX_PARTS = 3


def _shape_from_dict(path: str, d: Any) -> Shape:
    if not isinstance(d, dict) or "kind" not in d:
        raise _fail(path, f"must be a table with a 'kind' (one of {sorted(_SHAPES)})")
    d = dict(d)
    kind = d.pop("kind")
    cls = _SHAPES.get(kind)
    if cls is None:
        raise _fail(f"{path}.kind", f"unknown shape {kind!r}; use one of {sorted(_SHAPES)}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(d) - names
    if unknown:
        raise _fail(path, f"unknown field(s) {sorted(unknown)} for kind {kind!r}; allowed: {sorted(names)}")
    if cls is Sampled and "samples" in d:
        d["samples"] = tuple(d["samples"])
    try:
        return cls(**d)
    except TypeError as e:
        raise _fail(path, f"{e}") from None


def _shape_to_dict(s: Shape) -> dict:
    d = {"kind": s.kind}
    for f in dataclasses.fields(s):
        v = getattr(s, f.name)
        d[f.name] = list(v) if isinstance(v, tuple) else v
    return d


# --- sections --------------------------------------------------------------


def _check_fields(path: str, cls: type, d: Any) -> dict:
    if not isinstance(d, dict):
        raise _fail(path, f"must be a table, got {type(d).__name__}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(d) - names
    if unknown:
        raise _fail(path, f"unknown field(s) {sorted(unknown)}; allowed: {sorted(names)}")
    return d


@dataclass
class PlantConfig:
    """The handle: ``M xdd + C xd = u + u_h + eps``."""

    mass: float = 0.0035
    damping: float = 0.0
    coulomb: float = 0.0
    dt_s: float = 1e-3

    def validate(self, path: str = "plant") -> None:
        _positive(f"{path}.mass", self.mass)
        _non_negative(f"{path}.damping", self.damping)
        _non_negative(f"{path}.coulomb", self.coulomb)
        _positive(f"{path}.dt_s", self.dt_s)


@dataclass
class WorldConfig:
    """Noise and initial state of a simulated trial."""

    motor_noise_std: float = 1e-3
    position_noise_std: float = math.sqrt(1e-7)
    velocity_noise_std: float = math.sqrt(1e-7)
    seed: int = 0
    x0: float = 0.0
    v0: float = 0.0

    def validate(self, path: str = "world") -> None:
        _non_negative(f"{path}.motor_noise_std", self.motor_noise_std)
        _non_negative(f"{path}.position_noise_std", self.position_noise_std)
        _non_negative(f"{path}.velocity_noise_std", self.velocity_noise_std)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2**64:
            raise _fail(f"{path}.seed", f"must be an integer in [0, 2**64), got {self.seed!r}")
        _finite(f"{path}.x0", self.x0)
        _finite(f"{path}.v0", self.v0)


@dataclass
class SigmaConfig:
    """Merwe scaled sigma points."""

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0

    def validate(self, path: str, n: int = 6) -> None:
        _positive(f"{path}.alpha", self.alpha)
        _finite(f"{path}.beta", self.beta)
        _finite(f"{path}.kappa", self.kappa)
        if n + self.kappa <= 0:
            raise _fail(f"{path}.kappa", f"needs n + kappa > 0 (n = {n}), got {self.kappa}")


@dataclass
class FilterConfig:
    """A UKF on the 6-state extended model (stage 1: 3 measurements, stage 2: 5)."""

    Q: Any = field(default_factory=lambda: [1e-2] * 6)
    R: Any = field(default_factory=lambda: [1e-7] * 3)
    P0: Any = field(default_factory=lambda: [1e-4, 1e-4, 1e-4, 1.0, 1.0, 1.0])
    gains0: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])

    def validate(self, path: str, m: int) -> None:
        self.Q = _covariance(f"{path}.Q", self.Q, 6)
        self.R = _covariance(f"{path}.R", self.R, m)
        self.P0 = _covariance(f"{path}.P0", self.P0, 6)
        if len(self.gains0) != 3:
            raise _fail(f"{path}.gains0", f"needs 3 entries [Lhx, Lhv, Lhh], got {len(self.gains0)}")
        self.gains0 = [_finite(f"{path}.gains0[{i}]", g) for i, g in enumerate(self.gains0)]


@dataclass
class IntegratorConfig:
    """Stage 3: the goal-integration filters on ``[x - tau, xdot]``."""

    Q: Any = field(default_factory=lambda: [1e-2, 1e-2])
    R_sensor: Any = field(default_factory=lambda: [1e-7, 1e-7])
    P0: Any = field(default_factory=lambda: [1e-2, 1e-2])
    partner_window_s: float = 0.2

    def validate(self, path: str) -> None:
        self.Q = _covariance(f"{path}.Q", self.Q, 2)
        self.R_sensor = _covariance(f"{path}.R_sensor", self.R_sensor, 2)
        self.P0 = _covariance(f"{path}.P0", self.P0, 2)
        _positive(f"{path}.partner_window_s", self.partner_window_s)


@dataclass
class RobotConfig:
    """The robot: LQR weights, its estimators and the goal-integration switch."""

    q_pos: float = 1.0
    q_vel: float = 0.0
    integrate: bool = True
    gain_window_s: float = 8.0
    torque_limit: float = 1e3
    seed: int = 1
    prior_partner_gains: list[float] | None = None
    sigma: SigmaConfig = field(default_factory=SigmaConfig)
    stage1: FilterConfig = field(default_factory=FilterConfig)
    stage2: FilterConfig = field(default_factory=lambda: FilterConfig(R=[1e-7] * 5))
    stage3: IntegratorConfig = field(default_factory=IntegratorConfig)

    def validate(self, path: str = "robot") -> None:
        _positive(f"{path}.q_pos", self.q_pos)
        _non_negative(f"{path}.q_vel", self.q_vel)
        if not isinstance(self.integrate, bool):
            raise _fail(f"{path}.integrate", f"must be true or false, got {self.integrate!r}")
        _positive(f"{path}.gain_window_s", self.gain_window_s)
        _positive(f"{path}.torque_limit", self.torque_limit)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2**64:
            raise _fail(f"{path}.seed", f"must be an integer in [0, 2**64), got {self.seed!r}")
        if self.prior_partner_gains is not None:
            if len(self.prior_partner_gains) != 3:
                raise _fail(f"{path}.prior_partner_gains", "needs 3 entries [Lhx, Lhv, Lhh] or none")
            for i, g in enumerate(self.prior_partner_gains):
                _finite(f"{path}.prior_partner_gains[{i}]", g)
        self.sigma.validate(f"{path}.sigma")
        self.stage1.validate(f"{path}.stage1", 3)
        self.stage2.validate(f"{path}.stage2", 5)
        self.stage3.validate(f"{path}.stage3")


@dataclass
class PartnerConfig:
    """The partner (virtual human): imposed gains, or LQR weights."""

    gains: list[float] | None = field(default_factory=lambda: [0.0, 0.0, 2.0])
    q_pos: float | None = None
    q_vel: float | None = None
    torque_limit: float = 1e3
    estimates_robot: bool = False

    def validate(self, path: str = "partner") -> None:
        has_gains = self.gains is not None
        has_lqr = self.q_pos is not None or self.q_vel is not None
        if has_gains == has_lqr:
            raise _fail(path, "give either gains = [Lhx, Lhv, Lhh] or the LQR weights q_pos and q_vel, not both")
        if has_gains:
            if len(self.gains) != 3:
                raise _fail(f"{path}.gains", f"needs 3 entries [Lhx, Lhv, Lhh], got {len(self.gains)}")
            self.gains = [_finite(f"{path}.gains[{i}]", g) for i, g in enumerate(self.gains)]
        else:
            _positive(f"{path}.q_pos", self.q_pos)
            _non_negative(f"{path}.q_vel", self.q_vel if self.q_vel is not None else math.nan)
        _positive(f"{path}.torque_limit", self.torque_limit)
        if not isinstance(self.estimates_robot, bool):
            raise _fail(f"{path}.estimates_robot", "must be true or false")


@dataclass
class PhaseConfig:
    """One phase of the protocol."""

    kind: Literal["gains", "trajectory", "integration"]
    duration_s: float
    robot_target: list[Shape]
    partner_target: list[Shape]
    target_noise_std: float = 0.0

    def validate(self, path: str) -> None:
        if self.kind not in PHASE_KINDS:
            raise _fail(f"{path}.kind", f"must be one of {PHASE_KINDS}, got {self.kind!r}")
        _positive(f"{path}.duration_s", self.duration_s)
        _non_negative(f"{path}.target_noise_std", self.target_noise_std)
        for name in ("robot_target", "partner_target"):
            parts = getattr(self, name)
            if not isinstance(parts, list) or not 1 <= len(parts) <= MAX_PARTS:
                raise _fail(f"{path}.{name}", f"must be a list of 1 to {MAX_PARTS} shapes")
            for i, s in enumerate(parts):
                if not isinstance(s, tuple(_SHAPES.values())):
                    raise _fail(f"{path}.{name}[{i}]", f"must be a shape ({sorted(_SHAPES)}), got {s!r}")
                s.validate(f"{path}.{name}[{i}]")


@dataclass
class RealtimeConfig:
    """Thread settings of the real-time loop (each falls back with a warning)."""

    fifo_priority: int | None = None
    cpu: int | None = None
    mlockall: bool = True

    def validate(self, path: str) -> None:
        if self.fifo_priority is not None and not (isinstance(self.fifo_priority, int) and 1 <= self.fifo_priority <= 99):
            raise _fail(f"{path}.fifo_priority", f"must be an integer 1..99 or absent, got {self.fifo_priority!r}")
        if self.cpu is not None and not (isinstance(self.cpu, int) and self.cpu >= 0):
            raise _fail(f"{path}.cpu", f"must be a CPU index >= 0 or absent, got {self.cpu!r}")
        if not isinstance(self.mlockall, bool):
            raise _fail(f"{path}.mlockall", "must be true or false")


@dataclass
class RigConfig:
    """The real-time binary's ``[rig]`` table: CAN link, units, safety, logs.

    The simulation ignores it; ``sensaug-rt`` reads it (crates/sensaug-rt).
    """

    can: str = "udp:47100"
    node_id: int = 1
    position_unit: str = "deg"
    torque_limit_nm: float = 3.0
    watchdog_ms: int = 50
    feedback_timeout_ms: float = 20.0
    ramp_down_s: float = 0.2
    virtual_human: bool = True
    log: str = "out/rig_log.csv"
    stats: str = "out/rig_stats.json"
    ring_capacity: int = 65536
    realtime: RealtimeConfig = field(default_factory=RealtimeConfig)

    def validate(self, path: str = "rig") -> None:
        scheme, _, rest = self.can.partition(":")
        if scheme not in ("udp", "socketcan") or not rest:
            raise _fail(f"{path}.can", f"must be 'udp:<port>' or 'socketcan:<ifname>', got {self.can!r}")
        if scheme == "udp" and not (rest.isdigit() and 1 <= int(rest) <= 65535):
            raise _fail(f"{path}.can", f"UDP port must be 1..65535, got {rest!r}")
        if isinstance(self.node_id, bool) or not isinstance(self.node_id, int) or not 0 <= self.node_id <= 15:
            raise _fail(f"{path}.node_id", f"must be an integer 0..15, got {self.node_id!r}")
        if self.position_unit not in ("deg", "rad"):
            raise _fail(f"{path}.position_unit", f"must be 'deg' or 'rad', got {self.position_unit!r}")
        _positive(f"{path}.torque_limit_nm", self.torque_limit_nm)
        if isinstance(self.watchdog_ms, bool) or not isinstance(self.watchdog_ms, int) or not 1 <= self.watchdog_ms <= 65535:
            raise _fail(f"{path}.watchdog_ms", f"must be an integer 1..65535, got {self.watchdog_ms!r}")
        _positive(f"{path}.feedback_timeout_ms", self.feedback_timeout_ms)
        _non_negative(f"{path}.ramp_down_s", self.ramp_down_s)
        if not isinstance(self.virtual_human, bool):
            raise _fail(f"{path}.virtual_human", "must be true or false")
        if isinstance(self.ring_capacity, bool) or not isinstance(self.ring_capacity, int) or self.ring_capacity < 1024:
            raise _fail(f"{path}.ring_capacity", f"must be an integer >= 1024, got {self.ring_capacity!r}")
        self.realtime.validate(f"{path}.realtime")


MAX_PHASES = 4


@dataclass
class ScenarioConfig:
    """A whole trial: plant, world noise, robot, partner and phases."""

    phases: list[PhaseConfig]
    plant: PlantConfig = field(default_factory=PlantConfig)
    world: WorldConfig = field(default_factory=WorldConfig)
    robot: RobotConfig = field(default_factory=RobotConfig)
    partner: PartnerConfig = field(default_factory=PartnerConfig)
    rig: RigConfig = field(default_factory=RigConfig)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Checks every field; raises ``ValueError`` naming the first bad one."""
        self.plant.validate("plant")
        self.world.validate("world")
        self.robot.validate("robot")
        self.partner.validate("partner")
        self.rig.validate("rig")
        if not 1 <= len(self.phases) <= MAX_PHASES:
            raise _fail("phases", f"needs 1 to {MAX_PHASES} phases, got {len(self.phases)}")
        gains_known = self.robot.prior_partner_gains is not None
        for i, p in enumerate(self.phases):
            p.validate(f"phases[{i}]")
            if p.kind == "gains":
                gains_known = True
            elif not gains_known:
                raise _fail(
                    f"phases[{i}].kind",
                    f"a {p.kind!r} phase needs an earlier 'gains' phase or robot.prior_partner_gains",
                )
            ticks = p.duration_s / self.plant.dt_s
            if ticks < 1:
                raise _fail(f"phases[{i}].duration_s", f"shorter than one tick (dt_s = {self.plant.dt_s})")

    @property
    def duration_s(self) -> float:
        return sum(p.duration_s for p in self.phases)

    # --- TOML ---------------------------------------------------------------

    def to_dict(self) -> dict:
        """Plain nested dict (TOML-ready): covariances as lists."""

        def conv(obj: Any) -> Any:
            if isinstance(obj, np.ndarray):
                return _as_toml_cov(obj)
            if isinstance(obj, tuple(_SHAPES.values())):
                return _shape_to_dict(obj)
            if dataclasses.is_dataclass(obj):
                return {f.name: conv(getattr(obj, f.name)) for f in dataclasses.fields(obj) if getattr(obj, f.name) is not None}
            if isinstance(obj, list):
                return [conv(v) for v in obj]
            return obj

        return conv(self)

    def to_toml(self, path: str | Path | None = None) -> str:
        """The configuration as TOML text; also written to ``path`` if given."""
        text = tomli_w.dumps(self.to_dict())
        if path is not None:
            Path(path).write_text(text)
        return text

    @classmethod
    def from_dict(cls, d: dict) -> "ScenarioConfig":
        d = _check_fields("<root>", cls, d)
        if "phases" not in d:
            raise _fail("phases", "missing; a trial needs at least one [[phases]] table")

        def section(
            name: str, kls: type, sub: dict[str, type] | None = None, absent_is_none: tuple[str, ...] = ()
        ) -> Any:
            raw = _check_fields(name, kls, d.get(name, {}))
            kw = dict(raw)
            # TOML has no null: an optional field that was None is simply absent.
            for key in absent_is_none:
                kw.setdefault(key, None)
            for key, sk in (sub or {}).items():
                if key in kw:
                    nested = _check_fields(f"{name}.{key}", sk, kw[key])
                    kw[key] = sk(**nested)
            return kls(**kw)

        phases = []
        for i, p in enumerate(d["phases"]):
            p = dict(_check_fields(f"phases[{i}]", PhaseConfig, p))
            for name in ("robot_target", "partner_target"):
                if name not in p:
                    raise _fail(f"phases[{i}].{name}", "missing; give a list of shapes")
                parts = p[name] if isinstance(p[name], list) else [p[name]]
                p[name] = [_shape_from_dict(f"phases[{i}].{name}[{j}]", s) for j, s in enumerate(parts)]
            try:
                phases.append(PhaseConfig(**p))
            except TypeError as e:
                raise _fail(f"phases[{i}]", str(e)) from None
        try:
            return cls(
                phases=phases,
                plant=section("plant", PlantConfig),
                world=section("world", WorldConfig),
                robot=section(
                    "robot",
                    RobotConfig,
                    {"sigma": SigmaConfig, "stage1": FilterConfig, "stage2": FilterConfig, "stage3": IntegratorConfig},
                ),
                partner=section("partner", PartnerConfig, absent_is_none=("gains",)),
                rig=section("rig", RigConfig, {"realtime": RealtimeConfig}),
            )
        except TypeError as e:
            raise ValueError(f"<root>: {e}") from None

    @classmethod
    def from_toml(cls, source: str | Path) -> "ScenarioConfig":
        """Reads a TOML file (a path) or TOML text."""
        p = Path(source) if not isinstance(source, str) or "\n" not in source else None
        text = p.read_text() if p is not None else str(source)
        try:
            d = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise ValueError(f"{source if p else '<toml>'}: not valid TOML: {e}") from None
        return cls.from_dict(d)
