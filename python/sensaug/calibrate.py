"""The handle identified: inertia M, viscous damping C and Coulomb friction
F_c from a bounded excitation on the rig (``sensaug calibrate``,
docs/hardware.md "Calibrating the handle").

The excitation is an ordinary rig run (:func:`excitation_config`): one gain
phase in which the robot and the virtual human both track a chirp inside the
soft window, under the configuration's own torque limit, range of motion,
controlled stop and every other check of ``sensaug-rt``; nobody holds the
handle. The friction compensation is off for it (the raw handle is what is
measured).

The identification (:func:`identify`) is linear least squares on the exact
zero-order-hold step of ``M dv/dt = u - C v - F_c sign(v)`` with the torque
``u`` held over a tick of ``dt``:

    v[k+1] = a v[k] + b u[k] - b F_c sign(v[k]),
    a = exp(-C dt / M),  b = (1 - a) / C   (b = dt / M when C = 0),

linear in ``theta = (a, b, b F_c)``. ``u`` is the torque the drive applied
(the log's ``torque_nm``: the command rounded to the drive's torque step),
``v`` the drive's velocity report. Pairs are used only when both feedbacks
are fresh and consecutive, and when the handle moves the same way at both
ends faster than ``min_speed_rad_s``: at rest stiction holds the handle and
through a reversal the friction's sign changes inside the step, and neither
is the model above. Back from ``theta``:

    C = (1 - a) / b,   M = dt (a - 1) / (b ln a),   F_c = theta_3 / b,

and 95% confidence intervals by the delta method on the least-squares
covariance ``s^2 (X^T X)^-1``.
"""

from __future__ import annotations

import json
import math
import os
import sys
import tomllib
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Optional

import numpy as np
import tomli_w

from sensaug.config import ScenarioConfig
from sensaug.config_types import Chirp, Constant, PhaseConfig
from sensaug.logs import Log

__all__ = [
    "Estimate", "HandleEstimate", "excitation_config", "identify", "identify_log", "regression_pairs",
    "write_fragment", "calibrated_config", "including_config", "friction_points", "plot_fit", "Z95",
    "CALIBRATED_KEYS",
]  # fmt: skip

#: The normal quantile of a two-sided 95% interval.
Z95 = 1.959963984540054

#: rad per degree.
RAD_PER_DEG = math.pi / 180.0


@dataclass(frozen=True)
class Estimate:
    """One identified parameter: its value and 95% confidence interval."""

    value: float
    low: float
    high: float

    def __str__(self) -> str:
        return f"{self.value:.6g} (95% CI {self.low:.6g} .. {self.high:.6g})"

    def covers(self, truth: float) -> bool:
        return self.low <= truth <= self.high


@dataclass(frozen=True)
class HandleEstimate:
    """The identified handle: ``mass`` (kg m^2), ``damping`` (C, N m s/rad),
    ``coulomb`` (F_c, N m), each with its 95% interval; ``pairs`` used,
    the residual std of the velocity step (rad/s), the step's ``a``, ``b``."""

    mass: Estimate
    damping: Estimate
    coulomb: Estimate
    pairs: int
    residual_std_rad_s: float
    a: float
    b: float
    dt_s: float
    notes: list[str] = field(default_factory=list)

    def summary(self) -> str:
        return (
            f"M   = {self.mass} kg m^2\n"
            f"C   = {self.damping} N m s/rad\n"
            f"F_c = {self.coulomb} N m\n"
            f"({self.pairs} tick pairs, velocity-step residual std {self.residual_std_rad_s:.3g} rad/s)"
        )


def regression_pairs(
    v_rad_s: np.ndarray, torque_nm: np.ndarray, usable: np.ndarray, *, min_speed_rad_s: float
) -> np.ndarray:
    """Indices ``k`` whose step ``k -> k+1`` fits the model: ``usable`` at
    both ends (fresh, consecutive feedback; the controller commanding),
    finite values, and ``v[k]``, ``v[k+1]`` of one sign, both faster than
    ``min_speed_rad_s`` (no stiction, no reversal inside the step)."""
    v0, v1 = v_rad_s[:-1], v_rad_s[1:]
    ok = usable[:-1] & usable[1:] & np.isfinite(v0) & np.isfinite(v1) & np.isfinite(torque_nm[:-1])
    ok &= (np.abs(v0) > min_speed_rad_s) & (np.abs(v1) > min_speed_rad_s) & (np.sign(v0) == np.sign(v1))
    return np.flatnonzero(ok)


def _physical(theta: np.ndarray, dt_s: float) -> np.ndarray:
    """``(a, b, b F_c) -> (M, C, F_c)`` of the exact ZOH step."""
    a, b, bf = theta
    c = (1.0 - a) / b
    # (a - 1) / ln a -> 1 as a -> 1 (C -> 0): M -> dt / b without a 0/0.
    ratio = 1.0 if a == 1.0 else (a - 1.0) / math.log(a)
    return np.array([dt_s * ratio / b, c, bf / b])


def identify(
    v_rad_s: np.ndarray,
    torque_nm: np.ndarray,
    dt_s: float,
    *,
    usable: Optional[np.ndarray] = None,
    min_speed_rad_s: float = 0.02,
) -> HandleEstimate:
    """M, C and F_c from velocities ``v_rad_s[k]`` (rad/s) and the torque
    ``torque_nm[k]`` (N m) held from tick k to k+1 (the module's docstring
    has the model). ``usable``: ticks whose velocity is a fresh measurement
    (default all).

    Raises:
        ValueError: too few usable pairs, or an excitation that does not
            determine the three parameters (no motion both ways, a constant
            torque), or an identified step that is not a stable handle.
    """
    v = np.asarray(v_rad_s, dtype=float)
    u = np.asarray(torque_nm, dtype=float)
    use = np.ones(len(v), dtype=bool) if usable is None else np.asarray(usable, dtype=bool)
    k = regression_pairs(v, u, use, min_speed_rad_s=min_speed_rad_s)
    if len(k) < 50:
        raise ValueError(
            f"calibration: only {len(k)} usable tick pairs (fresh feedback, moving faster than "
            f"{min_speed_rad_s} rad/s); the excitation did not move the handle enough: run it longer or "
            "check that the drive is enabled and the handle free"
        )
    X = np.column_stack([v[k], u[k], -np.sign(v[k])])
    y = v[k + 1]
    if np.all(X[:, 2] == X[0, 2]):
        raise ValueError("calibration: the handle moved one way only; the Coulomb friction needs motion both ways")
    theta, _, rank, _ = np.linalg.lstsq(X, y, rcond=None)
    if rank < 3:
        raise ValueError("calibration: the excitation does not determine M, C and F_c (rank-deficient regressors)")
    residual = y - X @ theta
    dof = len(y) - 3
    s2 = float(residual @ residual) / dof
    cov = s2 * np.linalg.inv(X.T @ X)
    a, b = float(theta[0]), float(theta[1])
    if not (0.0 < a and b > 0.0):
        raise ValueError(
            f"calibration: the identified step (a = {a:.6g}, b = {b:.6g}) is not a handle with positive "
            "inertia; check the log's torque sign against the velocity's (the drive's direction)"
        )
    est = _physical(theta, dt_s)
    # Delta method: the map's Jacobian by central differences (steps scaled
    # to each parameter's standard error).
    J = np.empty((3, 3))
    for j in range(3):
        h = max(math.sqrt(cov[j, j]), 1e-12 * max(abs(theta[j]), 1e-300)) * 1e-3
        up, down = theta.copy(), theta.copy()
        up[j] += h
        down[j] -= h
        J[:, j] = (_physical(up, dt_s) - _physical(down, dt_s)) / (2 * h)
    std = np.sqrt(np.maximum(np.diag(J @ cov @ J.T), 0.0))
    mass, damping, coulomb = (Estimate(float(e), float(e - Z95 * s), float(e + Z95 * s)) for e, s in zip(est, std))
    return HandleEstimate(mass=mass, damping=damping, coulomb=coulomb, pairs=len(k),
                          residual_std_rad_s=math.sqrt(s2), a=a, b=b, dt_s=dt_s)  # fmt: skip


def _log_signals(log: Log) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """A rig log's velocity (rad/s), applied torque ``torque_nm`` (N m), the
    ticks usable for the fit (the controller commanding, not the controlled
    stop, with fresh feedback, each row the tick after the one before) and
    the tick (s).

    Raises:
        ValueError: not a rig log.
    """
    loop = log.meta.get("loop")
    if not loop or "rad_per_unit" not in loop:
        raise ValueError("log: not a rig log (no loop settings in its metadata); give the rig_log.csv of a rig run")
    usable = log["fresh"].astype(bool) & ~log["ramp"].astype(bool) & (log["phase"] >= 0)
    usable[1:] &= np.diff(log["tick"].astype(np.int64)) == 1
    return log["xdot"] * float(loop["rad_per_unit"]), log["torque_nm"], usable, float(loop["dt_s"])


def identify_log(log: Log, *, min_speed_rad_s: float = 0.02) -> HandleEstimate:
    """:func:`identify` on a rig log (``sensaug.load_log`` of ``rig_log.csv``):
    the applied torque ``torque_nm`` and the velocity ``xdot`` (controller
    units, times the loop's ``rad_per_unit``), on the ticks where the
    controller commanded (not the controlled stop) with fresh feedback at
    consecutive ticks.

    Raises:
        ValueError: not a rig log, or as :func:`identify`.
    """
    v, u, usable, dt_s = _log_signals(log)
    return identify(v, u, dt_s, usable=usable, min_speed_rad_s=min_speed_rad_s)


def excitation_config(config: ScenarioConfig, *, duration_s: float = 20.0, seed: int = 0) -> ScenarioConfig:
    """The calibration run of ``config``'s rig: one gain phase of
    ``duration_s`` in which the robot and the virtual human both track a
    chirp (0.1 Hz up to ``f1``) about the soft window's centre, its amplitude
    the smaller of 15 deg and 40% of the half window, ``f1`` so that the
    target's peak speed is 40% of ``rig.range.soft_speed_deg_s``. Everything
    else is ``config``'s: drive, bus, torque limit, range, controlled stop,
    every check. The friction compensation is off (the raw handle is
    measured), the virtual human on (nobody holds the handle).

    Raises:
        ConfigError: the configuration (with the run's changes) is invalid.
    """
    cfg = ScenarioConfig.from_dict(config.to_dict())
    r = cfg.rig.range
    unit_per_deg = 1.0 if cfg.rig.position_unit == "deg" else RAD_PER_DEG
    centre_deg = 0.5 * (r.soft_min_deg + r.soft_max_deg)
    amplitude_deg = min(15.0, 0.4 * 0.5 * (r.soft_max_deg - r.soft_min_deg))
    f1_hz = 0.4 * r.soft_speed_deg_s / (2 * math.pi * amplitude_deg)
    target = [Constant(value=centre_deg * unit_per_deg),
              Chirp(amplitude=amplitude_deg * unit_per_deg, f0_hz=0.1, f1_hz=f1_hz, duration_s=duration_s)]
    cfg.phases = [PhaseConfig(kind="gains", duration_s=duration_s, robot_target=target, partner_target=list(target),
                              target_noise_std=0.0)]  # fmt: skip
    cfg.robot.gain_window_s = min(cfg.robot.gain_window_s, 0.5 * duration_s)
    cfg.robot.integrate = False
    cfg.world.seed = seed
    cfg.rig.virtual_human = True
    cfg.rig.friction.coulomb_nm = 0.0
    cfg.rig.friction.viscous_nm_s_per_rad = 0.0
    cfg.validate()
    return cfg


def friction_points(log: Log, est: HandleEstimate, *, min_speed_rad_s: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Each fitted pair's mean velocity over its tick, ``(v[k] + v[k+1]) /
    2`` (rad/s), and the friction torque it implies (N m): the applied
    torque less the identified inertia's share, ``u[k] - M (v[k+1] - v[k])
    / dt``. Integrating the model over the tick, that is ``C`` times the
    tick's mean velocity (the trapezoid's, to O(dt^2)) plus ``F_c
    sign(v)``: the points lie on the identified line when the model holds."""
    v, u, usable, _ = _log_signals(log)
    k = regression_pairs(v, u, usable, min_speed_rad_s=min_speed_rad_s)
    return 0.5 * (v[k] + v[k + 1]), u[k] - est.mass.value * (v[k + 1] - v[k]) / est.dt_s


def plot_fit(log: Log, est: HandleEstimate, path: str | Path) -> Path:
    """``path`` (PNG): the friction each fitted pair implies against the
    velocity, with the identified ``C v + F_c sign(v)`` (the model a lab
    checks: a Stribeck dip or a position-dependent friction shows as points
    off the line), and the excitation's position and torque over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    v, friction = friction_points(log, est)
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    step = max(1, len(v) // 4000)
    ax.plot(v[::step], friction[::step], ".", ms=3, alpha=0.6, color="tab:gray", label="each fitted tick pair", zorder=3)
    grid = np.linspace(v.min(), v.max(), 400)
    c, fc = est.damping.value, est.coulomb.value
    model = c * grid + fc * np.sign(grid)
    ax.plot(grid[grid < 0], model[grid < 0], color="tab:red", lw=1.0, ls="--", zorder=4,
            label=f"identified: C = {c:.4g} N m s/rad, F_c = {fc:.4g} N m")
    ax.plot(grid[grid > 0], model[grid > 0], color="tab:red", lw=1.0, ls="--", zorder=4)
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set_xlabel("velocity, mean over the tick (rad/s)")
    ax.set_ylabel("friction implied: u - M dv/dt (N m)")
    ax.set_title(f"Friction of the handle (M = {est.mass.value:.4g} kg m^2)")
    ax.legend(loc="upper left", fontsize=8)
    t = log["t"]
    bx.plot(t, log["x"], color="tab:blue", lw=0.8)
    bx.set_xlabel("time (s)")
    bx.set_ylabel(f"position ({log.units.get('x', 'pos')})", color="tab:blue")
    tx = bx.twinx()
    tx.plot(t, log["torque_nm"], color="tab:orange", lw=0.5)
    tx.set_ylabel("torque applied (N m)", color="tab:orange")
    bx.set_title("The run fitted (the excitation)")
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _compensation(est: HandleEstimate) -> tuple[float, float, list[str]]:
    """The compensation's (F_c, C) from the estimate: negative estimates
    (noise about zero) compensate nothing."""
    notes = []
    fc, c = est.coulomb.value, est.damping.value
    if fc < 0:
        notes.append(f"F_c identified {fc:.3g} N m < 0: compensated as 0")
    if c < 0:
        notes.append(f"C identified {c:.3g} N m s/rad < 0: compensated as 0")
    return max(fc, 0.0), max(c, 0.0), notes


def calibrated_config(config: ScenarioConfig, est: HandleEstimate) -> ScenarioConfig:
    """``config`` with the identified handle: ``plant.mass`` = M, and
    ``rig.friction`` compensating F_c and C (``plant.damping`` = 0: the
    model is the handle after compensation, as the paper's). In Python, for
    a trial or a sweep; on the rig a configuration includes the fragment
    (:func:`write_fragment`, :func:`including_config`).

    Raises:
        ConfigError: the result is refused (e.g. the compensation above the
            torque limit), naming the field.
    """
    fc, c, _ = _compensation(est)
    cfg = ScenarioConfig.from_dict(config.to_dict())
    cfg.plant.mass = est.mass.value
    cfg.plant.damping = 0.0
    cfg.rig.friction.coulomb_nm = fc
    cfg.rig.friction.viscous_nm_s_per_rad = c
    cfg.validate()
    return cfg


#: The settings the fragment gives (dotted keys): what was identified. A
#: rig configuration that includes the fragment leaves them out (a setting
#: comes from one file, docs/config.md "Includes"); the compensation's
#: bands stay the rig configuration's.
CALIBRATED_KEYS = ("plant.mass", "plant.damping", "rig.friction.coulomb_nm", "rig.friction.viscous_nm_s_per_rad")


def write_fragment(path: str | Path, est: HandleEstimate, *, source: str) -> Path:
    """The configuration fragment a rig configuration includes
    (``include = ["calibration.toml"]``): :data:`CALIBRATED_KEYS`, the
    estimates and their intervals as comments."""
    fc, c, notes = _compensation(est)
    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        f"# The handle identified by sensaug calibrate, {when}, from {source}",
        f"# ({est.pairs} tick pairs; least squares on the exact ZOH step, docs/hardware.md).",
        f"#   M   = {est.mass} kg m^2",
        f"#   C   = {est.damping} N m s/rad",
        f"#   F_c = {est.coulomb} N m",
        *(f"# {n}" for n in notes),
        "# A rig configuration includes this file: include = [\"<path to it>\"] (relative to the",
        "# including file), and sets none of these four itself; calibrated_config.toml next to",
        "# this file is one (docs/hardware.md, \"Calibrating the handle\").",
        "",
        "[plant]",
        f"mass = {est.mass.value!r}  # kg m^2, the handle's inertia",
        "damping = 0.0  # the model's C after compensation",
        "",
        "[rig.friction]",
        f"coulomb_nm = {fc!r}",
        f"viscous_nm_s_per_rad = {c!r}",
        "",
    ]
    path = Path(path)
    path.write_text("\n".join(lines))
    return path


def _read_tables(path: Path) -> dict[str, Any]:
    """A configuration file's own tables as written (its includes not
    merged, no defaults filled)."""
    text = path.read_text()
    return json.loads(text) if path.suffix.lower() == ".json" else tomllib.loads(text)


def _without(tables: dict[str, Any], dotted: str) -> bool:
    """Removes ``dotted`` from ``tables`` (and tables it leaves empty);
    whether it was there."""
    *parents, leaf = dotted.split(".")
    chain = [tables]
    for p in parents:
        nxt = chain[-1].get(p)
        if not isinstance(nxt, dict):
            return False
        chain.append(nxt)
    found = chain[-1].pop(leaf, None) is not None
    for i in reversed(range(len(parents))):
        if chain[i + 1]:
            break
        chain[i].pop(parents[i])
    return found


def including_config(config: ScenarioConfig, config_path: Optional[Path], fragment: Path, path: Path) -> Path:
    """Writes ``path``: the rig configuration that includes ``fragment``.
    Its settings are ``config_path``'s own as written (else ``config``'s
    tables) without :data:`CALIBRATED_KEYS`; its includes are the file's,
    re-pointed from ``path``'s folder, except an earlier fragment (a file
    that sets only calibrated keys), which the new one replaces. Read back
    by the one schema before it is kept.

    Raises:
        ConfigError: the written configuration is refused (e.g. a file it
            includes gives a calibrated setting too: the message names the
            setting and both files); ``path`` is then removed.
    """
    folder = path.parent.resolve()
    if config_path is None:
        tables, entries = config.to_dict(), []
        tables.pop("included", None)
    else:
        tables = _read_tables(config_path)
        tables.pop("included", None)
        entries, _ = _includes(config_path, tables.pop("include", []))
    for key in CALIBRATED_KEYS:
        _without(tables, key)
    include = [os.path.relpath(e.resolve(), folder) for e in entries] + [os.path.relpath(fragment.resolve(), folder)]
    path.write_text(
        f"# The rig configuration with the handle calibrated: {config_path or 'the hi5_rig preset'}'s settings\n"
        "# including the fragment (written by sensaug calibrate; docs/hardware.md).\n"
        + tomli_w.dumps({"include": include, **tables})
    )
    try:
        ScenarioConfig.from_toml(path)
    except ValueError:
        path.unlink()
        raise
    return path


def _includes(config_path: Path, entries: list[str]) -> tuple[list[Path], list[Path]]:
    """``config_path``'s include entries as paths: the other files, and the
    earlier fragments (files that set calibrated keys only)."""
    here = config_path.resolve().parent
    paths = [here / e for e in entries]
    return [p for p in paths if not _is_fragment(p)], [p for p in paths if _is_fragment(p)]


def _is_fragment(path: Path) -> bool:
    """Whether ``path`` sets calibrated keys only (an earlier fragment)."""
    try:
        tables = _read_tables(path)
    except (OSError, ValueError):
        return False  # the schema's read of the written file names the problem
    removed = [_without(tables, k) for k in CALIBRATED_KEYS]
    return any(removed) and not tables


def drive_handle_args(mass: float, damping: float, coulomb: float) -> list[str]:
    """The virtual drive's options simulating a handle (its hidden truth:
    passed to the drive process only, never to the loop's configuration)."""
    return ["--mass", repr(mass), "--damping", repr(damping), "--coulomb", repr(coulomb)]


def run_calibration(
    config: ScenarioConfig,
    *,
    out: str | Path,
    duration_s: float = 20.0,
    seed: int = 0,
    handle: Optional[tuple[float, float, float]] = None,
    port: Optional[int] = None,
    progress: Optional[bool] = False,
) -> tuple[HandleEstimate, Any]:
    """Runs the excitation on the virtual rig (``handle`` = (M, C, F_c) of
    the simulated handle, given to the virtual drive only; None: the
    drive's defaults) and identifies it; the estimate and the rig run.

    Raises:
        ValueError: as :func:`identify`, or the run stopped before enough data.
        RuntimeError: ``sensaug-rt`` failed to start.
    """
    from sensaug import rig

    cfg = excitation_config(config, duration_s=duration_s, seed=seed)
    extra = None if handle is None else drive_handle_args(*handle)
    run = rig.run_virtual_rig(cfg, out=out, port=port, capture=None, progress=progress, stop_key=None,
                              drive_args=extra)  # fmt: skip
    if run.returncode != 0:
        raise ValueError(
            f"calibration: the excitation run stopped: {run.stats.get('stop_reason')} (exit {run.returncode}); "
            f"its log is {Path(out) / 'rig_log.csv'}"
        )
    return identify_log(run.log), run


def command(
    config_path: Optional[Path],
    *,
    out: Path,
    duration_s: float,
    seed: int,
    log_path: Optional[Path],
    write_excitation: Optional[Path],
    virtual_handle: Optional[tuple[float, float, float]],
    port: Optional[int],
    progress: Optional[bool],
) -> int:
    """``sensaug calibrate``: the excitation on the virtual rig (or a rig
    log's, ``log_path``), the identified handle printed, the fragment
    ``out/calibration.toml`` and ``out/calibrated_config.toml`` (the rig
    configuration including it, :func:`including_config`) written, and the
    line that includes the fragment in ``config_path``;
    ``write_excitation``: only the excitation run's configuration, for
    ``sensaug-rt`` on a real rig."""
    from sensaug import presets
    from sensaug.logs import load_log

    config = ScenarioConfig.from_toml(config_path) if config_path else presets.hi5_rig()
    if write_excitation is not None:
        excitation_config(config, duration_s=duration_s, seed=seed).to_toml(write_excitation)
        print(f"excitation run -> {write_excitation}: run it on the rig with sensaug-rt, nobody holding the "
              f"handle, then: sensaug calibrate {config_path or ''} --log <its rig_log.csv>".replace("  ", " "))
        return 0
    out.mkdir(parents=True, exist_ok=True)
    if log_path is not None:
        est, source = identify_log(load_log(log_path)), str(log_path)
    else:
        truth = "the drive's defaults" if virtual_handle is None else (
            f"M = {virtual_handle[0]:g} kg m^2, C = {virtual_handle[1]:g} N m s/rad, F_c = {virtual_handle[2]:g} N m")
        print(f"sensaug calibrate: {duration_s:g} s of excitation on the virtual rig "
              f"({config.rig.drive} drive; its handle, given to the drive process only: {truth})", flush=True)
        est, _ = run_calibration(config, out=out, duration_s=duration_s, seed=seed, handle=virtual_handle, port=port,
                                 progress=progress)  # fmt: skip
        source = f"{out / 'rig_log.csv'} (virtual rig, seed {seed})"
    print(est.summary())
    log = load_log(log_path) if log_path is not None else load_log(out / "rig_log.csv")
    picture = plot_fit(log, est, out / "calibration.png")
    fragment = write_fragment(out / "calibration.toml", est, source=source)
    print(f"fragment: {fragment} ({', '.join(CALIBRATED_KEYS)}); the fit: {picture}")
    if config_path is not None:
        _, earlier = _includes(config_path, _read_tables(config_path).get("include", []))
        if earlier:
            print(f"{config_path} includes the earlier calibration {', '.join(map(str, earlier))}: copy {fragment} over "
                  "it to run with the new one")
        else:
            line = f"include = [{json.dumps(os.path.relpath(fragment.resolve(), config_path.resolve().parent))}]"
            print(f"to run {config_path} with it: add the line  {line}  at its top (or the path of the handle's "
                  "own copy of the fragment) and remove those four settings from it")
    try:
        full = including_config(config, config_path, fragment, out / "calibrated_config.toml")
    except ValueError as e:
        print(f"sensaug calibrate: calibrated_config.toml not written: {e}", file=sys.stderr)
        return 1
    print(f"the rig configuration including it: {full}")
    return 0
