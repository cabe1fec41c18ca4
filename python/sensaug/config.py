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
import tomli_w

from sensaug import _core
from sensaug.config_types import (
    SHAPES,
    ChannelConfig,
    Chirp,
    Constant,
    Covariance,
    GainFilterConfig,
    Harmonics,
    IntegratorConfig,
    PartnerConfig,
    PartnerIntegrationConfig,
    PhaseConfig,
    PlantConfig,
    RealtimeConfig,
    RigCia402Config,
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
    "RigConfig",
    "ScenarioConfig",
    "check_file",
    "schema",
]

#: Raised for every configuration problem; ``str(e)`` is
#: ``"<dotted.field>: <what is wrong and how to fix it>"`` (a ``ValueError``).
ConfigError = _core.ConfigError


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
        f"{path}: a {type(obj).__name__} cannot be written to a configuration; "
        "use a number, a string, true/false, a list or a table"
    )


class ScenarioConfig(_ScenarioTables):
    """A whole trial: phases, plant, world, robot, partner and rig.

    Validated on construction and by :meth:`validate` (after editing fields).
    """

    def __post_init__(self) -> None:
        self.validate()

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict (TOML/JSON-ready); absent optional fields left out."""
        return _plain(self, "")

    def _toml(self) -> str:
        try:
            return tomli_w.dumps(self.to_dict())
        except TypeError as e:  # a value tomli_w cannot write, e.g. a nested None
            raise ConfigError(f"(config): cannot be written as TOML ({e}); check the field types") from None

    def validate(self) -> None:
        """Checks every field with the one validator (the same as ``sensaug-rt --check``).

        Raises:
            ConfigError: naming the first bad field and how to fix it.
        """
        _core.config_load(self._toml())

    def resolved_json(self) -> str:
        """The configuration as the Rust side sees it: JSON, every default filled in."""
        return _core.config_load(self._toml())

    def to_toml(self, path: str | Path | None = None) -> str:
        """The configuration as TOML with each field's description and unit as a
        comment; also written to ``path`` if given."""
        text = _core.config_to_toml(self._toml())
        if path is not None:
            Path(path).write_text(text)
        return text

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ScenarioConfig:
        """From a plain dict (as in a TOML file); validated."""
        try:
            text = tomli_w.dumps(_plain(d, ""))
        except TypeError as e:
            raise ConfigError(f"(config): cannot be written as TOML ({e}); check the field types") from None
        return cls._from_json(_core.config_load(text))

    @classmethod
    def _from_json(cls, text: str) -> ScenarioConfig:
        return super().from_dict(json.loads(text))  # type: ignore[return-value]

    @classmethod
    def from_toml(cls, source: str | Path) -> ScenarioConfig:
        """Reads a TOML (or ``.json``) file, or TOML text containing a newline."""
        if isinstance(source, str) and "\n" in source:
            return cls._from_json(_core.config_load(source))
        return cls._from_json(_core.config_load_file(str(source)))

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
    return ScenarioConfig._from_json(_core.config_check_file(str(path)))


def schema() -> dict[str, Any]:
    """The JSON Schema of a configuration file (fields, units, defaults, bounds)."""
    return json.loads(_core.config_schema())


# Shape classes by kind, for code that builds targets from names.
SHAPE_KINDS = tuple(SHAPES)
