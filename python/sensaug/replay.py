"""Offline replay of a recorded trial through the robot's controller.

``replay(log, config=None)`` re-runs the robot's estimators and control law
over the measurements a log recorded (``x_meas``, ``xdot_meas`` and whether
each was ``fresh``) with the configuration it was recorded with, and returns
the log with the controller's columns (:data:`ESTIMATE_COLUMNS`) replaced by
the replayed ones. The core makes the very call the rig loop and the
simulation make online (``Robot::tick_at``: update with the measurement,
command, predict; on a rig's log the prediction takes the torque the drive
applied for the robot, its ``u``), so a replay reproduces the online columns
bit for bit (``docs/logs.md``, "Replay").

The recorded configuration is checked before it is used: the log's
metadata carries the SHA-256 of the configuration the run had
(``config_sha256``, written with the log); a configuration edited since is
refused unless ``allow_edited_config=True`` says the lab knows.
"""

from __future__ import annotations

import copy
import warnings
from pathlib import Path

import numpy as np

from sensaug import _core
from sensaug.config import ScenarioConfig
from sensaug.logs import COLUMNS, SOURCES, UNKNOWN_INT, Log, UnverifiedLogWarning, from_records, load_log, to_json, to_records

__all__ = ["ESTIMATE_COLUMNS", "NEEDED_COLUMNS", "replay"]

#: The controller's columns a replay recomputes (everything else is copied):
#: the schema's columns the controller fills, in file order.
ESTIMATE_COLUMNS: tuple[str, ...] = tuple(c for c in COLUMNS if SOURCES[c] == "controller")
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


def _recorded_config(log: Log, allow_edited: bool) -> tuple[ScenarioConfig, bool | None]:
    """The configuration the log recorded, checked against the digest
    written with it; whether it matched (None: no digest to check)."""
    if "config" not in log.meta:
        raise ValueError("log.meta: no 'config' recorded; pass config= (the configuration of the run)")
    recorded = log.meta.get("config_sha256")
    config = log.meta["config"]
    now = _core.config_sha256(to_json(config))
    if recorded is None:
        config = _without_retired_fields(config)
        warnings.warn(
            "log.meta: no config_sha256 (a log written before format 2): the recorded configuration "
            "cannot be checked against the run's; replaying with it as it stands",
            UnverifiedLogWarning,
            stacklevel=3,
        )
        matches = None
    else:
        matches = recorded == now
        if not matches and not allow_edited:
            raise ValueError(
                f"log.meta.config: not the configuration the run was recorded with (its SHA-256 is "
                f"{now[:16]}..., the log recorded {str(recorded)[:16]}...): the metadata was edited "
                "after the run. Pass the run's configuration as config=, or allow_edited_config=True "
                "to replay with the edited one"
            )
        if not matches:
            warnings.warn(
                "log.meta.config: EDITED after the run (its SHA-256 differs from the recorded one); "
                "replaying with the edited configuration as asked (allow_edited_config=True)",
                UnverifiedLogWarning,
                stacklevel=3,
            )
    return ScenarioConfig.from_dict(config), matches


#: Settings a format-1 log may hold that later versions retired, and why a
#: replay may drop them (it never reads the rig's stop).
RETIRED_FIELDS = {
    "rig.ramp_down_s": "the open-loop ramp, replaced by the controlled stop (rig.stop_*; issue 17); the replay never reads it",
    "robot.stage3.partner_window_s": "the online channel variance's window, replaced by the adaptive channel "
    "(robot.stage3.channel; issue 22); the replay runs today's stage 3 with its defaults",
}


def _without_retired_fields(config: dict) -> dict:
    """``config`` without :data:`RETIRED_FIELDS` (a warning names each dropped)."""
    out = copy.deepcopy(config)
    for path, why in RETIRED_FIELDS.items():
        *tables, name = path.split(".")
        table = out
        for key in tables:
            table = table.get(key) if isinstance(table, dict) else None
        if isinstance(table, dict) and name in table:
            del table[name]
            warnings.warn(
                f"log.meta.config: {path} dropped: a setting of an older version ({why})",
                UnverifiedLogWarning,
                stacklevel=4,
            )
    return out


def replay(log: str | Path | Log, config: ScenarioConfig | None = None, *, allow_edited_config: bool = False) -> Log:
    """Re-runs the robot's controller over a recorded trial.

    Args:
        log: a log file's path (read with :func:`sensaug.load_log`, every
            checksum verified), or a :class:`Log` (``load_log``, a ``Trial``).
        config: the configuration to replay with; default the one the log
            recorded (``log.meta["config"]``), checked against the digest
            recorded with it (``meta["config_sha256"]``). Another
            configuration replays the same measurements through other
            estimator settings.
        allow_edited_config: replay with a recorded configuration that was
            edited after the run (its digest differs; for a file, its
            metadata line's checksum fails: the rows are still verified),
            with a warning, instead of refusing it.

    Returns:
        A :class:`Log`: the input's rows with :data:`ESTIMATE_COLUMNS`
        recomputed. Rows of a rig's controlled stop (``ramp``; the controller did
        not run) keep ``phase`` -1 and NaN estimates, as the rig logs them.
        ``meta["replay"]`` holds the robot's counters (e.g.
        ``missing_measurements``, the ticks without a fresh measurement).

    Raises:
        ValueError: the file is corrupted (``load_log``), the recorded
            configuration was edited (without ``allow_edited_config``), the
            log lacks a needed column, has missing ticks, is longer than the
            configuration's protocol, or its phases do not match the
            configuration's (the message names which).
        ConfigError: the configuration (given or recorded) is invalid.
    """
    if not isinstance(log, Log):
        log = load_log(log, edited_metadata_ok=allow_edited_config)
    n = _controlled_ticks(log)
    matches: bool | None = None
    if config is None:
        config, matches = _recorded_config(log, allow_edited_config)
    d = log.data[:n]
    records, counters = _core.replay_robot(
        config.resolved(),
        to_records(d),
        # A rig run's estimators predicted with the robot's part of the torque
        # the drive applied (its `u`), which no replayed command changes.
        applied_u=log.meta.get("source") == "rig",
    )
    columns = from_records(records)
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
    meta["replay"] = dict(counters, controller_ticks=n, recorded_config_verified=matches)
    return Log(data=data, meta=meta, verified=log.verified)
