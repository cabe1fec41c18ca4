"""The one log schema: a simulated trial saved and loaded back bit for bit,
its metadata, crash-truncated files, pandas and bad input; the checksums
verified by an independent reader (Python's zlib) and a corpus of corrupted
files, each refused by line or loaded unchanged; format-1 logs.

The rig side (the same schema from `sensaug-rt`, SIGKILL mid-run) is in
tests/test_rig.py; the rig's checksums are read independently in
tests/test_replay.py.
"""
from __future__ import annotations

import json
import random
import re
import warnings
import zlib
from pathlib import Path

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
    assert meta["format"] == "sensaug-log" and meta["format_version"] == 2
    assert meta["config_sha256"] == _core.config_sha256(json.dumps(trial.config.to_dict()))
    assert "crc32" not in meta
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
    assert list(df.columns) == [*logs.COLUMNS, "crc32"] and len(df) == len(trial)
    for name in ("t", "x", "u", "Lhh_hat", "e_hat_fused", "tau_h_var"):
        assert same_bits(df[name].to_numpy(), trial[name]), name
    assert df["tick"].dtype == np.int64 and df["phase"].dtype == np.int64
    via = trial.to_pandas()
    assert via["fresh"].dtype == bool and via.attrs["source"] == "simulation"
    np.testing.assert_array_equal(via["x"].to_numpy(), trial["x"])


def test_numpy_reads_the_file_without_custom_code(trial, saved):
    a = np.genfromtxt(saved, delimiter=",", names=True, skip_header=2, dtype=None)
    assert a.dtype.names == (*logs.COLUMNS, "crc32") and len(a) == len(trial)
    assert same_bits(np.asarray(a["x"], dtype=float), trial["x"])


def test_bad_files_and_bad_data_are_named(trial, tmp_path):
    other = tmp_path / "other.csv"
    other.write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match=r"other\.csv: line 1: not a sensaug log"):
        load_log(other)
    bad_row = tmp_path / "bad.csv"
    trial.save(bad_row)
    lines = bad_row.read_text().split("\n")
    lines[5] = lines[5].replace(",", ",x", 1)
    bad_row.write_text("\n".join(lines))
    with pytest.raises(ValueError, match=r"bad\.csv: line 6: checksum mismatch"):
        load_log(bad_row)
    # Without the checksums, the value itself is named.
    with pytest.raises(ValueError, match=r"bad\.csv: line 6: column t: 'x0.002' is not a valid float"):
        load_log(bad_row, verify=False)
    data = trial.data[["tick", "t"]]
    with pytest.raises(ValueError, match=r"data\.phase: missing column"):
        logs.to_records(data)
    wrong = {n: trial[n] for n in logs.COLUMNS} | {"phase": trial["phase"].astype(float)}
    with pytest.raises(ValueError, match=r"data\.phase: expected a 1-D int64 array"):
        logs.to_records(wrong)
    short = {n: trial[n] for n in logs.COLUMNS} | {"x": trial["x"][:10]}
    with pytest.raises(ValueError, match=r"data\.x: 10 values"):
        logs.to_records(short)
    # The Rust writer takes packed records and checks each value's code.
    bad_phase = trial.data.copy()
    bad_phase["phase"][3] = 99
    with pytest.raises(ValueError, match=r"data\.phase: expected int, got Int\(99\) \(row 3\)"):
        _core.write_log(str(tmp_path / "x.csv"), logs.to_records(bad_phase), meta_json="{}", end_json=None)
    with pytest.raises(ValueError, match=r"records: 7 bytes is not a whole number"):
        _core.write_log(str(tmp_path / "x.csv"), np.zeros(7, np.uint8), meta_json="{}", end_json=None)


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


# --- checksums ---------------------------------------------------------------------------


def verify_independently(path: Path) -> int:
    """docs/logs.md's rules, with nothing from sensaug: the metadata line's
    and the end line's checksum sit before their closing brace after
    ',"crc32":'; a row's is its last field; each is zlib.crc32 of the line's
    bytes before it, continued from the previous line's. Returns the rows
    verified; raises AssertionError at the first line that fails."""
    lines = path.read_bytes().split(b"\n")[:-1]
    assert lines[0] == b"# sensaug-log 2"
    crc = 0
    for n, line in enumerate(lines[1:], start=2):
        if n == 3:
            assert line.endswith(b",crc32"), "the header row ends with the checksum's column"
            continue
        if line.startswith(b"#"):
            at = line.rindex(b',"crc32":')
            checked, written = line[:at], line[at + 9 : -1]
        else:
            checked, _, written = line.rpartition(b",")
        crc = zlib.crc32(checked, crc)
        assert int(written) == crc, f"line {n}"
    return sum(1 for ln in lines[3:] if not ln.startswith(b"#"))


def test_an_independent_reader_verifies_every_line(trial, saved):
    assert verify_independently(saved) == len(trial)
    # The rows are what the loader returns: the checksum is extra.
    text = saved.read_text().split("\n")
    assert text[3].rpartition(",")[0].split(",")[0] == "0"


def test_a_flipped_fresh_or_an_edited_value_is_caught(trial, saved, tmp_path):
    lines = saved.read_text().split("\n")
    fresh = logs.COLUMNS.index("fresh")
    for name, edit in {
        "fresh": lambda f: f.__setitem__(fresh, "0" if f[fresh] == "1" else "1"),
        "x": lambda f: f.__setitem__(logs.COLUMNS.index("x"), repr(float(f[logs.COLUMNS.index("x")]) + 1e-9)),
    }.items():
        changed = list(lines)
        fields = changed[100].split(",")
        edit(fields)
        changed[100] = ",".join(fields)
        bad = tmp_path / f"{name}.csv"
        bad.write_text("\n".join(changed))
        with pytest.raises(ValueError, match=rf"{name}\.csv: line 101: checksum mismatch"):
            load_log(bad)
        with pytest.raises(AssertionError, match="line 101"):
            verify_independently(bad)


#: Corrupted files per kind (deletions: every line once, whatever this says).
CORRUPTIONS_PER_KIND = {"flip": 900, "bit": 300, "truncate": 300, "delete": 0, "duplicate": 150, "swap": 150}


def _corruptions(raw: bytes, rng: random.Random):
    """(kind, index of the first changed line, bytes) for many corruptions of
    ``raw``: random byte replacements and single-bit flips over the whole
    file, truncations at random bytes, every line deleted in turn, random
    lines duplicated, random adjacent lines swapped."""
    lines = raw.split(b"\n")[:-1]
    starts = np.cumsum([0] + [len(ln) + 1 for ln in lines])

    def line_of(pos: int) -> int:
        return int(np.searchsorted(starts, pos, side="right") - 1)

    for _ in range(CORRUPTIONS_PER_KIND["flip"]):
        pos = rng.randrange(len(raw))
        yield "flip", line_of(pos), raw[:pos] + bytes([raw[pos] ^ rng.randrange(1, 256)]) + raw[pos + 1 :]
    for _ in range(CORRUPTIONS_PER_KIND["bit"]):
        pos = rng.randrange(len(raw))
        yield "bit", line_of(pos), raw[:pos] + bytes([raw[pos] ^ (1 << rng.randrange(8))]) + raw[pos + 1 :]
    for _ in range(CORRUPTIONS_PER_KIND["truncate"]):
        pos = rng.randrange(len(raw))
        yield "truncate", line_of(pos), raw[:pos]
    join = lambda ls: b"\n".join(ls) + b"\n"  # noqa: E731
    for k in range(len(lines)):
        yield "delete", k, join(lines[:k] + lines[k + 1 :])
    for _ in range(CORRUPTIONS_PER_KIND["duplicate"]):
        k = rng.randrange(len(lines))
        yield "duplicate", k, join(lines[: k + 1] + lines[k:])
    for _ in range(CORRUPTIONS_PER_KIND["swap"]):
        k = rng.randrange(len(lines) - 1)
        yield "swap", k, join(lines[:k] + [lines[k + 1], lines[k]] + lines[k + 2 :])


def test_a_corruption_corpus_is_refused_by_line_or_loads_unchanged(tmp_path):
    """Every corrupted file either loads exactly as the original, or loads
    as a prefix of it with no end status — what a crash leaves, and all a
    cut at a line boundary can be told from — or raises a ValueError naming
    the file and a line. Nothing else: no other exception, no changed value.
    A prefix is accepted only when the corruption is a truncation or sits
    in the last line (the end status): anywhere else it would be a lost row."""
    trial = experiment.run(presets.hi5_experiment(2.0, seed=4, phase_s=0.1, target_noise_std=0.5))
    path = trial.save(tmp_path / "orig.csv")
    raw = path.read_bytes()
    orig = load_log(path)
    n_lines = raw.count(b"\n")
    rng = random.Random(20261126)
    outcomes: dict[str, dict[str, int]] = {}
    bad = tmp_path / "bad.csv"
    pattern = re.compile(rf"^{re.escape(str(bad))}: line (\d+): ")
    for kind, line, data in _corruptions(raw, rng):
        if data == raw:
            continue
        bad.write_bytes(data)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # an unverified load would be a failure
                log = load_log(bad)
        except ValueError as e:
            m = pattern.match(str(e))
            assert m, f"{kind} at line {line + 1}: {e}"
            assert 1 <= int(m.group(1)) <= n_lines + 1, str(e)
            outcome = "ValueError naming the line"
        else:
            rows = len(log)
            same = rows <= len(orig) and same_bits(log.data, orig.data[:rows])
            meta = {k: v for k, v in orig.meta.items() if k != "end"}
            assert same and {k: v for k, v in log.meta.items() if k != "end"} == meta, f"{kind} at line {line + 1}: changed"
            if rows == len(orig) and log.meta == orig.meta:
                outcome = "loads identically"
            else:
                assert not log.complete, f"{kind} at line {line + 1}: a cut log claims to be complete"
                assert kind == "truncate" or line == n_lines - 1, f"{kind} at line {line + 1}: rows lost silently"
                outcome = "loads as a crash-cut prefix, incomplete"
        outcomes.setdefault(kind, {}).setdefault(outcome, 0)
        outcomes[kind][outcome] += 1
    total = sum(sum(v.values()) for v in outcomes.values())
    print(f"\ncorruption corpus: {total} files ({len(orig)} rows, {n_lines} lines): {json.dumps(outcomes)}")
    assert total > 2000
    # Every kind was seen and refused somewhere (the loop above checked the
    # rest: refused by line, unchanged, or a crash-like prefix at the end).
    assert set(outcomes) == set(CORRUPTIONS_PER_KIND)
    assert all(v.get("ValueError naming the line", 0) > 0 for v in outcomes.values())


def test_a_format_1_log_loads_unverified(tmp_path):
    """A log written before the checksums (format 1, made by the code of
    9e3d605) still loads, with a warning and ``verified`` False."""
    old = Path(__file__).parent / "logs" / "trial_format1.csv"
    with pytest.warns(logs.UnverifiedLogWarning, match="format-1 log"):
        log = load_log(old)
    assert not log.verified and "UNVERIFIED" in repr(log)
    assert len(log) == 60 and log.complete and log.meta["format_version"] == 1
    assert log.data.dtype == logs.DTYPE and list(np.unique(log["phase"])) == [0, 1, 2]
    assert "config_sha256" not in log.meta
    # Its rows are counted by its end line: a deleted row is still caught.
    lines = old.read_bytes().split(b"\n")
    short = tmp_path / "short.csv"
    short.write_bytes(b"\n".join(lines[:10] + lines[11:]))
    with pytest.raises(ValueError, match=r"short\.csv: line 63: the end status counts 60 rows"):
        load_log(short)
    # Saved again, it is a format-2 log with checksums from now on, still
    # saying its rows were never verified.
    log.save(tmp_path / "again.csv")
    with pytest.warns(logs.UnverifiedLogWarning, match="saved from a log that was not verified"):
        again = load_log(tmp_path / "again.csv")
    assert not again.verified and again.meta["format_version"] == 2 and again.meta["unverified_source"]
    assert same_bits(again.data, log.data) and verify_independently(tmp_path / "again.csv") == 60


def test_an_edited_metadata_line_is_refused_unless_accepted(trial, saved, tmp_path):
    lines = saved.read_text().split("\n")
    lines[1] = lines[1].replace('"seed":', '"seed":1', 1)
    edited = tmp_path / "edited.csv"
    edited.write_text("\n".join(lines))
    with pytest.raises(ValueError, match=r"edited\.csv: line 2: checksum mismatch.*edited_metadata_ok=True"):
        load_log(edited)
    with pytest.warns(logs.UnverifiedLogWarning, match="metadata line was changed"):
        log = load_log(edited, edited_metadata_ok=True)
    assert not log.verified and log.meta["metadata_edited"] and same_bits(log.data, trial.data)
    # The rows are still verified against what the writer wrote.
    lines[50] = lines[50].replace(",1,", ",0,", 1)
    edited.write_text("\n".join(lines))
    with pytest.raises(ValueError, match=r"line 51: checksum mismatch"):
        load_log(edited, edited_metadata_ok=True)
