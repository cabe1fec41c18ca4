"""The live feed (``sensaug-rt --feed``, docs/live.md): a subscriber gets every
row of the run, byte for byte the log's, then the end status; addresses off
loopback are refused by name."""

from __future__ import annotations

import subprocess
import threading

import numpy as np
import pytest
from test_rig import stall_tolerant

from sensaug import presets, rig
from sensaug.feed import FeedReader, parse

pytestmark = pytest.mark.timeout(120)


def test_a_subscriber_gets_every_row_of_the_log_and_the_end_status(tmp_path):
    cfg = stall_tolerant(presets.hi5_rig(phase_s=0.7))  # the subject is the feed
    batches = []
    with FeedReader(0) as reader:

        def read() -> None:
            for b in reader.batches(timeout_s=30.0):
                batches.append(b)
                if b.end is not None:
                    return

        t = threading.Thread(target=read)
        t.start()
        run = rig.run_virtual_rig(cfg, out=tmp_path, capture=None, feed=[reader.address])
        t.join(timeout=40.0)
        lost = reader.lost
    # Any end will do (on this loaded 2-core VM a stalled drive can stop the
    # run early): the subject is that the feed carries what the log has.
    log = run.log
    assert len(log) > 0, run.stderr
    assert lost == 0 and batches and batches[-1].end is not None
    rows = np.concatenate([b.rows for b in batches])
    assert rows.tobytes() == log.data.tobytes(), "the feed's rows differ from the log's"
    assert [b.seq for b in batches] == list(range(len(batches)))
    assert {b.start_unix_ns for b in batches} == {int(log.meta["start_unix_s"] * 1e9)}
    assert max(len(b.rows) for b in batches) <= 64 and len(batches) < len(log) / 5, "rows are batched"
    end = batches[-1].end
    assert end["stop_reason"] == log.meta["end"]["stop_reason"] == run.stats["stop_reason"]
    assert log.meta["end"]["feed_datagrams_sent"] == len(batches) - 1


@pytest.mark.parametrize("addr", ["10.0.0.1:9870", "0.0.0.0:9870", "[::1]:9870", "127.0.0.1:0"])
def test_the_binary_refuses_a_feed_off_loopback_by_name(tmp_path, addr):
    cfg = presets.hi5_rig(phase_s=0.5)
    path = tmp_path / "c.toml"
    cfg.to_toml(path)
    proc = subprocess.run([str(rig.find_binary()), str(path), "--can", "udp:9", "--feed", addr,
                           "--log", str(tmp_path / "l.csv"), "--stats", str(tmp_path / "s.json")],
                          capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2
    assert "--feed" in proc.stderr and addr in proc.stderr.replace("[::1]", "[::1]"), proc.stderr
    assert not (tmp_path / "l.csv").exists()


def test_a_bad_datagram_is_named():
    with pytest.raises(ValueError, match="shorter than the 32-byte header"):
        parse(b"SAFD")
    with pytest.raises(ValueError, match="magic"):
        parse(b"XXXX" + bytes(28))
