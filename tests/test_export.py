"""``sensaug export LOG --to mcap``: read back with the ``mcap`` reader, every
channel checked against the CSV log (docs/live.md)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from mcap.reader import make_reader

from sensaug import experiment, logs, presets, topics
from sensaug.cli import main
from sensaug.export import RUN_TOPIC, to_mcap


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    trial = experiment.run(presets.hi5_experiment(2.0, seed=3, phase_s=1.0, target_noise_std=0.5))
    return trial.save(tmp_path_factory.mktemp("export") / "trial.csv")


def read_back(path):
    """Every message per topic (JSON decoded, with its log time), the
    schemas, channels, metadata and attachments."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        msgs: dict[str, list] = {}
        for schema, channel, message in reader.iter_messages():
            msgs.setdefault(channel.topic, []).append((message.log_time, json.loads(message.data)))
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        attachments = {a.name: a.data for a in reader.iter_attachments()}
    return summary, msgs, meta, attachments


def same(expected: np.ndarray, got: list) -> bool:
    """Equal value for value (the JSON is exact: shortest round-trip floats),
    null where the log has NaN or an infinity (JSON has neither; the rig's
    ``partner_var`` is inf while the partner channel is held out)."""
    for e, g in zip(expected.tolist(), got):
        if isinstance(e, float) and not math.isfinite(e):
            if g is not None:
                return False
        elif e != g:
            return False
    return len(expected) == len(got)


def check_against_log(mcap_path, log):
    summary, msgs, meta, attachments = read_back(mcap_path)
    start_ns = int(round(log.meta["start_unix_s"] * 1e9))
    covered = set()
    for topic in topics.TOPICS:
        got = msgs[topic.name]
        assert len(got) == len(log), topic.name
        times = np.array([ns for ns, _ in got])
        np.testing.assert_array_equal(times, start_ns + np.round(log["t"] * 1e9).astype(np.int64))
        for name in ("tick", "t", *topic.columns):
            assert same(log[name], [m[name] for _, m in got]), f"{topic.name}.{name} differs from the CSV"
        covered.update(topic.columns)
        # A schema per channel, with every field's unit.
        channel = next(c for c in summary.channels.values() if c.topic == topic.name)
        schema = json.loads(summary.schemas[channel.schema_id].data)
        assert summary.schemas[channel.schema_id].encoding == "jsonschema" and channel.message_encoding == "json"
        for name in topic.columns:
            assert schema["properties"][name]["unit"] == log.units[name]
    assert covered == set(logs.COLUMNS) - {"tick", "t"}, "every column is on a channel"
    # Never epoch 0: the first message is at the run's wall-clock start.
    assert summary.statistics.message_start_time == start_ns > 1.6e18
    assert meta["sensaug"]["source"] == log.meta["source"]
    assert json.loads(meta["config"]["json"]) == log.meta["config"]
    assert json.loads(attachments["meta.json"]) == log.meta
    assert json.loads(attachments["config.json"]) == log.meta["config"]
    return msgs


def test_a_simulated_trial_round_trips_through_mcap(saved, tmp_path):
    log = logs.load_log(saved)
    out = to_mcap(saved, tmp_path / "trial.mcap")
    msgs = check_against_log(out, log)
    run = [m for _, m in msgs[RUN_TOPIC]]
    assert [r["status"] for r in run] == ["running", "ended"]
    assert run[-1]["end"] == log.meta["end"]
    assert not (tmp_path / "trial.mcap.partial").exists()


def test_the_cli_exports_and_names_bad_input(saved, tmp_path, capsys):
    out = tmp_path / "cli.mcap"
    assert main(["export", str(saved), "--to", "mcap", "--out", str(out)]) == 0
    check_against_log(out, logs.load_log(saved))
    # Default output: beside the log, suffix .mcap.
    assert main(["export", str(saved), "--to", "mcap"]) == 0
    assert saved.with_suffix(".mcap").exists()
    bad = tmp_path / "bad.csv"
    bad.write_text("not a log\n")
    assert main(["export", str(bad), "--to", "mcap"]) == 2
    assert "not a sensaug log" in capsys.readouterr().err
    assert not (tmp_path / "bad.mcap").exists()


def test_a_log_without_a_start_time_is_dated_by_its_file(saved, tmp_path):
    log = logs.load_log(saved)
    log.meta["start_unix_s"] = 0.0
    path = log.save(tmp_path / "epoch0.csv")
    _, msgs, meta, _ = read_back(to_mcap(path, tmp_path / "epoch0.mcap"))
    first = msgs["/handle"][0][0]
    assert first > 1.6e18, "a timestamp from epoch 0"
    assert meta["sensaug"]["start_time_source"].startswith("file modification time")


def test_non_finite_values_are_json_null():
    """JSON has no NaN or infinity: both export as null (the rig writes inf in
    ``partner_var`` while the partner channel is held out, so a run whose
    feedback was late has infinities in its log)."""
    column = np.array([0.25, np.inf, -np.inf, np.nan, 1e-300])
    assert topics._json_texts(column) == ["0.25", "null", "null", "null", "1e-300"]
    assert same(column, [0.25, None, None, None, 1e-300])
    assert not same(column, [0.25, 0.0, None, None, 1e-300])
