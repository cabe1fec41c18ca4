"""A configuration is resolved once, into one value (``_core.Config``), and
that value is what runs, replays, sweeps and launches the rig (issue 18).

``_core.resolve_count()`` counts the resolutions on the calling thread (the
Rust schema's ``Resolved::new``): each test counts what one step costs.
"""

from __future__ import annotations

import copy
import pickle
from concurrent.futures import Executor, Future

import pytest

from sensaug import _core, presets, replay, run
from sensaug.config import ConfigError, ScenarioConfig
from sensaug.sweep import sweep


def resolves(step) -> tuple[int, object]:
    before = _core.resolve_count()
    out = step()
    return _core.resolve_count() - before, out


def short() -> ScenarioConfig:
    return presets.hi5_experiment(phase_s=1.0)


def test_a_simulated_trial_resolves_its_configuration_once():
    n, trial = resolves(lambda: run(short()))
    assert n == 1, "a preset built and run: one resolve"
    cfg = short()
    cfg.validate()
    n, _ = resolves(lambda: (run(cfg), run(cfg)))
    assert n == 0, "run takes the configuration as resolved"


def test_an_edit_resolves_again_once_and_is_run():
    cfg = short()
    cfg.world.seed = 7
    n, trial = resolves(lambda: run(cfg))
    assert n == 1
    assert trial.meta["config"]["world"]["seed"] == 7


def test_the_trial_metadata_is_the_resolved_configuration_serialised_in_rust():
    cfg = short()
    trial = run(cfg)
    described = cfg.resolved().metadata()
    assert trial.meta["config"] == described["config"] == cfg.resolved().to_dict()
    assert trial.meta["resolved"] == described["resolved"]
    assert list(trial.robot_gains) == described["resolved"]["robot"]["gains"]
    assert set(described["loop"]) >= {"period_ns", "feedback_timeout_ticks", "quiet_period_ms", "spin_us"}


def test_replay_and_the_rig_launchers_toml_reuse_the_resolved_configuration(tmp_path):
    cfg = short()
    trial = run(cfg)
    n, _ = resolves(lambda: replay(trial, cfg))
    assert n == 0
    n, text = resolves(lambda: cfg.to_toml(tmp_path / "rig_config.toml"))
    assert n == 0, "the rig launcher writes the resolved configuration's TOML"
    assert ScenarioConfig.from_toml(text) == cfg


def test_loading_a_file_resolves_once(tmp_path):
    path = tmp_path / "c.toml"
    short().to_toml(path)
    n, cfg = resolves(lambda: ScenarioConfig.from_toml(path))
    assert n == 1
    n, _ = resolves(lambda: run(cfg))
    assert n == 0


class InThread(Executor):
    """Runs each job on the calling thread, so its resolves are counted."""

    def submit(self, fn, /, *args, **kwargs):
        f: Future = Future()
        f.set_result(fn(*args, **kwargs))
        return f


def test_a_sweep_resolves_once_per_trial():
    cfg = short()
    n, df = resolves(lambda: sweep(cfg, {"robot.integrate": [True, False]}, seeds=[0, 1], executor=InThread(), progress=False))
    assert len(df) == 4
    assert n == 4


def test_the_resolved_configuration_is_immutable_and_shared_by_copies():
    cfg = short()
    handle = cfg.resolved()
    assert copy.deepcopy(handle) is handle
    n, back = resolves(lambda: pickle.loads(pickle.dumps(handle)))
    assert n == 1, "unpickled in another process, it is resolved there"
    assert back.to_dict() == handle.to_dict()


def test_a_config_error_carries_its_field_and_message():
    cfg = short()
    cfg.robot.q_pos = -1.0
    with pytest.raises(ConfigError) as e:
        cfg.validate()
    assert e.value.field == "robot.q_pos"
    assert str(e.value) == f"{e.value.field}: {e.value.message}"
    with pytest.raises(ConfigError) as e:
        _core.Config.from_text("phases = 3\n", format="toml")
    assert e.value.field == "phases"
