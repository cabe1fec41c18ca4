"""What the ``sensaug`` command tells a person (issue 23, "messages that say
what happened"): the help lists every subcommand in plain text, each command
has its own banner, ``check`` names the file, ``run`` prints the paper's
metrics with their windows, sweeps take list fields, Ctrl-C is an
interruption with exit code 130 and no result from a cut-off phase."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_rig import stall_tolerant

from sensaug import cli, experiment, presets

REPO = Path(__file__).resolve().parents[1]


def _short(phase_s: float = 2.0):
    cfg = presets.hi5_experiment(2.0, seed=1)
    for p in cfg.phases:
        p.duration_s = phase_s
    return cfg


def test_help_lists_every_subcommand_in_plain_text(capsys: pytest.CaptureFixture[str]) -> None:
    parser = cli.build_parser()
    commands = next(a for a in parser._actions if a.dest == "command").choices
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    text = capsys.readouterr().out
    assert len(commands) >= 9
    for name in commands:
        assert f"\n    {name} " in text, name
    assert "``" not in text and ":mod:" not in text and "python -m sensaug" not in text


def test_messages_name_the_sensaug_command() -> None:
    """No message tells a person to type ``python -m sensaug``: it fails
    outside an activated venv, where the ``sensaug`` command works."""
    found = [
        f"{p.relative_to(REPO)}:{i}"
        for p in (REPO / "python" / "sensaug").glob("*.py")
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if "python -m sensaug " in line and p.name != "__main__.py"
    ]
    assert found == []
    assert "`sensaug check FILE`" in presets.hi5_experiment(1.0).to_toml()


def test_check_names_the_file_when_its_syntax_is_bad(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "broken.toml"
    bad.write_text("[plant\nmass = 1\n")
    assert cli.main(["check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"{bad}: ") and "(config)" not in err, err


def test_run_prints_the_papers_metrics_with_their_windows(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = _short(3.0)
    cfg.to_toml(tmp_path / "t.toml")
    assert cli.main(["run", str(tmp_path / "t.toml")]) == 0
    out = capsys.readouterr().out
    assert "{" not in out, out  # no Python dict
    lines = out.splitlines()
    gain_row = next(ln for ln in lines if "partner gain L_hh" in ln)
    assert "last 3 s" in gain_row and "2.0000" in gain_row, gain_row
    assert any("partner-target estimate" in ln and "after 1.5 s" in ln for ln in lines), out
    assert any("with goal integration" in ln for ln in lines), out
    assert (tmp_path / "t.csv").is_file()


def test_grid_values_take_lists_and_scalars() -> None:
    assert cli._grid_values("0,0.5,true") == [0, 0.5, True]
    assert cli._grid_values("[1e-2,1e-3],[1e-3,1e-4]") == [[1e-2, 1e-3], [1e-3, 1e-4]]
    assert cli._grid_values("[1e-2, 1e-3]") == [[1e-2, 1e-3]]
    assert cli._grid_values("udp:1,udp:2") == ["udp:1", "udp:2"]


def test_sweep_of_a_list_field_and_without_a_grid(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = _short(1.0)
    cfg.phases = cfg.phases[:1]
    cfg.to_toml(tmp_path / "g.toml")
    args = ["sweep", str(tmp_path / "g.toml"), "--seeds", "2", "--quiet", "--out", str(tmp_path / "s")]
    assert cli.main([*args, "--grid", "robot.stage1.R=[1e-7,1e-7,1e-7],[1e-6,1e-6,1e-6]"]) == 0
    out = capsys.readouterr().out
    assert "[1e-06, 1e-06, 1e-06]" in out and "[1e-07, 1e-07, 1e-07]" in out
    assert cli.main(args) == 0
    out = capsys.readouterr().out
    assert "mean over seeds 0..1" in out and "\nseed " not in out, out


def test_an_interrupted_command_exits_130(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(experiment, "run", interrupted)
    _short(1.0).to_toml(tmp_path / "t.toml")
    assert cli.main(["run", str(tmp_path / "t.toml")]) == cli.EXIT_INTERRUPTED == 130
    assert "sensaug run: interrupted by the user (Ctrl-C)" in capsys.readouterr().err


def test_ctrl_c_on_the_rig_reports_an_interruption_and_only_completed_phases(tmp_path: Path) -> None:
    """Ctrl-C as a terminal sends it: SIGINT to the whole process group
    (the command, the virtual drive, sensaug-rt), once the log shows the
    second phase has begun."""
    cfg = stall_tolerant(presets.hi5_rig(phase_s=3.0))  # the subject is the interruption
    cfg.to_toml(tmp_path / "rig.toml")
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sensaug", "rig", str(tmp_path / "rig.toml"), "--out", str(out), "--no-capture", "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )
    log = out / "rig_log.csv"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None:
        # Phase 1 (trajectory) has begun: 3 s of the gain phase are in the log.
        if log.exists() and sum(1 for _ in log.open()) > 3600:
            break
        time.sleep(0.1)
    assert proc.poll() is None, proc.communicate()
    os.killpg(proc.pid, signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stdout + stderr
    assert "sensaug rig: one trial on the virtual rig" in stdout
    assert "INTERRUPTED by the user (Ctrl-C)" in stdout, stdout
    assert "Stage 1: partner gains (mean over the last" in stdout, stdout
    assert "Stage 2: cut off after" in stdout and "no result from a partial phase" in stdout, stdout
    assert "Stage 3: not reached (interrupted by the user)" in stdout, stdout
    assert "Traceback" not in stdout + stderr


def test_the_rig_with_a_person_prints_no_truth(tmp_path: Path) -> None:
    """rig.virtual_human = false: nobody knows the person's gains or target,
    so `sensaug rig` prints the estimates with their posterior std and, with
    no display, no error against a target nobody was shown (issue 19)."""
    cfg = presets.hi5_rig(phase_s=2.5)
    cfg.robot.gain_window_s = 1.0
    cfg.rig.virtual_human = False
    cfg.rig.realtime.fifo_priority = 20  # as the rig tests: this shared machine must not starve the drive
    stall_tolerant(cfg).to_toml(tmp_path / "person.toml")
    proc = subprocess.run(
        [sys.executable, "-m", "sensaug", "rig", str(tmp_path / "person.toml"), "--out", str(tmp_path / "out"),
         "--no-capture", "--quiet"], capture_output=True, text=True, timeout=120,
    )
    out = proc.stdout
    assert proc.returncode == 0, out + proc.stderr
    assert "A person at the handle (rig.virtual_human = false): no true partner gain or target" in out, out
    stage1 = out[out.index("Stage 1:"): out.index("Stage 2:")]
    assert "posterior std" in stage1 and "true" not in stage1 and "error" not in stage1, stage1
    stage2 = out[out.index("Stage 2:"): out.index("Stage 3:")]
    assert "no target was shown, so no error is computed" in stage2 and "%" not in stage2, stage2
    assert "Stage 3: RMSE of the robot's estimate of x - tau" in out, out  # its own target: no truth about the person
