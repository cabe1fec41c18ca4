"""The compact log (``Log.save("x.parquet")``): the same columns, types and
metadata as the CSV, read back bit for bit by ``load_log`` and
``Trial.load``, a fraction of the CSV's size (benches/log_sizes.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import sensaug
from sensaug import presets


@pytest.fixture(scope="module")
def trial() -> sensaug.Trial:
    cfg = presets.hi5_experiment(2.0, seed=4, target_noise_std=0.5)
    for p in cfg.phases:
        p.duration_s = 3.0
    return sensaug.run(cfg)


def test_round_trip_is_exact(trial: sensaug.Trial, tmp_path: Path) -> None:
    trial.save(tmp_path / "t.parquet")
    back = sensaug.load_log(tmp_path / "t.parquet")
    assert back.data.dtype == trial.data.dtype
    for name in trial.columns:
        a, b = trial[name], back[name]
        if a.dtype.kind == "f":
            assert np.array_equal(a.view(np.uint64), b.view(np.uint64)), name  # bit for bit, NaNs too
        else:
            assert np.array_equal(a, b), name
    assert back.meta == sensaug.load_log(trial.save(tmp_path / "t.csv")).meta
    again = sensaug.Trial.load(tmp_path / "t.parquet")
    assert again.config == trial.config and np.array_equal(again.partner_gains, trial.partner_gains)
    assert sensaug.replay(tmp_path / "t.parquet").meta["replay"] == sensaug.replay(tmp_path / "t.csv").meta["replay"]


def test_smaller_than_the_csv(trial: sensaug.Trial, tmp_path: Path) -> None:
    csv = trial.save(tmp_path / "t.csv").stat().st_size
    parquet = trial.save(tmp_path / "t.parquet").stat().st_size
    print(f"\n{len(trial)} ticks: CSV {csv / 1e6:.2f} MB, Parquet {parquet / 1e6:.2f} MB ({csv / parquet:.1f}x)")
    assert parquet < csv / 3


def test_a_foreign_parquet_file_is_refused(tmp_path: Path) -> None:
    pq.write_table(pa.table({"x": [1.0, 2.0]}), tmp_path / "other.parquet")
    with pytest.raises(ValueError, match=r"other\.parquet: a Parquet file without sensaug's metadata"):
        sensaug.load_log(tmp_path / "other.parquet")
    (tmp_path / "cut.parquet").write_bytes(b"PAR1" + b"\0" * 20)
    with pytest.raises(ValueError, match=r"cut\.parquet: not a readable Parquet file"):
        sensaug.load_log(tmp_path / "cut.parquet")


def test_a_changed_byte_is_caught_by_the_page_checksums(trial: sensaug.Trial, tmp_path: Path) -> None:
    """Parquet's CRC-32 page checksums are written and verified, as the CSV's
    line checksums are (docs/logs.md)."""
    path = trial.save(tmp_path / "t.parquet")
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 3] ^= 0x01
    path.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match=r"t\.parquet: not a readable Parquet file"):
        sensaug.load_log(path)


def test_an_unverified_log_stays_unverified(trial: sensaug.Trial, tmp_path: Path) -> None:
    unverified = sensaug.Log(data=trial.data, meta=dict(trial.meta), verified=False)
    unverified.save(tmp_path / "u.parquet")
    with pytest.warns(sensaug.logs.UnverifiedLogWarning, match="not verified when read"):
        back = sensaug.load_log(tmp_path / "u.parquet")
    assert not back.verified
