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


def _with_outputs(tmp_path: Path, log: Path, stats: Path) -> Path:
    text = (CORPUS / "valid_full.toml").read_text()
    text = text.replace('log = "out/rig_log.csv"', f'log = "{log}"').replace('stats = "out/rig_stats.json"', f'stats = "{stats}"')
    path = tmp_path / "outputs.toml"
    path.write_text(text)
    return path


def test_output_paths_made_at_test_time_get_the_same_named_verdict(tmp_path, capsys):
    """FIFOs, links and folders in the way of an output (made here: the
    corpus cannot hold them) are refused by both checkers alike, by field,
    without blocking on the FIFO (each check is bounded by the timeout)."""
    import os

    fifo = tmp_path / "fifo.csv"
    os.mkfifo(fifo)
    busy = tmp_path / "busy.csv"
    os.mkfifo(tmp_path / "busy.csv.partial")
    to_full = tmp_path / "to_full.csv"
    to_full.symlink_to("/dev/full")
    to_file = tmp_path / "to_file.csv"
    (tmp_path / "file.csv").write_text("x")
    to_file.symlink_to(tmp_path / "file.csv")
    folder = tmp_path / "folder.csv"
    folder.mkdir()
    ok = tmp_path / "new" / "log.csv"
    cases = {
        "fifo": (fifo, ok, "rig.log", "it is a FIFO (named pipe), not a regular file"),
        "fifo at .partial": (ok, busy, "rig.stats", "busy.csv.partial (where it is written until the run ends) is a FIFO"),
        "link to a device": (to_full, ok, "rig.log", "it is a symbolic link to /dev/full (a character device)"),
        "link to a file": (ok, to_file, "rig.stats", "it is a symbolic link to"),
        "folder": (folder, ok, "rig.log", "it is a directory, not a regular file; give a file path inside it"),
        "through a linked folder": (ok, tmp_path / "alias" / "log.csv", "rig.stats", "the same file as rig.log"),
    }
    (tmp_path / "new").mkdir()
    (tmp_path / "alias").symlink_to(tmp_path / "new")
    for what, (log, stats, field, message) in cases.items():
        path = _with_outputs(tmp_path, log, stats)
        py, rt = python_check(path, capsys), rt_check(path)
        assert py == rt, what
        assert py[0] == 2 and py[2].startswith(f"{field}: ") and message in py[2], (what, py[2])
    good = _with_outputs(tmp_path, ok, tmp_path / "stats.json")
    assert python_check(good, capsys) == rt_check(good) == (0, "valid\n", "")
    # --log X --stats X on the command line: the same rule.
    r = subprocess.run([str(RT), "--check", str(good), "--log", str(ok), "--stats", str(ok)],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and r.stderr.startswith(f"rig.stats: {ok} is the same file as rig.log"), r.stderr
