"""The bridge's data files — the Hi5 DBC and the CiA 402 EDS files — found in one place.

They live in ``firmware_bridge/`` (the Rust build and the docs read them
there). An installed wheel carries them as package data, ``sensaug_bridge/data/``
(``firmware_bridge/pyproject.toml`` maps that subpackage onto
``firmware_bridge/`` and takes ``*.dbc`` and ``*.eds`` from it), read through
:mod:`importlib.resources`. The editable install of the checkout
(``pip install -e firmware_bridge``, ``scripts/setup.sh``) has no ``data/``
folder: there the package's data folder is ``firmware_bridge/`` itself, two
levels above this package, so edits to the DBC take effect without a rebuild.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

__all__ = ["DATA_GLOBS", "data_dir", "data_file"]

#: The package-data globs of ``firmware_bridge/pyproject.toml``.
DATA_GLOBS = ("*.dbc", "*.eds")


def data_dir() -> Path:
    """The folder holding the data files: the package's ``data/`` (a wheel),
    else ``firmware_bridge/`` (the checkout's editable install).

    Raises:
        FileNotFoundError: neither exists (a broken install); says how to fix it.
    """
    package = files(__package__)
    if isinstance(package, Path):
        packaged = package / "data"
        if packaged.is_dir():
            return packaged
        checkout = package.resolve().parents[1]
        if (checkout / "pyproject.toml").is_file() and (checkout / "python" / __package__).is_dir():
            return checkout
    raise FileNotFoundError(
        f"the data folder of {__package__} is missing (looked in {package}/data and the checkout's "
        "firmware_bridge/): reinstall the sensaug-bridge wheel (scripts/build-wheels.sh builds it) "
        "or run scripts/setup.sh in the checkout"
    )


def data_file(name: str) -> Path:
    """The path of the data file ``name`` (e.g. ``"hi5.dbc"``).

    Raises:
        FileNotFoundError: the file is not in :func:`data_dir`; names the folder and the fix.
    """
    path = data_dir() / name
    if not path.is_file():
        raise FileNotFoundError(
            f"{name} is not among {__package__}'s data files in {path.parent} "
            f"(package data: {', '.join(DATA_GLOBS)} of firmware_bridge/); reinstall the sensaug-bridge wheel"
        )
    return path
