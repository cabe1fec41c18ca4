"""The package as a user installs it: the three wheels (scripts/build-wheels.sh,
manylinux2014, from its own build environment) checked for their tags, the
glibc their binaries need and their metadata, then installed into a fresh virtual
environment outside the checkout, then run from a folder outside it with an
environment that names nothing of the checkout.

pip may fetch the dependencies (numpy, pandas, matplotlib, python-can, ...)
from PyPI; its cache makes that quick after the first time.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
import tomllib
import zipfile
from dataclasses import dataclass
from pathlib import Path

import pytest
from test_rig import RIG_TEST_FIFO_PRIORITY, stall_tolerant

from sensaug import _resources, presets

REPO = Path(__file__).resolve().parents[1]


def workspace_version() -> str:
    return tomllib.loads((REPO / "Cargo.toml").read_text())["workspace"]["package"]["version"]


@dataclass
class Installed:
    venv: Path
    cwd: Path
    env: dict[str, str]

    def bin(self, name: str) -> Path:
        return self.venv / "bin" / name

    def run(self, *args: str | Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [str(a) for a in args], cwd=self.cwd, env=self.env, capture_output=True, text=True, timeout=timeout
        )


def _clean_env() -> dict[str, str]:
    """This process's environment without anything that points at the checkout:
    no PYTHONPATH, VIRTUAL_ENV or SENSAUG_* overrides, no checkout folder on PATH."""
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith(("SENSAUG_", "PYTHON", "VIRTUAL_ENV", "CONDA", "PYTEST", "MAMBA"))
    }
    env["PATH"] = os.pathsep.join(
        p for p in env.get("PATH", "").split(os.pathsep) if p and not Path(p).resolve().is_relative_to(REPO)
    )
    env["MPLBACKEND"] = "Agg"
    return env


@dataclass
class Wheels:
    folder: Path
    names: list[str]
    build_log: str


@pytest.fixture(scope="module")
def wheels(tmp_path_factory: pytest.TempPathFactory) -> Wheels:
    """The three wheels as ``scripts/build-wheels.sh`` builds them (its own
    build environment, zig for glibc 2.17; nothing of the test venv)."""
    folder = tmp_path_factory.mktemp("wheels")
    t0 = time.perf_counter()
    built = subprocess.run(
        ["bash", str(REPO / "scripts" / "build-wheels.sh"), str(folder)],
        capture_output=True,
        text=True,
        env=_clean_env(),
        timeout=1800,
    )
    assert built.returncode == 0, built.stdout + built.stderr
    names = sorted(p.name for p in folder.glob("*.whl"))
    assert [n.split("-")[0] for n in names] == ["sensaug", "sensaug_bridge", "sensaug_rt"], names
    print(f"\nwheels built in {time.perf_counter() - t0:.1f} s: {', '.join(names)}")
    return Wheels(folder=folder, names=names, build_log=built.stdout + built.stderr)


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory, wheels: Wheels) -> Installed:
    root = tmp_path_factory.mktemp("install")
    assert not root.resolve().is_relative_to(REPO)
    venv, cwd = root / "venv", root / "work"
    cwd.mkdir()
    t1 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, env=_clean_env(), timeout=300)
    pip = subprocess.run(
        [str(venv / "bin" / "python"), "-m", "pip", "install", "-q", *(str(wheels.folder / n) for n in wheels.names)],
        capture_output=True,
        text=True,
        env=_clean_env(),
        timeout=1200,
    )
    assert pip.returncode == 0, pip.stdout + pip.stderr
    print(f"\nvenv + pip install {time.perf_counter() - t1:.1f} s")
    return Installed(venv=venv, cwd=cwd, env=_clean_env())


#: The oldest glibc the wheels may need: manylinux2014 (CentOS 7's 2.17; every
#: Ubuntu since 18.04 has more).
GLIBC_FLOOR = (2, 17)


def _wheel_file(wheel: Path, suffix: str) -> str:
    with zipfile.ZipFile(wheel) as z:
        (name,) = [n for n in z.namelist() if n.endswith(suffix)]
        return z.read(name).decode()


def _glibc_needed(binary: Path) -> tuple[int, int]:
    """The highest ``GLIBC_x.y`` symbol version ``binary`` requires, read by
    binutils' readelf (the ELF version-needs section), not by our build tools."""
    out = subprocess.run(["readelf", "--version-info", "--wide", str(binary)], capture_output=True, text=True, check=True)
    versions = {(int(a), int(b)) for a, b in re.findall(r"Name: GLIBC_(\d+)\.(\d+)", out.stdout)}
    assert versions, f"{binary}: no GLIBC version needs found by readelf"
    return max(versions)


def test_wheels_are_manylinux2014_and_need_glibc_2_17_at_most(wheels: Wheels, tmp_path: Path) -> None:
    """The tags a lab PC's pip matches (glibc 2.17+ for the two binary
    wheels, any platform for the bridge) and, independently of the tags, the
    glibc symbol versions the binaries inside really need."""
    tags = {n.split("-")[0]: _wheel_file(wheels.folder / n, ".dist-info/WHEEL") for n in wheels.names}
    platform_tags = {k: set(re.findall(r"^Tag: (\S+)$", v, re.M)) for k, v in tags.items()}
    assert platform_tags == {
        "sensaug": {"cp311-abi3-manylinux_2_17_x86_64", "cp311-abi3-manylinux2014_x86_64"},
        "sensaug_rt": {"py3-none-manylinux_2_17_x86_64", "py3-none-manylinux2014_x86_64"},
        "sensaug_bridge": {"py3-none-any"},
    }, platform_tags
    binaries = []
    for n in wheels.names:
        with zipfile.ZipFile(wheels.folder / n) as z:
            for member in z.namelist():
                if member.endswith(".so") or member.endswith("/scripts/sensaug-rt"):
                    binaries.append(Path(z.extract(member, tmp_path / n)))
    assert sorted(b.name for b in binaries) == ["_core.abi3.so", "sensaug-rt"], binaries
    needed = {b.name: _glibc_needed(b) for b in binaries}
    print(f"\nhighest GLIBC symbol version needed: {needed}")
    assert all(v <= GLIBC_FLOOR for v in needed.values()), needed


def test_wheel_metadata_is_complete(wheels: Wheels) -> None:
    """What PyPI shows and what ``pip show`` prints: a description (the README
    for sensaug), the license, classifiers; ``twine check --strict`` passed in
    the build script (its output is in the build log)."""
    assert wheels.build_log.count("PASSED") == 3, wheels.build_log[-2000:]
    readme = (REPO / "README.md").read_text()
    for n in wheels.names:
        meta = _wheel_file(wheels.folder / n, ".dist-info/METADATA")
        head, _, body = meta.partition("\n\n")
        assert re.search(r"^Summary: \S", head, re.M), (n, head)
        assert re.search(r"^License-Expression: MIT$", head, re.M), (n, head)
        assert re.search(r"^License-File: LICENSE$", head, re.M), (n, head)
        assert re.search(r"^Description-Content-Type: text/markdown", head, re.M), (n, head)
        assert len(re.findall(r"^Classifier: ", head, re.M)) >= 4, (n, head)
        assert len(body) > 200, (n, body)
        if n.startswith("sensaug-"):
            assert body.strip() == readme.strip()


def test_pins_and_versions_are_the_cargo_workspace_version() -> None:
    """The bridge's static version and sensaug's pins on its companion wheels
    (setuptools and dependency strings cannot read Cargo.toml)."""
    v = workspace_version()
    root = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    bridge = tomllib.loads((REPO / "firmware_bridge" / "pyproject.toml").read_text())["project"]
    assert bridge["version"] == v
    assert f"sensaug-bridge=={v}" in root["dependencies"]
    assert root["optional-dependencies"]["rt"] == [f"sensaug-rt=={v}"]


def test_version_is_the_cargo_workspace_version(installed: Installed) -> None:
    out = installed.run(installed.bin("sensaug"), "--version")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == f"sensaug {workspace_version()}"
    code = "import importlib.metadata as m; print(m.version('sensaug-bridge'), m.version('sensaug-rt'))"
    out = installed.run(installed.bin("python"), "-c", code)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [workspace_version()] * 2


_PROBE = """
import json, sys
import sensaug, sensaug.cli, sensaug.rig, sensaug.plots
import sensaug_bridge, sensaug_bridge.protocol, sensaug_bridge.virtual_hi5
from importlib.resources import files
from sensaug_bridge import resources
print(json.dumps({
    "sensaug": sensaug.__file__,
    "bridge": sensaug_bridge.__file__,
    "binary": str(sensaug.rig.find_binary()),
    "dbc": str(sensaug_bridge.protocol.dbc_path()),
    "data": sorted(p.name for p in resources.data_dir().iterdir()),
    "typed": [files("sensaug").joinpath("py.typed").is_file(), files("sensaug_bridge").joinpath("py.typed").is_file()],
    "modules": sorted(str(getattr(m, "__file__", None)) for m in list(sys.modules.values())
                      if getattr(m, "__file__", None)),
}))
"""


def test_the_installed_package_uses_nothing_from_the_checkout(installed: Installed) -> None:
    out = installed.run(installed.bin("python"), "-c", _PROBE)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    venv = installed.venv.resolve()
    for key in ("sensaug", "bridge", "binary", "dbc"):
        assert Path(got[key]).resolve().is_relative_to(venv), (key, got[key])
    assert Path(got["binary"]).name == "sensaug-rt"
    from_checkout = [m for m in got["modules"] if Path(m).resolve().is_relative_to(REPO)]
    assert from_checkout == []
    # Every *.dbc and *.eds of firmware_bridge/ is package data, and nothing else.
    expected = sorted(p.name for g in ("*.dbc", "*.eds") for p in (REPO / "firmware_bridge").glob(g))
    assert "hi5.dbc" in expected
    assert got["data"] == expected
    assert got["typed"] == [True, True]


def test_paper_on_a_reduced_budget(installed: Installed) -> None:
    out = installed.run(installed.bin("sensaug"), "paper", "--seeds", "1", "--plots", "paper", timeout=600)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Stage 1, Hi5" in out.stdout and "Simulation section" in out.stdout
    plots = sorted((installed.cwd / "paper").glob("*.png"))
    assert len(plots) >= 2 and all(p.stat().st_size > 1000 for p in plots), plots


def test_short_demo_completes(installed: Installed) -> None:
    """The virtual rig from the installed package: the drive as
    ``python -m sensaug_bridge.virtual_hi5`` of the venv, the binary of the
    sensaug-rt wheel. 2 s phases; the rig's stall limits at the schema's
    bounds (this shared machine stalls for tens of ms now and then)."""
    cfg = stall_tolerant(presets.hi5_rig(phase_s=2.0))
    cfg.rig.realtime.fifo_priority = RIG_TEST_FIFO_PRIORITY  # loop and drive (tests/test_rig.py)
    cfg.to_toml(installed.cwd / "short.toml")
    out = installed.run(installed.bin("sensaug"), "demo", "--config", "short.toml", "--out", "demo", timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    demo = installed.cwd / "demo"
    stats = json.loads((demo / "rig_stats.json").read_text())
    assert stats["stop_reason"] == "completed", stats["stop_reason"]
    assert stats["ticks"] == round(cfg.duration_s / cfg.plant.dt_s), stats["ticks"]
    assert (demo / "rig_log.csv").stat().st_size > 0
    assert sorted(p.name for p in demo.glob("*.png")), "no plots written"


def test_a_missing_binary_says_how_to_get_it(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.delenv("SENSAUG_RT", raising=False)
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setattr(_resources.sysconfig, "get_path", lambda name: str(tmp_path))
    monkeypatch.setattr(_resources, "_checkout_binary", lambda: None)
    with pytest.raises(FileNotFoundError, match=r"install the sensaug-rt wheel.*cargo build --release -p sensaug-rt"):
        _resources.rt_binary()
    monkeypatch.setenv("SENSAUG_RT", str(tmp_path / "nowhere"))
    with pytest.raises(FileNotFoundError, match="SENSAUG_RT=.*nowhere: no such file"):
        _resources.rt_binary()


def test_a_missing_data_file_names_the_package_data() -> None:
    from sensaug_bridge import resources

    assert resources.data_file("hi5.dbc").is_file()
    with pytest.raises(FileNotFoundError, match=r"missing\.eds is not among sensaug_bridge's data files"):
        resources.data_file("missing.eds")


def test_the_docs_pages_ship_with_the_package(installed: Installed) -> None:
    """Messages and help name docs/NAME.md; the installed package has them."""
    listing = installed.run(installed.bin("sensaug"), "docs")
    assert listing.returncode == 0, listing.stderr
    names = {ln.split()[0] for ln in listing.stdout.splitlines()[1:]}
    assert names == {p.stem for p in (REPO / "docs").glob("*.md")}, listing.stdout
    page = installed.run(installed.bin("sensaug"), "docs", "docs/logs.md")
    assert page.returncode == 0 and page.stdout == (REPO / "docs" / "logs.md").read_text()
