"""Parameter sweeps over seeds, on local cores or any ``concurrent.futures``
executor (a Dask ``distributed`` client's executor runs them on a cluster).

``sweep(base, grid={"partner.gains.lhh": [0, 1, 2]}, seeds=range(12))`` runs
one trial per grid point and seed and returns a tidy :class:`pandas.DataFrame`:
one row per trial with the swept values, the seed and every headline metric.
Each trial crosses into Rust once and releases the GIL, so the default
executor is a thread pool with one worker per core. A trial is described to
its worker by the configuration's TOML text, so the same seeds give
bit-identical numbers whatever executor runs them.

Grid keys are dotted paths of the configuration schema (``docs/config.md``):
``robot.stage3.partner_window_s``, ``phases[2].target_noise_std``,
``phases[*].target_noise_std`` (every phase), and the gain lists by index or by
name (``partner.gains[2]`` is ``partner.gains.lhh``; ``lhx``, ``lhv``,
``lhh``).
"""

from __future__ import annotations

import copy
import itertools
import math
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import Executor, ThreadPoolExecutor
from typing import Any

import numpy as np

from sensaug import experiment
from sensaug.config import ConfigError, ScenarioConfig

__all__ = ["sweep", "set_path", "trial_metrics", "ROBOT_SEED_OFFSET"]

#: The robot's noise seed is the trial seed plus this (as in the presets), so
#: world and robot noise streams differ.
ROBOT_SEED_OFFSET = 1_000_003
_GAIN_NAMES = {"lhx": 0, "lhv": 1, "lhh": 2}
_SEGMENT = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[(?:\d+|\*)\])*)")


def _segments(path: str) -> list[str | int]:
    """``phases[*].robot_target[0].amplitude`` -> ``['phases', '*', 'robot_target', 0, 'amplitude']``."""
    out: list[str | int] = []
    for part in path.split("."):
        m = _SEGMENT.fullmatch(part)
        if m is None:
            raise ConfigError(f"{path}: not a dotted path of the configuration (e.g. robot.stage3.partner_window_s)")
        out.append(m.group(1))
        for idx in re.findall(r"\[(\d+|\*)\]", m.group(2)):
            out.append("*" if idx == "*" else int(idx))
    return out


def _assign(obj: Any, segs: list[str | int], value: Any, path: str, done: str) -> None:
    head, rest = segs[0], segs[1:]
    where = f"{done}.{head}" if isinstance(head, str) and done else (f"{done}[{head}]" if done else str(head))
    if isinstance(obj, list) and isinstance(head, str) and head in _GAIN_NAMES:
        head = _GAIN_NAMES[head]
    if head == "*":
        if not isinstance(obj, list):
            raise ConfigError(f"{path}: {done} is not a list; [*] needs one")
        for i, item in enumerate(obj):
            if rest:
                _assign(item, rest, value, path, f"{done}[{i}]")
            else:
                obj[i] = value
        return
    if isinstance(head, int):
        if not isinstance(obj, list) or not -len(obj) <= head < len(obj):
            raise ConfigError(f"{path}: {where} does not exist (index out of range or not a list)")
        if rest:
            _assign(obj[head], rest, value, path, where)
        else:
            obj[head] = value
        return
    if not hasattr(obj, "__dataclass_fields__") or head not in obj.__dataclass_fields__:
        raise ConfigError(f"{path}: {where} is not a field of the configuration; see `python -m sensaug schema`")
    if rest:
        child = getattr(obj, head)
        if child is None:
            raise ConfigError(f"{path}: {where} is not set in the base configuration; give it a value first")
        if isinstance(child, tuple):
            child = list(child)
            setattr(obj, head, child)
        _assign(child, rest, value, path, where)
    else:
        setattr(obj, head, value)


def set_path(config: ScenarioConfig, path: str, value: Any) -> None:
    """Sets the field at dotted ``path`` (in place, not validated).

    Raises:
        ConfigError: the path names no field of this configuration.
    """
    _assign(config, _segments(path), value, path, "")


def _nan_metrics(kind: str) -> dict[str, float]:
    return {
        "gains": {"Lhx_hat": math.nan, "Lhv_hat": math.nan, "Lhh_hat": math.nan},
        "trajectory": {"tau_h_rmse": math.nan},
        "integration": {"rmse_measured": math.nan, "rmse_own": math.nan, "rmse_integrated": math.nan},
    }[kind]


def trial_metrics(trial: experiment.Trial) -> dict[str, float]:
    """The paper's headline numbers of one trial (NaN for a phase it lacks):
    the gain estimate over the last ``robot.gain_window_s`` of the first gain
    phase, the partner-target RMSE of the first trajectory phase and the RMSEs
    of the first integration phase, each after a settling time of 2 s (half
    the phase if it is shorter than 4 s)."""
    out: dict[str, float] = {}

    def skip(kind: str) -> float:
        return min(2.0, trial.config.phases[trial.phases_of(kind)[0]].duration_s / 2)

    if trial.phases_of("gains"):
        g = trial.gain_estimate(last_s=trial.config.robot.gain_window_s)
        out.update(Lhx_hat=float(g[0]), Lhv_hat=float(g[1]), Lhh_hat=float(g[2]))
    else:
        out.update(_nan_metrics("gains"))
    if trial.phases_of("trajectory"):
        out["tau_h_rmse"] = trial.partner_target_rmse(skip_s=skip("trajectory"))
    else:
        out.update(_nan_metrics("trajectory"))
    if trial.phases_of("integration"):
        r = trial.integration_rmse(skip_s=skip("integration"))
        out.update(rmse_measured=r["measured"], rmse_own=r["own"], rmse_integrated=r["integrated"])
    else:
        out.update(_nan_metrics("integration"))
    out["estimator_errors"] = float(trial.summary.get("estimator_errors", 0))
    return out


def _run_one(toml: str) -> dict[str, float]:
    """One trial from its configuration text (a top-level function, so that
    process pools and Dask can ship it)."""
    return trial_metrics(experiment.run(ScenarioConfig.from_toml(toml)))


def _points(grid: Mapping[str, Sequence[Any]]) -> list[dict[str, Any]]:
    keys = list(grid)
    for k in keys:
        if isinstance(grid[k], (str, bytes)) or not isinstance(grid[k], Iterable):
            raise ConfigError(f"grid.{k}: give a list of values to sweep, got {grid[k]!r}")
    values = [list(grid[k]) for k in keys]
    for k, v in zip(keys, values):
        if not v:
            raise ConfigError(f"grid.{k}: empty; give at least one value")
    return [dict(zip(keys, combo)) for combo in itertools.product(*values)]


def sweep(
    base_config: ScenarioConfig,
    grid: Mapping[str, Sequence[Any]] | None = None,
    seeds: Iterable[int] = range(12),
    executor: Executor | None = None,
    *,
    progress: bool | None = None,
) -> "pandas.DataFrame":  # noqa: F821
    """Runs ``base_config`` at every grid point for every seed.

    Arguments:
        base_config: the configuration to vary (not modified).
        grid: dotted path -> values; the cartesian product is run.
        seeds: trial seeds; each sets ``world.seed`` and ``robot.seed``
            (= seed + ``ROBOT_SEED_OFFSET``).
        executor: any ``concurrent.futures.Executor`` (e.g. a Dask
            ``distributed.Client(...).get_executor()``); default: a thread pool
            with one worker per core.
        progress: show a tqdm progress bar (default: when on a terminal).

    Returns:
        A DataFrame with one row per trial: the swept values, ``seed``, and the
        metrics of :func:`trial_metrics`; rows in grid-then-seed order.

    Raises:
        ConfigError: a grid key names no field, or a swept value is invalid
            (named like ``partner.gains[2]: ...``), before any trial runs.
    """
    import pandas as pd
    from tqdm.auto import tqdm

    points = _points(grid or {})
    seed_list = [int(s) for s in seeds]
    if not seed_list:
        raise ConfigError("seeds: empty; give at least one seed")
    jobs: list[tuple[dict[str, Any], int, str]] = []
    for point in points:
        for seed in seed_list:
            cfg = copy.deepcopy(base_config)
            for path, value in point.items():
                set_path(cfg, path, value)
            cfg.world.seed = seed
            cfg.robot.seed = seed + ROBOT_SEED_OFFSET
            cfg.validate()
            jobs.append((point, seed, cfg._toml()))

    own = executor is None
    pool = ThreadPoolExecutor(max_workers=os.cpu_count() or 1) if own else executor
    try:
        futures = [pool.submit(_run_one, toml) for _, _, toml in jobs]
        bar = tqdm(total=len(futures), desc="sweep", unit="trial", disable=None if progress is None else not progress)
        results = []
        for f in futures:
            results.append(f.result())
            bar.update(1)
        bar.close()
    finally:
        if own:
            pool.shutdown()
    rows = [{**point, "seed": seed, **metrics} for (point, seed, _), metrics in zip(jobs, results)]
    df = pd.DataFrame(rows)
    for key in points[0]:
        if df[key].map(lambda v: isinstance(v, (list, tuple, np.ndarray))).any():
            df[key] = df[key].map(repr)
    return df
