"""No dependency cycles at the edges (issue 18): the bridge's Python package
never imports ``sensaug`` (which depends on it), and the configuration crate
(so the Python extension) links the bridge without its transports."""

from __future__ import annotations

import ast
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_no_module_of_the_bridge_imports_sensaug():
    """No ``import sensaug`` (or ``from sensaug...``) under firmware_bridge/python."""
    found = []
    for path in sorted((ROOT / "firmware_bridge" / "python").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            found += [f"{path.name}:{node.lineno} {n}" for n in names if n.split(".")[0] == "sensaug"]
    assert not found, found


def crates_linked(package: str) -> set[str]:
    """The crates ``package`` links (normal dependencies, features as a build of it alone resolves them)."""
    out = subprocess.run(
        ["cargo", "tree", "-p", package, "-e", "normal", "--prefix", "none", "--offline"],
        cwd=ROOT, capture_output=True, text=True, timeout=120, check=True,
    ).stdout
    return {line.split()[0] for line in out.splitlines() if line.strip()}


def test_the_python_extension_links_no_transport():
    """sensaug-config takes the bridge's DBC ranges and bus URL parsing only
    (``default-features = false``): the extension links no socket code
    (socket2 is the transports' own dependency), while the rig binary does."""
    ext = crates_linked("sensaug-py")
    assert "sensaug-bridge" in ext and "sensaug-config" in ext
    assert "socket2" not in ext, sorted(ext)
    assert "socket2" in crates_linked("sensaug-rt")
