"""What sensaug needs from outside its own Python files, found in one place:
its version (package metadata) and the real-time binary ``sensaug-rt``.

The data files of the CAN protocol (``hi5.dbc``, the EDS files) belong to
the bridge package and are found by ``sensaug_bridge.resources``.
"""

from __future__ import annotations

import os
import shutil
import sysconfig
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

__all__ = ["RT_BINARY", "package_version", "rt_binary"]

#: The executable's name (the ``sensaug-rt`` wheel installs it on PATH).
RT_BINARY = "sensaug-rt"


def package_version() -> str:
    """The installed distribution's version (the Cargo workspace version:
    maturin writes it into the metadata); ``0+unknown`` when sensaug runs
    from a source tree that was never installed."""
    try:
        return version("sensaug")
    except PackageNotFoundError:
        return "0+unknown"


def docs_dir() -> Path:
    """The docs pages (``docs/*.md``): the wheel's copy (``sensaug/docs``,
    put there by scripts/build-wheels.sh), else the checkout's ``docs/``."""
    here = Path(__file__).resolve().parent
    packaged = here / "docs"
    if packaged.is_dir():
        return packaged
    checkout = here.parents[1] / "docs"
    if checkout.is_dir():
        return checkout
    raise FileNotFoundError(f"the docs pages: neither {packaged} nor {checkout} exists; reinstall the sensaug wheel")


def _checkout_binary() -> Path | None:
    """``target/release/sensaug-rt`` of the checkout this package runs from
    (an editable install), or None when it is not in a checkout."""
    root = Path(__file__).resolve().parents[2]
    if not (root / "Cargo.toml").is_file() or not (root / "crates" / "sensaug-rt").is_dir():
        return None
    return root / "target" / "release" / RT_BINARY


def rt_binary() -> Path:
    """The ``sensaug-rt`` executable, looked for in this order:

    1. ``$SENSAUG_RT`` (an explicit path; it must exist);
    2. the scripts folder of the running Python environment, where
       ``pip install sensaug-rt`` (or ``sensaug[rt]``) puts it, so an
       environment that is not activated finds its own copy;
    3. ``PATH`` (:func:`shutil.which`);
    4. the checkout's ``target/release`` (``scripts/setup.sh`` builds it).

    Raises:
        FileNotFoundError: not found; says where it looked and how to get it.
    """
    env = os.environ.get("SENSAUG_RT")
    if env:
        if not Path(env).is_file():
            raise FileNotFoundError(f"SENSAUG_RT={env}: no such file; point it at the sensaug-rt executable or unset it")
        return Path(env)
    scripts = Path(sysconfig.get_path("scripts")) / RT_BINARY
    if scripts.is_file() and os.access(scripts, os.X_OK):
        return scripts
    on_path = shutil.which(RT_BINARY)
    if on_path:
        return Path(on_path)
    checkout = _checkout_binary()
    if checkout is not None and checkout.is_file():
        return checkout
    looked = f"{scripts.parent}, PATH" + (f", {checkout}" if checkout is not None else "")
    raise FileNotFoundError(
        f"sensaug-rt not found (looked in $SENSAUG_RT, {looked}): install the sensaug-rt wheel "
        "(pip install 'sensaug[rt]' with the wheels from scripts/build-wheels.sh), or in a checkout "
        "build it with `cargo build --release -p sensaug-rt` (scripts/setup.sh does), or set SENSAUG_RT"
    )
