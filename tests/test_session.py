"""Sessions of trials (sensaug.session, docs/person.md): the plan's checks,
the block order, the paper's plan reduced on the virtual rig, and a session
killed mid-trial and resumed."""

from __future__ import annotations

import csv
import hashlib
import itertools
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from sensaug.config import ConfigError, ScenarioConfig
from sensaug.session import block_order, expand, latin_square, load_session, run_session

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "configs" / "session_hi5_paper.toml"
TEMPLATE = ROOT / "configs" / "session_template.toml"


@pytest.mark.parametrize("n", range(1, 9))
def test_the_latin_square_is_balanced(n):
    rows = latin_square(n)
    assert len(rows) == (n if n % 2 == 0 else 2 * n)
    for row in rows:
        assert sorted(row) == list(range(n))
    for col in zip(*rows[:n]):
        assert sorted(col) == list(range(n))
    # Each ordered pair of neighbours equally often (once; twice over 2n rows for odd n).
    pairs = [p for row in rows for p in zip(row, row[1:])]
    counts = {p: pairs.count(p) for p in itertools.permutations(range(n), 2)}
    assert len(set(counts.values())) <= 1, counts


def test_the_block_order_follows_the_participant_number():
    plan = ScenarioConfig.from_toml(TEMPLATE)
    orders = [block_order(plan, f"P{i:02d}")[0] for i in range(4)]
    assert all(o[0] == 0 for o in orders), "the practice block comes first"
    assert sorted(tuple(o[1:]) for o in orders) != [tuple(orders[0][1:])] * 4
    for position in range(1, 5):
        assert sorted(o[position] for o in orders) == [1, 2, 3, 4]
    with pytest.raises(ValueError, match="--participant"):
        block_order(plan, "alice")


def test_a_condition_that_sets_a_field_wrongly_is_named(tmp_path):
    text = PAPER.read_text().replace('"partner.gains.lhh" = 0.5', '"partner.gainz.lhh" = 0.5')
    (tmp_path / "bad.toml").write_text(text)
    with pytest.raises(ConfigError, match=r"session\.blocks\[1\]\.set: partner\.gainz\.lhh"):
        expand(ScenarioConfig.from_toml(tmp_path / "bad.toml"), "P0")
    proc = subprocess.run([sys.executable, "-m", "sensaug", "check", str(tmp_path / "bad.toml")],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and "session.blocks[1].set: partner.gainz.lhh" in proc.stderr


@pytest.mark.parametrize("old, new, named", [
    ('"partner.gains.lhh" = 0.5', '"partner.gainz.lhh" = 0.5', "session.blocks[1].set: partner.gainz.lhh: partner.gainz"),
    ('"partner.gains.lhh" = 0.5', '"partner.gains.lhh" = 1e9', "session.blocks[1].set: partner.gains[2]"),
    ('"partner.gains.lhh" = 0.5', '"partner.gains.lhh" = "high"', "session.blocks[1].set: partner.gains[2]"),
    ('"partner.gains.lhh" = 0.5', '"phases[3].duration_s" = 5.0', "session.blocks[1].set: phases[3].duration_s: phases[3] does not exist"),
    ('"partner.gains.lhh" = 0.5', '"display.sigma_v" = -1.0', "session.blocks[1].set: display.sigma_v"),
    ('"partner.gains.lhh" = 0.5', '"phases[*].duration_s" = 0.0', "session.blocks[1].set: phases[0].duration_s"),
    ('"partner.gains.lhh" = 2.0 }\n\n[[session.blocks]]\nname = "integration"',
     '"partner.gains.lhh" = 2.0, "robot.stage3.channel.gate" = -3.0 }\n\n[[session.blocks]]\nname = "integration"',
     "session.blocks[5].set: robot.stage3.channel.gate"),
    (None, None, None),
])
def test_both_checkers_expand_the_conditions_alike(tmp_path, old, new, named):
    """`sensaug check` and `sensaug-rt --check` expand every block of a plan
    (one implementation, sensaug_config::person::check_conditions) and print
    the same first bad field; the session runner's expansion refuses the
    same plans, naming the same block and path."""
    from sensaug.rig import find_binary

    text = PAPER.read_text()
    if old is not None:
        assert old in text, old
        text = text.replace(old, new, 1)
    path = tmp_path / "plan.toml"
    path.write_text(text)
    outs = [subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path)
            for cmd in ([sys.executable, "-m", "sensaug", "check", str(path)], [str(find_binary()), "--check", str(path)])]
    if named is None:
        assert [(o.returncode, o.stdout.strip()) for o in outs] == [(0, "valid")] * 2, outs
        expand(ScenarioConfig.from_toml(path), "P0")
        return
    assert [o.returncode for o in outs] == [2, 2], outs
    assert outs[0].stderr == outs[1].stderr, outs
    assert outs[0].stderr.startswith(named), outs[0].stderr
    with pytest.raises(ConfigError) as e:
        expand(ScenarioConfig.from_toml(path), "P0")
    assert str(e.value).startswith(named.split(": ")[0] + ": " + named.split(": ")[1].split(".")[0]), (str(e.value), named)


def test_the_schema_refuses_unsafe_or_ambiguous_plans(tmp_path):
    base = PAPER.read_text()
    cases = {
        'name = "trajectory"': ('name = "gains_lhh0_0"', "session.blocks[5].name"),
        "phases = [0, 1]": ("phases = [0, 7]", "session.blocks[5].phases[1]"),
        "virtual_human = true": ("virtual_human = false", None),
    }
    for old, (new, field) in cases.items():
        text = base.replace(old, new, 1)
        if field is None:  # a person at the handle and a display told to ignore freezes
            text, field = text.replace('on_freeze = "stop"', 'on_freeze = "continue"'), "display.on_freeze"
        (tmp_path / "p.toml").write_text(text)
        with pytest.raises(ConfigError, match=field.replace("[", r"\[").replace("]", r"\]").replace(".", r"\.")):
            ScenarioConfig.from_toml(tmp_path / "p.toml")


def reduced_paper(tmp_path: Path, phase_s: float, trials: int, window_s: float) -> Path:
    text = PAPER.read_text()
    text = text.replace("duration_s = 20.0", f"duration_s = {phase_s}")
    text = text.replace("gain_window_s = 8.0", f"gain_window_s = {window_s}")
    text = text.replace("trials = 12", f"trials = {trials}").replace("trials = 3", "trials = 1")
    path = tmp_path / "paper_reduced.toml"
    path.write_text(text)
    return path


def test_the_paper_plan_runs_end_to_end_reduced_on_the_virtual_rig(tmp_path):
    """The paper's plan on the virtual rig, 4 s phases, one trial per block:
    every block runs to a finished attempt and the manifest has one row per
    attempt with the estimates and the virtual human's gain beside them
    (the numbers: the simulated run below and docs/person.md)."""
    plan = reduced_paper(tmp_path, 4.0, 1, 2.0)
    folder = run_unattended(plan, "P00", tmp_path / "sessions")
    s = load_session(folder)
    done = s.finished()
    assert list(done["trial"]) == list(range(7)), s.manifest[["trial", "block", "stop_reason"]]
    assert list(done["block"]) == [b.name for b in ScenarioConfig.from_toml(plan).session.blocks]
    assert done["Lhh_hat"].notna().all() and np.allclose(done["truth_Lhh"], [0, 0.5, 1, 1.5, 2, 2, 2])
    assert done["tau_h_rmse"].notna().sum() == 2 and done["rmse_integrated"].notna().sum() == 1
    assert s.log(6).complete
    assert len(s.plot_blocks(tmp_path / "figs")) == 7


def test_the_paper_plan_reduced_reproduces_the_gain_table_simulated(tmp_path):
    """The same plan simulated (session.rig = false), 10 s gain phases and
    two trials per gain: each gain's mean estimate is within 0.05 of the
    virtual human's (the full plan, 12 x 20 s trials: within 0.02,
    docs/person.md)."""
    plan = reduced_paper(tmp_path, 10.0, 2, 4.0)
    plan.write_text(plan.read_text().replace("rig = true", "rig = false"))
    folder = run_session(plan, "P00", out=tmp_path / "sessions", progress=lambda _: None)
    df = load_session(folder).manifest
    assert (df["finished"] == 1).all()
    gains = df[df["block"].str.startswith("gains")].groupby("truth_Lhh")["Lhh_hat"].mean()
    assert np.allclose(gains.index, [0, 0.5, 1, 1.5, 2])
    assert (abs(gains - gains.index) < 0.05).all(), gains


def run_unattended(plan: Path, participant: str, out: Path) -> Path:
    """run_session, resumed (at most twice) when the loop stopped one trial
    3 times in a row: the virtual drive, a Python process, is starved on a
    loaded 2-core machine; resuming is what a lab does then."""
    for attempt in range(3):
        try:
            return run_session(plan, participant, out=out, resume=attempt > 0, progress=lambda _: None)
        except RuntimeError as e:
            if "attempts in a row stopped" not in str(e) or attempt == 2:
                raise
    raise AssertionError("unreachable")


def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_a_session_killed_mid_trial_resumes_without_losing_finished_trials(tmp_path):
    """SIGKILL to the session's process group (launcher, loop, virtual drive)
    during its third trial; --resume: the finished trials' files are byte
    for byte what they were, the interrupted attempt has a manifest row
    (interrupted) and its trial ran again as attempt 2; every trial has
    exactly one finished attempt."""
    plan = reduced_paper(tmp_path, 2.0, 2, 1.0)
    text = plan.read_text()
    cut = text.index('[[session.blocks]]\nname = "gains_lhh1_0"')
    plan.write_text(text[:cut])  # two blocks of two gain trials
    out = tmp_path / "sessions"
    cmd = [sys.executable, "-m", "sensaug", "session", str(plan), "--participant", "P01", "--out", str(out)]
    manifest = out / "P01" / "manifest.csv"

    def rows() -> list[dict]:
        return list(csv.DictReader(manifest.open())) if manifest.exists() else []

    def third_trial_running() -> bool:
        done = {r["trial"] for r in rows() if r["finished"] == "1"}
        return done == {"0", "1"} and any((out / "P01" / "trials").glob("002_*/rig_log.csv"))

    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    try:
        while not third_trial_running():
            assert time.monotonic() - t0 < 240, "the session did not reach its third trial"
            if proc.poll() is not None:
                # The loop stopped a trial 3 times in a row (a loaded machine): resume, as a lab would.
                err = proc.communicate()[1].decode()
                assert "attempts in a row stopped" in err, err
                proc = subprocess.Popen(cmd + ["--resume"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        start_new_session=True)
            time.sleep(0.05)
        time.sleep(0.5)  # mid-trial: the 2 s trial's log is being written
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    finished_before = {d.name: _digest(d) for d in (out / "P01" / "trials").iterdir()}
    killed = {d.name for d in (out / "P01" / "trials").glob("002_*")} - {
        r["folder"].removeprefix("trials/") for r in rows()}
    assert len(killed) == 1, killed
    for name in killed:
        del finished_before[name]
    # The virtual drive and the loop were in the killed group: nothing holds the bus.
    res = subprocess.run(cmd + ["--resume"], capture_output=True, text=True, timeout=180)
    assert "was interrupted" in res.stdout
    for _ in range(2):  # the loop stopped a trial 3 times in a row (a loaded machine): resume again
        if res.returncode == 0 or "attempts in a row stopped" not in res.stderr:
            break
        res = subprocess.run(cmd + ["--resume"], capture_output=True, text=True, timeout=180)
    assert res.returncode == 0, res.stderr
    for name, digest in finished_before.items():
        assert _digest(out / "P01" / "trials" / name) == digest, name
    df = load_session(out / "P01").manifest
    # The killed trial's attempt is in the manifest as interrupted; a new
    # attempt of that trial follows (more attempts only if the loop itself
    # stopped one: MAX_ATTEMPTS, which a loaded machine can cause).
    interrupted = df[df["stop_reason"] == "interrupted"]
    assert len(interrupted) == 1 and interrupted["trial"].iloc[0] == 2, df[["trial", "attempt", "stop_reason"]]
    assert interrupted["folder"].iloc[0] == f"trials/{killed.pop()}"
    assert sorted(set(df["trial"])) == [0, 1, 2, 3]
    for trial, g in df.groupby("trial"):
        assert list(g["attempt"]) == list(range(1, len(g) + 1)), g
        assert g["finished"].sum() == 1 and g["finished"].iloc[-1] == 1, g
    for d in (out / "P01" / "trials").iterdir():
        assert f"trials/{d.name}" in set(df["folder"]), f"{d.name} has no manifest row"
    # Without --resume an existing session is refused, not overwritten.
    again = subprocess.run(cmd, capture_output=True, text=True)
    assert again.returncode == 2 and "--resume" in again.stderr
