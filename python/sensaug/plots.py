"""Quick-look plots of a trial or a rig run, as matplotlib Figures.

``Trial.plot(kind)`` returns them (Jupyter shows a Figure by itself);
``write_trial_plots`` and ``write_rig_plots`` save them as the PNG files
``sensaug paper``, ``run`` and ``demo`` write. One name per curve everywhere
(the paper's symbols), every axis with its unit (the log's), legends beside
the axes, never over the data. A gain estimate starts far from the truth: the
y-range shows the converged part (the last 3/4 of the phase and the truth)
and the shaded start marks the transient whose values leave the range.

Figures are built without pyplot, so importing this module selects no
backend and saving works headless.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Optional

import numpy as np
from matplotlib.figure import Figure

from sensaug.logs import Log

if TYPE_CHECKING:
    from sensaug.experiment import Trial
    from sensaug.rig import RigRun

__all__ = [
    "gains_figure",
    "integration_figure",
    "timing_figure",
    "trajectories_figure",
    "trajectory_figure",
    "trial_figure",
    "trial_figures",
    "write_rig_plots",
    "write_trial_plots",
    "RIG_PLOTS",
]

#: Each curve's one name (mathtext), in every plot.
NAMES = {
    "x": "handle $x$",
    "tau": "robot target $\\tau$",
    "tau_h": "partner target $\\tau_h$",
    "tau_h_hat": "robot's estimate $\\hat\\tau_h$",
    "Lhx_hat": "$\\hat L_{hx}$",
    "Lhv_hat": "$\\hat L_{hv}$",
    "Lhh_hat": "$\\hat L_{hh}$",
    "e": "true $x - \\tau$",
    "e_meas": "measured",
    "e_hat_own": "own sensing only",
    "e_hat_fused": "with goal integration",
}

#: The part of a gain phase whose estimates set the y-range (its last 3/4).
CONVERGED_FRACTION = 0.75


def _unit(log: Log, column: str) -> str:
    return log.units.get(column, "")


def _new(figsize: tuple[float, float] = (10, 3.6)):
    fig = Figure(figsize=figsize, layout="constrained")
    return fig, fig.subplots()


def _legend(ax) -> None:
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)


def trajectories_figure(log: Log, title: str) -> Figure:
    """The handle and both targets over the whole run."""
    fig, ax = _new()
    t = log["t"]
    ax.plot(t, log["tau"], lw=0.8, label=NAMES["tau"])
    ax.plot(t, log["tau_h"], "--", lw=0.8, label=NAMES["tau_h"])
    ax.plot(t, log["x"], lw=1.0, label=NAMES["x"])
    ax.set(xlabel="t (s)", ylabel=f"position ({_unit(log, 'x')})", title=f"{title}: trajectories")
    _mark_phases(ax, log)
    _legend(ax)
    return fig


def _mark_phases(ax, log: Log) -> None:
    """A thin line where each phase begins, its name under the top edge."""
    phase, t = log["phase"], log["t"]
    names = log.meta.get("phase_names", [])
    starts = [0, *(np.flatnonzero(np.diff(phase)) + 1)] if len(phase) else []
    for i in starts:
        if 0 <= phase[i] < len(names):
            ax.axvline(t[i], color="0.6", lw=0.6)
            ax.text(t[i], 0.98, f" {names[phase[i]]}", transform=ax.get_xaxis_transform(), va="top", fontsize=7,
                    color="0.4")


def gains_figure(log: Log, mask: np.ndarray, true_gains: Optional[np.ndarray], title: str) -> Figure:
    """The robot's estimates of the partner's gains (eq. gains) in one gain
    phase, each with its truth dotted in the same colour (``true_gains``
    None: a person, who has no true gain; only the estimates)."""
    fig, ax = _new()
    t = log["t"][mask]
    converged = t >= t[0] + (1 - CONVERGED_FRACTION) * (t[-1] - t[0]) if len(t) else t.astype(bool)
    shown = [] if true_gains is None else [np.asarray(true_gains, dtype=float)]
    for i, col in enumerate(("Lhx_hat", "Lhv_hat", "Lhh_hat")):
        y = log[col][mask]
        line = ax.plot(t, y, lw=0.8, label=f"{NAMES[col]} ({_unit(log, col)})")[0]
        if true_gains is not None:
            ax.axhline(true_gains[i], color=line.get_color(), ls=":", lw=1.2)
        shown.append(y[converged])
    if true_gains is not None:
        ax.plot([], [], color="0.3", ls=":", lw=1.2, label="truth (dotted)")
    values = np.concatenate(shown)
    values = values[np.isfinite(values)]
    if len(t) and values.size:
        lo, hi = values.min(), values.max()
        pad = 0.15 * max(hi - lo, 0.1 * max(abs(lo), abs(hi)), 1e-6)
        ax.set_ylim(lo - pad, hi + pad)
        ax.axvspan(t[0], t[~converged][-1] if (~converged).any() else t[0], color="0.9", zorder=0,
                   label="transient (may leave the range)")
    ax.set(xlabel="t (s)", ylabel="gain", title=f"{title}: the robot's estimates of the partner's gains")
    _legend(ax)
    return fig


def trajectory_figure(log: Log, mask: np.ndarray, title: str) -> Figure:
    """The partner's target and the robot's estimate of it in a trajectory phase."""
    fig, ax = _new()
    t = log["t"][mask]
    # The estimate under the truth: where they agree the dashed truth shows on it.
    ax.plot(t, log["tau_h_hat"][mask], color="0.2", lw=2.0, label=NAMES["tau_h_hat"])
    ax.plot(t, log["tau_h"][mask], "--", color="tab:red", lw=1.0, label=NAMES["tau_h"])
    ax.set(xlabel="t (s)", ylabel=f"position ({_unit(log, 'tau_h')})", title=f"{title}: partner target estimate")
    _legend(ax)
    return fig


def integration_figure(log: Log, mask: np.ndarray, title: str) -> Figure:
    """The robot's tracking error ``x - tau``: measured, estimated from its own
    sensing only, with goal integration, and the truth."""
    fig, ax = _new()
    t = log["t"][mask]
    ax.plot(t, log["e_meas"][mask], ".", ms=1, color="0.7", label=NAMES["e_meas"])
    ax.plot(t, log["e_hat_own"][mask], lw=0.8, color="tab:blue", label=NAMES["e_hat_own"])
    ax.plot(t, log["x"][mask] - log["tau"][mask], "k", lw=1.6, label=NAMES["e"])
    ax.plot(t, log["e_hat_fused"][mask], lw=0.8, color="tab:orange", label=NAMES["e_hat_fused"])
    ax.set(xlabel="t (s)", ylabel=f"$x - \\tau$ ({_unit(log, 'e_meas')})", title=f"{title}: goal integration")
    _legend(ax)
    return fig


def timing_figure(log: Log, deadline_us: float, title: str) -> Figure:
    """Histograms of the loop's wake-up latency and tick compute time, with
    the tick period (each tick's deadline)."""
    fig, ax = _new()
    ax.hist(log["wake_latency_us"], bins=200, log=True, color="tab:blue", alpha=0.7, label="wake-up latency")
    ax.hist(log["compute_us"], bins=200, log=True, color="tab:orange", alpha=0.7, label="tick compute")
    ax.axvline(deadline_us, color="r", lw=1.2, label=f"deadline: the {deadline_us / 1e3:g} ms tick period")
    ax.set(xlabel="time (µs)", ylabel="ticks", title=f"{title}: loop timing")
    _legend(ax)
    return fig


def trial_figure(trial: Trial, kind: str, index: int | None = None) -> Figure:
    """One quick-look plot of a simulated trial (``Trial.plot``): ``kind``
    of ``experiment.PLOT_KINDS``; ``index`` the phase (default the first of that kind)."""
    title = trial.meta.get("source", "trial")
    if kind == "trajectories":
        return trajectories_figure(trial, title)
    i = trial._default(index, kind)
    m = trial.phase_mask(i)
    name = f"{title}, phase {i}"
    if kind == "gains":
        return gains_figure(trial, m, trial.partner_gains, name)
    if kind == "trajectory":
        return trajectory_figure(trial, m, name)
    return integration_figure(trial, m, name)


def trial_figures(trial: Trial) -> list[Figure]:
    """Every quick-look plot of a trial: trajectories, then one per phase."""
    figs = [trajectories_figure(trial, trial.meta.get("source", "trial"))]
    for i, phase in enumerate(trial.config.phases):
        figs.append(trial_figure(trial, phase.kind, i))
    return figs


def _save(fig: Figure, path: Path) -> Path:
    fig.savefig(path, dpi=110)
    return path


#: The files :func:`write_rig_plots` writes into its folder.
RIG_PLOTS = ("rig_gains.png", "rig_trajectory.png", "rig_integration.png", "rig_timing.png")


def write_trial_plots(trial: Trial, folder: Path, *, prefix: str) -> list[Path]:
    """The quick-look plots as PNG files ``{prefix}_trajectories.png``,
    ``{prefix}_{kind}_phase{i}.png``."""
    folder = Path(folder)
    written = [_save(trajectories_figure(trial, prefix), folder / f"{prefix}_trajectories.png")]
    for i, phase in enumerate(trial.config.phases):
        m = trial.phase_mask(i)
        name = f"{prefix}, phase {i}"
        if phase.kind == "gains":
            fig = gains_figure(trial, m, trial.partner_gains, name)
        elif phase.kind == "trajectory":
            fig = trajectory_figure(trial, m, name)
        else:
            fig = integration_figure(trial, m, name)
        written.append(_save(fig, folder / f"{prefix}_{phase.kind}_phase{i}.png"))
    return written


def write_rig_plots(run: RigRun, folder: Path) -> list[Path]:
    """Plots of a virtual-rig run (``sensaug.rig.RigRun``): gains, partner
    target, goal integration, and the loop's timing against its deadline."""
    folder = Path(folder)
    log = run.log
    figures = (
        # A person has no true gain (docs/person.md): none is drawn.
        gains_figure(log, run.phase_mask("gains"),
                     np.asarray(run.stats["partner_gains_true"]) if run.config.rig.virtual_human else None, "rig"),
        trajectory_figure(log, run.phase_mask("trajectory"), "rig"),
        integration_figure(log, run.phase_mask("integration"), "rig"),
        timing_figure(log, run.config.plant.dt_s * 1e6, "rig"),
    )
    return [_save(fig, folder / name) for fig, name in zip(figures, RIG_PLOTS)]
