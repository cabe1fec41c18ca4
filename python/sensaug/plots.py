"""Plots of a trial, written as PNG files.

Figures are built as :class:`matplotlib.figure.Figure` objects without
pyplot, so importing this module selects no backend and saving works headless.
"""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure

from sensaug.experiment import Trial

__all__ = ["write_trial_plots", "write_rig_plots"]


def write_trial_plots(trial: Trial, folder: Path, *, prefix: str) -> list[Path]:
    """One figure per phase kind present: positions and targets, gain
    estimates, partner-target estimate, goal-integration estimates."""
    folder = Path(folder)
    t = trial["t"]
    written: list[Path] = []

    fig, ax = _subplots()
    ax.plot(t, trial["tau"], lw=0.8, label="robot target tau")
    ax.plot(t, trial["tau_h"], "--", lw=0.8, label="partner target tau_h")
    ax.plot(t, trial["x"], lw=1.0, label="handle x")
    ax.set(xlabel="t (s)", ylabel="position", title=f"{prefix}: trajectories")
    ax.legend(loc="upper right", fontsize=8)
    written.append(_save(fig, folder / f"{prefix}_trajectories.png"))

    for i in trial.phases_of("gains"):
        m = trial.phase_mask(i)
        fig, ax = _subplots()
        for f, true in zip(("Lhx_hat", "Lhv_hat", "Lhh_hat"), trial.partner_gains):
            line = ax.plot(t[m], trial[f][m], lw=0.8, label=f)[0]
            ax.axhline(true, color=line.get_color(), ls=":", lw=1.0)
        ax.set(xlabel="t (s)", ylabel="gain", title=f"{prefix}: partner gain estimates (dotted: truth)")
        ax.legend(loc="upper right", fontsize=8)
        written.append(_save(fig, folder / f"{prefix}_gains_phase{i}.png"))

    for i in trial.phases_of("trajectory"):
        m = trial.phase_mask(i)
        fig, ax = _subplots()
        ax.plot(t[m], trial["tau_h"][m], "r--", lw=1.0, label="tau_h (true)")
        ax.plot(t[m], trial["tau_h_hat"][m], "k", lw=0.8, label="tau_h^ (robot's estimate)")
        ax.set(xlabel="t (s)", ylabel="position", title=f"{prefix}: partner target estimate")
        ax.legend(loc="upper right", fontsize=8)
        written.append(_save(fig, folder / f"{prefix}_trajectory_phase{i}.png"))

    for i in trial.phases_of("integration"):
        m = trial.phase_mask(i)
        fig, ax = _subplots()
        ax.plot(t[m], trial["e_meas"][m], ".", ms=1, color="0.7", label="measured x - tau")
        ax.plot(t[m], trial["e_hat_own"][m], lw=0.8, label="own sensing only")
        ax.plot(t[m], trial["e"][m], "k", lw=1.6, label="true x - tau")
        ax.plot(t[m], trial["e_hat_fused"][m], lw=0.8, color="tab:orange", label="with goal integration")
        ax.set(xlabel="t (s)", ylabel="x - tau", title=f"{prefix}: goal integration")
        ax.legend(loc="upper right", fontsize=8)
        written.append(_save(fig, folder / f"{prefix}_integration_phase{i}.png"))
    return written


def _subplots(figsize: tuple[float, float] = (9, 3.5)):
    fig = Figure(figsize=figsize)
    return fig, fig.subplots()


def _save(fig: Figure, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


#: The files :func:`write_rig_plots` writes into its folder.
RIG_PLOTS = ("rig_gains.png", "rig_trajectory.png", "rig_integration.png", "rig_timing.png")


def write_rig_plots(run, folder: Path) -> list[Path]:
    """Plots of a virtual-rig run (``sensaug.rig.RigRun``): gains, partner
    target, goal integration, and the loop's wake-up latency."""
    folder = Path(folder)
    d = run.log
    t = d["t"]
    written: list[Path] = []
    true = run.stats["partner_gains_true"]

    m = run.phase_mask("gains")
    fig, ax = _subplots()
    for f, tr in zip(("Lhx_hat", "Lhv_hat", "Lhh_hat"), true):
        line = ax.plot(t[m], d[f][m], lw=0.8, label=f)[0]
        ax.axhline(tr, color=line.get_color(), ls=":", lw=1.0)
    ax.set(xlabel="t (s)", ylabel="gain", title="rig: partner gain estimates (dotted: truth)")
    ax.legend(loc="upper right", fontsize=8)
    written.append(_save(fig, folder / RIG_PLOTS[0]))

    m = run.phase_mask("trajectory")
    fig, ax = _subplots()
    ax.plot(t[m], d["tau_h"][m], "r--", lw=1.0, label="tau_h (true)")
    ax.plot(t[m], d["tau_h_hat"][m], "k", lw=0.8, label="tau_h^ (robot's estimate)")
    ax.set(xlabel="t (s)", ylabel="position (deg)", title="rig: partner target estimate")
    ax.legend(loc="upper right", fontsize=8)
    written.append(_save(fig, folder / RIG_PLOTS[1]))

    m = run.phase_mask("integration")
    fig, ax = _subplots()
    ax.plot(t[m], d["e_meas"][m], ".", ms=1, color="0.7", label="measured x - tau")
    ax.plot(t[m], d["e_hat_own"][m], lw=0.8, label="without integration")
    ax.plot(t[m], d["x"][m] - d["tau"][m], "k", lw=1.6, label="true x - tau")
    ax.plot(t[m], d["e_hat_fused"][m], lw=0.8, color="tab:orange", label="with integration")
    ax.set(xlabel="t (s)", ylabel="x - tau (deg)", title="rig: goal integration")
    ax.legend(loc="upper right", fontsize=8)
    written.append(_save(fig, folder / RIG_PLOTS[2]))

    fig, ax = _subplots()
    ax.hist(d["wake_latency_us"], bins=200, log=True, color="tab:blue", alpha=0.7, label="wake-up latency")
    ax.hist(d["compute_us"], bins=200, log=True, color="tab:orange", alpha=0.7, label="tick compute")
    ax.set(xlabel="us", ylabel="ticks", title="rig: loop timing")
    ax.legend(loc="upper right", fontsize=8)
    written.append(_save(fig, folder / RIG_PLOTS[3]))
    return written
