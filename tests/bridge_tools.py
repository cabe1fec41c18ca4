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
