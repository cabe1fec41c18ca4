"""The package's types as a notebook or an editor sees them: pyright in
strict mode passes on the README's python examples, and the return types a
user relies on are precise (not ``Any``)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from test_docs import python_blocks

REPO = Path(__file__).resolve().parents[1]

_REVEAL = """
import sensaug
from sensaug import presets
cfg = presets.hi5_experiment(2.0)
trial = sensaug.run(cfg)
reveal_type(sensaug.sweep(cfg, seeds=[0]))
reveal_type(sensaug.load_log("x.csv").to_pandas())
reveal_type(trial.plot("gains"))
reveal_type(trial.plot())
reveal_type(trial.metrics())
reveal_type(trial.meta)
"""


def _pyright(tmp_path: Path, code: str) -> dict:
    (tmp_path / "example.py").write_text(code)
    venv = Path(sys.prefix)
    (tmp_path / "pyrightconfig.json").write_text(json.dumps({
        "typeCheckingMode": "strict",
        "venvPath": str(venv.parent),
        "venv": venv.name,
        "pythonVersion": "3.11",
        # The examples end lines with bare expressions to show what they are.
        "reportUnusedExpression": False,
    }))
    out = subprocess.run([str(venv / "bin" / "pyright"), "--outputjson", "-p", str(tmp_path / "pyrightconfig.json")],
                         cwd=tmp_path, capture_output=True, text=True, timeout=600)
    return json.loads(out.stdout)


def test_pyright_strict_passes_on_the_readme_examples(tmp_path: Path) -> None:
    report = _pyright(tmp_path, "\n\n".join(python_blocks(REPO / "README.md")))
    errors = [f"{d['range']['start']['line'] + 1}: {d['message']}" for d in report["generalDiagnostics"]
              if d["severity"] == "error"]
    assert report["summary"]["filesAnalyzed"] == 1
    assert errors == [], "\n".join(errors)


def test_return_types_are_precise(tmp_path: Path) -> None:
    report = _pyright(tmp_path, _REVEAL)
    revealed = [d["message"] for d in report["generalDiagnostics"] if d["severity"] == "information"]
    assert revealed == [
        'Type of "sensaug.sweep(cfg, seeds=[0])" is "DataFrame"',
        'Type of "sensaug.load_log("x.csv").to_pandas()" is "DataFrame"',
        'Type of "trial.plot("gains")" is "Figure"',
        'Type of "trial.plot()" is "list[Figure]"',
        'Type of "trial.metrics()" is "DataFrame"',
        'Type of "trial.meta" is "dict[str, Any]"',
    ], revealed


def test_the_stub_of_the_compiled_module_matches_it():
    """``python/sensaug/_core.pyi`` (hand-written) against ``sensaug._core``
    as built: every name, signature and default (``mypy.stubtest``)."""
    proc = subprocess.run(
        [sys.executable, "-m", "mypy.stubtest", "sensaug._core"],
        capture_output=True, text=True, cwd=REPO, timeout=300,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
