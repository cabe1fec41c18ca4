"""``sensaug export LOG --to mcap``: any sensaug log (a simulated trial, a rig
run, a session's trial) as an MCAP file that Foxglove and PlotJuggler open
(``docs/live.md``).

* One channel per topic of :data:`sensaug.topics.TOPICS` (every column of
  the log in exactly one), JSON messages with a JSON Schema per channel
  carrying each field's unit; a ``/run`` channel with the run's end status.
* Timestamps: the run's clock (``t``, s from tick 0) offset to its wall-clock
  start (``meta.start_unix_s``), in ns since the Unix epoch — never from
  epoch 0, which Foxglove rejects (foxglove/mcap #1296). A log without a
  start time takes its file's modification time less the run's duration
  (said in the file's ``sensaug`` metadata record, ``start_time_source``).
* The log's metadata as MCAP metadata records (``sensaug``: scalar keys;
  ``config``: the configuration as JSON text) and as attachments
  (``meta.json``, ``config.json``, ``config.toml`` when the configuration
  rebuilds), so `mcap info`/Foxglove show them.

Written with the Foxglove SDK's MCAP writer (Rust; the Python ``mcap``
writer took ~4x longer on a 40 000-tick trial); read back in the tests with
the ``mcap`` package's reader, an independent implementation.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from sensaug import logs, topics
from sensaug.logs import Log, load_log

__all__ = ["RUN_TOPIC", "RUN_SCHEMA", "start_unix_ns", "to_mcap", "log_time_ns"]

#: The run's status: its source, and at the last tick, the end status.
RUN_TOPIC = "/run"
RUN_SCHEMA = {
    "title": "sensaug.run",
    "description": "the run: source, and the end status after the last tick (stop_reason; absent after a crash)",
    "type": "object",
    "properties": {
        "tick": {"type": "integer", "description": "tick number [1]"},
        "t": {"type": "number", "description": "time of the tick [s]"},
        "source": {"type": "string", "description": "simulation or rig"},
        "status": {"type": "string", "description": "running, ended (end line present) or no end line (a crash)"},
        "stop_reason": {"type": ["string", "null"], "description": "why the run stopped (rig), null in simulations"},
        "end": {"type": ["object", "null"], "description": "the log's end line"},
    },
}
_MEDIA_JSON = "application/json"


def start_unix_ns(log: Log, path: Path | None = None) -> tuple[int, str]:
    """The run's wall-clock start (ns since the epoch) and where it came from."""
    start = log.meta.get("start_unix_s")
    if isinstance(start, (int, float)) and start > 0:
        return int(round(start * 1e9)), "meta.start_unix_s"
    if path is None:
        raise ValueError("meta.start_unix_s: missing or not > 0 and no file to date the run by; set log.meta['start_unix_s']")
    duration = float(log["t"][-1]) if len(log) else 0.0
    return int(round((path.stat().st_mtime - duration) * 1e9)), "file modification time less the run's duration"


def log_time_ns(start_ns: int, t) -> object:
    """``start_ns`` plus the run's clock ``t`` (s), in ns (scalar or array)."""
    import numpy as np

    return start_ns + np.round(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64)


def _scalar_meta(meta: dict) -> dict[str, str]:
    return {k: (v if isinstance(v, str) else json.dumps(v)) for k, v in meta.items() if not isinstance(v, (dict, list))}


def _run_message(log: Log, tick: int, t: float, ended: bool) -> bytes:
    end = log.meta.get("end") if ended else None
    status = ("ended" if log.complete else "no end line") if ended else "running"
    msg = {"tick": tick, "t": t, "source": log.meta.get("source", "?"), "status": status,
           "stop_reason": (end or {}).get("stop_reason"), "end": end}
    return logs.to_json(msg).encode()


def to_mcap(log: Log | str | Path, out: str | Path) -> Path:
    """Writes ``log`` (a :class:`Log` or a log file) to ``out`` as MCAP (zstd
    chunks; the Foxglove SDK's writer); the file appears at ``out`` only once
    complete."""
    import foxglove

    path = None
    if not isinstance(log, Log):
        path = Path(log)
        log = load_log(path)
    out = Path(out)
    start_ns, source = start_unix_ns(log, path)
    times = log_time_ns(start_ns, log["t"]).tolist()
    tmp = out.with_name(out.name + ".partial")
    # A context of its own: only this file's channels reach this writer (not
    # a live view's in the same process).
    ctx = foxglove.Context()
    writer = foxglove.open_mcap(tmp, allow_overwrite=True, context=ctx)
    try:
        channels = {}
        for topic in (*topics.TOPICS, None):
            name, schema = (RUN_TOPIC, RUN_SCHEMA) if topic is None else (topic.name, topics.json_schema(topic, units=log.units))
            units = {k: p["unit"] for k, p in schema["properties"].items() if "unit" in p}
            channels[name] = foxglove.Channel(name, schema=schema, context=ctx, metadata={"units": json.dumps(units)})
        for topic in topics.TOPICS:
            log_message = channels[topic.name].base.log
            for ns, data in zip(times, topics.messages(log.data, topic)):
                log_message(data, ns)
        if len(log):
            ticks = log["tick"]
            for i, ended in ((0, False), (len(log) - 1, True)):
                channels[RUN_TOPIC].log(_run_message(log, int(ticks[i]), float(log["t"][i]), ended), log_time=times[i])
        meta = {k: v for k, v in log.meta.items() if k != "columns"}
        writer.write_metadata("sensaug", {**_scalar_meta(meta), "start_time_source": source,
                                          "exported_from": str(path) if path else ""})
        writer.write_metadata("config", {"json": logs.to_json(log.meta.get("config"))})
        attach = [("meta.json", _MEDIA_JSON, logs.to_json(log.meta)),
                  ("config.json", _MEDIA_JSON, logs.to_json(log.meta.get("config")))]
        toml = _config_toml(log.meta.get("config"))
        if toml is not None:
            attach.append(("config.toml", "application/toml", toml))
        for name, media, text in attach:
            writer.attach(log_time=start_ns, create_time=start_ns, name=name, media_type=media, data=text.encode())
    finally:
        writer.close()
    os.replace(tmp, out)
    return out


def _config_toml(config: dict | None) -> str | None:
    """The configuration as TOML when it rebuilds as a ``ScenarioConfig``."""
    if not config:
        return None
    from sensaug.config import ScenarioConfig

    try:
        return ScenarioConfig.from_dict(config).to_toml()
    except (ValueError, TypeError, KeyError):
        return None
