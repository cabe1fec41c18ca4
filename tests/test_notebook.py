"""The API in Jupyter: examples/quickstart.ipynb executed by nbconvert in a
real kernel (ipykernel), without ipywidgets (as in a bare JupyterLab
install): short HTML reprs for the configuration and the trial, a Figure
from ``Trial.plot``, a Parquet log through ``load_log``, ``replay`` matching
the online estimates, and a sweep whose progress shows as text with no
"IProgress not found" warning."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import nbformat
import pytest
from nbconvert.preprocessors import ExecutePreprocessor

REPO = Path(__file__).resolve().parents[1]
NOTEBOOK = REPO / "examples" / "quickstart.ipynb"


@pytest.fixture(scope="module")
def executed(tmp_path_factory: pytest.TempPathFactory) -> nbformat.NotebookNode:
    nb = nbformat.read(NOTEBOOK, as_version=4)
    ExecutePreprocessor(timeout=300, kernel_name="python3").preprocess(
        nb, {"metadata": {"path": str(tmp_path_factory.mktemp("notebook"))}}
    )
    return nb


def _outputs(nb: nbformat.NotebookNode, index: int) -> list[dict]:
    return nb.cells[index].outputs


def test_no_ipywidgets_here() -> None:
    """The case the notebook test covers: without ipywidgets tqdm.auto warns."""
    assert importlib.util.find_spec("ipywidgets") is None


def test_reprs_are_short_and_html(executed: nbformat.NotebookNode) -> None:
    for cell, name in ((1, "ScenarioConfig"), (2, "Trial")):
        (out,) = _outputs(executed, cell)
        text, html = out["data"]["text/plain"], out["data"]["text/html"]
        assert text.startswith(f"<{name}") and len(text) < 200, text
        assert "<table" in html
    assert "partner gain L_hh" in _outputs(executed, 3)[0]["data"]["text/html"]


def test_plot_returns_a_figure(executed: nbformat.NotebookNode) -> None:
    (out,) = _outputs(executed, 4)
    assert "image/png" in out["data"] and out["data"]["text/plain"].startswith("<Figure")


def test_parquet_log_and_replay(executed: nbformat.NotebookNode) -> None:
    assert _outputs(executed, 5)[0]["data"]["text/plain"].startswith("<Log simulation: 12000 ticks")
    assert _outputs(executed, 6)[0]["data"]["text/plain"] == "True"


def test_sweep_shows_progress_without_a_warning(executed: nbformat.NotebookNode) -> None:
    outs = _outputs(executed, 7)
    stderr = "".join(o.get("text", "") for o in outs if o.get("name") == "stderr")
    assert "sweep:" in stderr and "4/4" in stderr, stderr
    every = "".join(str(o) for c in executed.cells if c.cell_type == "code" for o in c.outputs)
    assert "IProgress" not in every and "Warning" not in every
    assert "partner.gains.lhh" in outs[-1]["data"]["text/plain"]
