"""The one log schema: a simulated trial saved and loaded back bit for bit,
its metadata, crash-truncated files, pandas and bad input.

The rig side (the same schema from `sensaug-rt`, SIGKILL mid-run) is in
tests/test_rig.py.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

import sensaug
from sensaug import _core, experiment, logs, presets
from sensaug.logs import load_log


@pytest.fixture(scope="module")
def trial() -> experiment.Trial:
    # Short, but every phase kind, so every estimate column is exercised.
    return experiment.run(presets.hi5_experiment(2.0, seed=1, phase_s=2.0, target_noise_std=0.5))


@pytest.fixture(scope="module")
def saved(trial, tmp_path_factory):
    return trial.save(tmp_path_factory.mktemp("logs") / "trial.csv")


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and np.array_equal(np.ascontiguousarray(a).view(np.uint8), np.ascontiguousarray(b).view(np.uint8))


def test_the_schema_is_typed_and_comes_from_rust():
    schema = _core.log_schema()
    assert [c[0] for c in schema["columns"]] == list(logs.COLUMNS)
    kinds = {c[0]: c[2] for c in schema["columns"]}
    for name in ("tick", "phase", "drive_state", "feedback_age_ticks", "guard"):
        assert kinds[name] == "int" and logs.DTYPE[name] == np.int64, name
    for name in ("fresh", "ramp"):
        assert logs.DTYPE[name] == np.bool_, name
    # The variance columns and what a replay needs are there.
    for name in ("Lhx_var", "tau_h_var", "e_hat_own_var", "e_hat_fused_var", "x_meas", "xdot_meas", "fresh", "e_meas", "u"):
        assert name in logs.COLUMNS, name
    assert logs.PHASE_NAMES == ("gains", "trajectory", "integration")
    assert all(logs.UNITS[n] for n in logs.COLUMNS)


def test_docs_list_the_schema_as_it_is():
    """docs/logs.md's column table is the Rust table, row for row."""
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[1] / "docs" / "logs.md").read_text()
    rows = [f"| `{n}` | {u} | {k} | {d} |" for n, u, k, d in _core.log_schema()["columns"]]
    assert "\n".join(rows) in doc


def test_a_simulated_trial_is_in_the_schema(trial):
    assert trial.data.dtype == logs.DTYPE
    np.testing.assert_array_equal(trial["tick"], np.arange(len(trial)))
    assert list(np.unique(trial["phase"])) == [0, 1, 2]
    assert trial["fresh"].all() and not trial["ramp"].any()
    assert np.all(trial["drive_state"] == logs.UNKNOWN_INT) and np.all(trial["guard"] == logs.UNKNOWN_INT)
    assert np.isnan(trial["torque_nm"]).all() and np.isnan(trial["wake_latency_us"]).all()
    assert np.isnan(trial["sleep_latency_us"]).all()
    # Stage-3 columns only in the integration phase, with their variances.
    integ = trial["phase"] == 2
    assert np.isfinite(trial["e_hat_fused_var"][integ]).all() and np.isnan(trial["e_hat_fused_var"][~integ]).all()
    assert "Trial simulation: 6000 ticks" in repr(trial)


def test_save_and_load_round_trip_bit_exactly(trial, saved):
    log = load_log(saved)
    assert isinstance(log, sensaug.Log)
    assert log.columns == trial.columns == logs.COLUMNS
    assert log.data.dtype == trial.data.dtype
    for name in logs.COLUMNS:
        assert same_bits(log[name], trial[name]), name
    assert log.meta == json.loads(json.dumps(trial.meta))


def test_the_file_carries_its_metadata(trial, saved):
    meta = load_log(saved).meta
    assert meta["format"] == "sensaug-log" and meta["format_version"] == 1
    assert meta["source"] == "simulation"
    assert meta["package_version"] == "0.1.0"
    assert "git_commit" in meta  # None outside a git checkout
    assert meta["start_time_utc"].endswith("Z") and meta["start_unix_s"] > 1.7e9
    assert meta["config"] == trial.config.to_dict()
    assert meta["resolved"]["robot"]["gains"] == list(trial.robot_gains)
    assert meta["phase_names"] == ["gains", "trajectory", "integration"]
    assert {c["name"]: c["unit"] for c in meta["columns"]} == logs.UNITS
    assert meta["units"]["pos"] and meta["end"]["ticks"] == len(trial)
    assert meta["loop"] is None


def test_trial_load_rebuilds_the_trial(trial, saved):
    back = experiment.Trial.load(saved)
    assert back.config.to_dict() == trial.config.to_dict()
    assert back.summary == trial.summary
    np.testing.assert_array_equal(back.robot_gains, trial.robot_gains)
    np.testing.assert_array_equal(back.partner_gains, trial.partner_gains)
    np.testing.assert_array_equal(back.gain_estimate(), trial.gain_estimate())
    assert back.integration_rmse(skip_s=0.5) == trial.integration_rmse(skip_s=0.5)


def test_a_log_cut_mid_line_loads_every_complete_row(saved, tmp_path):
    text = saved.read_bytes()
    lines = text.split(b"\n")
    # Cut inside data row 1234 (line 3 + 1234), as a killed writer would.
    keep = b"\n".join(lines[: 3 + 1234]) + b"\n" + lines[3 + 1234][:17]
    cut = tmp_path / "cut.csv"
    cut.write_bytes(keep)
    log = load_log(cut)
    assert len(log) == 1234 and not log.complete
    full = load_log(saved)
    for name in logs.COLUMNS:
        assert same_bits(log[name], full[name][:1234]), name
    # Cut right after the header: no rows, still the metadata.
    head = tmp_path / "head.csv"
    head.write_bytes(b"\n".join(lines[:3]) + b"\n")
    empty = load_log(head)
    assert len(empty) == 0 and empty.data.dtype == logs.DTYPE and empty.meta["source"] == "simulation"


def test_pandas_reads_the_file_without_custom_code(trial, saved):
    pd = pytest.importorskip("pandas")
    # pandas >= 3 parses floats round-trip by default (float_precision deprecated).
    df = pd.read_csv(saved, comment="#")
    assert list(df.columns) == list(logs.COLUMNS) and len(df) == len(trial)
    for name in ("t", "x", "u", "Lhh_hat", "e_hat_fused", "tau_h_var"):
        assert same_bits(df[name].to_numpy(), trial[name]), name
    assert df["tick"].dtype == np.int64 and df["phase"].dtype == np.int64
    via = trial.to_pandas()
    assert via["fresh"].dtype == bool and via.attrs["source"] == "simulation"
    np.testing.assert_array_equal(via["x"].to_numpy(), trial["x"])


def test_numpy_reads_the_file_without_custom_code(trial, saved):
    a = np.genfromtxt(saved, delimiter=",", names=True, skip_header=2, dtype=None)
    assert a.dtype.names == logs.COLUMNS and len(a) == len(trial)
    assert same_bits(np.asarray(a["x"], dtype=float), trial["x"])


def test_bad_files_and_bad_data_are_named(trial, tmp_path):
    other = tmp_path / "other.csv"
    other.write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match=r"other\.csv: not a sensaug log"):
        load_log(other)
    bad_row = tmp_path / "bad.csv"
    trial.save(bad_row)
    lines = bad_row.read_text().split("\n")
    lines[5] = lines[5].replace(",", ",x", 1)
    bad_row.write_text("\n".join(lines))
    with pytest.raises(ValueError, match=r"bad\.csv: a data row does not parse"):
        load_log(bad_row)
    data = trial.data[["tick", "t"]]
    with pytest.raises(ValueError, match=r"data\.phase: missing column"):
        _core.write_log(str(tmp_path / "x.csv"), data, meta_json="{}")
    wrong = {n: trial[n] for n in logs.COLUMNS} | {"phase": trial["phase"].astype(float)}
    with pytest.raises(ValueError, match=r"data\.phase: expected a 1-D int64 array"):
        _core.write_log(str(tmp_path / "x.csv"), wrong, meta_json="{}")
    short = {n: trial[n] for n in logs.COLUMNS} | {"x": trial["x"][:10]}
    with pytest.raises(ValueError, match=r"data\.x: 10 values"):
        _core.write_log(str(tmp_path / "x.csv"), short, meta_json="{}")


def test_packed_records_view_and_bad_bytes_are_named(trial):
    # The core hands a trial over as packed rows in DTYPE's layout (one
    # buffer, viewed without a copy); other bytes are refused by name.
    raw = np.frombuffer(trial.data.tobytes(), dtype=np.uint8).copy()
    assert logs.from_records(raw).tobytes() == trial.data.tobytes()
    np.testing.assert_array_equal(logs.from_records(raw)["tick"], np.arange(len(trial)))
    with pytest.raises(ValueError, match="records: expected 1-D uint8 bytes"):
        logs.from_records(raw[:-1])
    with pytest.raises(ValueError, match="records: expected 1-D uint8 bytes"):
        logs.from_records(raw.view(np.int8))
