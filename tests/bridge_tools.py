"""The generators in ``firmware_bridge/tools`` loaded as modules, for the
tests that compare their output with what is committed (golden frames, the
docs' tables)."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[1]
TOOLS = ROOT / "firmware_bridge" / "tools"


def load_tool(name: str) -> ModuleType:
    """``firmware_bridge/tools/<name>.py`` as a module (its ``main`` not run)."""
    spec = importlib.util.spec_from_file_location(name, TOOLS / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def regenerated(name: str, committed: Path, tmp_path: Path) -> tuple[str, str]:
    """The text tool ``name`` writes afresh (into ``tmp_path``) and the
    committed file's text, for a byte-for-byte comparison."""
    out = tmp_path / committed.name
    assert load_tool(name).main([f"{name}.py", str(out)]) == 0
    return out.read_text(), committed.read_text()
