"""The memory of a simulated trial, checked before it runs.

A trial keeps its whole log in memory (one record of ``logs.DTYPE`` per
tick). The core computes the log's size from the configuration
(``_core.trial_memory``) and refuses, before anything runs, a trial whose
log needs more than its budget (half of the memory available, or
``memory_budget`` / ``--max-memory``), naming the fields that make it large
and the fix. The finding: ``sensaug run`` of 3 phases x 3600 s at dt 1e-4
(both checkers accept it) aborted the interpreter with a 39 GB allocation.
"""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from sensaug import _core, experiment, logs, presets
from sensaug.config import ConfigError
from sensaug.experiment import TrialTooLargeError, trial_memory

#: The finding's log: 108,000,000 rows of logs.DTYPE (GB = 1e9 bytes, as the
#: message says it), so a new log column moves it.
NEEDS = f"{108_000_000 * logs.DTYPE.itemsize / 1e9:.2f} GB"
MESSAGE = (
    r"^phases\[\*\]\.duration_s, plant\.dt_s: 3 phase\(s\) of 10800 s in all at plant\.dt_s = 0\.0001 s "
    rf"are 108000000 ticks, whose log needs {re.escape(NEEDS)} of memory, "
)
FIX = "shorten the phases, raise plant.dt_s, or split the trial into shorter runs"


def small():
    return presets.hi5_experiment(phase_s=2.0)


def finding():
    """The finding's configuration: 3 x 3600 s at dt 1e-4."""
    cfg = presets.hi5_experiment(2.0)
    cfg.plant.dt_s = 1e-4
    for p in cfg.phases:
        p.duration_s = 3600.0
    cfg.validate()
    return cfg


def test_the_log_size_is_the_core_s_and_the_run_s():
    """Derived once, in Rust, from the configuration: the ticks and bytes it
    gives are those of the log a run returns."""
    cfg = small()
    ticks, nbytes = cfg.resolved().trial_memory(memory_budget=None)
    trial = experiment.run(cfg)
    assert ticks == len(trial) == 6000
    assert nbytes == trial_memory(cfg) == trial.data.nbytes == ticks * logs.DTYPE.itemsize


def test_a_trial_over_its_budget_is_refused_before_it_runs():
    cfg = small()
    need = trial_memory(cfg)
    with pytest.raises(TrialTooLargeError, match=r"^phases\[\*\]\.duration_s, plant\.dt_s: 3 phase\(s\) of 6 s in all") as e:
        experiment.run(cfg, memory_budget=need - 1)
    assert str(e.value).endswith(FIX)
    assert isinstance(e.value, ConfigError) and isinstance(e.value, ValueError)
    assert len(experiment.run(cfg, memory_budget=need)) == 6000


def test_the_finding_is_accepted_by_both_checkers_and_refused_by_its_size(tmp_path):
    cfg = finding()
    path = tmp_path / "long.toml"
    cfg.to_toml(path)
    assert subprocess.run([sys.executable, "-m", "sensaug", "check", str(path)], capture_output=True).returncode == 0
    assert cfg.resolved().trial_memory(memory_budget=None) == (108_000_000, 108_000_000 * logs.DTYPE.itemsize)
    with pytest.raises(TrialTooLargeError, match=MESSAGE + r"more than the 1\.00 GB this trial may take"):
        experiment.run(cfg, memory_budget=10**9)


def _run_cli(*args: str):
    return subprocess.run([sys.executable, "-m", "sensaug", *args], capture_output=True, text=True, timeout=300)


def test_cli_run_refuses_the_finding_with_a_message(tmp_path):
    """No abort (SIGABRT), no log: exit 2 and the message, with --max-memory."""
    path = tmp_path / "long.toml"
    finding().to_toml(path)
    r = _run_cli("run", str(path), "--max-memory", "4")
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith("error: phases[*].duration_s, plant.dt_s: 3 phase(s) of 10800 s")
    assert f"{NEEDS} of memory, more than the 4.00 GB this trial may take; " + FIX in r.stderr
    assert not path.with_suffix(".csv").exists()


def test_cli_run_refuses_the_finding_on_this_machine(tmp_path):
    """Without --max-memory: the budget is half the memory available here."""
    budget = _core.available_memory()
    if budget is None or budget >= 39.1e9:
        pytest.skip(f"this machine may hold a 39 GB log (budget {budget} bytes); the --max-memory test covers the check")
    path = tmp_path / "long.toml"
    finding().to_toml(path)
    r = _run_cli("run", str(path))
    assert r.returncode == 2, r.stderr
    assert f"{NEEDS} of memory, more than the" in r.stderr and FIX in r.stderr


def test_cli_sweep_refuses_the_finding_before_any_trial(tmp_path):
    path = tmp_path / "long.toml"
    finding().to_toml(path)
    r = _run_cli("sweep", str(path), "--seeds", "3", "--max-memory", "2", "--out", str(tmp_path / "out"), "--quiet")
    assert r.returncode == 2, r.stderr
    assert f"{NEEDS} of memory, more than the 2.00 GB" in r.stderr
    assert not (tmp_path / "out").exists()


def test_max_memory_must_be_positive(tmp_path):
    path = tmp_path / "small.toml"
    small().to_toml(path)
    r = _run_cli("run", str(path), "--max-memory", "0")
    assert r.returncode == 2 and "--max-memory: must be > 0 GB" in r.stderr


def test_available_memory_is_half_of_what_is_left():
    """Linux: half of MemAvailable (or of a cgroup's remaining limit)."""
    budget = _core.available_memory()
    assert budget is not None, "Linux has /proc/meminfo"
    with open("/proc/meminfo") as f:
        avail = next(int(line.split()[1]) * 1024 for line in f if line.startswith("MemAvailable:"))
    assert 0 < budget <= avail // 2 * 1.1  # memory moves a little between the two reads
