"""The live view (docs/live.md): the decimator keeps every bin's extremes, and
a real Foxglove WebSocket client connected to the loopback server receives
every channel at the configured rate, timestamps monotonic, values equal to
the log's at those ticks — fed by a short virtual-rig run through
``sensaug-rt --feed``."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import pytest
from test_rig import stall_tolerant

from sensaug import logs, presets, topics
from sensaug.export import RUN_TOPIC
from sensaug.live import Client, Decimator, LiveView, _split, layout

pytestmark = pytest.mark.timeout(180)


def rows(n: int, start: int = 0) -> np.ndarray:
    r = np.zeros(n, dtype=logs.DTYPE)
    r["tick"] = np.arange(start, start + n)
    r["t"] = r["tick"] * 1e-3
    r["x"] = np.sin(r["t"])
    r["compute_us"] = 20.0
    r["Lhx_hat"] = np.nan
    return r


def test_each_bin_keeps_its_last_value_min_and_max():
    data = rows(1000)
    data["compute_us"][437] = 900.0  # a one-tick spike
    dec = Decimator(100.0)
    out = []
    for k in range(0, 1000, 7):  # batches that do not line up with bins
        out += dec.push(data[k : k + 7])
    out += dec.flush()
    assert len(out) == 100
    assert [s["tick"] for s in out] == list(range(9, 1000, 10))
    for s in out:
        b = data[s["tick"] - 9 : s["tick"] + 1]
        assert s["x"] == data["x"][s["tick"]]
        assert (s["x_min"], s["x_max"]) == (b["x"].min(), b["x"].max())
        assert s["Lhx_hat"] is None and s["Lhx_hat_min"] is None  # NaN: not known
        assert isinstance(s["tick"], int) and isinstance(s["fresh"], bool)
    spike = out[43]
    assert spike["compute_us_max"] == 900.0 and spike["compute_us"] == 20.0
    with pytest.raises(ValueError, match="rate_hz"):
        Decimator(0.0)


def test_an_infinity_is_null_and_the_message_is_json():
    """The rig's partner_var is inf while the partner channel is held out
    (a person-like partner's run holds it out for whole phases): the bin's
    value is null, as NaN, and its message serialises (an inf used to stop
    the live view's thread: JSON has no infinity)."""
    data = rows(20)
    data["partner_var"] = np.inf
    dec = Decimator(100.0)
    out = dec.push(data) + dec.flush()
    assert out and all(s["partner_var"] is None and s["partner_var_max"] is None for s in out)
    for msg in _split(out[0]).values():
        json.loads(logs.to_json(msg))


def test_the_layout_file_is_the_generated_one():
    committed = json.loads((Path(__file__).parent.parent / "docs" / "live_layout.json").read_text())
    assert committed == json.loads(layout().to_json()), "regenerate: python -m sensaug live --write-layout docs/live_layout.json"
    text = json.dumps(committed)
    for topic in topics.TOPICS[:-1]:  # every rig channel is plotted (the mirror is simulation-only)
        assert f'"{topic.name}.' in text, topic.name


def short_rig():
    """A 3 s virtual-rig run (three 1 s phases), stall-tolerant
    (test_rig.stall_tolerant): on this loaded 2-core VM the loop or the
    Python drive stalls now and then; the subject is the live view."""
    return stall_tolerant(presets.hi5_rig(phase_s=1.0))


def wait_for(cond, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.05)
    return cond()


def same_value(expected, got) -> bool:
    """The log's value and the message's (NaN and infinities are null, as
    JSON has neither; ints and bools exact; floats exact: JSON carries their
    shortest round-trip digits)."""
    if isinstance(expected, float) and not math.isfinite(expected):
        return got is None
    return expected == got


def test_a_real_client_gets_every_channel_at_the_rate_with_the_logs_values(tmp_path):
    from sensaug import rig

    rate = 100.0
    with LiveView(feed_port=0, port=0, rate_hz=rate) as view:
        assert view.server.port and view.url.startswith("ws://127.0.0.1:")
        view.serve_in_thread()
        client = Client(view.url)
        try:
            assert wait_for(lambda: len(client.channels) == len(topics.TOPICS) + 1, 10.0), client.channels
            run = rig.run_virtual_rig(short_rig(), out=tmp_path, capture=None, feed=[view.reader.address])
            # Any end will do (a stalled drive on this loaded VM may stop the
            # run early): the subject is that the view shows what the log has.
            assert len(run.log) > 0, run.stderr
            assert wait_for(lambda: any(m["status"] == "ended" for _, m in client.topic(RUN_TOPIC)), 10.0)
        finally:
            client.close()
        lost = view.reader.lost
    log = run.log
    assert lost == 0, "loopback datagrams lost"
    end = log.meta["end"]
    assert end["feed_datagrams_sent"] > 0 and end["feed_datagrams_dropped"] == 0
    start_ns = log.meta["start_unix_s"] * 1e9
    bins = np.floor(log["t"] * rate + 1e-9).astype(np.int64)
    last_of_bin = np.flatnonzero(np.diff(bins, append=bins[-1] + 1))  # each bin's last tick
    for topic in topics.TOPICS:
        got = client.topic(topic.name)
        assert [m["tick"] for _, m in got] == log["tick"][last_of_bin].tolist(), f"{topic.name}: not one message per bin"
        times = np.array([ns for ns, _ in got], dtype=np.int64)
        assert np.all(np.diff(times) > 0), f"{topic.name}: timestamps not increasing"
        np.testing.assert_allclose(times - start_ns, log["t"][last_of_bin] * 1e9, atol=1e3)  # 1 us: float rounding
        # The configured rate: one message per 10 ms of the run's clock.
        assert np.median(np.diff(times)) == pytest.approx(1e9 / rate, rel=1e-6)
        for (_, msg), k in zip(got, last_of_bin):
            b = bins == bins[k]
            for name in topic.columns:
                col = log[name]
                assert same_value(col[k].item(), msg[name]), f"{topic.name}.{name} at tick {k}"
                finite = col[b][~np.isnan(col[b])] if col.dtype.kind == "f" else col[b]
                # JSON has no infinity: a non-finite extreme (partner_var is
                # inf while the channel is held out) arrives as null.
                lo = finite.min().item() if finite.size else None
                hi = finite.max().item() if finite.size else None
                lo, hi = (None if isinstance(v, float) and not math.isfinite(v) else v for v in (lo, hi))
                assert (msg[f"{name}_min"], msg[f"{name}_max"]) == (lo, hi), f"{topic.name}.{name} extremes at tick {k}"
    status = [m for _, m in client.topic(RUN_TOPIC)]
    assert status[0]["status"] == "running" and status[-1]["status"] == "ended"
    assert status[-1]["stop_reason"] == end["stop_reason"] == run.stats["stop_reason"]

    # The same run's log exported to MCAP reads back equal to the CSV.
    from test_export import check_against_log

    from sensaug.export import to_mcap

    check_against_log(to_mcap(tmp_path / "rig_log.csv", tmp_path / "rig_log.mcap"), log)


def test_the_server_listens_on_loopback_only_by_default():
    """The WebSocket server's listening socket is 127.0.0.1 (``/proc/net/tcp``:
    state 0A = LISTEN, address 0100007F = 127.0.0.1); ``--lan`` widens it."""
    with LiveView(feed_port=0, port=0) as view:
        lines = Path("/proc/net/tcp").read_text().splitlines()[1:]
        port_hex = f"{view.port:04X}"
        listening = [ln.split()[1] for ln in lines if ln.split()[1].endswith(":" + port_hex) and ln.split()[3] == "0A"]
        assert listening == ["0100007F:" + port_hex], listening
