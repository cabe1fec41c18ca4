"""The one configuration validator, seen through both entry points.

Every file of tests/config_corpus (malformed and edge-case configurations,
made by make_corpus.py) goes through ``python -m sensaug check`` and
``sensaug-rt --check``: the verdicts, exit codes and messages must be
identical, the first stderr line must start with the field EXPECTED.json
names, and the message must read as advice (no Rust debug output, no Python
exception names, no bare line numbers).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from sensaug import cli

ROOT = Path(__file__).resolve().parent.parent
CORPUS = ROOT / "tests" / "config_corpus"
EXPECTED: dict[str, str] = json.loads((CORPUS / "EXPECTED.json").read_text())
RT = ROOT / "target" / "release" / "sensaug-rt"

# Signs of a message written for a programmer instead of the user.
LEAKS = [
    r"\{\s*\w+:",  # Rust debug struct
    r"\bSome\(|\bNone\b|Err\(|Ok\(",
    r"\b(ValueError|TypeError|KeyError|AttributeError|Traceback)\b",
    r"\b[fiu](8|16|32|64)\b",  # Rust number types
    r"^line \d+|: line \d+$",  # a bare line number
]


def python_check(path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = cli.main(["check", str(path)])
    out, err = capsys.readouterr()
    return code, out, err


def rt_check(path: Path) -> tuple[int, str, str]:
    r = subprocess.run([str(RT), "--check", str(path)], capture_output=True, text=True, timeout=30)
    return r.returncode, r.stdout, r.stderr


def test_corpus_is_large_and_complete():
    files = sorted(p.name for p in CORPUS.iterdir() if p.suffix in (".toml", ".json") and p.name != "EXPECTED.json")
    assert files == sorted(EXPECTED), "EXPECTED.json and the corpus files differ: run make_corpus.py"
    malformed = [f for f, field in EXPECTED.items() if field != "valid"]
    assert len(malformed) >= 120


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_both_entry_points_agree(name: str, capsys: pytest.CaptureFixture[str]):
    path = CORPUS / name
    py = python_check(path, capsys)
    rt = rt_check(path)
    assert py == rt, f"python -m sensaug check and sensaug-rt --check disagree on {name}"
    code, out, err = py
    field = EXPECTED[name]
    if field == "valid":
        assert (code, out, err) == (0, "valid\n", "")
        return
    assert code == 2 and out == ""
    first = err.splitlines()[0]
    shown = str(path) if field == "(file)" else field
    # The named field, or an entry inside it (`robot.stage1.R[1]`).
    named = re.match(rf"{re.escape(shown)}((\[\d+\])*): (.*)$", first)
    assert named, f"{name}: expected the field {shown!r} first, got {first!r}"
    message = named.group(3)
    assert len(message) > 10
    for leak in LEAKS:
        assert not re.search(leak, message), f"{name}: {message!r} matches {leak!r}"


def test_module_entry_point_runs_as_a_process():
    """``python -m sensaug check`` itself (not just cli.main) on a good and a bad file."""
    good = subprocess.run([sys.executable, "-m", "sensaug", "check", str(CORPUS / "valid_full.toml")],
                          capture_output=True, text=True, timeout=60)
    assert (good.returncode, good.stdout) == (0, "valid\n")
    bad = subprocess.run([sys.executable, "-m", "sensaug", "check", str(CORPUS / "range_watchdog_65535.toml")],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2
    assert bad.stderr.splitlines()[0] == rt_check(CORPUS / "range_watchdog_65535.toml")[2].splitlines()[0]


def test_missing_file_is_named(tmp_path, capsys):
    path = tmp_path / "nope.toml"
    py, rt = python_check(path, capsys), rt_check(path)
    assert py == rt
    assert py[0] == 2 and py[2].startswith(f"{path}: cannot open")


def test_rt_help_lists_every_option():
    r = subprocess.run([str(RT), "--help"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0
    for opt in ("--check", "--print-resolved", "--can", "--log", "--stats", "--help", "--version"):
        assert opt in r.stdout
