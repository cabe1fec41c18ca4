"""Jupyter support: progress bars that work on a terminal and in Jupyter,
with or without ipywidgets, and never warn; Figures that show themselves.

The quick-look plots are built without pyplot (no backend is selected on
import), so IPython has not registered its PNG formatter for Figures:
:func:`show_figures_inline` does, as ``%matplotlib inline`` would.

``tqdm.auto`` in a Jupyter kernel without ipywidgets warns "IProgress not
found" and falls back to a text bar on stderr, which tqdm's default then
hides (stderr is not a terminal there). Here: in a kernel, the widget bar if
ipywidgets is installed, else the text bar shown (Jupyter renders its
carriage returns); elsewhere the text bar on stderr, by default only on a
terminal.
"""

from __future__ import annotations

import importlib.util
import sys
from typing import Any

__all__ = ["bar", "in_notebook", "show_figures_inline"]


def in_notebook() -> bool:
    """Whether this process is a Jupyter (IPython) kernel."""
    ipython = sys.modules.get("IPython")
    if ipython is None:
        return False
    shell = ipython.get_ipython()
    return shell is not None and "IPKernelApp" in getattr(shell, "config", {})


def bar(*, total: float, desc: str, unit: str, progress: bool | None, **kwargs: Any):
    """A tqdm bar. ``progress``: True always, False never, None on a terminal
    or in a notebook."""
    if in_notebook():
        if progress is False:
            from tqdm.std import tqdm as text_tqdm

            return text_tqdm(total=total, disable=True)
        if importlib.util.find_spec("ipywidgets") is not None:
            from tqdm.notebook import tqdm as notebook_tqdm

            kwargs.pop("bar_format", None)
            return notebook_tqdm(total=total, desc=desc, unit=unit, **kwargs)
        from tqdm.std import tqdm as text_tqdm

        return text_tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, disable=False, **kwargs)
    from tqdm.std import tqdm as text_tqdm

    return text_tqdm(total=total, desc=desc, unit=unit, disable=None if progress is None else not progress, **kwargs)


def show_figures_inline() -> None:
    """In a Jupyter kernel, display matplotlib Figures as PNG (idempotent)."""
    if not in_notebook():
        return
    from IPython import get_ipython
    from IPython.core.pylabtools import select_figure_formats

    select_figure_formats(get_ipython(), {"png"})
