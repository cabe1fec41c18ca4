"""Sweeps: dotted paths of the one schema, tidy results, and bit-identical
numbers whatever executor runs the trials (serial, threads, a Dask cluster)."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pandas as pd
import pytest

from sensaug import presets
from sensaug.config import ConfigError
from sensaug.sweep import ROBOT_SEED_OFFSET, set_path, sweep


def base():
    cfg = presets.hi5_experiment(phase_s=6.0)
    cfg.robot.gain_window_s = 2.0
    return cfg


GRID = {"partner.gains.lhh": [0.5, 2.0], "phases[2].target_noise_std": [0.1, 1.0]}


def test_set_path_reaches_fields_lists_and_named_gains():
    cfg = base()
    set_path(cfg, "partner.gains.lhh", 1.5)
    set_path(cfg, "partner.gains[0]", 0.25)
    set_path(cfg, "phases[*].target_noise_std", 0.3)
    set_path(cfg, "robot.stage3.channel.hold_max_s", 0.4)
    assert cfg.partner.gains == [0.25, 0.0, 1.5]
    assert [p.target_noise_std for p in cfg.phases] == [0.3, 0.3, 0.3]
    assert cfg.robot.stage3.channel.hold_max_s == 0.4
    cfg.validate()


@pytest.mark.parametrize(
    "path,expect",
    [
        ("robot.stage3.target_noise_std", r"^robot\.stage3\.target_noise_std: robot\.stage3\.target_noise_std is not a field"),
        ("phases[7].duration_s", r"phases\[7\] does not exist"),
        ("robot.q pos", r"not a dotted path"),
        ("partner.q_pos.x", r"partner\.q_pos is not set"),
    ],
)
def test_bad_grid_keys_are_named_before_anything_runs(path, expect):
    with pytest.raises(ConfigError, match=expect):
        sweep(base(), {path: [1.0]}, seeds=[0])


def test_bad_swept_values_name_the_field():
    with pytest.raises(ConfigError, match=r"^rig\.watchdog_ms: 1000 is out of range"):
        sweep(base(), {"rig.watchdog_ms": [50, 1000]}, seeds=[0])


def test_tidy_frame_one_row_per_trial_and_seeds_set():
    df = sweep(base(), GRID, seeds=range(2), progress=False)
    assert len(df) == 2 * 2 * 2
    assert list(df.columns[:3]) == ["partner.gains.lhh", "phases[2].target_noise_std", "seed"]
    for col in ("Lhh_hat", "tau_h_rmse", "rmse_own", "rmse_integrated"):
        assert np.isfinite(df[col]).all()
    # The gain estimate follows the swept gain.
    by = df.groupby("partner.gains.lhh")["Lhh_hat"].mean()
    assert abs(by[0.5] - 0.5) < 0.05 and abs(by[2.0] - 2.0) < 0.05
    # Integration helps more at the higher injected noise.
    gain = df["rmse_own"] / df["rmse_integrated"]
    assert gain[df["phases[2].target_noise_std"] == 1.0].mean() > gain[df["phases[2].target_noise_std"] == 0.1].mean()


def test_seed_sets_world_and_robot_seeds():
    a = sweep(base(), {}, seeds=[3], progress=False)
    cfg = base()
    cfg.world.seed, cfg.robot.seed = 3, 3 + ROBOT_SEED_OFFSET
    from sensaug import experiment
    from sensaug.sweep import trial_metrics

    expected = trial_metrics(experiment.run(cfg))
    assert a.iloc[0]["Lhh_hat"] == expected["Lhh_hat"]


def test_same_numbers_whatever_the_executor():
    serial = sweep(base(), GRID, seeds=range(2), executor=ThreadPoolExecutor(1), progress=False)
    threads = sweep(base(), GRID, seeds=range(2), progress=False)
    pd.testing.assert_frame_equal(serial, threads, check_exact=True)


def test_dask_local_cluster_gives_identical_numbers():
    distributed = pytest.importorskip("distributed", reason="dask[distributed] is in requirements-dev.txt")
    cluster = distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None
    )
    try:
        with distributed.Client(cluster, timeout=60) as client:
            on_dask = sweep(base(), GRID, seeds=range(2), executor=client.get_executor(), progress=False)
    finally:
        cluster.close(timeout=30)
    local = sweep(base(), GRID, seeds=range(2), progress=False)
    pd.testing.assert_frame_equal(on_dask, local, check_exact=True)


def test_cli_sweep_writes_results_config_and_grid(tmp_path):
    from sensaug import cli
    from sensaug.config import ScenarioConfig

    path = tmp_path / "base.toml"
    base().to_toml(path)
    out = tmp_path / "sweep"
    code = cli.main(["sweep", str(path), "--grid", "partner.gains.lhh=0.5,2.0", "--seeds", "2", "--out", str(out)])
    assert code == 0
    df = pd.read_csv(out / "results.csv")
    assert len(df) == 4 and set(df["partner.gains.lhh"]) == {0.5, 2.0}
    assert ScenarioConfig.from_toml(out / "config.toml").to_dict() == base().to_dict()
    assert (out / "grid.json").is_file() and (out / "README.md").is_file()


# --- seed fields in the grid: swept, never silently overridden ---------------


def _expected(cfg) -> dict:
    from sensaug import experiment
    from sensaug.sweep import trial_metrics

    return trial_metrics(experiment.run(cfg))


@pytest.mark.parametrize("field", ["world.seed", "robot.seed"])
def test_a_seed_field_in_the_grid_is_swept(field):
    """The grid sets the field; the trial seed sets the other seeds only."""
    df = sweep(base(), {field: [5, 6]}, seeds=[3], progress=False)
    assert list(df[field]) == [5, 6]
    assert df.iloc[0]["rmse_own"] != df.iloc[1]["rmse_own"], "the rows differ: the grid's seed took effect"
    for value, row in zip((5, 6), df.itertuples()):
        cfg = base()
        cfg.world.seed, cfg.robot.seed = 3, 3 + ROBOT_SEED_OFFSET
        set_path(cfg, field, value)
        assert row.rmse_own == _expected(cfg)["rmse_own"]


def test_a_grid_over_every_seed_takes_one_seed():
    grid = {"world.seed": [1, 2], "robot.seed": [7]}
    with pytest.raises(ConfigError, match=r"^seeds: the grid sets every seed of the trial \(world\.seed, robot\.seed\), so 2 seeds would repeat identical trials; give one seed"):
        sweep(base(), grid, seeds=range(2))
    df = sweep(base(), grid, seeds=[0], progress=False)
    assert len(df) == 2 and df.iloc[0]["rmse_own"] != df.iloc[1]["rmse_own"]


def test_seed_sets_every_seed_as_the_presets_do():
    """With a goal-integrating partner the trial seed also sets
    partner.integration.seed: seed s of a sweep is seed s of the preset."""
    from sensaug import presets
    from sensaug.sweep import PARTNER_SEED_OFFSET

    def integration(seed=0):
        cfg = presets.simulation_integration(seed=seed, phase_s=3.0)
        cfg.robot.gain_window_s = 1.0
        return cfg

    df = sweep(integration(), {}, seeds=[0, 4], progress=False)
    for seed, row in zip((0, 4), df.itertuples()):
        assert integration(seed).partner.integration.seed == seed + PARTNER_SEED_OFFSET
        assert row.rmse_integrated == _expected(integration(seed))["rmse_integrated"]
    # Swept by the grid, it is left to the grid.
    df = sweep(integration(), {"partner.integration.seed": [11, 12]}, seeds=[0], progress=False)
    assert df.iloc[0]["rmse_integrated"] != df.iloc[1]["rmse_integrated"]


def test_cli_sweeps_a_seed_grid_and_refuses_one_that_repeats(tmp_path, capsys):
    from sensaug import cli

    path = tmp_path / "base.toml"
    base().to_toml(path)
    out = tmp_path / "sweep"
    assert cli.main(["sweep", str(path), "--grid", "world.seed=1,2", "--seeds", "1", "--workers", "1", "--out", str(out), "--quiet"]) == 0
    df = pd.read_csv(out / "results.csv")
    assert list(df["world.seed"]) == [1, 2] and df["rmse_own"].nunique() == 2
    code = cli.main(["sweep", str(path), "--grid", "world.seed=1,2", "--grid", "robot.seed=3", "--seeds", "2",
                     "--out", str(tmp_path / "no"), "--quiet"])
    assert code == 2
    assert "error: seeds: the grid sets every seed of the trial (world.seed, robot.seed)" in capsys.readouterr().err
    assert not (tmp_path / "no").exists()


# --- memory: the largest trial checked before anything runs -----------------


def test_a_sweep_whose_trial_does_not_fit_is_refused_before_it_runs():
    from sensaug.experiment import TrialTooLargeError, trial_memory

    need = trial_memory(base())
    with pytest.raises(TrialTooLargeError, match=r"^phases\[\*\]\.duration_s, plant\.dt_s: .*shorten the phases, raise plant\.dt_s"):
        sweep(base(), {"phases[0].duration_s": [6.0, 12.0]}, seeds=[0], memory_budget=need)


class _Counting(ThreadPoolExecutor):
    """A thread pool that records the most trials running at once."""

    def __init__(self, workers: int):
        super().__init__(workers)
        self.lock = threading.Lock()
        self.running = self.most = 0

    def submit(self, fn, *args, **kwargs):
        def counted(*a, **k):
            with self.lock:
                self.running += 1
                self.most = max(self.most, self.running)
            try:
                return fn(*a, **k)
            finally:
                with self.lock:
                    self.running -= 1

        return super().submit(counted, *args, **kwargs)


def test_no_more_trials_run_at_once_than_fit_the_budget():
    from sensaug.experiment import trial_memory

    need = trial_memory(base())
    for budget, most in ((need, 1), (2 * need, 2)):
        pool = _Counting(4)
        df = sweep(base(), {}, seeds=range(4), executor=pool, memory_budget=budget, progress=False)
        pool.shutdown()
        assert pool.most <= most, (budget, pool.most)
        pd.testing.assert_frame_equal(df, sweep(base(), {}, seeds=range(4), progress=False), check_exact=True)
