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


def test_constructor_defaults_are_the_schemas() -> None:
    """The binding keeps no defaults of its own (``sensaug._core``'s
    constructors require every keyword); the package's estimators and plant
    take an omitted keyword's default from the configuration schema, and
    their signatures (``inspect``, pyright) say so."""
    import inspect

    import sensaug
    from sensaug import _core

    defs = json.loads(_core.config_schema())["$defs"]

    def defaults(spec: str) -> dict:
        return {n: p["default"] for n, p in defs[spec]["properties"].items() if "default" in p}

    plant, sigma, channel, world = (defaults(s) for s in ("PlantSpec", "SigmaSpec", "ChannelSpec", "WorldSpec"))
    expected = {
        sensaug.Plant: {"damping": plant["damping"], "coulomb": plant["coulomb"], "dt_s": plant["dt_s"],
                        "x0": world["x0"], "v0": world["v0"]},
        sensaug.GainEstimator: {"damping": plant["damping"], "dt": plant["dt_s"], **sigma},
        sensaug.TrajectoryEstimator: {"damping": plant["damping"], "dt": plant["dt_s"], **sigma},
        sensaug.GoalIntegrator: {"damping": plant["damping"], "dt": plant["dt_s"], **channel},
    }  # fmt: skip
    for cls, want in expected.items():
        shown = {n: p.default for n, p in inspect.signature(cls).parameters.items() if n in want}
        assert shown == want, cls.__name__
        core = next(c for c in cls.__mro__ if c.__module__ == "sensaug._core")
        assert all(p.default is inspect.Parameter.empty for p in inspect.signature(core).parameters.values()), core
    # ... and an omitted keyword behaves as the schema's default given.
    a = sensaug.Plant(mass=0.5)
    b = _core.Plant(mass=0.5, damping=plant["damping"], coulomb=plant["coulomb"], dt_s=plant["dt_s"],
                    x0=world["x0"], v0=world["v0"])  # fmt: skip
    for p in (a, b):
        p.step(1.0)
    assert (a.x, a.v) == (b.x, b.v)
