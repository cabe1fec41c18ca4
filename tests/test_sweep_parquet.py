"""A sweep's results are saved as Parquet beside the CSV: the same table,
typed, readable by pandas and pyarrow without custom code."""

from __future__ import annotations

import json

import pandas as pd
import pyarrow.parquet as pq

from sensaug import cli, presets


def test_the_sweep_writes_parquet_equal_to_its_csv(tmp_path):
    cfg = presets.hi5_experiment(phase_s=1.0)
    cfg.robot.gain_window_s = 0.5
    path = tmp_path / "base.toml"
    cfg.to_toml(path)
    out = tmp_path / "sweep"
    code = cli.main(["sweep", str(path), "--grid", "partner.gains.lhh=0.5,2.0", "--seeds", "2",
                     "--workers", "1", "--out", str(out), "--quiet"])
    assert code == 0
    csv = pd.read_csv(out / "results.csv")
    parquet = pd.read_parquet(out / "results.parquet")
    assert len(parquet) == 4
    pd.testing.assert_frame_equal(parquet, csv, check_exact=False, rtol=1e-15)
    assert parquet["seed"].dtype == "int64"
    meta = json.loads(pq.read_schema(out / "results.parquet").metadata[b"sensaug"])
    assert meta["grid"] == {"partner.gains.lhh": [0.5, 2.0]} and meta["seeds"] == [0, 1]


def test_a_column_mixing_numbers_and_text_is_written_as_text(tmp_path):
    df = pd.DataFrame({"rig.can": [1, "udp:1"], "seed": [0, 1], "rmse": [0.5, 0.25]})
    csv, parquet = cli.write_results(df, tmp_path, {"grid": {}, "seeds": [0, 1]})
    back = pd.read_parquet(parquet)
    assert back["rig.can"].tolist() == ["1", "udp:1"]
    assert back["rmse"].tolist() == [0.5, 0.25]
