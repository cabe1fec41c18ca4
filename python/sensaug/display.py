"""The participant's display: a full-screen OpenGL window (pyglet) showing
the handle's position (a cursor) and the target the current phase shows the
person, with text prompts between trials (docs/person.md).

It runs as its own process (``python -m sensaug.display`` or ``sensaug
display``) and never talks to the 1 kHz loop: it reads the loop's live feed
(:class:`FeedTail`: ``sensaug-rt --feed``, loopback datagrams sent by the
log writer thread, off the loop's thread, never waiting on a reader), so a
slow, frozen or killed display costs the loop nothing. The launcher watches the
display's own log (:class:`DisplayWatch`): a display that has drawn nothing
for ``display.freeze_timeout_ms`` ends the trial with the loop's controlled
stop (SIGTERM) or, with the virtual human and ``on_freeze = "continue"``,
is recorded and ignored.

Every frame is logged (:class:`DisplayLog`, :func:`load_display_log`): the
swap time on ``CLOCK_MONOTONIC`` (the rig's clock: ``rig_stats.json``
``start.tick0_monotonic_ns`` is tick 0's time on it), the tick shown, the
cursor and target as drawn (position unit and px), the dots' refresh number
(the dots are :func:`visual_dots` of the seed and that number) and the
frames dropped before it.
"""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Protocol

import numpy as np

from sensaug.config import ScenarioConfig

__all__ = [
    "DISPLAY_COLUMNS",
    "DisplayLog",
    "DisplayWatch",
    "Geometry",
    "FeedTail",
    "ScriptedSource",
    "Shown",
    "Source",
    "display_latency",
    "load_display_log",
    "visual_dots",
]

#: Format line of a display log.
DISPLAY_FORMAT = "# sensaug-display-log 1"
#: Columns of a display log, one row per frame (units in its metadata).
DISPLAY_COLUMNS = (
    "frame", "swap_ns", "tick", "t", "phase", "x", "cursor_px", "target", "target_px",
    "dots_refresh", "dropped", "prompt",
)
DISPLAY_UNITS = {
    "frame": "1", "swap_ns": "ns CLOCK_MONOTONIC", "tick": "1 (-1: no row yet)", "t": "s", "phase": "1",
    "x": "pos", "cursor_px": "px", "target": "pos", "target_px": "px",
    "dots_refresh": "1 (-1: one target drawn)", "dropped": "frames", "prompt": "text shown (empty: none)",
}

#: The display process's niceness (lower priority than the loop and the drive).
DISPLAY_NICE = 10

#: Nominal frame period when the window has no vsync (Xvfb): 60 Hz.
FRAME_S = 1 / 60

#: Colours (RGB) the tests look for in read-back frames.
BACKGROUND = (20, 20, 20)
CURSOR_RGB = (240, 240, 240)
TARGET_RGB = (230, 60, 40)
CURSOR_RADIUS_PX = 8
TARGET_RADIUS_PX = 14
DOT_RADIUS_PX = 2


@dataclass(frozen=True)
class Geometry:
    """Position unit -> screen pixel (origin bottom-left, as OpenGL's)."""

    width_px: int
    height_px: int
    px_per_unit: float
    direction: str = "right"

    def to_px(self, pos: float) -> tuple[float, float]:
        cx, cy = self.width_px / 2, self.height_px / 2
        d = pos * self.px_per_unit
        return {
            "right": (cx + d, cy),
            "left": (cx - d, cy),
            "up": (cx, cy + d),
            "down": (cx, cy - d),
        }[self.direction]

    def along(self, pos: float) -> float:
        """The coordinate of ``pos`` along the movement axis (px)."""
        x, y = self.to_px(pos)
        return x if self.direction in ("right", "left") else y


def visual_dots(seed: int, refresh: int, count: int, sigma: float) -> np.ndarray:
    """The ``refresh``-th set of dots: ``count`` x 2 offsets (position unit)
    from the target, along and across the movement axis, each N(0, sigma^2).
    A pure function of its arguments, so a trial re-renders exactly."""
    rng = np.random.default_rng([int(seed), int(refresh)])
    return rng.normal(0.0, sigma, size=(count, 2))


@dataclass
class Shown:
    """What one frame shows: the newest row the display has (or none)."""

    tick: int = -1
    t: float = math.nan
    phase: int = -1
    x: float = math.nan
    target: float = math.nan


class Source(Protocol):
    """Where the display gets the loop's state: ``poll()`` returns the newest
    row without blocking (None: nothing new)."""

    def poll(self) -> Optional[Shown]: ...


class FeedTail:
    """The loop's live feed (``sensaug-rt --feed 127.0.0.1:PORT``,
    :mod:`sensaug.feed`): a loopback UDP socket the display holds for its
    whole life; :meth:`poll` drains what the log writer thread sent since
    the last frame, without blocking, and returns the newest row.

    The loop's tick never sees the display: the writer thread sends each
    batch with one non-blocking ``sendto`` and the kernel drops what a slow,
    frozen or dead display does not read (``docs/live.md``). A trial's rows
    are told from an earlier run's late datagrams by the run's start
    (:meth:`follow`: only runs started at or after a given time)."""

    def __init__(self, port: int = 0) -> None:
        from sensaug.feed import FeedReader

        self.reader = FeedReader(port)
        self._since_unix_ns: Optional[int] = None

    @property
    def address(self) -> str:
        """What the launcher gives ``sensaug-rt --feed``."""
        return self.reader.address

    def follow(self, since_unix_ns: Optional[int]) -> None:
        """Show only runs that started at or after ``since_unix_ns`` (the
        launcher's clock just before it started the run; None: none)."""
        self._since_unix_ns = since_unix_ns

    def poll(self) -> Optional[Shown]:
        newest = None
        while (batch := self.reader.recv(0.0)) is not None:
            if self._since_unix_ns is None or batch.start_unix_ns < self._since_unix_ns or not len(batch.rows):
                continue
            newest = batch.rows[-1]
        if newest is None:
            return None
        return Shown(tick=int(newest["tick"]), t=float(newest["t"]), phase=int(newest["phase"]),
                     x=float(newest["x"]), target=float(newest["tau_h"]))

    def close(self) -> None:
        self.reader.close()


class ScriptedSource:
    """Plays a log (a simulated trial's or a rig's) at wall-clock speed from
    the first poll: a source to test and rehearse the display without a rig."""

    def __init__(self, log, speed: float = 1.0) -> None:
        self._data = log.data if hasattr(log, "data") else log
        self._speed = speed
        self._t0: Optional[float] = None

    def poll(self) -> Optional[Shown]:
        now = time.monotonic()
        if self._t0 is None:
            self._t0 = now
        t = (now - self._t0) * self._speed
        k = int(np.searchsorted(self._data["t"], t, side="right")) - 1
        if k < 0:
            return None
        r = self._data[min(k, len(self._data) - 1)]
        return Shown(tick=int(r["tick"]), t=float(r["t"]), phase=int(r["phase"]), x=float(r["x"]),
                     target=float(r["tau_h"]))

    @property
    def done(self) -> bool:
        return self._t0 is not None and (time.monotonic() - self._t0) * self._speed > float(self._data["t"][-1])


class DisplayLog:
    """The display's log: one CSV row per frame, each flushed to the kernel
    at once (the launcher's freeze watch reads the file's growth)."""

    def __init__(self, path: str | Path, meta: dict) -> None:
        self.path = Path(path)
        self._f = open(self.path, "w", buffering=1)  # noqa: SIM115 - line-buffered, one row per frame
        self._f.write(DISPLAY_FORMAT + "\n# " + json.dumps(meta, allow_nan=False) + "\n")
        self._f.write(",".join(DISPLAY_COLUMNS) + "\n")

    def frame(self, frame: int, swap_ns: int, shown: Shown, cursor_px: float, target_px: float,
              dots_refresh: int, dropped: int, prompt: str) -> None:
        prompt = prompt.replace(",", ";").replace("\n", " ")
        self._f.write(f"{frame},{swap_ns},{shown.tick},{shown.t!r},{shown.phase},{shown.x!r},{cursor_px!r},"
                      f"{shown.target!r},{target_px!r},{dots_refresh},{dropped},{prompt}\n")

    def close(self, end: dict) -> None:
        self._f.write("# " + json.dumps({"end": end}) + "\n")
        self._f.close()


def load_display_log(path: str | Path):
    """A display log as a DataFrame (metadata, and ``end`` after a clean end,
    in ``df.attrs``). A partial last line (a killed display) is ignored."""
    import pandas as pd

    path = Path(path)
    raw = path.read_bytes()
    lines = raw[: raw.rfind(b"\n") + 1].decode().split("\n")[:-1]
    if len(lines) < 3 or lines[0] != DISPLAY_FORMAT:
        raise ValueError(f"{path}: not a sensaug display log (first line {lines[0][:40] if lines else ''!r})")
    meta = json.loads(lines[1][2:])
    body = [ln for ln in lines[3:] if not ln.startswith("#")]
    for ln in lines[3:]:
        if ln.startswith("# "):
            meta.update(json.loads(ln[2:]))
    rows = [ln.split(",", len(DISPLAY_COLUMNS) - 1) for ln in body]
    df = pd.DataFrame(rows, columns=list(DISPLAY_COLUMNS))
    for c in ("frame", "swap_ns", "tick", "phase", "dots_refresh", "dropped"):
        df[c] = df[c].astype("int64")
    for c in ("t", "x", "cursor_px", "target", "target_px"):
        df[c] = df[c].astype("float64")
    df.attrs.update(meta)
    return df


def display_latency(display_log, rig_stats: dict, dt_s: float) -> dict:
    """Tick-to-swap latency (ms, p50/p99/max) of the frames that showed a
    tick: swap time minus the tick's time on ``CLOCK_MONOTONIC`` (tick 0's
    command time from the rig's stats + tick * dt), and the dropped frames."""
    t0 = (rig_stats.get("start") or {}).get("tick0_monotonic_ns") or 0
    df = display_log
    shown = df[df["tick"] >= 0]
    out = {"frames": int(len(df)), "dropped": int(df["dropped"].sum())}
    if t0 and len(shown):
        lat_ms = (shown["swap_ns"].to_numpy() - (t0 + shown["tick"].to_numpy() * dt_s * 1e9)) / 1e6
        out.update(latency_p50_ms=float(np.percentile(lat_ms, 50)),
                   latency_p99_ms=float(np.percentile(lat_ms, 99)), latency_max_ms=float(lat_ms.max()))
    return out


# --- the control channel: launcher <-> display over loopback UDP -----------

def _udp(port: int = 0) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port))
    sock.setblocking(False)
    return sock


@dataclass
class Command:
    """What the launcher asks the display to do next."""

    #: Text shown (empty: none).
    prompt: str = ""
    #: Show the feed's run that started at or after this time (ns since the
    #: Unix epoch, the launcher's clock before it started sensaug-rt; None:
    #: show only the prompt).
    follow_since_unix_ns: Optional[int] = None
    #: Write this display log while following it.
    display_log: Optional[str] = None
    #: Visual noise of this trial.
    sigma_v: float = 0.0
    seed: int = 0
    #: Phase codes drawn with visual noise.
    noisy_phases: list[int] = field(default_factory=list)
    #: Quit the display.
    quit: bool = False


# --- the window ---------------------------------------------------------------

def _window(cfg, visible: bool = True):
    import pyglet

    d = cfg.display
    try:
        config = pyglet.gl.Config(double_buffer=True)
        win = pyglet.window.Window(
            fullscreen=d.fullscreen, width=None if d.fullscreen else d.width_px,
            height=None if d.fullscreen else d.height_px, vsync=True, caption="sensaug", config=config,
            visible=visible)
    except pyglet.window.NoSuchConfigException:
        win = pyglet.window.Window(fullscreen=d.fullscreen, width=None if d.fullscreen else d.width_px,
                                   height=None if d.fullscreen else d.height_px, vsync=True, caption="sensaug")
    return win


class Renderer:
    """Draws one frame: the target (one ring, or a cloud of dots), the cursor
    and a prompt, with pyglet's batched shapes."""

    def __init__(self, win, geometry: Geometry, dots: int) -> None:
        import pyglet
        from pyglet import shapes

        self.pyglet = pyglet
        self.win, self.geom = win, geometry
        self.batch = pyglet.graphics.Batch()
        self.target = shapes.Arc(0, 0, TARGET_RADIUS_PX, thickness=3, color=TARGET_RGB, batch=self.batch)
        self.dots = [shapes.Circle(0, 0, DOT_RADIUS_PX, color=TARGET_RGB, batch=self.batch) for _ in range(dots)]
        self.cursor = shapes.Circle(0, 0, CURSOR_RADIUS_PX, color=CURSOR_RGB, batch=self.batch)
        self.label = pyglet.text.Label("", font_size=24, x=win.width // 2, y=win.height * 3 // 4,
                                       anchor_x="center", anchor_y="center", color=(*CURSOR_RGB, 255),
                                       batch=self.batch)

    def draw(self, shown: Shown, prompt: str, dots: Optional[np.ndarray]) -> tuple[float, float]:
        """Draws; returns the cursor's and the target's px along the axis (NaN: not drawn)."""
        gl = self.pyglet.gl
        gl.glClearColor(*(c / 255 for c in BACKGROUND), 1.0)
        self.win.clear()
        cursor_px = target_px = math.nan
        has_row = shown.tick >= 0 and math.isfinite(shown.x)
        self.cursor.visible = has_row
        if has_row:
            self.cursor.position = self.geom.to_px(shown.x)
            cursor_px = self.geom.along(shown.x)
        has_target = has_row and math.isfinite(shown.target)
        self.target.visible = has_target and dots is None
        for i, dot in enumerate(self.dots):
            dot.visible = has_target and dots is not None and i < len(dots)
        if has_target:
            target_px = self.geom.along(shown.target)
            if dots is None:
                self.target.position = self.geom.to_px(shown.target)
            else:
                tx, ty = self.geom.to_px(shown.target)
                s = self.geom.px_per_unit
                horizontal = self.geom.direction in ("right", "left")
                sign = -1.0 if self.geom.direction in ("left", "down") else 1.0
                for dot, (a, c) in zip(self.dots, dots):
                    along, across = sign * a * s, c * s
                    dot.position = (tx + along, ty + across) if horizontal else (tx + across, ty + along)
        self.label.text = prompt
        self.batch.draw()
        return cursor_px, target_px


def save_frame(path: str | Path) -> None:
    """The back buffer (the frame about to be shown) as a PNG."""
    import pyglet

    pyglet.image.get_buffer_manager().get_color_buffer().save(str(path))


def run_display(cfg: ScenarioConfig, *, control_port: int = 0, reply_port: int = 0,
                source: Optional[Source] = None, display_log: Optional[str | Path] = None,
                prompt: str = "", duration_s: Optional[float] = None,
                screenshots: Optional[Path] = None, screenshot_frames: tuple[int, ...] = (),
                screenshot_every: int = 0, visible: bool = True) -> int:
    """The display's loop: poll the source, draw, flip, log; until told to
    quit, Esc (sent to the launcher), the window closed, or ``duration_s``.

    ``control_port``: a loopback UDP port the launcher sends :class:`Command`
    JSON to (0: none); key presses (space, escape, digits, return, closing
    the window) are sent as ``{"key": name}`` to ``reply_port``. Under a
    launcher the display holds a :class:`FeedTail` of its own and says its
    address with its first frame (``{"key": "ready", "feed": ...}``); the
    launcher gives it to ``sensaug-rt --feed``.
    ``screenshots``: a folder for PNGs of the frames in ``screenshot_frames``
    or of every ``screenshot_every``-th frame (relative to the trial's
    display log's folder when commanded)."""
    import pyglet
    from pyglet.window import key

    d = cfg.display
    win = _window(cfg, visible=visible)
    geom = Geometry(win.width, win.height, d.px_per_unit, d.direction.value if hasattr(d.direction, "value") else d.direction)
    renderer = Renderer(win, geom, d.dots)
    ctl = _udp(control_port) if control_port else None
    reply = socket.socket(socket.AF_INET, socket.SOCK_DGRAM) if reply_port else None
    pressed: list[str] = []
    feed = FeedTail() if ctl is not None else None

    def send(name: str, **extra: str) -> None:
        pressed.append(name)
        if reply is not None:
            reply.sendto(json.dumps({"key": name, **extra}).encode(), ("127.0.0.1", reply_port))

    names = {key.SPACE: "space", key.ESCAPE: "escape", key.RETURN: "return", key.R: "r", key.Q: "q",
             **{getattr(key, f"_{i}"): str(i) for i in range(10)}}

    @win.event
    def on_key_press(symbol, modifiers):  # noqa: ARG001
        if symbol in names:
            send(names[symbol])
        return pyglet.event.EVENT_HANDLED  # Esc must not close the window by itself

    @win.event
    def on_close():
        send("close")

    cmd = Command(prompt=prompt, sigma_v=d.sigma_v, seed=d.seed,
                  noisy_phases=noisy_phases(cfg))
    log: Optional[DisplayLog] = None
    if display_log is not None:
        log = _open_log(display_log, cfg, geom, cmd, win)
    frame, dropped_total = 0, 0
    shots_rel = screenshots if control_port and screenshots is not None else None
    shown = Shown()
    ready = False
    t_start = time.monotonic()
    last_swap: Optional[int] = None
    try:
        while True:
            win.dispatch_events()
            if "close" in pressed and ctl is None:
                break
            if ctl is not None:
                new = _receive(ctl)
                if new is not None:
                    if log is not None:
                        log.close({"frames": frame, "dropped": dropped_total})
                        log = None
                    if new.quit:
                        break
                    cmd, shown, frame, dropped_total, last_swap = new, Shown(), 0, 0, None
                    feed.follow(cmd.follow_since_unix_ns)
                    source = feed
                    if cmd.display_log:
                        log = _open_log(cmd.display_log, cfg, geom, cmd, win)
                        if shots_rel is not None:
                            screenshots = Path(cmd.display_log).parent / shots_rel
                            screenshots.mkdir(parents=True, exist_ok=True)
            if source is not None:
                latest = source.poll()
                if latest is not None:
                    shown = latest
            dots = None
            refresh = -1
            if cmd.sigma_v > 0 and shown.phase in cmd.noisy_phases and math.isfinite(shown.t):
                refresh = int(shown.t * 1000.0 // d.refresh_ms)
                dots = visual_dots(cmd.seed, refresh, d.dots, cmd.sigma_v)
            cursor_px, target_px = renderer.draw(shown, cmd.prompt, dots)
            if screenshots is not None and log is not None and (
                    frame in screenshot_frames or (screenshot_every and frame % screenshot_every == 0)):
                save_frame(screenshots / f"frame_{frame:05d}.png")
            win.flip()
            swap = time.monotonic_ns()
            if frame == 0 and not ready:
                # After the first frame: shaders compiled, the window mapped.
                send("ready", **({"feed": feed.address} if feed is not None else {}))
                ready = True
            dropped = 0
            if last_swap is not None:
                gap = (swap - last_swap) / 1e9
                dropped = max(0, round(gap / FRAME_S) - 1)
                if gap < 0.9 * FRAME_S:  # no vsync (Xvfb): pace to about 60 Hz ourselves
                    time.sleep(FRAME_S - gap)
            last_swap = swap
            dropped_total += dropped
            if log is not None:
                log.frame(frame, swap, shown, cursor_px, target_px, refresh, dropped, cmd.prompt)
            frame += 1
            if duration_s is not None and time.monotonic() - t_start >= duration_s:
                break
            if isinstance(source, ScriptedSource) and source.done and ctl is None:
                break
    finally:
        if log is not None:
            log.close({"frames": frame, "dropped": dropped_total})
        for src in {id(x): x for x in (feed, source) if isinstance(x, FeedTail)}.values():
            src.close()
        win.close()
    return 0


def noisy_phases(cfg: ScenarioConfig) -> list[int]:
    """Phase codes drawn with visual noise: integration phases."""
    from sensaug.logs import PHASE_NAMES

    return [PHASE_NAMES.index("integration")]


def _open_log(path, cfg, geom: Geometry, cmd: Command, win) -> DisplayLog:
    import pyglet

    d = cfg.display
    meta = {
        "format": "sensaug-display-log", "format_version": 1,
        "clock": "CLOCK_MONOTONIC (python time.monotonic_ns); the rig's tick 0: rig_stats.json start.tick0_monotonic_ns",
        "window_px": [win.width, win.height], "px_per_unit": d.px_per_unit, "direction": geom.direction,
        "fullscreen": d.fullscreen, "vsync_requested": True, "vsync": bool(win.vsync),
        "gl_renderer": pyglet.gl.gl_info.get_renderer(), "gl_version": pyglet.gl.gl_info.get_version_string(),
        "dots": d.dots, "sigma_v": cmd.sigma_v, "seed": cmd.seed, "refresh_ms": d.refresh_ms,
        "noisy_phases": cmd.noisy_phases, "frame_s_without_vsync": FRAME_S,
        "source": "the loop's live feed (sensaug-rt --feed, the log writer thread's datagrams; the newest row at each frame)",
        "units": DISPLAY_UNITS,
        "dots_rule": "sensaug.display.visual_dots(seed, dots_refresh, dots, sigma_v): offsets along, across the axis",
    }
    return DisplayLog(path, meta)


def _receive(sock: socket.socket) -> Optional[Command]:
    """The newest command waiting (None: none)."""
    newest = None
    while True:
        try:
            data = sock.recv(65536)
        except BlockingIOError:
            return newest
        newest = Command(**json.loads(data))


# --- the launcher's side --------------------------------------------------------

class DisplayProcess:
    """The display as a subprocess the launcher drives over loopback UDP:
    :meth:`show` a prompt or a trial, :meth:`keys` read presses."""

    def __init__(self, cfg: ScenarioConfig, *, workdir: Path, env: Optional[dict] = None) -> None:
        self.cfg = cfg
        self.keys_sock = _udp()
        self.reply_port = self.keys_sock.getsockname()[1]
        probe = _udp()
        self.control_port = probe.getsockname()[1]
        probe.close()
        workdir.mkdir(parents=True, exist_ok=True)
        cfg_path = workdir / "display_config.toml"
        cfg.to_toml(cfg_path)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "sensaug.display", str(cfg_path), "--control-port", str(self.control_port),
             "--reply-port", str(self.reply_port)],
            env={**os.environ, **(env or {})}, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
            # Below the loop and the drive: a software-rendered (llvmpipe)
            # display must not take their CPU on a machine with few cores.
            preexec_fn=lambda: os.nice(DISPLAY_NICE))
        self._tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        #: The display's feed socket, for ``sensaug-rt --feed`` (said with "ready").
        self.feed_address: Optional[str] = None
        # The window is up before a trial starts (the freeze watch times frames).
        if self.wait_key({"ready"}, timeout_s=60.0) is None:
            err = self.proc.stderr.read() if self.proc.poll() is not None else "no window after 60 s"
            self.close()
            raise RuntimeError(f"display: could not open the window: {err.strip()[-2000:]}")

    def show(self, cmd: Command) -> None:
        self._tx.sendto(json.dumps(cmd.__dict__).encode(), ("127.0.0.1", self.control_port))

    def keys(self) -> list[str]:
        out = []
        while True:
            try:
                msg = json.loads(self.keys_sock.recv(4096))
            except BlockingIOError:
                return out
            self.feed_address = msg.get("feed", self.feed_address)
            out.append(msg["key"])

    def wait_key(self, wanted: set[str], poll_s: float = 0.02, timeout_s: Optional[float] = None) -> Optional[str]:
        """The first key of ``wanted`` pressed (None on timeout or a dead display)."""
        t0 = time.monotonic()
        while timeout_s is None or time.monotonic() - t0 < timeout_s:
            for k in self.keys():
                if k in wanted:
                    return k
            if self.proc.poll() is not None:
                return None
            time.sleep(poll_s)
        return None

    def alive(self) -> bool:
        return self.proc.poll() is None

    def close(self) -> None:
        if self.proc.poll() is None:
            self.show(Command(quit=True))
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.keys_sock.close()
        self._tx.close()


class DisplayWatch:
    """Watches a trial's display while the loop runs, on a thread of the
    launcher: the display log must grow at least every
    ``display.freeze_timeout_ms`` once its first frame is written; Esc or a
    closed window on the display, or a frozen or dead display with
    ``on_freeze = "stop"``, sends the loop SIGTERM (its controlled stop).

    After :meth:`stop`: ``reason`` (None, "escape", "display frozen",
    "display exited"), ``detected_ns`` (CLOCK_MONOTONIC), ``stopped_loop``."""

    def __init__(self, display: DisplayProcess, display_log: Path, rt: subprocess.Popen) -> None:
        self.display, self.path, self.rt = display, display_log, rt
        d = display.cfg.display
        self.timeout_ns = int(d.freeze_timeout_ms * 1e6)
        self.stop_on_freeze = (d.on_freeze.value if hasattr(d.on_freeze, "value") else d.on_freeze) == "stop"
        self.reason: Optional[str] = None
        self.detected_ns = 0
        self.stopped_loop = False
        self.freezes = 0
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> "DisplayWatch":
        self._thread.start()
        return self

    def _trip(self, reason: str, stop: bool) -> None:
        if self.reason is None:
            self.reason, self.detected_ns = reason, time.monotonic_ns()
        if stop and not self.stopped_loop and self.rt.poll() is None:
            self.rt.send_signal(signal.SIGTERM)
            self.stopped_loop = True

    def _run(self) -> None:
        # The trial's first frame (a new log) may take a little longer: allow 1 s.
        size, changed = -1, time.monotonic_ns() + max(0, int(1e9) - self.timeout_ns)
        frozen = False
        while not self._done.wait(0.005) and self.rt.poll() is None:
            if any(k in ("escape", "close") for k in self.display.keys()):
                self._trip("escape", True)
            if not self.display.alive():
                self._trip("display exited", self.stop_on_freeze)
                continue
            try:
                now_size = self.path.stat().st_size
            except FileNotFoundError:
                now_size = -1
            now = time.monotonic_ns()
            if now_size != size:
                size, changed, frozen = now_size, now, False
            elif now - changed > self.timeout_ns and not frozen:
                frozen = True
                self.freezes += 1
                self._trip("display frozen", self.stop_on_freeze)

    def stop(self) -> None:
        self._done.set()
        self._thread.join()


def watch_summary(watch: DisplayWatch, run) -> dict:
    """After a rig run with the display: the display closes the trial's log
    (a blank prompt), then its frames, drops, latency and the watch's event."""
    event = watch.reason
    if watch.display.alive() and event != "display frozen":
        watch.display.show(Command(prompt=""))
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline and not watch.path.read_bytes().rstrip().endswith(b"}}"):
            time.sleep(0.01)
    out: dict = {"event": event, "detected_monotonic_ns": watch.detected_ns or None,
                 "stopped_loop": watch.stopped_loop, "freezes": watch.freezes}
    try:
        df = load_display_log(watch.path)
    except (FileNotFoundError, ValueError):
        return {**out, "frames": 0, "dropped": 0}
    out.update(display_latency(df, run.stats, run.config.plant.dt_s))
    return out


def main(argv: list[str] | None = None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="sensaug display", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config", type=Path, help="the trial configuration (its [display] table)")
    p.add_argument("--feed", type=int, default=None, metavar="PORT",
                   help="show the runs of `sensaug-rt --feed 127.0.0.1:PORT` (default: play --replay, or show a prompt)")
    p.add_argument("--replay", type=Path, default=None, help="play a saved log (simulated or rig) at wall-clock speed")
    p.add_argument("--display-log", type=Path, default=None, help="write the frame log here")
    p.add_argument("--prompt", default="", help="text shown")
    p.add_argument("--duration", type=float, default=None, help="close after this many seconds")
    p.add_argument("--window", action="store_true", help="a window of [display] width_px x height_px, not full screen")
    p.add_argument("--screenshots", type=Path, default=None, help="folder for PNGs of --screenshot-frames")
    p.add_argument("--screenshot-frames", default="", help="frame numbers to save, comma-separated")
    p.add_argument("--control-port", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--reply-port", type=int, default=0, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    cfg = ScenarioConfig.from_toml(args.config)
    if args.window:
        cfg.display.fullscreen = False
    source: Optional[Source] = None
    if args.feed is not None:
        try:
            tail = FeedTail(args.feed)
        except ValueError as e:
            p.error(str(e))
        tail.follow(0)  # every run sent to this port
        source = tail
    elif args.replay is not None:
        from sensaug.logs import load_log

        source = ScriptedSource(load_log(args.replay))
    if args.screenshots is not None and not args.control_port:
        args.screenshots.mkdir(parents=True, exist_ok=True)
    frames = tuple(int(f) for f in args.screenshot_frames.split(",") if f.strip())
    every = 0
    # Tests and rehearsals: SENSAUG_DISPLAY_SCREENSHOTS=DIR:N saves every N-th frame of each trial.
    shots_env = os.environ.get("SENSAUG_DISPLAY_SCREENSHOTS")
    if shots_env and args.screenshots is None:
        where, _, n = shots_env.rpartition(":")
        args.screenshots, every = Path(where), int(n)
    return run_display(cfg, control_port=args.control_port, reply_port=args.reply_port, source=source,
                       display_log=args.display_log, prompt=args.prompt, duration_s=args.duration,
                       screenshots=args.screenshots, screenshot_frames=frames, screenshot_every=every)


if __name__ == "__main__":
    sys.exit(main())
