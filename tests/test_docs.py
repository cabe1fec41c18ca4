"""The docs ship and their examples work: the site (docs/*.md, the README as
its home page, the API reference) builds with mkdocs in strict mode, and
every ``python`` code block of the README and docs/*.md runs as written.

A block that is not meant to run (it needs hardware, say) is preceded by a
line ``<!-- not run: why -->``; there is none today. The blocks of one file
run in order in one process (later blocks use earlier ones' names), README
first, in a folder where ``sensaug demo`` (2 s phases) has just written
``out/``: the README's and docs' examples read ``out/rig_log.csv``.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from test_rig import stall_tolerant

from sensaug import presets

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
_BLOCK = re.compile(r"(?P<before>[^\n]*)\n```python\n(?P<code>.*?)\n```", re.S)


def python_blocks(page: Path) -> list[str]:
    """The page's ``python`` blocks meant to run."""
    return [m["code"] for m in _BLOCK.finditer(page.read_text()) if not m["before"].startswith("<!-- not run")]


def _env() -> dict[str, str]:
    return dict(os.environ, MPLBACKEND="Agg")


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    cwd = tmp_path_factory.mktemp("docs_examples")
    stall_tolerant(presets.hi5_rig(phase_s=2.0)).to_toml(cwd / "short.toml")
    # The examples need a rig log, not a perfect run: a run this shared
    # machine stalls into a safety stop (exit 1) still writes one. A run that
    # never started (the drive too slow to boot under load) is tried again.
    for _attempt in range(2):
        demo = subprocess.run(
            [sys.executable, "-m", "sensaug", "demo", "--config", "short.toml", "--no-plots", "--no-capture", "--quiet"],
            cwd=cwd, capture_output=True, text=True, timeout=180, env=_env(),
        )
        if (cwd / "out" / "rig_log.csv").is_file():
            break
    assert demo.returncode in (0, 1) and (cwd / "out" / "rig_log.csv").is_file(), demo.stdout + demo.stderr
    return cwd


def test_the_pages_have_examples() -> None:
    counts = {p.name: len(python_blocks(p)) for p in PAGES}
    assert counts["README.md"] >= 2 and counts["logs.md"] >= 2, counts


def _run_blocks(page: Path, cwd: Path) -> subprocess.CompletedProcess[str]:
    code = "\n\n".join(python_blocks(page))
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=600, env=_env())


@pytest.fixture(scope="module")
def readme_run(workdir: Path) -> subprocess.CompletedProcess[str]:
    return _run_blocks(REPO / "README.md", workdir)


def test_readme_code_blocks_run(readme_run: subprocess.CompletedProcess[str]) -> None:
    assert readme_run.returncode == 0, f"README.md: its python blocks fail:\n{readme_run.stderr[-3000:]}"


@pytest.mark.parametrize("page", [p for p in PAGES[1:] if python_blocks(p)], ids=lambda p: p.name)
def test_docs_code_blocks_run(page: Path, workdir: Path, readme_run: subprocess.CompletedProcess[str]) -> None:
    """After the README's (they wrote trial.csv, which the docs' read)."""
    assert readme_run.returncode == 0, "the README's blocks failed first"
    run = _run_blocks(page, workdir)
    assert run.returncode == 0, f"{page.name}: its python blocks fail:\n{run.stderr[-3000:]}"


def test_site_builds_strictly(tmp_path: Path) -> None:
    """mkdocs --strict: a broken link, a page outside the navigation or an
    unreadable docstring fails the build. The API reference documents the
    notebook API (plot, repr) and every page of docs/ is on the site."""
    site = tmp_path / "site"
    built = subprocess.run(
        ["bash", str(REPO / "scripts" / "build-docs.sh"), str(site)],
        capture_output=True, text=True, timeout=600, env=dict(os.environ, SENSAUG_SKIP_SETUP="1"),
    )
    assert built.returncode == 0, built.stdout + built.stderr
    assert "WARNING" not in built.stderr, built.stderr
    api = (site / "api" / "index.html").read_text()
    for name in ("sensaug.experiment.Trial.plot", "sensaug.experiment.run", "sensaug.logs.load_log", "sensaug.sweep.sweep",
                 "sensaug.figures.measure", "sensaug.figures.write_all", "sensaug.figures.fig_rmse",
                 "sensaug.figures.fig_integration"):
        assert f'id="{name}"' in api, name
    for page in (REPO / "docs").glob("*.md"):
        assert (site / page.stem / "index.html").is_file(), page.name
    assert (site / "index.html").is_file() and (site / "search" / "search_index.json").is_file()
