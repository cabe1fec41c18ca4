"""The live view (docs/live.md): the decimator keeps every bin's extremes, and
a real Foxglove WebSocket client connected to the loopback server receives
every channel at the configured rate, timestamps monotonic, values equal to
the log's at those ticks — fed by a short virtual-rig run through
``sensaug-rt --feed``."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest

from sensaug import logs, presets, topics
from sensaug.export import RUN_TOPIC
from sensaug.live import Client, Decimator, LiveView, layout

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


def test_the_layout_file_is_the_generated_one():
    from pathlib import Path

    committed = json.loads((Path(__file__).parent.parent / "docs" / "live_layout.json").read_text())
    assert committed == json.loads(layout().to_json()), "regenerate: python -m sensaug live --write-layout docs/live_layout.json"
    text = json.dumps(committed)
    for topic in topics.TOPICS[:-1]:  # every rig channel is plotted (the mirror is simulation-only)
        assert f'"{topic.name}.' in text, topic.name
