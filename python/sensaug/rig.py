"""The experiment on the virtual Hi5 rig: the virtual drive (Python,
python-can) and the real-time binary (`sensaug-rt`, Rust) as two processes
on the loopback CAN bus, then the log read back (``sensaug.load_log``: the
same schema as a simulated trial, ``docs/logs.md``).

The real-time binary is found by :func:`find_binary`: ``$SENSAUG_RT``, the
environment's scripts folder or PATH (the ``sensaug-rt`` wheel), else the
checkout's ``target/release`` (``scripts/setup.sh`` builds it).

Each run's output folder gets the resolved configuration, the log, the
statistics, a capture of the bus traffic (``bus.log``, candump's log format,
recorded by ``sensaug.capture`` off the real-time thread) and a
``README.txt`` saying what each file is. Every one of these paths is checked
before anything is written or started (:func:`check_outputs`): each a
regular file or absent, no two the same (``docs/safety.md``, "Output
paths").
"""

from __future__ import annotations

import errno
import importlib
import importlib.metadata
import json
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from sensaug import _core, _resources, metrics
from sensaug.capture import BusCapture, CaptureStats
from sensaug.config import ScenarioConfig
from sensaug.logs import Log, load_log

__all__ = [
    "STOP_KEYS", "RigRun", "StopKey", "bus_port", "capture_format", "check_outputs", "find_binary", "run_virtual_rig",
    "stop_process", "write_readme",
]  # fmt: skip


def find_binary() -> Path:
    """The `sensaug-rt` executable (:func:`sensaug._resources.rt_binary`:
    ``$SENSAUG_RT``, the environment, PATH, the checkout's ``target/release``)."""
    return _resources.rt_binary()


@dataclass
class RigRun:
    """What one rig run produced."""

    config: ScenarioConfig
    log: Log
    stats: dict
    returncode: int
    drive_returncode: int
    stderr: str
    #: The loopback bus's UDP port.
    port: int = 0
    #: The bus capture (None with ``capture=None``).
    capture: Optional[CaptureStats] = None
    #: File name in the output folder -> one line of what it is (``README.txt``).
    files: dict[str, str] = field(default_factory=dict)
    #: Whether the user interrupted the run (Ctrl-C); the log holds what ran.
    interrupted: bool = False
    #: With the participant's display: frames, dropped frames, tick-to-swap
    #: latency (ms) and the display's event ("escape", "display frozen",
    #: "display exited"; None) (``sensaug.display``).
    display: Optional[dict] = None
    #: The experimenter's stop key, when it was pressed (:class:`StopKey`):
    #: the key, ``pressed_monotonic_ns`` and whether it stopped the loop.
    stop_key: Optional[dict] = None

    def write_readme(self, out: str | Path, extra: dict[str, str] | None = None) -> Path:
        """``out/README.txt``: this run's files (and ``extra`` ones, e.g. plots)."""
        return write_readme(
            Path(out), {**self.files, **(extra or {})},
            title=f"sensaug virtual-rig run on the loopback CAN bus, port {self.port}",
        )

    def phase_mask(self, kind: str, *, skip_s: float = 0.0, last_s: float | None = None) -> np.ndarray:
        m = self.log["phase"] == self.log.phase_code(kind)
        if not m.any():
            raise ValueError(f"kind: the log has no {kind!r} phase")
        t = self.log["t"]
        t0, t1 = t[m][0], t[m][-1]
        if last_s is not None:
            return m & (t > t1 - last_s)
        return m & (t >= t0 + skip_s)

    def gain_window_s(self, last_s: float | None = None) -> float:
        """The window :meth:`gain_estimate` averages over: ``last_s`` (default
        the robot's own, ``robot.gain_window_s``), or the whole gain phase
        when it ran shorter."""
        t = self.log["t"][self.log["phase"] == self.log.phase_code("gains")]
        ran = float(t[-1] - t[0]) + self.config.plant.dt_s if len(t) else 0.0
        return min(last_s or self.config.robot.gain_window_s, ran)

    def gain_estimate(self, last_s: float | None = None) -> np.ndarray:
        """Mean estimated gains over the last :meth:`gain_window_s` of the gain phase."""
        return metrics.gain_estimate(self.log, self.phase_mask("gains", last_s=self.gain_window_s(last_s)))

    def completed_phases(self) -> list[str]:
        """The phase kinds the run went through to their end: every tick the
        configuration gives them is in the log (one tick short allowed: the
        last tick of a stopped run may be its first stop tick), in order."""
        dt = self.config.plant.dt_s
        done = []
        for kind in ("gains", "trajectory", "integration"):
            planned = round(sum(p.duration_s for p in self.config.phases if p.kind == kind) / dt)
            ran = int((self.log["phase"] == self.log.phase_code(kind)).sum())
            if planned and ran >= planned - 1:
                done.append(kind)
        return done

    def partner_target_rmse(self, skip_s: float = 2.0) -> float:
        return metrics.partner_target_rmse(self.log, self.phase_mask("trajectory", skip_s=skip_s))

    def integration_rmse(self, skip_s: float = 2.0) -> dict[str, float]:
        """RMSE of the robot's (x - tau) estimate against x - tau, with the
        measured x and the true target (the binary injected the noise)."""
        return metrics.integration_rmse(self.log, self.phase_mask("integration", skip_s=skip_s))


def bus_port(port: int | None = None) -> int:
    """The loopback bus port for a run: ``port`` checked, or a free one.

    Raises:
        ValueError: ``port`` is not an integer in 1..=65535, or something on
            this machine already holds it (another rig, drive or logger).
    """
    from sensaug_bridge.udp_bus import BROADCAST_ADDR, free_port

    if port is None:
        return free_port()
    if isinstance(port, bool) or not isinstance(port, int) or not 1 <= port <= 65535:
        raise ValueError(f"port: must be a UDP port 1..=65535, got {port!r}; or omit it for a free one")
    # Binding without SO_REUSEPORT fails while any bus peer holds the port.
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        try:
            sock.bind((BROADCAST_ADDR, port))
        except OSError as err:
            why = (
                "is in use (another rig, drive or python-can logger is on it)"
                if err.errno == errno.EADDRINUSE
                else f"cannot be bound ({err.strerror})"
            )
            raise ValueError(f"port: {port} {why}; pick another port or omit it for a free one") from None
    return port


def check_outputs(outputs: dict[str, str | Path]) -> None:
    """Checks output paths by name before a run writes any of them, as
    ``sensaug-rt`` checks its own (one implementation, in Rust): each a
    regular file or absent (never a device, FIFO, socket, folder or link),
    its ``<path>.partial`` too, and no two the same file.

    Raises:
        ConfigError: ``<name>: <path> is a FIFO (named pipe), not a regular
            file; ...``, at the first bad one.
    """
    _core.check_output_paths([(name, str(path)) for name, path in outputs.items()])


def _output_folder(out: Path) -> Path:
    """``out`` created if needed; a ValueError if it is something else."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise ValueError(f"out: {out} exists and is not a directory; give a folder for the run's files") from None
    return out


def write_readme(out: Path, files: dict[str, str], *, title: str) -> Path:
    """``out/README.txt``: what the run was and one line per file it wrote."""
    width = max(len(name) for name in files) if files else 0
    lines = [
        title,
        f"written {datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M:%S')} UTC by sensaug; "
        "other files in this folder are not from this run.",
        "",
        *(f"{name.ljust(width)}  {what}" for name, what in files.items()),
    ]
    path = Path(out) / "README.txt"
    path.write_text("\n".join(lines) + "\n")
    return path


#: The entry-point group of the virtual drives, as python-can's
#: ``can.interface``: one entry per ``[rig] drive`` profile, its name the
#: profile, its value the drive's module (run with ``python -m``; its
#: ``PROFILE_NAME`` names the profile for people). ``sensaug_bridge``
#: registers ``hi5`` and ``cia402`` (firmware_bridge/pyproject.toml).
VIRTUAL_DRIVE_ENTRY_POINTS = "sensaug.virtual_drives"


def virtual_drives() -> dict[str, str]:
    """``[rig] drive`` profile -> the module of its virtual drive, from the
    installed packages' :data:`VIRTUAL_DRIVE_ENTRY_POINTS`."""
    return {ep.name: ep.module for ep in importlib.metadata.entry_points(group=VIRTUAL_DRIVE_ENTRY_POINTS)}


def _drive_module(drive: str) -> str:
    drives = virtual_drives()
    if drive not in drives:
        raise ValueError(
            f"rig.drive: no virtual drive is registered for {drive!r} (registered: {sorted(drives)}); "
            f"install the package that registers it under the {VIRTUAL_DRIVE_ENTRY_POINTS!r} entry points "
            f"(pip install -e firmware_bridge registers hi5 and cia402)"
        )
    return drives[drive]


def drive_profile_name(drive: str) -> str:
    """The profile's name for people (its virtual drive's ``PROFILE_NAME``)."""
    return str(getattr(importlib.import_module(_drive_module(drive)), "PROFILE_NAME", drive))


def standard_drive(cfg: Any) -> bool:
    """Whether the virtual rig simulates a standard CiA 402 drive (no SYNC
    counter echo 0x2000: ``sensaug-virtual-cia402 --standard``): when the
    configuration runs the CiA 402 profile with ``rig.cia402.freshness =
    "standard"`` (docs/cia402.md, "Freshness without 0x2000")."""
    return cfg.rig.drive == "cia402" and cfg.rig.cia402.freshness == "standard"


def start_drive(
    port: int,
    *,
    duration_s: float,
    extra: list[str] | None = None,
    drive: str = "hi5",
    fifo_priority: int | None = None,
    standard: bool = False,
) -> subprocess.Popen:
    """The virtual drive of profile ``drive`` ("hi5" or "cia402", registered
    under :data:`VIRTUAL_DRIVE_ENTRY_POINTS`) as a subprocess on the loopback bus at ``port``;
    under SCHED_FIFO at ``fifo_priority`` when given (the loop's
    ``rig.realtime.fifo_priority``: a real drive is hardware that never
    stalls, and a simulated one held off the CPU starves the loop of
    feedback)."""
    cmd = [
        sys.executable,
        "-m",
        _drive_module(drive),
        "--channel",
        str(port),
        "--duration",
        f"{duration_s:g}",
        "-q",
        *([] if fifo_priority is None else ["--fifo-priority", str(fifo_priority)]),
        *(["--standard"] if standard else []),
        *(extra or []),
    ]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def stop_process(proc: subprocess.Popen, timeout_s: float = 10.0) -> int:
    """SIGTERM, then SIGKILL after ``timeout_s``; the exit code."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


#: The experimenter's stop keys in the launcher's terminal (docs/safety.md,
#: "The stop key"): the space bar, the largest key, and ``s``. Each sends
#: the loop SIGTERM: its controlled stop, then the drive disabled.
STOP_KEYS = {b" ": "SPACE", b"s": "s", b"S": "S"}

#: The hint printed when a trial starts with the stop key armed.
STOP_KEY_HINT = "press SPACE or s in this terminal to stop the trial (controlled stop, drive disabled)"


class StopKey:
    """The experimenter's stop key: a thread of the launcher reads its
    terminal while a trial runs and sends the loop SIGTERM (its controlled
    stop) on any of :data:`STOP_KEYS`. The loop is another process and
    never waits on it.

    The terminal is switched to cbreak mode for the trial (a key arrives
    without Enter; Ctrl-C stays a signal) and restored after; keys typed
    before the trial are discarded, so a key pressed between trials does not
    stop the next one. Armed only when ``stream`` is a terminal and this
    process is its foreground (:meth:`arm`); otherwise (a pipe, CI, a
    background job) there is nothing to read.

    After :meth:`stop`: ``key`` (None if no stop key was pressed),
    ``pressed_ns`` (CLOCK_MONOTONIC, when the launcher read it) and
    ``stopped_loop``."""

    def __init__(self, fd: int, rt: subprocess.Popen) -> None:
        import termios

        self.fd, self.rt = fd, rt
        self.key: Optional[str] = None
        self.pressed_ns = 0
        self.stopped_loop = False
        self._saved = termios.tcgetattr(fd)
        self._wake_r, self._wake_w = os.pipe()
        self._thread = threading.Thread(target=self._run, daemon=True)

    @classmethod
    def arm(cls, rt: subprocess.Popen, stream=None) -> Optional["StopKey"]:
        """A started watch of ``stream`` (default: stdin) for ``rt``, or None
        when ``stream`` is not this process's foreground terminal."""
        import termios
        import tty

        stream = sys.stdin if stream is None else stream
        try:
            fd = stream.fileno()
            if not os.isatty(fd) or os.tcgetpgrp(fd) != os.getpgrp():
                return None
            watch = cls(fd, rt)
            tty.setcbreak(fd, termios.TCSANOW)
            termios.tcflush(fd, termios.TCIFLUSH)
        except (AttributeError, ValueError, OSError, termios.error):
            return None
        watch._thread.start()
        return watch

    def _run(self) -> None:
        while self.rt.poll() is None:
            ready, _, _ = select.select([self.fd, self._wake_r], [], [], 0.5)
            if self._wake_r in ready:
                return
            if self.fd not in ready:
                continue
            try:
                typed = os.read(self.fd, 64)
            except OSError:
                return
            if not typed:
                return
            hit = next((name for key, name in STOP_KEYS.items() if key in typed), None)
            if hit is not None and self.key is None:
                self.key, self.pressed_ns = hit, time.monotonic_ns()
                if self.rt.poll() is None:
                    self.rt.send_signal(signal.SIGTERM)
                    self.stopped_loop = True

    def stop(self) -> Optional[dict]:
        """Ends the watch and restores the terminal; what happened (None if
        no stop key was pressed)."""
        import termios

        os.write(self._wake_w, b"x")
        self._thread.join()
        os.close(self._wake_r)
        os.close(self._wake_w)
        try:
            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)
        except termios.error:
            pass
        if self.key is None:
            return None
        return {"key": self.key, "pressed_monotonic_ns": self.pressed_ns, "stopped_loop": self.stopped_loop}


def run_virtual_rig(
    config: ScenarioConfig | str | Path,
    *,
    out: str | Path = "out",
    port: int | None = None,
    timeout_s: float | None = None,
    capture: str | None = "bus.log",
    progress: bool | None = False,
    also_written: dict[str, Path] | None = None,
    feed: Sequence[str] = (),
    display=None,
    stop_key: bool | None = None,
    drive_args: Sequence[str] | None = None,
) -> RigRun:
    """Runs one trial on the virtual rig and returns its log and statistics.

    ``config`` is a configuration or a TOML path; its ``[rig]`` table is used
    (``drive`` picks the virtual drive started, :func:`virtual_drives`)
    except for the CAN URL (``port``, checked by :func:`bus_port`; default: a
    free loopback port) and the output paths (under ``out``). ``capture`` is
    the bus capture's file name in ``out`` (the suffix picks python-can's
    writer: ``.log`` candump's log format, ``.blf``...); None records none.
    ``out/README.txt`` lists what the run wrote. ``progress``: a tqdm bar of
    the protocol's seconds on stderr (None: only on a terminal), drawn by
    this launcher while it waits, never by the real-time process. ``feed``:
    loopback addresses (``127.0.0.1:PORT``) that get the run's rows live
    (``sensaug-rt --feed``, ``sensaug.feed``; the live view, a display).
    ``also_written``: files the caller writes into ``out`` afterwards (by
    name, e.g. plots), checked with the run's own before it starts.

    Every output path is checked first (:func:`check_outputs`); nothing is
    written and nothing started when one is refused. The statistics are
    read from ``sensaug-rt``'s stdout; if it could not save
    ``rig_stats.json`` the run stands and the README says the file is missing.

    ``display``: a running :class:`sensaug.display.DisplayProcess` shows the
    trial (fed by the loop's live feed, one more ``--feed`` address;
    ``out/display_log.csv``) and is watched
    (:class:`sensaug.display.DisplayWatch`: Esc, a frozen or dead display).

    ``stop_key``: watch this process's terminal for the experimenter's stop
    key (:class:`StopKey`, :data:`STOP_KEYS`; the hint is printed on stderr
    when the trial starts); None: when stdin is the foreground terminal.

    ``drive_args``: more options for the virtual drive's process (e.g. the
    handle it simulates, ``--mass``, ``--damping``, ``--coulomb``: a truth
    the loop's configuration does not see; ``sensaug calibrate``).

    Raises:
        ConfigError: an output path is refused (named).
        RuntimeError: ``sensaug-rt`` ended before reporting (set-up error).
    """
    cfg = config if isinstance(config, ScenarioConfig) else ScenarioConfig.from_toml(config)
    out = _output_folder(Path(out))
    toml_path = out / "rig_config.toml"
    log_path, stats_path = out / "rig_log.csv", out / "rig_stats.json"
    check_outputs({
        "configuration copy": toml_path, "rig.log": log_path, "rig.stats": stats_path,
        **({"capture": out / capture} if capture else {}), "README": out / "README.txt", **(also_written or {}),
        **({"display log": out / "display_log.csv"} if display is not None else {}),
    })  # fmt: skip
    port = bus_port(port)
    cfg.to_toml(toml_path)
    binary = find_binary()
    budget = timeout_s or cfg.duration_s + 30.0
    # The capture's socket is bound before the drive boots: every frame of
    # the run is queued for it from here on.
    recorder = BusCapture(port, out / capture).start() if capture else None
    captured: Optional[CaptureStats] = None
    drive: Optional[subprocess.Popen] = None
    interrupted = False
    watch = None
    key_watch: Optional[StopKey] = None
    key_event: Optional[dict] = None
    try:
        drive = start_drive(port, duration_s=budget + 5.0, drive=cfg.rig.drive,
                            fifo_priority=cfg.rig.realtime.fifo_priority, standard=standard_drive(cfg),
                            extra=list(drive_args or []))
        time.sleep(0.5)
        if display is not None:
            feed = [*feed, _show_trial(display, cfg, out)]
        with _ElapsedBar(cfg.duration_s, progress):
            proc = subprocess.Popen(
                [str(binary), str(toml_path), "--can", f"udp:{port}", "--log", str(log_path), "--stats", str(stats_path),
                 *(arg for addr in feed for arg in ("--feed", addr))],
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
            watch = None if display is None else _watch_display(display, out, proc)
            if stop_key is not False:
                key_watch = StopKey.arm(proc)
                if key_watch is not None:
                    print(f"sensaug: {STOP_KEY_HINT}", file=sys.stderr, flush=True)
            try:
                rt_stdout, rt_stderr = proc.communicate(timeout=budget)
            except KeyboardInterrupt:
                # Ctrl-C: the terminal sent SIGINT to the whole group; make sure
                # sensaug-rt has it too, then let it finish its controlled stop
                # and write its statistics and the log's end line.
                interrupted = True
                proc.send_signal(signal.SIGINT)
                rt_stdout, rt_stderr = proc.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()
                raise
            finally:
                if watch is not None:
                    watch.stop()
                if key_watch is not None:
                    key_event = key_watch.stop()
    finally:
        if drive is not None:
            stop_process(drive)
        # Both processes have exited: drain what they sent, then close.
        if recorder is not None:
            captured = recorder.stop()
    # sensaug-rt prints its statistics on stdout at the end of every run
    # that reached its loop, saved or not: an older rig_stats.json is never
    # taken for this run's.
    try:
        stats = json.loads(rt_stdout)
    except json.JSONDecodeError:
        raise RuntimeError(f"sensaug-rt failed (exit {proc.returncode}): {rt_stderr.strip()}") from None
    stats_lost = next((ln for ln in rt_stderr.splitlines() if ln.startswith("warning: rig.stats:")), None)
    files = {
        toml_path.name: "the configuration the run used, resolved (TOML; sensaug.ScenarioConfig.from_toml)",
        log_path.name: "the controller's log, one row per tick (CSV; sensaug.load_log, docs/logs.md)",
        stats_path.name: "sensaug-rt's statistics: stop reason, loop timing, CAN counters (JSON)"
        if stats_lost is None else f"NOT WRITTEN by this run ({stats_lost.removeprefix('warning: ')})",
    }
    if captured is not None:
        lost = captured.dropped_kernel + captured.dropped_malformed
        note = "" if captured.error is None and lost == 0 else f"; INCOMPLETE: {captured.error or f'{lost} frames lost'}"
        files[captured.path.name] = (
            f"every frame on the bus (port {port}), {captured.frames} frames, "
            f"{capture_format(captured.path)}{note}"
        )
    run = RigRun(
        config=cfg,
        log=load_log(log_path),
        stats=stats,
        returncode=proc.returncode,
        drive_returncode=drive.returncode,
        stderr=rt_stderr,
        port=port,
        interrupted=interrupted,
        capture=captured,
        files=files,
        stop_key=key_event,
    )
    if watch is not None:
        from sensaug.display import watch_summary

        run.display = watch_summary(watch, run)
        files["display_log.csv"] = "the participant's display: one row per frame (sensaug.display.load_display_log)"
    run.write_readme(out)
    return run


def _show_trial(display, cfg: ScenarioConfig, out: Path) -> str:
    """Tells ``display`` to show the run about to start (the feed's next run
    and its display log); the display's feed address for ``--feed``."""
    from sensaug.display import Command, noisy_phases

    display.show(Command(follow_since_unix_ns=time.time_ns(), display_log=str(out / "display_log.csv"),
                         sigma_v=cfg.display.sigma_v, seed=cfg.display.seed, noisy_phases=noisy_phases(cfg)))
    if display.feed_address is None:
        raise RuntimeError("display: it did not say its feed address; it is not a sensaug display of this version")
    return display.feed_address


def _watch_display(display, out: Path, proc: subprocess.Popen):
    """The watch of the display showing this run (Esc, a frozen or dead display)."""
    from sensaug.display import DisplayWatch

    return DisplayWatch(display, out / "display_log.csv", proc).start()


class _ElapsedBar:
    """A tqdm bar of wall-clock seconds against ``total_s``, ticked by a
    thread of this (launcher) process while the run's subprocess works."""

    def __init__(self, total_s: float, progress: bool | None) -> None:
        import threading

        from sensaug._jupyter import bar

        self._bar = bar(total=round(total_s, 1), desc="rig", unit="s", progress=progress, leave=False,
                        bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.1f}/{total:.1f} s")
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._tick, daemon=True)

    def _tick(self) -> None:
        t0 = time.monotonic()
        while not self._done.wait(0.25):
            self._bar.n = min(round(time.monotonic() - t0, 1), self._bar.total)
            self._bar.refresh()

    def __enter__(self) -> "_ElapsedBar":
        if not self._bar.disable:
            self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._done.set()
        if self._thread.is_alive():
            self._thread.join()
        self._bar.close()


def capture_format(path: Path) -> str:
    """One line naming the capture file's format and what reads it."""
    suffix = path.suffix.lower()
    if suffix == ".log":
        return "candump -l log format (can.LogReader, canplayer, log2asc)"
    if suffix == ".blf":
        return "Vector BLF (can.LogReader)"
    return f"python-can's {suffix} format (can.LogReader)"
