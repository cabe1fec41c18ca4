"""The experimenter's live view: ``sensaug live`` reads the rig's live feed
(``sensaug.feed``), decimates it and serves it to Foxglove over its WebSocket
protocol (the Foxglove SDK's server); ``docs/live.md``.

* Channels: the topics of :data:`sensaug.topics.TOPICS` (handle, targets,
  phase, partner gains and variances, partner target, goal integration,
  torques, safety, loop timing, the mirror) and ``/run`` (source, status,
  stop reason, datagrams lost), each with a JSON Schema carrying units.
* Decimation: the rows of each bin of ``1/rate_hz`` s of the run's clock
  become one message per topic, at the bin's last tick: every field's value
  at that tick, and ``<field>_min`` / ``<field>_max`` over the bin (NaN
  ignored; null when none is known), so a one-tick spike stays visible.
  State is one bin's running extremes: memory does not grow with the run.
* Off the loop: this is a separate process reading UDP datagrams; the rig
  loop's tick does not know it exists. The server keeps at most
  ``backlog`` messages per client and drops the oldest for a client that
  does not keep up, so a stalled viewer bounds memory too.
* Loopback only by default (``host`` 127.0.0.1); ``--lan`` opens it to the
  lab network (0.0.0.0).
"""

from __future__ import annotations

import math
import signal
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from sensaug import logs, topics
from sensaug.export import RUN_SCHEMA, RUN_TOPIC
from sensaug.feed import Batch, FeedReader

__all__ = ["DEFAULT_PORT", "DEFAULT_FEED_PORT", "DEFAULT_RATE_HZ", "Decimator", "LiveView", "layout", "topic_schema"]

#: Foxglove's default WebSocket port.
DEFAULT_PORT = 8765
#: The live view's default feed port (``sensaug-rt --feed 127.0.0.1:9870``).
DEFAULT_FEED_PORT = 9870
#: Messages per topic per second.
DEFAULT_RATE_HZ = 100.0
#: Messages kept per client before the oldest are dropped (~1 s of every topic).
DEFAULT_BACKLOG = 1024

_FIELDS = ("tick", "t")


def topic_schema(topic: topics.Topic) -> dict:
    """A live topic's JSON Schema: the log topic's fields plus each column's
    bin minimum and maximum."""
    base = topics.json_schema(topic)
    extra = {}
    for name in topic.columns:
        prop = base["properties"][name]
        for end in ("min", "max"):
            extra[f"{name}_{end}"] = {**prop, "description": f"{end}imum over the bin of: {prop['description']}"}
    base["properties"].update(extra)
    base["description"] += "; decimated: the value at the bin's last tick, and each field's min and max over the bin"
    return base


_COLUMNS = tuple(c for t in topics.TOPICS for c in t.columns)
_INT = {name for name in _COLUMNS if logs.DTYPE[name].kind in "iu"}
_BOOL = {name for name in _COLUMNS if logs.DTYPE[name].kind == "b"}


def _json_value(name: str, v: float):
    # JSON has neither NaN nor infinity: both are null, as in the export
    # (the rig's partner_var is inf while the partner channel is held out).
    if not math.isfinite(v):
        return None
    if name in _BOOL:
        return bool(v)
    if name in _INT:
        return int(v)
    return v


@dataclass
class Decimator:
    """Rows in, one summary per bin of ``1/rate_hz`` s out (the run's clock)."""

    rate_hz: float = DEFAULT_RATE_HZ
    _bin: int | None = None
    _lo: np.ndarray = field(default_factory=lambda: np.full(len(_COLUMNS), np.nan))
    _hi: np.ndarray = field(default_factory=lambda: np.full(len(_COLUMNS), np.nan))
    _last: np.void | None = None

    def __post_init__(self) -> None:
        if not (self.rate_hz > 0 and math.isfinite(self.rate_hz)):
            raise ValueError(f"rate_hz: must be a finite rate > 0 Hz, got {self.rate_hz}")

    def push(self, rows: np.ndarray) -> list[dict]:
        """Adds rows (in tick order); returns the summaries of the bins they closed."""
        if len(rows) == 0:
            return []
        bins = np.floor(rows["t"] * self.rate_hz + 1e-9).astype(np.int64)
        values = np.column_stack([rows[c].astype(np.float64) for c in _COLUMNS])
        out = []
        edges = np.flatnonzero(np.diff(bins)) + 1
        for seg in np.split(np.arange(len(rows)), edges):
            b = int(bins[seg[0]])
            if self._bin is not None and b != self._bin:
                out.append(self._close())
            self._bin = b
            with np.errstate(all="ignore"):
                self._lo = np.fmin(self._lo, np.nanmin(np.where(np.isnan(values[seg]), np.inf, values[seg]), axis=0))
                self._hi = np.fmax(self._hi, np.nanmax(np.where(np.isnan(values[seg]), -np.inf, values[seg]), axis=0))
            self._last = rows[seg[-1]]
        return out

    def flush(self) -> list[dict]:
        """The open bin's summary (end of a run), if any."""
        return [self._close()] if self._last is not None else []

    def _close(self) -> dict:
        last = self._last
        summary = {"tick": int(last["tick"]), "t": float(last["t"])}
        for i, name in enumerate(_COLUMNS):
            lo, hi = self._lo[i], self._hi[i]
            summary[name] = _json_value(name, float(last[name]))
            summary[f"{name}_min"] = None if not math.isfinite(lo) else _json_value(name, lo)
            summary[f"{name}_max"] = None if not math.isfinite(hi) else _json_value(name, hi)
        self._lo = np.full(len(_COLUMNS), np.nan)
        self._hi = np.full(len(_COLUMNS), np.nan)
        self._last = None
        self._bin = None
        return summary


def _split(summary: dict) -> dict[str, dict]:
    """One bin's summary as one message per topic."""
    out = {}
    for topic in topics.TOPICS:
        msg = {"tick": summary["tick"], "t": summary["t"]}
        for name in topic.columns:
            for key in (name, f"{name}_min", f"{name}_max"):
                msg[key] = summary[key]
        out[topic.name] = msg
    return out


class LiveView:
    """The feed reader, the decimator and the Foxglove WebSocket server.

    ``run()`` serves until :meth:`stop` (or SIGINT/SIGTERM in ``sensaug
    live``); ``serve_in_thread()`` starts it in a thread (tests, ``demo --live``).
    """

    def __init__(
        self,
        *,
        feed_port: int = DEFAULT_FEED_PORT,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        rate_hz: float = DEFAULT_RATE_HZ,
        backlog: int = DEFAULT_BACKLOG,
    ) -> None:
        import foxglove

        self.decimator = Decimator(rate_hz)
        self.reader = FeedReader(feed_port)
        self._context = foxglove.Context()
        try:
            self.server = foxglove.start_server(
                name="sensaug live view", host=host, port=port, context=self._context, message_backlog_size=backlog
            )
        except Exception as e:  # the SDK raises its own error type for a taken port
            self.reader.close()
            raise ValueError(f"--port {port}: the live view cannot listen on {host}:{port} ({e}); choose another port") from None
        self.host = host
        self.channels = {
            t.name: foxglove.Channel(t.name, schema=topic_schema(t), context=self._context) for t in topics.TOPICS
        }
        self.channels[RUN_TOPIC] = foxglove.Channel(RUN_TOPIC, schema=RUN_SCHEMA, context=self._context)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._start_ns: int | None = None
        self._last_tick, self._last_t = 0, 0.0
        #: Bins published (all runs) and runs seen.
        self.bins = 0
        self.runs = 0

    @property
    def port(self) -> int:
        return self.server.port

    @property
    def url(self) -> str:
        return f"ws://{'127.0.0.1' if self.host in ('0.0.0.0', '') else self.host}:{self.port}"

    def _publish(self, summary: dict) -> None:
        self._last_tick, self._last_t = summary["tick"], summary["t"]
        ns = self._start_ns + round(summary["t"] * 1e9)
        for topic, msg in _split(summary).items():
            self.channels[topic].log(logs.to_json(msg), log_time=ns)
        self.bins += 1

    def _run_status(self, batch: Batch, status: str, end: dict | None = None) -> None:
        tick, t = self._last_tick, self._last_t
        msg = {"tick": tick, "t": t, "source": "rig", "status": status,
               "stop_reason": (end or {}).get("stop_reason"), "end": end,
               "feed_datagrams_lost": self.reader.lost}
        self.channels[RUN_TOPIC].log(logs.to_json(msg), log_time=batch.start_unix_ns + round(t * 1e9))

    def handle(self, batch: Batch) -> None:
        """One feed datagram: a new run resets the bins; rows are decimated
        and published; the end status closes the run."""
        if batch.start_unix_ns != self._start_ns:
            for s in self.decimator.flush():
                self._publish(s)
            self._start_ns = batch.start_unix_ns
            self._last_tick, self._last_t = 0, 0.0
            self.runs += 1
            self._run_status(batch, "running")
        for s in self.decimator.push(batch.rows):
            self._publish(s)
        if batch.end is not None:
            for s in self.decimator.flush():
                self._publish(s)
            self._run_status(batch, "ended", batch.end)

    def run(self) -> None:
        while not self._stop.is_set():
            batch = self.reader.recv(timeout_s=0.2)
            if batch is not None:
                self.handle(batch)

    def serve_in_thread(self) -> "LiveView":
        self._thread = threading.Thread(target=self.run, name="sensaug-live", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self.server.stop()
        self.reader.close()

    def __enter__(self) -> "LiveView":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def layout():
    """The Foxglove layout of the live view (and of an exported MCAP file):
    the useful plots in one import (``docs/live_layout.json``)."""
    import foxglove.layouts as fl

    def plot(title: str, *paths: str, label: str | None = None) -> fl.PlotPanel:
        return fl.PlotPanel(title=title, config=fl.PlotConfig(
            paths=[fl.PlotSeries(value=p, enabled=True, timestamp_method="receiveTime") for p in paths],
            show_legend=True, y_axis_label=label, time_window_mode="automatic"))

    def item(panel, proportion: float = 1.0) -> fl.SplitItem:
        return fl.SplitItem(proportion=proportion, content=panel)

    def column(*panels) -> fl.SplitContainer:
        return fl.SplitContainer(direction="column", items=[item(p) for p in panels])

    u = logs.UNITS
    left = column(
        plot("Handle and targets [pos]", "/handle.x", "/targets.tau", "/targets.tau_h",
             "/partner_target.tau_h_hat", label=u["x"]),
        plot("Partner gains (estimates)", "/partner_gains.Lhx_hat", "/partner_gains.Lhv_hat",
             "/partner_gains.Lhh_hat", label=f"{u['Lhx_hat']}, {u['Lhv_hat']}"),
        plot("Partner-gain variances", "/partner_gains.Lhx_var", "/partner_gains.Lhv_var", "/partner_gains.Lhh_var"),
        plot("Partner delay assumed [ms] (robot.partner_delay)", "/partner_delay.partner_delay_visual_ms",
             "/partner_delay.partner_delay_proprioceptive_ms", label="ms"),
        plot("Goal integration: (x - tau) estimates [pos]", "/targets.e", "/goal_integration.e_hat_own",
             "/goal_integration.e_hat_fused", label=u["e"]),
    )
    right = column(
        plot("Torque: commanded [trq] and sent [N m] (bin min/max)", "/torque.u", "/torque.torque_nm",
             "/torque.torque_nm_min", "/torque.torque_nm_max"),
        plot("Loop: compute and wake-up latency [us] (bin max)", "/loop.compute_us_max",
             "/loop.wake_latency_us_max", "/loop.compute_us", label="us"),
        plot("Missing feedback: ticks since the last (bin max)", "/safety.feedback_age_ticks_max",
             "/handle.fresh_min"),
        fl.StateTransitionsPanel(title="Phase, drive state, guard", config=fl.StateTransitionsConfig(paths=[
            fl.StateTransitionsSeries(value="/phase.phase", label="phase (0 gains, 1 trajectory, 2 integration, -1 stop)"),
            fl.StateTransitionsSeries(value="/safety.drive_state", label="drive (0 boot 1 disabled 2 enabled 3 fault)"),
            fl.StateTransitionsSeries(value="/safety.guard_max", label="guard (0 passed 1 clamped 2 non-finite)"),
            fl.StateTransitionsSeries(value="/run.status", label="run"),
        ])),
        fl.RawMessagesPanel(title="Run: status and stop reason", config=fl.RawMessagesConfig(topic_path="/run")),
    )
    return fl.Layout(content=fl.SplitContainer(direction="row", items=[item(left), item(right)]))


def serve(feed_port: int, host: str, port: int, rate_hz: float) -> int:
    """``sensaug live``: serves until SIGINT or SIGTERM."""
    view = LiveView(feed_port=feed_port, host=host, port=port, rate_hz=rate_hz)
    print(f"sensaug live: feed 127.0.0.1:{view.reader.port} -> Foxglove WebSocket {view.url} "
          f"({rate_hz:g} Hz per topic, min/max per bin)")
    print(f"run the rig with: sensaug demo --feed {view.reader.address}  (or sensaug-rt ... --feed {view.reader.address})")
    print("in Foxglove: Open connection -> Foxglove WebSocket -> the URL above; "
          "Layout -> Import from file -> docs/live_layout.json", flush=True)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: view._stop.set())
    try:
        view.run()
    finally:
        view.stop()
        print(f"sensaug live: {view.runs} runs, {view.bins} bins published, {view.reader.lost} feed datagrams lost")
    return 0


class LiveProcess:
    """``sensaug live`` in its own process (``sensaug demo --live``, the
    benchmark): started on a free feed port, stopped with SIGTERM."""

    def __init__(self, port: int = DEFAULT_PORT, rate_hz: float = DEFAULT_RATE_HZ, lan: bool = False,
                 timeout_s: float = 20.0) -> None:
        import socket
        import subprocess
        import sys

        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            probe.bind(("127.0.0.1", 0))
            self.feed_port = probe.getsockname()[1]
        cmd = [sys.executable, "-m", "sensaug", "live", "--feed-port", str(self.feed_port), "--port", str(port),
               "--rate", str(rate_hz), *(["--lan"] if lan else [])]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.url = ""
        ready = threading.Event()

        def read() -> None:
            for line in self.proc.stdout:
                if "Foxglove WebSocket ws://" in line and not self.url:
                    self.url = line.split("Foxglove WebSocket ", 1)[1].split()[0]
                    ready.set()
                self.lines.append(line)

        self.lines: list[str] = []
        threading.Thread(target=read, daemon=True).start()
        if not ready.wait(timeout_s):
            self.stop()
            raise RuntimeError(f"sensaug live did not start in {timeout_s:g} s: {self.proc.stderr.read().strip()}")

    @property
    def feed_address(self) -> str:
        return f"127.0.0.1:{self.feed_port}"

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=10)
            except Exception:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode


class Client:
    """A minimal Foxglove WebSocket client (the SDK's protocol, ``foxglove.sdk.v1``):
    subscribes to every advertised channel and collects ``(topic, log time
    ns, message)``. The tests' and the benchmark's viewer; ``stall=True``
    subscribes and then never reads (a frozen viewer)."""

    SUBPROTOCOL = "foxglove.sdk.v1"

    def __init__(self, url: str, *, stall: bool = False) -> None:
        from websockets.sync.client import connect

        self._connection = connect(url, subprotocols=[self.SUBPROTOCOL], open_timeout=5, max_size=None)
        self.ws = self._connection.__enter__()
        self.stall = stall
        self.channels: dict[int, dict] = {}
        self.messages: list[tuple[str, int, dict]] = []
        self._subs: dict[int, str] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, name="foxglove-client", daemon=True)
        self._thread.start()

    def _subscribe(self, channels: list[dict]) -> None:
        subs = []
        for ch in channels:
            self.channels[ch["id"]] = ch
            sid = len(self._subs) + 1
            self._subs[sid] = ch["topic"]
            subs.append({"id": sid, "channelId": ch["id"]})
        self.ws.send(logs.to_json({"op": "subscribe", "subscriptions": subs}))

    def _read(self) -> None:
        import json
        import struct

        from websockets.exceptions import ConnectionClosed

        while not self._stop.is_set():
            try:
                frame = self.ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            except ConnectionClosed:
                return
            if isinstance(frame, str):
                op = json.loads(frame)
                if op.get("op") == "advertise":
                    self._subscribe(op["channels"])
                    if self.stall:
                        self._stop.wait()
                        return
                continue
            if frame[0] == 1:
                sid, ns = struct.unpack_from("<IQ", frame, 1)
                self.messages.append((self._subs[sid], ns, json.loads(frame[13:])))

    def topic(self, name: str) -> list[tuple[int, dict]]:
        return [(ns, m) for t, ns, m in list(self.messages) if t == name]

    def close(self) -> None:
        self._stop.set()
        self._connection.__exit__(None, None, None)
        self._thread.join(timeout=5.0)
