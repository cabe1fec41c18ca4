"""``sensaug.replay``: the robot's controller re-run offline over a log
reproduces the columns computed online, tick by tick and bit for bit, for a
simulated trial and for a virtual-rig run (whose loaded VM loses feedback on
some ticks: the ``fresh`` column says which). A log whose recorded
configuration was edited after the run is refused (or replayed with a loud
warning when the lab says so); a flipped ``fresh`` is caught by the row
checksum."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_logs import verify_independently
from test_rig import short_config, stall_tolerant

import sensaug
from sensaug import _core, experiment, presets, rig
from sensaug import logs
from sensaug.logs import UNKNOWN_INT, UnverifiedLogWarning, load_log
from sensaug.replay import ESTIMATE_COLUMNS


def assert_columns_identical(replayed, online, rows=slice(None)) -> None:
    """Every estimate column equal bit for bit (NaN where NaN), every tick."""
    for c in ESTIMATE_COLUMNS:
        a, b = replayed[c][rows], online[c][rows]
        if a.dtype.kind == "f":
            a, b = a.view(np.int64), b.view(np.int64)  # bit patterns: -0.0 and NaNs too
        bad = np.flatnonzero(a != b)
        assert bad.size == 0, f"{c}: first differs at tick {bad[0]}: {replayed[c][bad[0]]!r} vs {online[c][bad[0]]!r}"


def sim_config():
    """A short noisy simulated trial: sensor, motor and target-view noise
    (the robot draws the latter from its own seed every integration tick)."""
    cfg = presets.hi5_experiment(target_noise_std=1.0)
    for ph, s in zip(cfg.phases, (3.0, 1.5, 1.5)):
        ph.duration_s = s
    cfg.robot.gain_window_s = 0.5
    cfg.validate()
    return cfg


def test_a_saved_simulated_trial_replays_bit_for_bit(tmp_path):
    trial = experiment.run(sim_config())
    path = trial.save(tmp_path / "sim.csv")
    out = sensaug.replay(path)
    online = load_log(path)
    assert len(out) == len(online) == len(trial)
    assert set(np.unique(online["phase"])) == {0, 1, 2}
    # The stages actually produced estimates that the comparison covers.
    for c in ("Lhh_hat", "tau_h_hat", "e_hat_fused", "partner_var"):
        assert np.isfinite(online[c]).any(), c
    assert_columns_identical(out, online)
    # The file's floats are exact: the in-memory trial agrees too.
    assert_columns_identical(out, trial)
    assert out.meta["replay"]["missing_measurements"] == 0
    # The non-estimate columns are the log's.
    np.testing.assert_array_equal(out["x"], online["x"])


def test_replay_is_not_trivially_equal(tmp_path):
    """The comparison can fail: another robot seed changes the integration
    phase's target-view noise, so e_meas and the stage-3 estimates differ."""
    trial = experiment.run(sim_config())
    cfg = sim_config()
    cfg.robot.seed += 1
    out = sensaug.replay(trial, cfg)
    integ = trial["phase"] == 2
    assert not np.array_equal(out["e_meas"][integ], trial["e_meas"][integ])
    np.testing.assert_array_equal(out["Lhh_hat"][~integ], trial["Lhh_hat"][~integ])


def test_a_missed_measurement_changes_the_replay(tmp_path):
    """`fresh` is read: a tick marked stale is predict-only, so the estimates
    from that tick on differ from the online ones."""
    trial = experiment.run(sim_config())
    edited = sensaug.Log(data=trial.data.copy(), meta=dict(trial.meta))
    edited.data["fresh"][1000] = False
    out = sensaug.replay(edited)
    assert out.meta["replay"]["missing_measurements"] == 1
    assert_columns_identical(out, trial, slice(0, 1000))
    assert out["Lhh_hat"][1000] != trial["Lhh_hat"][1000]


def test_bad_logs_get_named_errors(tmp_path):
    trial = experiment.run(sim_config())
    no_fresh = sensaug.Log(data=trial.data[[n for n in trial.columns if n != "fresh"]], meta=trial.meta)
    with pytest.raises(ValueError, match="missing column.*fresh"):
        sensaug.replay(no_fresh)
    gap = sensaug.Log(data=np.delete(trial.data, 10), meta=trial.meta)
    with pytest.raises(ValueError, match=r"log.tick: row 10 is tick 11"):
        sensaug.replay(gap)
    shorter = sim_config()
    shorter.phases[2].duration_s = 0.5
    with pytest.raises(ValueError, match="protocol ends at tick 5000"):
        sensaug.replay(trial, shorter)
    other = sim_config()
    other.phases[0].duration_s, other.phases[1].duration_s = 2.0, 2.5
    with pytest.raises(ValueError, match="config: tick 2000 is in phase 1 here but 0 in the log"):
        sensaug.replay(trial, other)
    no_config = sensaug.Log(data=trial.data, meta={k: v for k, v in trial.meta.items() if k != "config"})
    with pytest.raises(ValueError, match="no 'config' recorded"):
        sensaug.replay(no_config)
    with pytest.raises(ValueError, match="^records: 5 bytes is not a whole number of"):
        sensaug._core.replay_robot(sim_config().resolved(), np.zeros(5, dtype=np.uint8), applied_u=False)


def test_the_replayed_columns_follow_the_schemas_source_tags():
    """Replay recomputes the columns the schema tags ``controller`` (no
    hand-kept list): the core's replay returns packed records in which those
    equal the online trial's bit for bit, the measurement it read and the
    tick's time are filled, and every other world or rig column is unknown."""
    assert ESTIMATE_COLUMNS == tuple(c for c in logs.COLUMNS if logs.SOURCES[c] == "controller")
    assert {"phase", "u", "e_meas", "partner_delay_margin_nats"} <= set(ESTIMATE_COLUMNS)
    assert set(logs.SOURCES.values()) == {"time", "controller", "world", "rig"}
    cfg = sim_config()
    trial = experiment.run(cfg)
    d = trial.data
    records, counters = _core.replay_robot(cfg.resolved(), logs.to_records(d), applied_u=False)
    assert records.dtype == np.uint8
    replayed = logs.from_records(records)
    assert counters["ticks"] == len(replayed) == len(d)
    assert_columns_identical(replayed, d)
    read = {"x_meas", "xdot_meas", "fresh"}
    for c in logs.COLUMNS:
        if logs.SOURCES[c] == "time" or c in read:
            assert np.array_equal(replayed[c], d[c]), c
        elif logs.SOURCES[c] != "controller":
            col = replayed[c]
            unknown = np.isnan(col) if col.dtype.kind == "f" else col == (False if col.dtype == bool else UNKNOWN_INT)
            assert unknown.all(), c


def test_a_virtual_rig_run_replays_tick_by_tick(tmp_path):
    # The subject is the replay, not the stall limits (a loaded run stopped on
    # 101 stale ticks with only the timeout and watchdog widened).
    cfg = stall_tolerant(short_config())
    run = rig.run_virtual_rig(cfg, out=tmp_path, timeout_s=120.0)
    assert run.returncode == 0, run.stderr
    log = run.log
    assert log.meta["source"] == "rig" and len(log) == 5000
    out = sensaug.replay(tmp_path / "rig_log.csv")
    assert_columns_identical(out, log)
    # What sensaug-rt wrote verifies with zlib alone, and its configuration
    # digest is that of the configuration it recorded.
    assert verify_independently(tmp_path / "rig_log.csv") == len(log)
    assert log.meta["config_sha256"] == _core.config_sha256(json.dumps(log.meta["config"]))
    assert out.meta["replay"]["recorded_config_verified"] is True
    stale = int((~log["fresh"]).sum())
    assert out.meta["replay"]["missing_measurements"] == stale
    # Without the `fresh` column's information (every tick taken as fresh)
    # the replay would differ as soon as a tick lost its feedback.
    if stale:
        all_fresh = sensaug.Log(data=log.data.copy(), meta=log.meta)
        all_fresh.data["fresh"][:] = True
        naive = sensaug.replay(all_fresh)
        assert not np.array_equal(naive["Lhh_hat"], log["Lhh_hat"])
    last = np.flatnonzero(log["phase"] == 0)[-1]
    print(f"\nrig replay: {len(log)} ticks, {stale} without fresh feedback, Lhh {log['Lhh_hat'][last]:.6f} "
          f"online = {out['Lhh_hat'][last]:.6f} replayed (bit-identical in all {len(ESTIMATE_COLUMNS)} columns)")


def test_a_ramp_down_is_left_as_logged(tmp_path):
    """Rows of a rig's ramp-down (the controller did not run) stay phase -1
    and NaN; the controller's ticks before it are replayed. Built from a
    simulated trial with its tail marked as a ramp."""
    trial = experiment.run(sim_config())
    data = trial.data.copy()
    tail = slice(4000, None)
    data["ramp"][tail] = True
    data["phase"][tail] = UNKNOWN_INT
    for c in ESTIMATE_COLUMNS[1:]:
        data[c][tail] = np.nan
    out = sensaug.replay(sensaug.Log(data=data, meta=trial.meta))
    assert out.meta["replay"]["controller_ticks"] == 4000
    assert_columns_identical(out, trial, slice(0, 4000))
    assert np.all(out["phase"][tail] == UNKNOWN_INT) and np.isnan(out["u"][tail]).all()


def test_an_edited_recorded_configuration_is_refused_unless_allowed(tmp_path):
    """`replay` used to run without a warning on a log whose metadata
    configuration was edited: another robot seed gives other stage-3
    estimates, silently. The digest recorded with the log tells."""
    trial = experiment.run(sim_config())
    assert sensaug.replay(trial).meta["replay"]["recorded_config_verified"] is True
    meta = json.loads(json.dumps(trial.meta))
    meta["config"]["robot"]["seed"] += 1
    edited = sensaug.Log(data=trial.data, meta=meta)
    with pytest.raises(ValueError, match=r"^log\.meta\.config: not the configuration the run was recorded with"):
        sensaug.replay(edited)
    with pytest.warns(UnverifiedLogWarning, match="EDITED after the run"):
        out = sensaug.replay(edited, allow_edited_config=True)
    assert out.meta["replay"]["recorded_config_verified"] is False
    integ = trial["phase"] == 2
    assert not np.array_equal(out["e_meas"][integ], trial["e_meas"][integ])
    # In a file, the metadata line's checksum fails first; the override
    # reads it with the rows still verified.
    path = trial.save(tmp_path / "trial.csv")
    lines = path.read_text().split("\n")
    seed = trial.config.robot.seed
    assert lines[1].count(f'"seed":{seed}') == 1
    lines[1] = lines[1].replace(f'"seed":{seed}', f'"seed":{seed + 1}')
    path.write_text("\n".join(lines))
    with pytest.raises(ValueError, match=r"trial\.csv: line 2: checksum mismatch.*allow_edited_config=True"):
        sensaug.replay(path)
    with pytest.warns(UnverifiedLogWarning) as caught:
        out = sensaug.replay(path, allow_edited_config=True)
    assert {str(w.message).split(": ")[0] for w in caught} >= {str(path), "log.meta.config"}
    assert out.meta["replay"]["recorded_config_verified"] is False
    # Given explicitly, another configuration is the supported use: no check.
    with pytest.warns(UnverifiedLogWarning, match="metadata line was changed"):
        given = sensaug.replay(path, trial.config, allow_edited_config=True)
    assert given.meta["replay"]["recorded_config_verified"] is None


def test_a_flipped_fresh_column_in_a_file_is_caught(tmp_path):
    """A stale tick marked fresh (or the reverse) changes the replay
    (test_a_missed_measurement_changes_the_replay); in a file, the row's
    checksum refuses it first."""
    trial = experiment.run(sim_config())
    path = trial.save(tmp_path / "trial.csv")
    lines = path.read_text().split("\n")
    k = 1000  # row k is line k + 4
    fields = lines[k + 3].split(",")
    col = sensaug.logs.COLUMNS.index("fresh")
    assert fields[col] == "1"
    fields[col] = "0"
    lines[k + 3] = ",".join(fields)
    path.write_text("\n".join(lines))
    with pytest.raises(ValueError, match=rf"trial\.csv: line {k + 4}: checksum mismatch"):
        sensaug.replay(path)


def test_a_format_1_log_replays_with_a_warning():
    """A log written before the digest (format 1) replays with its recorded
    configuration, and says it could not check it; settings later versions
    retired are dropped by name. Its gain and trajectory phases (ticks 0-39)
    replay bit for bit; its integration phase runs today's stage 3 (issue
    22's adaptive channel), so only there the estimates may differ."""
    old = Path(__file__).parent / "logs" / "trial_format1.csv"
    with pytest.warns(UnverifiedLogWarning) as caught:
        out = sensaug.replay(old)
    assert any("format-1 log" in str(w.message) for w in caught)
    assert any("no config_sha256" in str(w.message) for w in caught)
    assert any("robot.stage3.partner_window_s dropped" in str(w.message) for w in caught)
    assert out.meta["replay"]["recorded_config_verified"] is None
    with pytest.warns(UnverifiedLogWarning):
        recorded = load_log(old)
    before_integration = slice(0, int(np.flatnonzero(recorded["phase"] == 2)[0]))
    assert before_integration.stop == 40
    assert_columns_identical(out, recorded, before_integration)
    assert np.isfinite(out["u"]).all()


def test_a_feedback_gap_leaves_the_stage1_gains_where_they_were():
    """Stage 1 restarts its measured rows after ticks without feedback
    (GainEstimator::resync, docs/model.md "Feedback gaps"): a gap late in the
    gain phase leaves the gain window's mean where the run without a gap
    put it. Before, the first measurement after a 20-tick gap moved Lhh by
    up to 0.2 (of 2) and a 60-tick gap by up to 0.49 (10 starts,
    this loop with other starts)."""
    trial = experiment.run(short_config())
    log = sensaug.Log(data=trial.data.copy(), meta=dict(trial.meta))
    gain_ticks = np.flatnonzero(log["phase"] == 0)
    window = slice(gain_ticks[-1] + 1 - 500, gain_ticks[-1] + 1)  # robot.gain_window_s = 0.5
    names = ["Lhx_hat", "Lhv_hat", "Lhh_hat"]

    def window_gains(data) -> np.ndarray:
        out = sensaug.replay(sensaug.Log(data=data, meta=log.meta))
        return np.array([out[n][window].mean() for n in names])

    reference = window_gains(log.data.copy())
    assert abs(reference[2] - 2.0) < 0.002, reference
    for gap, tolerance in ((10, 0.005), (20, 0.005), (60, 0.05)):
        for start in (1650, 2150, 2650):
            d = log.data.copy()
            d["fresh"][start:start + gap] = False
            gains = window_gains(d)
            assert np.abs(gains - reference).max() < tolerance, (gap, start, gains, reference)
