"""Offline replay of a recorded trial through the robot's controller.

``replay(log, config=None)`` re-runs the robot's estimators and control law
over the measurements a log recorded (``x_meas``, ``xdot_meas`` and whether
each was ``fresh``) with the configuration it was recorded with, and returns
the log with the controller's columns (:data:`ESTIMATE_COLUMNS`) replaced by
the replayed ones. The core makes the very call the rig loop and the
simulation make online (``Robot::tick_at``: update with the measurement,
command, predict), so a replay reproduces the online columns bit for bit
(``docs/logs.md``, "Replay").
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sensaug import _core
from sensaug.config import ScenarioConfig
from sensaug.logs import UNKNOWN_INT, Log, load_log

__all__ = ["ESTIMATE_COLUMNS", "NEEDED_COLUMNS", "replay"]

#: The controller's columns a replay recomputes (everything else is copied).
ESTIMATE_COLUMNS: tuple[str, ...] = (
    "phase", "u", "e_meas",
    "Lhx_hat", "Lhv_hat", "Lhh_hat", "Lhx_var", "Lhv_var", "Lhh_var",
    "tau_h_hat", "tau_h_var",
    "e_hat_own", "e_hat_fused", "e_hat_own_var", "e_hat_fused_var", "partner_var",
)  # fmt: skip
#: The columns a replay reads: the measurement the robot received, whether
#: it was new that tick, the tick number, and the rig's controlled-stop flag (``ramp``).
NEEDED_COLUMNS: tuple[str, ...] = ("tick", "x_meas", "xdot_meas", "fresh", "ramp")


def _controlled_ticks(log: Log) -> int:
    """Ticks the controller ran: the rows before the first controlled-stop row.
    Checks the columns and that the ticks are 0, 1, 2... without gaps."""
    missing = [c for c in NEEDED_COLUMNS + ESTIMATE_COLUMNS if c not in log.columns]
    if missing:
        raise ValueError(
            f"log: missing column(s) {', '.join(missing)}; replay needs a log of the current "
            "schema (docs/logs.md), as written by sensaug-rt or Trial.save"
        )
    ticks = log["tick"]
    gaps = np.flatnonzero(ticks != np.arange(len(ticks)))
    if gaps.size:
        k = int(gaps[0])
        raise ValueError(
            f"log.tick: row {k} is tick {int(ticks[k])}, expected {k}; a log with missing ticks "
            "(ring overflow, edited file) cannot be replayed"
        )
    ramp = np.flatnonzero(log["ramp"])
    n = int(ramp[0]) if ramp.size else len(log)
    if ramp.size and not log["ramp"][n:].all():
        raise ValueError(f"log.ramp: controller ticks after the controlled stop began at tick {n}; the log is not one run")
    return n


def replay(log: str | Path | Log, config: ScenarioConfig | None = None) -> Log:
    """Re-runs the robot's controller over a recorded trial.

    Args:
        log: a log file's path, or a :class:`Log` (``load_log``, a ``Trial``).
        config: the configuration to replay with; default the one the log
            recorded (``log.meta["config"]``). Another configuration replays
            the same measurements through other estimator settings.

    Returns:
        A :class:`Log`: the input's rows with :data:`ESTIMATE_COLUMNS`
        recomputed. Rows of a rig's controlled stop (``ramp``; the controller did
        not run) keep ``phase`` -1 and NaN estimates, as the rig logs them.
        ``meta["replay"]`` holds the robot's counters (e.g.
        ``missing_measurements``, the ticks without a fresh measurement).

    Raises:
        ValueError: the log lacks a needed column, has missing ticks, is
            longer than the configuration's protocol, or its phases do not
            match the configuration's (the message names which).
        ConfigError: the configuration (given or recorded) is invalid.
    """
    if not isinstance(log, Log):
        log = load_log(log)
    n = _controlled_ticks(log)
    if config is None:
        if "config" not in log.meta:
            raise ValueError("log.meta: no 'config' recorded; pass config= (the configuration of the run)")
        config = ScenarioConfig.from_dict(log.meta["config"])
    d = log.data[:n]
    columns, counters = _core.replay_robot(
        config._toml(),
        np.ascontiguousarray(d["x_meas"], dtype=np.float64),
        np.ascontiguousarray(d["xdot_meas"], dtype=np.float64),
        np.ascontiguousarray(d["fresh"], dtype=np.bool_),
    )
    beyond = np.flatnonzero(columns["phase"] == UNKNOWN_INT)
    if beyond.size:
        raise ValueError(
            f"log: {n} controller ticks, but the configuration's protocol ends at tick {int(beyond[0])}; "
            "pass the configuration the log was recorded with"
        )
    recorded = d["phase"]
    differ = np.flatnonzero((recorded != UNKNOWN_INT) & (recorded != columns["phase"]))
    if differ.size:
        k = int(differ[0])
        raise ValueError(
            f"config: tick {k} is in phase {int(columns['phase'][k])} here but {int(recorded[k])} in the log; "
            "pass the configuration the log was recorded with"
        )
    data = log.data.copy()
    for c in ESTIMATE_COLUMNS:
        data[c][:n] = columns[c]
    meta = dict(log.meta)
    meta["replay"] = dict(counters, controller_ticks=n)
    return Log(data=data, meta=meta)
