"""Trial configuration: typed tables checked by the one schema.

The tables (``PlantConfig``, ``RobotConfig``, ...) are generated from the
JSON Schema of the Rust crate ``sensaug-config`` (``config_types.py``), so
their fields, defaults and descriptions are the ones the real-time binary
``sensaug-rt`` reads. Validation runs in Rust too: ``ScenarioConfig.validate``
hands the configuration to the same validator as ``sensaug-rt --check``, so
both give the same verdict and the same message, which names the field by its
dotted path (``robot.stage1.Q``) and says how to fix it.

Covariances are given as a list of diagonal entries or a full nested list
(or a numpy array).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from sensaug import _core
from sensaug.config_types import (
    SHAPES,
    ChannelConfig,
    Chirp,
    Constant,
    Covariance,
    GainFilterConfig,
    Harmonics,
    IncludedFile,
    IntegratorConfig,
    PartnerConfig,
    PartnerIntegrationConfig,
    PhaseConfig,
    PlantConfig,
    RealtimeConfig,
    RigCia402Config,
    RigFrictionConfig,
    RigRangeConfig,
    RigConfig,
    RobotConfig,
    RoundedSquare,
    Sampled,
    Shape,
    SigmaConfig,
    Square,
    TrajectoryFilterConfig,
    WorldConfig,
)
from sensaug.config_types import ScenarioConfig as _ScenarioTables

__all__ = [
    "ConfigError",
    "Constant",
    "Square",
    "RoundedSquare",
    "Chirp",
    "Harmonics",
    "Sampled",
    "Shape",
    "Covariance",
    "PlantConfig",
    "WorldConfig",
    "SigmaConfig",
    "GainFilterConfig",
    "TrajectoryFilterConfig",
    "IntegratorConfig",
    "ChannelConfig",
    "RobotConfig",
    "PartnerConfig",
    "PartnerIntegrationConfig",
    "PhaseConfig",
    "RealtimeConfig",
    "RigCia402Config",
    "RigFrictionConfig",
    "RigRangeConfig",
    "RigConfig",
    "IncludedFile",
    "ScenarioConfig",
    "check_file",
    "schema",
]

class ConfigError(ValueError):
    """Raised for every configuration problem, by the core (the binding
    raises this class) and by the Python side alike: ``e.field`` is the
    dotted field path, ``e.message`` what is wrong and how to fix it,
    ``str(e)`` is ``"<field>: <message>"``."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(field, message)  # the args a pickled error is rebuilt from
        self.field, self.message = field, message

    def __str__(self) -> str:
        return f"{self.field}: {self.message}"


def _plain(obj: Any, path: str) -> Any:
    """The configuration as plain TOML-ready values (absent = ``None`` dropped)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        d: dict[str, Any] = {}
        kind = getattr(type(obj), "kind", None)
        if isinstance(kind, str):
            d["kind"] = kind
        for f in dataclasses.fields(obj):
            v = getattr(obj, f.name)
            if v is not None:
                d[f.name] = _plain(v, f"{path}.{f.name}" if path else f.name)
        return d
    if isinstance(obj, dict):
        return {k: _plain(v, f"{path}.{k}" if path else str(k)) for k, v in obj.items() if v is not None}
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist(), path)
    if isinstance(obj, (list, tuple)):
        return [_plain(v, f"{path}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (bool, int, float, str)):
        return obj
    raise ConfigError(
        path or "(config)",
        f"a {type(obj).__name__} cannot be written to a configuration; "
        "use a number, a string, true/false, a list or a table",
    )


class ScenarioConfig(_ScenarioTables):
    """A whole trial: phases, plant, world, robot, partner and rig.

    Resolved by the one schema, once, when first needed (:meth:`resolved`:
    by ``run``, ``replay``, ``sweep``, ``to_toml`` and the rig launcher),
    or now by :meth:`validate`; again only after a field was edited.
    """

    def _keep(self, resolved: _core.Config, tables: dict[str, Any]) -> None:
        # Not dataclass fields: equality, ``to_dict`` and ``replace`` skip them.
        object.__setattr__(self, "_resolved", resolved)
        object.__setattr__(self, "_resolved_tables", tables)

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict (TOML/JSON-ready); absent optional fields left out."""
        return _plain(self, "")

    def validate(self) -> None:
        """Checks every field with the one validator (the same as
        ``sensaug-rt --check``) and keeps the configuration it resolves to.

        Raises:
            ConfigError: naming the first bad field and how to fix it.
        """
        tables = self.to_dict()
        self._keep(_core.Config(tables), tables)

    def resolved(self) -> _core.Config:
        """The configuration resolved by the one schema (``_core.Config``:
        every default filled in, gains solved, the rig loop's settings),
        built once per configuration and passed to ``run``, ``replay``,
        ``sweep`` and the rig launcher; resolved again only after a field
        was edited.

        Raises:
            ConfigError: an edit made the configuration invalid.
        """
        tables = self.to_dict()
        if tables != getattr(self, "_resolved_tables", None):
            self._keep(_core.Config(tables), tables)
        return self._resolved  # type: ignore[no-any-return]

    def resolved_json(self) -> str:
        """The configuration as the Rust side sees it: JSON, every default filled in."""
        return self.resolved().to_text(format="json")

    def to_toml(self, path: str | Path | None = None) -> str:
        """The configuration as TOML with each field's description and unit as a
        comment; also written to ``path`` if given."""
        text = self.resolved().to_text(format="toml")
        if path is not None:
            Path(path).write_text(text)
        return text

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ScenarioConfig:
        """From a plain dict (as in a TOML file); validated."""
        return cls._from_resolved(_core.Config(_plain(d, "")))

    @classmethod
    def _from_resolved(cls, resolved: _core.Config) -> ScenarioConfig:
        """The tables of a resolved configuration, keeping it (not resolved again)."""
        config: ScenarioConfig = super().from_dict(resolved.to_dict())
        config._keep(resolved, config.to_dict())
        return config

    @classmethod
    def from_toml(cls, source: str | Path) -> ScenarioConfig:
        """Reads a TOML (or ``.json``) file, or TOML text containing a newline."""
        if isinstance(source, str) and "\n" in source:
            return cls._from_resolved(_core.Config.from_text(source, format="toml"))
        return cls._from_resolved(_core.Config.from_file(str(source), check_outputs=False))

    @property
    def duration_s(self) -> float:
        """Length of the protocol (s)."""
        return math.fsum(p.duration_s for p in self.phases)

    def __repr__(self) -> str:
        """One line: the protocol, the step, the partner; ``to_toml()`` has it all."""
        phases = ", ".join(f"{p.kind} {p.duration_s:g} s" for p in self.phases)
        gains = self.partner.gains
        partner = "partner LQR weights" if gains is None else "partner gains [" + ", ".join(f"{g:g}" for g in gains) + "]"
        return (
            f"<ScenarioConfig: {phases}; dt {self.plant.dt_s * 1e3:g} ms, mass {self.plant.mass:g}; "
            f"{partner}; seed {self.world.seed}>"
        )

    def _repr_html_(self) -> str:
        """Jupyter: the phases as a table, the whole TOML (with units) folded."""
        import html

        rows = "".join(
            f"<tr><td>{i}</td><td>{p.kind}</td><td>{p.duration_s:g}</td><td>{p.target_noise_std:g}</td></tr>"
            for i, p in enumerate(self.phases)
        )
        return (
            f"<p>{html.escape(repr(self))}</p>"
            "<table><tr><th>phase</th><th>kind</th><th>duration (s)</th><th>target noise std</th></tr>"
            f"{rows}</table><details><summary>TOML (every field, its unit)</summary>"
            f"<pre>{html.escape(self.to_toml())}</pre></details>"
        )


def check_file(path: str | Path) -> ScenarioConfig:
    """Reads and validates a configuration file (TOML, or JSON by extension),
    exactly as ``sensaug-rt --check`` does, its rig output paths included
    (``rig.log``, ``rig.stats``: regular files or absent, distinct;
    ``docs/safety.md``, "Output paths").

    Raises:
        ConfigError: naming the first bad field (or the file) and how to fix it.
    """
    return ScenarioConfig._from_resolved(_core.Config.from_file(str(path), check_outputs=True))


def schema() -> dict[str, Any]:
    """The JSON Schema of a configuration file (fields, units, defaults, bounds)."""
    return json.loads(_core.config_schema())


# Shape classes by kind, for code that builds targets from names.
SHAPE_KINDS = tuple(SHAPES)
