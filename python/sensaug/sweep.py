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
``robot.stage3.channel.gate``, ``phases[2].target_noise_std``,
``phases[*].target_noise_std`` (every phase), and the gain lists by index or by
name (``partner.gains[2]`` is ``partner.gains.lhh``; ``lhx``, ``lhv``,
``lhh``).

Seeds: each trial seed ``s`` sets every noise seed of the configuration
(:data:`SEED_FIELDS`): ``world.seed = s``, ``robot.seed = s +
ROBOT_SEED_OFFSET`` and, with a goal-integrating partner,
``partner.integration.seed = s + PARTNER_SEED_OFFSET`` (as the presets do).
A seed field in the grid is swept like any other field: the grid sets it and
the trial seed sets only the others. A grid that sets every seed of the
trial takes a single seed (more would repeat identical trials).

Memory: a trial keeps its whole log in memory while it runs. The largest
trial's log is computed from its configuration before anything runs; a
sweep whose trial would not fit raises ``TrialTooLargeError``, and at most
as many trials run at once as fit in the memory budget together.
"""

from __future__ import annotations

import copy
import itertools
import math
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ThreadPoolExecutor, wait
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import pandas

from sensaug import _core, experiment
from sensaug.config import ConfigError, ScenarioConfig
from sensaug.presets import PARTNER_SEED_OFFSET

__all__ = ["sweep", "set_path", "trial_metrics", "ROBOT_SEED_OFFSET", "PARTNER_SEED_OFFSET", "SEED_FIELDS"]

#: The robot's noise seed is the trial seed plus this (as in the presets), so
#: world and robot noise streams differ.
ROBOT_SEED_OFFSET = 1_000_003

#: Every noise seed of a configuration and its offset from the trial seed
#: (``partner.integration.seed`` only when the partner integrates goals).
SEED_FIELDS: dict[str, int] = {
    "world.seed": 0,
    "robot.seed": ROBOT_SEED_OFFSET,
    "partner.integration.seed": PARTNER_SEED_OFFSET,
}
_GAIN_NAMES = {"lhx": 0, "lhv": 1, "lhh": 2}
_SEGMENT = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[(?:\d+|\*)\])*)")


def _segments(path: str) -> list[str | int]:
    """``phases[*].robot_target[0].amplitude`` -> ``['phases', '*', 'robot_target', 0, 'amplitude']``."""
    out: list[str | int] = []
    for part in path.split("."):
        m = _SEGMENT.fullmatch(part)
        if m is None:
            raise ConfigError(path, "not a dotted path of the configuration (e.g. robot.stage3.channel.gate)")
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
            raise ConfigError(path, f"{done} is not a list; [*] needs one")
        for i, item in enumerate(obj):
            if rest:
                _assign(item, rest, value, path, f"{done}[{i}]")
            else:
                obj[i] = value
        return
    if isinstance(head, int):
        if not isinstance(obj, list) or not -len(obj) <= head < len(obj):
            raise ConfigError(path, f"{where} does not exist (index out of range or not a list)")
        if rest:
            _assign(obj[head], rest, value, path, where)
        else:
            obj[head] = value
        return
    if not hasattr(obj, "__dataclass_fields__") or head not in obj.__dataclass_fields__:
        raise ConfigError(path, f"{where} is not a field of the configuration; see `sensaug schema`")
    if rest:
        child = getattr(obj, head)
        if child is None:
            raise ConfigError(path, f"{where} is not set in the base configuration; give it a value first")
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


def _run_one(config: ScenarioConfig, memory_budget: int | None = None) -> dict[str, float]:
    """One trial of a validated configuration (a top-level function, so that
    process pools and Dask can ship it; pickled, its resolved configuration
    is resolved again where it lands)."""
    return trial_metrics(experiment.run(config, memory_budget=memory_budget))


def _canonical(path: str) -> str:
    """A grid key as its parsed segments joined by dots, to compare with
    :data:`SEED_FIELDS` however it was written."""
    return ".".join(str(s) for s in _segments(path))


def _seeded_fields(config: ScenarioConfig, grid_keys: Iterable[str]) -> dict[str, int]:
    """The seed fields a trial seed sets in ``config``: every one the
    configuration has (:data:`SEED_FIELDS`), less those the grid sets."""
    swept = {_canonical(k) for k in grid_keys}
    present = {k: off for k, off in SEED_FIELDS.items() if k != "partner.integration.seed" or config.partner.integration is not None}
    return {k: off for k, off in present.items() if k not in swept}


def _seed(config: ScenarioConfig, fields: Mapping[str, int], seed: int) -> None:
    for path, offset in fields.items():
        set_path(config, path, seed + offset)


def _in_flight(jobs: list[ScenarioConfig], memory_budget: int | None) -> int:
    """How many trials may run at once: as many of the largest as fit the
    budget together (default: ``_core.available_memory()``). Raises
    ``TrialTooLargeError`` (the core's message) when not even one fits."""
    budget = _core.available_memory() if memory_budget is None else memory_budget
    if budget is None:
        return len(jobs)
    largest = max(cfg.resolved().trial_memory(memory_budget=budget)[1] for cfg in jobs)
    return max(1, min(len(jobs), budget // max(1, largest)))


def _run_all(pool: Executor, jobs: list[ScenarioConfig], in_flight: int, memory_budget: int | None, bar) -> list[dict[str, float]]:
    """Every job on ``pool``, at most ``in_flight`` at once; results in job order."""
    results: list[Any] = [None] * len(jobs)
    pending: dict[Future, int] = {}
    queue = iter(enumerate(jobs))

    def submit_next() -> None:
        for i, cfg in itertools.islice(queue, 1):
            pending[pool.submit(_run_one, cfg, memory_budget)] = i

    for _ in range(in_flight):
        submit_next()
    try:
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                results[pending.pop(f)] = f.result()
                bar.update(1)
                submit_next()
    finally:
        for f in pending:
            f.cancel()
    return results


def _points(grid: Mapping[str, Sequence[Any]]) -> list[dict[str, Any]]:
    keys = list(grid)
    for k in keys:
        if isinstance(grid[k], (str, bytes)) or not isinstance(grid[k], Iterable):
            raise ConfigError(f"grid.{k}", f"give a list of values to sweep, got {grid[k]!r}")
    values = [list(grid[k]) for k in keys]
    for k, v in zip(keys, values):
        if not v:
            raise ConfigError(f"grid.{k}", "empty; give at least one value")
    return [dict(zip(keys, combo)) for combo in itertools.product(*values)]


def sweep(
    base_config: ScenarioConfig,
    grid: Mapping[str, Sequence[Any]] | None = None,
    seeds: Iterable[int] = range(12),
    executor: Executor | None = None,
    *,
    progress: bool | None = None,
    workers: int | None = None,
    memory_budget: int | None = None,
) -> pandas.DataFrame:
    """Runs ``base_config`` at every grid point for every seed.

    Arguments:
        base_config: the configuration to vary (not modified).
        grid: dotted path -> values; the cartesian product is run. A seed
            field (:data:`SEED_FIELDS`) is swept like any other.
        seeds: trial seeds; each sets every seed field the grid does not:
            ``world.seed`` (= seed), ``robot.seed`` (= seed +
            ``ROBOT_SEED_OFFSET``) and ``partner.integration.seed`` (= seed +
            ``PARTNER_SEED_OFFSET``, with a goal-integrating partner).
        executor: any ``concurrent.futures.Executor`` (e.g. a Dask
            ``distributed.Client(...).get_executor()``); default: a thread pool
            with ``workers`` threads.
        progress: show a progress bar (default: on a terminal, and in
            Jupyter, as a widget if ipywidgets is installed, else as text).
        workers: threads of the default pool (default: one per core).
        memory_budget: the most bytes the logs of the trials running at once
            may take (default: half of the memory available on this
            machine); fewer trials then run at once. Each trial is also
            checked where it runs (a Dask worker: against its own memory).

    Returns:
        A DataFrame with one row per trial: the swept values, ``seed``, and the
        metrics of :func:`trial_metrics`; rows in grid-then-seed order.

    Raises:
        ConfigError: a grid key names no field, a swept value is invalid
            (named like ``partner.gains[2]: ...``), or the grid sets every
            seed of the trial and more than one seed is given, before any
            trial runs.
        TrialTooLargeError: a trial's log would not fit the memory budget
            (a ``ConfigError``), before any trial runs.
    """
    import pandas as pd

    from sensaug._jupyter import bar as progress_bar

    points = _points(grid or {})
    seed_list = [int(s) for s in seeds]
    if not seed_list:
        raise ConfigError("seeds", "empty; give at least one seed")
    if workers is not None and workers < 1:
        raise ValueError(f"workers: must be >= 1, got {workers}")
    jobs: list[tuple[dict[str, Any], int, str]] = []
    for point in points:
        for seed in seed_list:
            cfg = copy.deepcopy(base_config)
            for path, value in point.items():
                set_path(cfg, path, value)
            seeded = _seeded_fields(cfg, point)
            if not seeded and len(seed_list) > 1:
                raise ConfigError(
                    "seeds",
                    f"the grid sets every seed of the trial ({', '.join(k for k in point if _canonical(k) in SEED_FIELDS)}), "
                    f"so {len(seed_list)} seeds would repeat identical trials; give one seed (seeds=[0], --seeds 1)"
                )
            _seed(cfg, seeded, seed)
            cfg.validate()
            jobs.append((point, seed, cfg))

    configs = [cfg for _, _, cfg in jobs]
    in_flight = _in_flight(configs, memory_budget)
    own = executor is None
    pool = ThreadPoolExecutor(max_workers=min(in_flight, workers or os.cpu_count() or 1)) if own else executor
    try:
        bar = progress_bar(total=len(jobs), desc="sweep", unit="trial", progress=progress)
        results = _run_all(pool, configs, in_flight, memory_budget, bar)
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
