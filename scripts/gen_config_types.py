"""Writes python/sensaug/config_types.py from the configuration's JSON Schema.

The schema is generated from the Rust types in crates/sensaug-config (the one
source of every field, default, bound and description); this script turns it
into typed Python dataclasses so that editors complete and check them.
tests/test_config_schema.py fails when the committed file is not what this
script writes.

Usage: python scripts/gen_config_types.py [--check]
"""

from __future__ import annotations

import json
import keyword
import sys
import textwrap
from pathlib import Path

OUT = Path(__file__).resolve().parent.parent / "python" / "sensaug" / "config_types.py"

#: Rust schema type -> Python class.
CLASS = {
    "ScenarioSpec": "ScenarioConfig",
    "PhaseSpec": "PhaseConfig",
    "PlantSpec": "PlantConfig",
    "WorldSpec": "WorldConfig",
    "SigmaSpec": "SigmaConfig",
    "GainFilterSpec": "GainFilterConfig",
    "TrajectoryFilterSpec": "TrajectoryFilterConfig",
    "ChannelSpec": "ChannelConfig",
    "IntegratorSpec": "IntegratorConfig",
    "RobotSpec": "RobotConfig",
    "PartnerSpec": "PartnerConfig",
    "PartnerIntegrationSpec": "PartnerIntegrationConfig",
    "HumanSpec": "HumanConfig",
    "GainDriftSpec": "GainDriftConfig",
    "RealtimeSpec": "RealtimeConfig",
    "Cia402Spec": "RigCia402Config",
    "RangeSpec": "RigRangeConfig",
    "FrictionSpec": "RigFrictionConfig",
    "RigSpec": "RigConfig",
    "DisplaySpec": "DisplayConfig",
    "SessionSpec": "SessionConfig",
    "BlockSpec": "BlockConfig",
    "IncludedFile": "IncludedFile",
}


def camel(kind: str) -> str:
    return "".join(p.capitalize() for p in kind.split("_"))


def optional_ref(s: dict) -> dict | None:
    """The ``$ref`` branch of an optional table (``anyOf: [$ref, null]``)."""
    branches = s.get("anyOf") or []
    refs = [b for b in branches if "$ref" in b]
    if len(branches) == 2 and len(refs) == 1 and {"type": "null"} in branches:
        return refs[0]
    return None


def ref_name(s: dict) -> str | None:
    r = s.get("$ref") or (optional_ref(s) or {}).get("$ref")
    return r.rsplit("/", 1)[-1] if r else None


class Gen:
    def __init__(self, schema: dict) -> None:
        self.schema = schema
        self.defs = schema["$defs"]
        self.lines: list[str] = []

    def doc(self, text: str, indent: str) -> list[str]:
        text = text.replace("\\", "\\\\").replace('"""', "'''")
        body = textwrap.fill(" ".join(text.split()), 100 - len(indent) - 6)
        ls = body.splitlines()
        if len(ls) == 1:
            return [f'{indent}"""{ls[0]}"""']
        return [f'{indent}"""{ls[0]}'] + [f"{indent}{x}" for x in ls[1:]] + [f'{indent}"""']

    def py_type(self, s: dict) -> str:
        opt = optional_ref(s)
        if opt is not None:
            return f"{self.py_type(opt)} | None"
        name = ref_name(s)
        if name:
            if name.startswith("Covariance"):
                return "Covariance"
            if name == "ShapeSpec":
                return "Shape"
            d = self.defs[name]
            if "anyOf" in d:  # an untagged choice (robot.partner_delay: "auto" or ms)
                return " | ".join(self.py_type(b) for b in d["anyOf"])
            if "enum" in d or "oneOf" in d and all("const" in b for b in d["oneOf"]):
                return self.enum_type(d)
            return CLASS[name]
        t = s.get("type")
        nullable = isinstance(t, list) and "null" in t
        if isinstance(t, list):
            t = next(x for x in t if x != "null")
        base = {
            "number": "float",
            "integer": "int",
            "boolean": "bool",
            "string": "str",
            "object": "dict[str, Any]",
        }.get(t)
        if t == "array":
            item = s.get("items", {})
            inner = self.py_type(item)
            base = f"list[{inner}]"
        if base is None:
            raise SystemExit(f"unsupported schema: {s}")
        return f"{base} | None" if nullable else base

    def enum_type(self, d: dict) -> str:
        values = d.get("enum") or [b["const"] for b in d["oneOf"]]
        return "Literal[" + ", ".join(json.dumps(v) for v in values) + "]"

    def default(self, prop: dict, required: bool) -> str | None:
        if required:
            return None
        if "default" not in prop:
            return "None"
        v = prop["default"]
        name = ref_name(prop)
        if name in CLASS:
            return f"field(default_factory=lambda: {CLASS[name]}.from_dict({v!r}))"
        if name and name.startswith("Covariance"):
            return f"field(default_factory=lambda: {v!r})"
        if isinstance(v, (list, dict)):
            return f"field(default_factory=lambda: {v!r})"
        return repr(v)

    def converter(self, prop: dict) -> str | None:
        name = ref_name(prop)
        if name in CLASS:
            return f"{CLASS[name]}.from_dict"
        if prop.get("type") == "array" and ref_name(prop.get("items", {})) == "ShapeSpec":
            return "_shapes"
        if prop.get("type") == "array" and ref_name(prop.get("items", {})) in CLASS:
            return f"_list_of({CLASS[ref_name(prop['items'])]}.from_dict)"
        return None

    def dataclass(self, cls: str, d: dict, kind: str | None = None) -> None:
        props = d["properties"]
        tag = "kind" if kind is not None else None
        required = [p for p in d.get("required", []) if p != tag]
        order = required + [p for p in props if p not in required and p != tag]
        self.lines += ["", "", "@dataclass"]
        self.lines.append(f"class {cls}(_Table):")
        self.lines += self.doc(d.get("description", cls), "    ")
        self.lines.append("")
        if kind is not None:
            self.lines.append(f"    kind: ClassVar[str] = {kind!r}")
        for p in order:
            prop = props[p]
            name = p + "_" if keyword.iskeyword(p) else p
            dflt = self.default(prop, p in required)
            ann = self.py_type(prop)
            if dflt == "None" and not ann.endswith("| None"):
                ann += " | None"
            self.lines.append(f"    {name}: {ann}" + (f" = {dflt}" if dflt is not None else ""))
            desc = prop.get("description") or self.defs.get(ref_name(prop) or "", {}).get("description")
            if desc:
                self.lines += self.doc(desc, "    ")
        convs = {p: c for p in order if (c := self.converter(props[p]))}
        if convs:
            self.lines.append("")
            self.lines.append("    _nested = {" + ", ".join(f"{p!r}: {c}" for p, c in convs.items()) + "}")

    def run(self) -> str:
        self.lines = [
            '"""Typed configuration tables, generated from the JSON Schema of',
            "crates/sensaug-config by scripts/gen_config_types.py: do not edit.",
            "",
            "Every field, default and description comes from the Rust schema; the",
            "bounds are enforced there (``sensaug.config`` validates through it).",
            '"""',
            "",
            "# ruff: noqa: E501",
            "from __future__ import annotations",
            "",
            "from dataclasses import dataclass, field, fields",
            "from typing import Any, Callable, ClassVar, Literal, Self, Sequence, Union",
            "",
            "import numpy as np",
            "",
            "#: A covariance: N diagonal entries or an N x N nested list (or array).",
            "Covariance = Union[Sequence[float], Sequence[Sequence[float]], np.ndarray]",
            "",
            "",
            "class _Table:",
            '    """A table of the schema: built from a plain dict by :meth:`from_dict`."""',
            "",
            "    #: Field -> converter of the field's plain value (nested tables, shapes).",
            "    _nested: ClassVar[dict[str, Callable[[Any], Any]]] = {}",
            "",
            "    @classmethod",
            "    def from_dict(cls, d: dict[str, Any]) -> Self:",
            '        """From a plain dict as the schema describes it (already validated);',
            '        a shape\'s ``kind`` tag is dropped (it is the class, not a field)."""',
            "        kw = dict(d)",
            '        if "kind" not in {f.name for f in fields(cls)}:  # type: ignore[arg-type]',
            '            kw.pop("kind", None)',
            "        for name, convert in cls._nested.items():",
            "            if kw.get(name) is not None:",
            "                kw[name] = convert(kw[name])",
            "        return cls(**kw)",
        ]
        shapes = self.defs["ShapeSpec"]["oneOf"]
        shape_classes = []
        for b in shapes:
            kind = b["properties"]["kind"]["const"]
            cls = camel(kind)
            shape_classes.append((kind, cls))
            self.dataclass(cls, b, kind=kind)
        self.lines += [
            "",
            "",
            "Shape = Union[" + ", ".join(c for _, c in shape_classes) + "]",
            "#: Shape class by its ``kind``.",
            "SHAPES: dict[str, type] = {" + ", ".join(f"{k!r}: {c}" for k, c in shape_classes) + "}",
            "",
            "",
            "def _shapes(items: list[Any]) -> list[Shape]:",
            "    out = []",
            "    for s in items:",
            "        if isinstance(s, dict):",
            '            s = SHAPES[s["kind"]].from_dict(s)',
            "        out.append(s)",
            "    return out",
            "",
            "",
            "def _list_of(conv: Callable[[dict[str, Any]], Any]) -> Callable[[list[Any]], list[Any]]:",
            "    return lambda items: [conv(x) if isinstance(x, dict) else x for x in items]",
        ]
        # Leaves first, so default factories refer to defined classes.
        done: set[str] = set()

        def emit(name: str) -> None:
            if name in done:
                return
            d = self.defs[name] if name != "ScenarioSpec" else self.schema
            for prop in d["properties"].values():
                for r in (ref_name(prop), ref_name(prop.get("items", {}))):
                    if r in CLASS:
                        emit(r)
            done.add(name)
            self.dataclass(CLASS[name], d)

        for name in CLASS:
            emit(name)
        self.lines.append("")
        return "\n".join(self.lines)


def main() -> int:
    from sensaug import _core

    text = Gen(json.loads(_core.config_schema())).run()
    if "--check" in sys.argv:
        if OUT.read_text() != text:
            print(f"{OUT} is stale: run python scripts/gen_config_types.py", file=sys.stderr)
            return 1
        return 0
    OUT.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
