"""Run whole trials and read their logs as numpy arrays.

``run(config)`` hands the configuration :class:`~sensaug.config.ScenarioConfig`
resolved (``config.resolved()``: LQR weights to gains, covariances to
matrices, once per configuration) to Rust, where the core runs the whole
trial in one call and the log's metadata is built; it returns a
:class:`Trial`: a log of the one schema
(``sensaug.logs``, ``docs/logs.md``) plus the configuration that produced it.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, overload

import numpy as np

if TYPE_CHECKING:
    import pandas
    from matplotlib.figure import Figure

from sensaug import _core, logs, metrics
from sensaug.config import ConfigError, ScenarioConfig

__all__ = ["Trial", "run", "trial_memory", "TrialTooLargeError", "FIELDS", "PHASE_KINDS", "PLOT_KINDS"]


class TrialTooLargeError(ConfigError):
    """Raised by :func:`run` (and ``sweep``) before a trial whose log would
    not fit in memory (the core raises it: ``phases[*].duration_s,
    plant.dt_s`` and the fix)."""


#: Column names of ``Trial.data`` (the one log schema, ``sensaug.logs``).
FIELDS: tuple[str, ...] = logs.COLUMNS


#: The phase kinds, in the order of their codes in logs.
PHASE_KINDS: tuple[str, ...] = ("gains", "trajectory", "integration")

#: What :meth:`Trial.plot` draws.
PLOT_KINDS: tuple[str, ...] = ("trajectories", "gains", "trajectory", "integration")

#: The partner's gains as the paper writes them: on position, velocity, its target.
GAIN_SYMBOLS: tuple[str, ...] = ("L_hx", "L_hv", "L_hh")


def _fmt(values: Any) -> str:
    return "[" + ", ".join(f"{v:.4g}" for v in values) + "]"


@dataclass(repr=False)
class Trial(logs.Log):
    """One trial's log and the configuration that produced it.

    ``data`` is a structured array (one record per tick) with the columns of
    the one log schema (:data:`FIELDS`, ``docs/logs.md``); ``trial["x"]`` is a
    column; ``meta`` holds the configuration, versions and units. ``phase``
    is an integer code, its names in ``meta["phase_names"]`` (0 gains,
    1 trajectory, 2 integration). Estimates a phase does not produce are NaN.
    ``save(path)`` writes the log file, ``Trial.load(path)`` reads it back.
    """

    config: ScenarioConfig = None  # type: ignore[assignment]
    summary: dict[str, Any] = field(default_factory=dict)
    robot_gains: np.ndarray = field(default_factory=lambda: np.zeros(3))
    partner_gains: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def load(cls, path: str | Path) -> "Trial":
        """A trial from a log file (``Trial.save`` or a rig log): the
        configuration rebuilt from its metadata, the summary from its end line."""
        log = logs.load_log(path)
        try:
            config = ScenarioConfig.from_dict(log.meta["config"])
        except (KeyError, TypeError) as e:
            raise ValueError(f"{path}: metadata has no usable configuration ({e})") from None
        resolved = log.meta.get("resolved") or {}
        return cls(
            data=log.data,
            meta=log.meta,
            verified=log.verified,
            config=config,
            summary=dict(log.meta.get("end") or {}),
            robot_gains=np.asarray(resolved.get("robot", {}).get("gains", np.zeros(3)), dtype=float),
            partner_gains=np.asarray(resolved.get("partner", {}).get("gains", np.zeros(3)), dtype=float),
        )

    def phase_mask(self, index: int, *, last_s: float | None = None, skip_s: float = 0.0) -> np.ndarray:
        """Ticks of phase ``index`` (position in ``config.phases``), optionally
        only its last ``last_s`` seconds or without its first ``skip_s``."""
        if not 0 <= index < len(self.config.phases):
            raise ValueError(f"index: phase {index} does not exist (trial has {len(self.config.phases)})")
        t = self.data["t"]
        dt = self.config.plant.dt_s
        start = sum(p.duration_s for p in self.config.phases[:index])
        end = start + self.config.phases[index].duration_s
        lo = start + skip_s if last_s is None else end - last_s
        return (t >= lo - dt / 2) & (t < end - dt / 2)

    def phases_of(self, kind: str) -> list[int]:
        """Indices of the phases of ``kind`` ('gains', 'trajectory', 'integration')."""
        if kind not in PHASE_KINDS:
            raise ValueError(f"kind: must be one of {PHASE_KINDS}, got {kind!r}")
        return [i for i, p in enumerate(self.config.phases) if p.kind == kind]

    # --- the paper's headline numbers --------------------------------------

    def gain_estimate(self, index: int | None = None, *, last_s: float = 8.0) -> np.ndarray:
        """Mean estimated partner gains ``[Lhx, Lhv, Lhh]`` over the last
        ``last_s`` of a gain phase (the paper reports the final 8 s)."""
        return metrics.gain_estimate(self.data, self.phase_mask(self._default(index, "gains"), last_s=last_s))

    def partner_target_rmse(self, index: int | None = None, *, skip_s: float = 2.0) -> float:
        """RMSE of ``tau_h^`` against ``tau_h`` in a trajectory phase, after ``skip_s``."""
        return metrics.partner_target_rmse(self.data, self.phase_mask(self._default(index, "trajectory"), skip_s=skip_s))

    def integration_rmse(self, index: int | None = None, *, skip_s: float = 2.0) -> dict[str, float]:
        """RMSE of the robot's ``(x - tau)^`` against the true ``x - tau`` in an
        integration phase: raw measurement, own sensing only, integrated."""
        return metrics.integration_rmse(self.data, self.phase_mask(self._default(index, "integration"), skip_s=skip_s))

    def metrics(self) -> pandas.DataFrame:
        """The paper's metrics of every phase, one row each, with its unit and
        window: the gain estimates (mean over the last 8 s, or the whole
        phase when shorter), the partner-target RMSE and the goal-integration
        RMSEs (after the first 2 s, or half the phase when shorter).
        ``sensaug run`` prints this table."""
        import pandas as pd

        units = self.units
        rows: list[dict[str, Any]] = []
        for i, phase in enumerate(self.config.phases):
            at = {"phase": i, "kind": phase.kind}
            if phase.kind == "gains":
                window = min(8.0, phase.duration_s)
                est = self.gain_estimate(i, last_s=window)
                for name, col, true, e in zip(GAIN_SYMBOLS, metrics.GAIN_FIELDS, self.partner_gains, est):
                    rows.append({**at, "quantity": f"partner gain {name}", "unit": units[col],
                                 "window": f"last {window:g} s", "true": float(true), "estimate": float(e)})
                continue
            skip = min(2.0, phase.duration_s / 2)
            window = f"after {skip:g} s"
            if phase.kind == "trajectory":
                rows.append({**at, "quantity": "RMSE of the partner-target estimate", "unit": units["tau_h_hat"],
                             "window": window, "true": np.nan, "estimate": self.partner_target_rmse(i, skip_s=skip)})
            else:
                r = self.integration_rmse(i, skip_s=skip)
                for key, what in (("measured", "measured"), ("own", "own sensing only"),
                                  ("integrated", "with goal integration")):
                    rows.append({**at, "quantity": f"RMSE of x - tau, {what}", "unit": units["e_meas"],
                                 "window": window, "true": np.nan, "estimate": r[key]})
        return pd.DataFrame(rows, columns=["phase", "kind", "quantity", "unit", "window", "true", "estimate"])

    def _repr_html_(self) -> str:
        import html

        return (
            f"<p>{html.escape(repr(self))}; partner gains {_fmt(self.partner_gains)}; columns: <code>trial[\"x\"]</code>, "
            f"plots: <code>trial.plot(kind)</code> ({', '.join(PLOT_KINDS)})</p>"
            + self.metrics().to_html(index=False, float_format=lambda v: f"{v:.4g}", na_rep="")
        )

    @overload
    def plot(self, kind: Literal["all"] = "all") -> list[Figure]: ...
    @overload
    def plot(self, kind: Literal["trajectories", "gains", "trajectory", "integration"]) -> Figure: ...

    def plot(self, kind: str = "all") -> Figure | list[Figure]:
        """The quick-look plots (``sensaug.plots``) as matplotlib Figures:
        ``"trajectories"``, ``"gains"``, ``"trajectory"``, ``"integration"``
        (one Figure; the first phase of that kind) or ``"all"`` (a list, one
        per plot ``sensaug run``, ``paper`` and ``demo`` write). In Jupyter a
        Figure shows itself; elsewhere ``fig.savefig("x.png")``."""
        from sensaug import _jupyter, plots

        _jupyter.show_figures_inline()
        if kind == "all":
            return plots.trial_figures(self)
        if kind not in PLOT_KINDS:
            raise ValueError(f"kind: must be one of {('all', *PLOT_KINDS)}, got {kind!r}")
        return plots.trial_figure(self, kind)

    def _default(self, index: int | None, kind: str) -> int:
        if index is not None:
            return index
        found = self.phases_of(kind)
        if not found:
            raise ValueError(f"index: this trial has no {kind!r} phase")
        return found[0]


def trial_memory(config: ScenarioConfig) -> int:
    """Bytes the log of ``config``'s trial takes in memory (one record per
    tick, as :func:`run` keeps it), computed by the core from the
    configuration, as ``run`` checks it."""
    return config.resolved().trial_memory(memory_budget=None)[1]


@functools.lru_cache(maxsize=1)
def _git_commit() -> str | None:
    """The git commit of this package's checkout (looked up once per process)."""
    return _core.git_commit(str(Path(__file__).resolve().parent))


def run(config: ScenarioConfig, *, memory_budget: int | None = None) -> Trial:
    """Runs one whole trial in the compiled core and returns its log.

    The log is kept whole in memory (one record of ``logs.DTYPE`` per tick),
    so its size is checked before the trial runs.

    Arguments:
        config: the trial.
        memory_budget: the most bytes the log may take; default: half of the
            memory available (``_core.available_memory()``).

    Raises:
        TrialTooLargeError: the log would not fit (a ``ConfigError`` naming
            ``phases[*].duration_s`` and ``plant.dt_s`` and the fix), before
            anything runs.
    """
    records, summary, meta = _core.run_scenario(config.resolved(), memory_budget=memory_budget, git_commit=_git_commit())
    summary = dict(summary)
    meta["end"] = summary
    return Trial(
        data=logs.from_records(records),
        meta=meta,
        config=config,
        summary=summary,
        robot_gains=np.asarray(meta["resolved"]["robot"]["gains"], dtype=float),
        partner_gains=np.asarray(meta["resolved"]["partner"]["gains"], dtype=float),
    )
