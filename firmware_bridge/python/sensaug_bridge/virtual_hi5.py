"""A virtual Hi5 drive: the wrist robot's DC-motor driver, simulated on any python-can bus.

Run it with ``sensaug-virtual-hi5`` or ``python -m sensaug_bridge.virtual_hi5``
(default bus: the loopback ``sensaug_udp`` interface, port 47100, node 1). The
behaviour, the choices and their reasons are in ``docs/virtual_hi5.md``; in short:

* BOOT -> DISABLED at start; a Fault frame on every state or fault change, a
  Heartbeat every ``heartbeat_period_s`` (10 Hz).
* SetState(enable, watchdog_ms, sequence): DISABLED -> ENABLED, arms the
  watchdog, expects ``sequence`` next (resync); while ENABLED the same
  watchdog only resyncs and another one is refused; SetState(disable):
  ENABLED -> DISABLED, torque 0.
* A TorqueCommand is accepted only with a good CRC-16 (the frame id as data
  id), while ENABLED, with exactly the expected sequence (one more than the
  last accepted) and ``|torque|`` within the torque limit: then step the 1-DoF
  plant (``sensaug_bridge.plant.Plant``) once and reply with one Feedback echoing the
  sequence. The plant's clock is the host's command stream (one step per
  command), so a run is deterministic. Commands queued while the process was
  off the CPU are read as one backlog: each steps the plant, only the last
  is answered (an answer to a superseded command would reach the host stale).
* Bad CRC, wrong DLC, unknown id, out-of-range torque (rejected, never
  clamped): dropped and counted (Heartbeat counters, saturating at 255); no
  Feedback. A valid command with another sequence while ENABLED (a second
  command source, or a lost command) latches FAULT(SEQUENCE).
* Watchdog (no accepted command for ``watchdog_ms`` while ENABLED), emergency
  stop, overspeed: torque 0, FAULT with the flag latched until ClearFaults.
* The handle: while not ENABLED the plant keeps moving at zero torque in real
  time (a free handle coasts after a stop, :func:`coast`); with ``log`` every
  step is recorded, commanded or free (:class:`DriveLog`), so a test measures
  the handle's travel after a stop on the drive's own record.
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, field, fields
from typing import Any, Callable, Iterator, Optional, Sequence

import can

from sensaug_bridge import protocol as p
from sensaug_bridge.plant import Plant
from sensaug_bridge.protocol import FaultFlag, State

__all__ = ["PROFILE_NAME", "DriveConfig", "VirtualHi5", "encoder_counts", "main", "new_plant", "parse_args"]

#: The drive profile's name for people (this module is the virtual drive of
#: ``[rig] drive = "hi5"``, registered under the ``sensaug.virtual_drives``
#: entry points).
PROFILE_NAME = "Hi5"

_COUNTER_MAX = 255
#: Most frames handled as one backlog (:meth:`VirtualHi5.run`): bounded so
#: that a flood cannot starve the heartbeat and the watchdog.
BACKLOG_MAX = 256


@dataclass
class DriveConfig:
    """Everything the virtual drive can be configured with. Units in the names."""

    node: int = 1
    torque_limit_nm: float = 3.0
    mass: float = 0.0035
    damping: float = 0.0
    coulomb: float = 0.0
    dt_s: float = 1e-3
    encoder_counts_per_rev: int = 2**20
    max_velocity_rad_s: float = 8.0
    heartbeat_period_s: float = 0.1
    x0_rad: float = 0.0
    #: The velocity reported is the plant's times this: 1 in normal use; any
    #: other value is a drive (or a master's velocity unit) that is wrong,
    #: for the tests of the controller's feedback consistency check.
    velocity_report_scale: float = 1.0

    def validate(self) -> None:
        """Raises ValueError naming the field."""
        self._check_node()
        checks: list[tuple[str, float, bool]] = [
            ("torque_limit_nm", self.torque_limit_nm, self.torque_limit_nm > 0),
            ("mass", self.mass, self.mass > 0),
            ("damping", self.damping, self.damping >= 0),
            ("coulomb", self.coulomb, self.coulomb >= 0),
            ("dt_s", self.dt_s, self.dt_s > 0),
            ("max_velocity_rad_s", self.max_velocity_rad_s, self.max_velocity_rad_s > 0),
            ("heartbeat_period_s", self.heartbeat_period_s, self.heartbeat_period_s > 0),
            ("x0_rad", self.x0_rad, True),
            ("velocity_report_scale", self.velocity_report_scale, True),
        ]
        for name, value, ok in checks:
            if not (math.isfinite(value) and ok):
                raise ValueError(f"{name}: invalid value {value!r}")
        if self.encoder_counts_per_rev < 1:
            raise ValueError(
                f"encoder_counts_per_rev: must be >= 1, got {self.encoder_counts_per_rev}"
            )

    def _check_node(self) -> None:
        p.frame_id("TorqueCommand", self.node)  # checks the Hi5 node range 0..15


def read_backlog(bus: can.BusABC, first: can.Message) -> list[can.Message]:
    """``first`` and the frames already queued behind it on ``bus`` (at most
    :data:`BACKLOG_MAX`, so that a flood cannot starve the heartbeat and the
    watchdog). Shared by every virtual drive profile."""
    frames = [first]
    while len(frames) < BACKLOG_MAX and (msg := bus.recv(0.0)) is not None:
        frames.append(msg)
    return frames


def new_plant(config: DriveConfig) -> Plant:
    """The drive's 1-DoF load (:class:`sensaug_bridge.plant.Plant`, the
    controller's model step for step) with the config's M, C, F_c, dt, x0 (v0 = 0).

    Shared by every virtual drive profile (Hi5, CiA 402)."""
    return Plant(
        mass=config.mass, damping=config.damping, coulomb=config.coulomb, dt_s=config.dt_s, x0=config.x0_rad, v0=0.0
    )


def encoder_counts(x_rad: float, counts_per_rev: int) -> int:
    """The encoder: position quantised to whole counts (``2 pi / counts_per_rev`` rad each)."""
    return round(x_rad / (2.0 * math.pi / counts_per_rev))


@dataclass
class DriveLog:
    """The handle's record (kept only when logging is on): one row per plant
    step, commanded (an accepted TorqueCommand; CiA 402 a SYNC while enabled)
    or free (``free``: the handle coasting at zero torque while the drive
    applies no commands, :func:`coast`). ``t_s`` is the step's end (free) or
    the command's arrival, seconds after ``t0_monotonic_s`` (the drive's start
    on ``time.monotonic``, the clock other processes share)."""

    t_s: list[float] = field(default_factory=list)
    sequence: list[int] = field(default_factory=list)
    torque_cmd_nm: list[float] = field(default_factory=list)
    torque_nm: list[float] = field(default_factory=list)
    position_rad: list[float] = field(default_factory=list)
    velocity_rad_s: list[float] = field(default_factory=list)
    latency_s: list[float] = field(default_factory=list)
    free: list[bool] = field(default_factory=list)
    t0_monotonic_s: float = 0.0

    def add(
        self, t_s: float, sequence: int, torque_cmd_nm: float, torque_nm: float, position_rad: float,
        velocity_rad_s: float, latency_s: float = 0.0, free: bool = False,
    ) -> None:
        """One plant step."""
        self.t_s.append(t_s)
        self.sequence.append(sequence)
        self.torque_cmd_nm.append(torque_cmd_nm)
        self.torque_nm.append(torque_nm)
        self.position_rad.append(position_rad)
        self.velocity_rad_s.append(velocity_rad_s)
        self.latency_s.append(latency_s)
        self.free.append(free)

    def latency_summary(self) -> dict[str, float]:
        """Handling latency percentiles of the commanded steps, us (empty without any)."""
        lat = sorted(t for t, free in zip(self.latency_s, self.free) if not free)
        if not lat:
            return {}
        return {
            "latency_us_p50": round(lat[len(lat) // 2] * 1e6, 1),
            "latency_us_p99": round(lat[min(len(lat) - 1, int(0.99 * len(lat)))] * 1e6, 1),
            "latency_us_max": round(lat[-1] * 1e6, 1),
        }

    def save(self, path: str) -> None:
        import numpy as np

        np.savez(
            path,
            t_s=np.asarray(self.t_s, dtype=np.float64),
            sequence=np.asarray(self.sequence, dtype=np.uint8),
            torque_cmd_nm=np.asarray(self.torque_cmd_nm, dtype=np.float64),
            torque_nm=np.asarray(self.torque_nm, dtype=np.float64),
            position_rad=np.asarray(self.position_rad, dtype=np.float64),
            velocity_rad_s=np.asarray(self.velocity_rad_s, dtype=np.float64),
            latency_s=np.asarray(self.latency_s, dtype=np.float64),
            free=np.asarray(self.free, dtype=np.bool_),
            t0_monotonic_s=np.float64(self.t0_monotonic_s),
        )


def coast(plant: Plant, since_s: float, now_s: float, dt_s: float, log: Optional[DriveLog], t0_s: float,
          encode: Callable[[float], float]) -> float:
    """The free handle from ``since_s`` to ``now_s``: whole plant steps of
    ``dt_s`` at zero torque (a handle at rest stays at rest and is not
    stepped); each step recorded in ``log`` (``free``, position through
    ``encode``, the encoder). Returns the time stepped to."""
    steps = int((now_s - since_s) / dt_s)
    if steps <= 0:
        return since_s
    for i in range(steps):
        if plant.v == 0.0:
            break
        x, v = plant.step(0.0)
        if log is not None:
            log.add(since_s + (i + 1) * dt_s - t0_s, 0, 0.0, 0.0, encode(x), v, free=True)
    return since_s + steps * dt_s


class VirtualDrive:
    """What every virtual drive profile shares: the bus (the caller's, not
    closed here), its validated configuration, the clock, the plant and its
    encoder, the record of its steps (``log``), and resets asked for from a
    signal handler. A profile adds its protocol: :meth:`start`,
    :meth:`reset`, :meth:`run`, :meth:`stop`, :meth:`summary`.
    """

    def __init__(self, bus: can.BusABC, config: DriveConfig, log: bool, clock: Callable[[], float]) -> None:
        config.validate()
        self.config = config
        self.bus = bus
        self._clock = clock
        self.plant = new_plant(config)
        self._rad_per_count = 2.0 * math.pi / config.encoder_counts_per_rev
        #: The clock at :meth:`start`: the log's time origin.
        self._t0 = 0.0
        #: Resets done (:meth:`reset`).
        self.resets = 0
        self._reset_requested = False
        self.log: Optional[DriveLog] = DriveLog() if log else None
        #: The handle coasts (zero torque, real time) from here while the
        #: drive is not enabled.
        self._coast_s = 0.0

    def reset(self) -> None:
        """A restart of the drive's electronics; each profile its own."""
        raise NotImplementedError

    def request_reset(self) -> None:
        """Asks :meth:`run` to :meth:`reset` at its next iteration (safe from
        a signal handler)."""
        self._reset_requested = True

    def _iterations(self, stop: Optional[threading.Event], end: float) -> Iterator[float]:
        """The serve loop's iterations: each one's clock time, until ``stop``
        is set or the clock reaches ``end``; a reset asked for is done first."""
        while stop is None or not stop.is_set():
            now = self._clock()
            if now >= end:
                break
            if self._reset_requested:
                self._reset_requested = False
                self.reset()
            yield now

    def _encoder(self, x_rad: float) -> float:
        """The encoder's reading of ``x_rad``: whole counts (increments)."""
        return encoder_counts(x_rad, self.config.encoder_counts_per_rev) * self._rad_per_count

    def _with_latency(self, counts: dict[str, Any]) -> dict[str, Any]:
        """``counts`` for the report at exit, with the log's command-to-answer
        latencies when there is a log."""
        if self.log is not None:
            counts.update(self.log.latency_summary())
        return counts


class VirtualHi5(VirtualDrive):
    """The drive's state machine on a python-can bus.

    Not thread-safe: one thread calls :meth:`start`, then :meth:`run` (or
    :meth:`handle` and :meth:`poll` itself), then :meth:`stop`. The bus is owned
    by the caller and is not closed here.
    """

    def __init__(self, bus: can.BusABC, config: Optional[DriveConfig] = None, *, log: bool = False,
                 clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__(bus, config or DriveConfig(), log, clock)
        #: On SocketCAN python-can's ``Message.timestamp`` is the kernel's
        #: arrival time (``SO_TIMESTAMPNS``, wall clock): the watchdog is then
        #: measured from when a frame arrived, not from when this process read it.
        self.kernel_timestamps = _has_kernel_timestamps(bus)
        cfg = self.config
        self._ids = {name: p.frame_id(name, cfg.node) for name in p.BASE_IDS}
        self._handlers: dict[int, Callable[[can.Message, float], None]] = {
            self._ids["TorqueCommand"]: self._on_torque,
            self._ids["SetState"]: self._on_set_state,
            self._ids["ClearFaults"]: self._on_clear_faults,
            self._ids["EmergencyStop"]: self._on_emergency_stop,
        }
        self.state = State.BOOT
        self.fault_flags = FaultFlag.NONE
        #: Torque applied to the plant now (0 unless ENABLED).
        self.torque_nm = 0.0
        self.watchdog_s = 0.0
        self._last_valid_s = 0.0
        #: The only TorqueCommand sequence accepted next (None: not ENABLED).
        self._expected_seq: Optional[int] = None
        self._fault_counter = 0
        self._hb_counter = 0
        self._next_hb_s = 0.0
        # Error counts (unbounded here; the Heartbeat saturates them at 255).
        self.crc_errors = 0
        self.length_errors = 0
        self.sequence_errors = 0
        self.unknown_ids = 0
        self.range_errors = 0
        #: Frames that are valid but not acted on: torque commands while not
        #: ENABLED, SetState with a bad request/watchdog value or a watchdog
        #: change while ENABLED. Not in the Heartbeat.
        self.ignored = 0
        self.accepted = 0
        #: Answer the TorqueCommand being handled (False for one a later
        #: command in the same backlog supersedes).
        self._answer = True

    # -- set-up --------------------------------------------------------------------

    def start(self) -> None:
        """Announce BOOT, move to DISABLED, send the first Heartbeat."""
        now = self._clock()
        self._t0 = now
        self._coast_s = now
        if self.log is not None:
            self.log.t0_monotonic_s = now
        self._send_fault()
        self._set_state(State.DISABLED)
        self._send_heartbeat()
        self._next_hb_s = now + self.config.heartbeat_period_s

    def reset(self) -> None:
        """A restart of the drive's electronics (a power glitch; ``SIGUSR1`` to
        the CLI): torque 0, faults and watchdog cleared, then the boot of
        :meth:`start`: a Fault frame reporting BOOT, DISABLED, a Heartbeat.
        The handle (the plant) keeps its motion."""
        self.resets += 1
        self.torque_nm = 0.0
        self.fault_flags = FaultFlag.NONE
        self._expected_seq = None
        self.state = State.BOOT
        self._send_fault()
        self._set_state(State.DISABLED)
        self._send_heartbeat()
        self._next_hb_s = self._clock() + self.config.heartbeat_period_s

    def stop(self) -> None:
        """Zero torque, leave ENABLED for DISABLED, send a final Fault and Heartbeat."""
        self.torque_nm = 0.0
        if self.state == State.ENABLED:
            self._set_state(State.DISABLED)
        else:
            self._send_fault()
        self._send_heartbeat()

    # -- the loop ------------------------------------------------------------------

    def run(self, stop: Optional[threading.Event] = None, duration_s: Optional[float] = None) -> None:
        """Serve the bus until ``stop`` is set or ``duration_s`` has passed.

        Receives with a short blocking timeout (at most 10 ms, shorter when the
        watchdog or the next heartbeat is due sooner); no sleeps; the watchdog is
        checked on every iteration with the monotonic clock.
        """
        end = math.inf if duration_s is None else self._clock() + duration_s
        recv = self.bus.recv
        # With kernel timestamps: the time up to which the bus has been read
        # (the last frame's arrival, or when a receive came back empty). A
        # command still queued in the socket after a stall of this process
        # is not a missed command.
        read_until = self._clock()
        for now in self._iterations(stop, end):
            self.poll(now, read_until if self.kernel_timestamps else None)
            due = min(self._next_hb_s, end, now + 0.01)
            if self.state == State.ENABLED:
                due = min(due, self._last_valid_s + self.watchdog_s)
            msg = recv(max(due - now, 0.0))
            if msg is None:
                read_until = self._clock()
            else:
                read_until = self._handle_backlog(read_backlog(self.bus, msg))

    def _handle_backlog(self, frames: list[can.Message]) -> float:
        """Handles ``frames`` in order, answering only the last TorqueCommand
        among them (every one steps the plant); returns the last frame's
        arrival time."""
        commands = {i for i, m in enumerate(frames) if m.arbitration_id == self._ids["TorqueCommand"]}
        last_command = max(commands, default=-1)
        at = self._clock()
        for i, msg in enumerate(frames):
            self._answer = i == last_command or i not in commands
            at = self.received_at(msg)
            self.handle(msg, at)
        self._answer = True
        return at

    def received_at(self, msg: can.Message) -> float:
        """When ``msg`` arrived, on the drive's clock: the kernel's receive
        time when the bus has one (SocketCAN), else now."""
        now = self._clock()
        if not self.kernel_timestamps:
            return now
        # Message.timestamp is CLOCK_REALTIME; its age converts it to our clock.
        return now - max(time.time() - msg.timestamp, 0.0)

    def poll(self, now: float, read_until: Optional[float] = None) -> None:
        """Watchdog check and heartbeat; called on every loop iteration.

        ``read_until``: the bus has only been read up to this time (kernel
        timestamps); the watchdog is checked there instead of at ``now``.
        """
        self._check_watchdog(now if read_until is None else min(now, read_until))
        if self.state != State.ENABLED:
            self._coast_s = coast(self.plant, self._coast_s, now, self.config.dt_s, self.log, self._t0,
                                  self._encoder)
        if now >= self._next_hb_s:
            self._send_heartbeat()
            # Skip missed beats instead of bursting after a stall.
            period = self.config.heartbeat_period_s
            self._next_hb_s = max(self._next_hb_s + period, now + 0.5 * period)

    def handle(self, msg: can.Message, now: float) -> None:
        """Act on one received frame. Never raises on bad input."""
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id or msg.is_fd:
            self.unknown_ids += 1
            return
        handler = self._handlers.get(msg.arbitration_id)
        if handler is not None:
            handler(msg, now)
        elif p.classify(msg.arbitration_id) is None:
            self.unknown_ids += 1
        # else: a protocol frame for another node, or another drive's
        # Feedback/Fault/Heartbeat: not ours, silently ignored.

    # -- handlers --------------------------------------------------------------------

    def _on_torque(self, msg: can.Message, now: float) -> None:
        t_rx = time.perf_counter()
        self._check_watchdog(now)
        data = bytes(msg.data[: msg.dlc])
        if len(data) != 8:
            self.length_errors += 1
            return
        try:
            cmd = p.TorqueCommand.decode(data, msg.arbitration_id)
        except p.ProtocolError as err:
            if err.kind == "crc":
                self.crc_errors += 1
            else:  # non-zero reserved byte, torque outside the DBC range
                self.range_errors += 1
            return
        if self.state != State.ENABLED or self._expected_seq is None:
            self.ignored += 1
            return
        if cmd.sequence != self._expected_seq:
            # Valid, but not the next: a second command source, or a lost command.
            self.sequence_errors += 1
            self._latch(FaultFlag.SEQUENCE)
            return
        self._expected_seq = (cmd.sequence + 1) % 256
        cfg = self.config
        if abs(cmd.torque_nm) > cfg.torque_limit_nm:
            # Rejected and counted, never clamped; the sequence is consumed.
            self.range_errors += 1
            return
        self._last_valid_s = now
        self.accepted += 1
        torque = cmd.torque_nm
        self.torque_nm = torque
        x, v = self.plant.step(torque)
        if abs(v) > cfg.max_velocity_rad_s:
            self.torque_nm = 0.0
            self._latch(FaultFlag.OVERSPEED)
        # The encoder: position quantised to whole counts, then to the field's 1e-6 rad.
        x_q = self._encoder(x)
        x_rep = p.saturate("Feedback", "position", x_q)
        v_rep = p.saturate("Feedback", "velocity", v * cfg.velocity_report_scale)
        reply = p.Feedback(
            position_rad=x_rep,
            velocity_rad_s=v_rep,
            sequence=cmd.sequence,
            state=self.state,
            torque_limited=False,
            fault_active=bool(self.fault_flags),
        ).encode(cfg.node)
        if self._answer:
            self.bus.send(reply)
        if self.log is not None:
            self.log.add(now - self._t0, cmd.sequence, cmd.torque_nm, torque, x_q, v, time.perf_counter() - t_rx)

    def _on_set_state(self, msg: can.Message, now: float) -> None:
        try:
            req = p.SetState.decode(bytes(msg.data[: msg.dlc]))
        except p.ProtocolError as err:
            if err.kind == "length":
                self.length_errors += 1
            else:
                self.ignored += 1
            return
        if not req.enable:
            self.torque_nm = 0.0
            if self.state == State.ENABLED:
                self._set_state(State.DISABLED)
            return
        if self.state == State.DISABLED:
            self.watchdog_s = req.watchdog_ms / 1000.0
            self._last_valid_s = now
            self._expected_seq = req.sequence
            self._set_state(State.ENABLED)
        elif self.state == State.ENABLED and req.watchdog_ms == round(self.watchdog_s * 1000.0):
            # Resync only: the watchdog is neither changed nor re-armed.
            self._expected_seq = req.sequence
        else:
            # FAULT, or a watchdog change while ENABLED: refused.
            self.ignored += 1

    def _on_clear_faults(self, msg: can.Message, now: float) -> None:
        if msg.dlc != p.DLC["ClearFaults"]:
            self.length_errors += 1
            return
        if self.state == State.FAULT:
            self.fault_flags = FaultFlag.NONE
            self._set_state(State.DISABLED)
        elif self.fault_flags:
            self.fault_flags = FaultFlag.NONE
            self._send_fault()

    def _on_emergency_stop(self, msg: can.Message, now: float) -> None:
        # Acted on whatever its length: a stop request is never dropped.
        self.torque_nm = 0.0
        self._latch(FaultFlag.EMERGENCY_STOP)

    # -- state changes ---------------------------------------------------------------

    def _check_watchdog(self, now: float) -> None:
        if self.state == State.ENABLED and now - self._last_valid_s > self.watchdog_s:
            self.torque_nm = 0.0
            self._latch(FaultFlag.WATCHDOG)

    def _latch(self, flag: FaultFlag) -> None:
        changed = not (self.fault_flags & flag) or self.state != State.FAULT
        self.fault_flags |= flag
        self._expected_seq = None
        self.torque_nm = 0.0
        if self.state != State.FAULT:
            self._leave(State.FAULT)
        if changed:
            self._send_fault()

    def _set_state(self, state: State) -> None:
        if state != State.ENABLED:
            self.torque_nm = 0.0
            self._expected_seq = None
        self._leave(state)
        self._send_fault()

    def _leave(self, state: State) -> None:
        """The state changes to ``state``; leaving ENABLED, the handle coasts from now."""
        if self.state == State.ENABLED and state != State.ENABLED:
            self._coast_s = self._clock()
        self.state = state

    # -- frames out ------------------------------------------------------------------

    def _send_fault(self) -> None:
        self.bus.send(p.Fault(self.state, self.fault_flags, self._fault_counter).encode(self.config.node))
        self._fault_counter = (self._fault_counter + 1) & 0xFF

    def heartbeat(self) -> p.Heartbeat:
        """The Heartbeat as it would be sent now (counters saturated at 255).

        Malformed datagrams dropped by the transport (``bus.drop_reasons``, the
        ``sensaug_udp`` bus) are folded in: wrong size, len or reserved bytes
        count as length errors; a standard id over 0x7FF as an unknown id.
        (Extended, remote and error frames arrive as messages and count as
        unknown ids when handled.)
        """
        length_errors = self.length_errors
        unknown_ids = self.unknown_ids
        drops = getattr(self.bus, "drop_reasons", None)
        if drops:
            length_errors += drops.get("size", 0) + drops.get("len", 0) + drops.get("reserved", 0)
            unknown_ids += drops.get("id", 0)
        return p.Heartbeat(
            state=self.state,
            fault_flags=self.fault_flags,
            counter=self._hb_counter,
            crc_errors=min(self.crc_errors, _COUNTER_MAX),
            length_errors=min(length_errors, _COUNTER_MAX),
            sequence_errors=min(self.sequence_errors, _COUNTER_MAX),
            unknown_ids=min(unknown_ids, _COUNTER_MAX),
            range_errors=min(self.range_errors, _COUNTER_MAX),
        )

    def _send_heartbeat(self) -> None:
        self.bus.send(self.heartbeat().encode(self.config.node))
        self._hb_counter = (self._hb_counter + 1) & 0xFF

    def summary(self) -> dict[str, Any]:
        """Counts for a one-line report at exit."""
        hb = self.heartbeat()
        return self._with_latency({
            "state": self.state.name,
            "fault_flags": int(self.fault_flags),
            "accepted": self.accepted,
            "ignored": self.ignored,
            "crc_errors": self.crc_errors,
            "length_errors": hb.length_errors,
            "sequence_errors": self.sequence_errors,
            "unknown_ids": hb.unknown_ids,
            "range_errors": self.range_errors,
            "resets": self.resets,
        })


def _has_kernel_timestamps(bus: can.BusABC) -> bool:
    """python-can's ``socketcan`` bus: every Message.timestamp is SO_TIMESTAMPNS."""
    try:
        from can.interfaces.socketcan import SocketcanBus
    except ImportError:  # not Linux
        return False
    return isinstance(bus, SocketcanBus)


# -- command line ----------------------------------------------------------------------


def add_drive_args(ap: argparse.ArgumentParser, d: DriveConfig) -> None:
    """The options every virtual drive profile shares (bus, plant, encoder, limits, run);
    a DriveConfig setting's option stores under the field's name."""
    ap.add_argument("-i", "--interface", default="sensaug_udp", help="python-can interface (default sensaug_udp)")
    ap.add_argument("-c", "--channel", default="47100", help="python-can channel; for sensaug_udp the UDP port (default 47100)")
    ap.add_argument("--torque-limit", dest="torque_limit_nm", type=float, default=d.torque_limit_nm, help="N m (default 3)")
    ap.add_argument("--mass", type=float, default=d.mass, help="inertia M, kg m^2 (default 0.0035)")
    ap.add_argument("--damping", type=float, default=d.damping, help="viscous C, N m s/rad (default 0)")
    ap.add_argument("--coulomb", type=float, default=d.coulomb, help="Coulomb friction, N m (default 0)")
    ap.add_argument("--dt", dest="dt_s", type=float, default=d.dt_s, help="plant step per command, s (default 0.001)")
    ap.add_argument("--x0", dest="x0_rad", type=float, default=d.x0_rad, help="initial position, rad (default 0)")
    ap.add_argument(
        "--encoder-counts-per-rev", type=int, default=d.encoder_counts_per_rev, help="default 2**20 = 1048576"
    )
    ap.add_argument(
        "--max-velocity", dest="max_velocity_rad_s", type=float, default=d.max_velocity_rad_s, help="OVERSPEED fault above this, rad/s (default 8, inside the +-8.39 rad/s Feedback field)"
    )
    ap.add_argument("--heartbeat-hz", type=float, default=1.0 / d.heartbeat_period_s, help="default 10")
    ap.add_argument(
        "--velocity-report-scale", type=float, default=d.velocity_report_scale,
        help="report the plant's velocity times this (default 1; else a faulty drive, for tests)",
    )
    ap.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    ap.add_argument("--log", default=None, metavar="FILE.npz",
                    help="save the handle's record: t_s, torque_nm, position_rad, velocity_rad_s, free, ...")
    ap.add_argument(
        "--fifo-priority", type=int, default=None, metavar="1..99",
        help="run under SCHED_FIFO at this priority (needs CAP_SYS_NICE; refused: a warning, and the "
             "default scheduler). A real drive never stalls; this keeps the simulated one from being "
             "held off the CPU by other processes (docs/virtual_hi5.md)",
    )
    ap.add_argument("-q", "--quiet", action="store_true", help="no summary line on stderr at exit")


def drive_config_fields(args: argparse.Namespace) -> dict[str, Any]:
    """The DriveConfig fields from the options of :func:`add_drive_args` (plus
    ``--node``): each under its field's name, but the heartbeat, given as a rate."""
    config = {f.name: getattr(args, f.name) for f in fields(DriveConfig) if f.name != "heartbeat_period_s"}
    config["heartbeat_period_s"] = 1.0 / args.heartbeat_hz if args.heartbeat_hz > 0 else math.nan
    return config


def serve(prog: str, args: argparse.Namespace, config: DriveConfig, make_drive: Callable[[can.BusABC], Any]) -> int:
    """Run one virtual drive from the command line: validate, open the bus, start,
    run until SIGINT/SIGTERM/--duration, stop, save the log, print the summary.
    SIGUSR1 resets the drive (``request_reset``: a power glitch, for the
    tests of a drive reset mid-run). Exit code 0 on a clean stop, 2 for a bad
    option value, 1 if the bus cannot be opened."""
    try:
        config.validate()
    except ValueError as err:
        print(f"{prog}: {err}", file=sys.stderr)
        return 2
    stop = threading.Event()

    def _on_signal(signum: int, frame: Any) -> None:
        stop.set()

    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    if args.fifo_priority is not None:
        if not 1 <= args.fifo_priority <= 99:
            print(f"{prog}: --fifo-priority: must be 1..99, got {args.fifo_priority}", file=sys.stderr)
            return 2
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.fifo_priority))
        except OSError as err:
            print(f"{prog}: warning: SCHED_FIFO {args.fifo_priority} refused ({err.strerror}); "
                  "running under the default scheduler", file=sys.stderr)
    try:
        bus = can.Bus(interface=args.interface, channel=args.channel)
    except (can.CanError, ValueError, OSError, NotImplementedError) as err:
        print(f"{prog}: cannot open bus: {err}", file=sys.stderr)
        return 1
    try:
        drive = make_drive(bus)
        signal.signal(signal.SIGUSR1, lambda signum, frame: drive.request_reset())
        drive.start()
        # Everything built so far (canopen's dictionary, python-can, numpy)
        # moves out of the collector's reach: a collection then walks only
        # the frames' short-lived objects, not the whole heap, and pauses
        # the drive for microseconds, not milliseconds.
        gc.collect()
        gc.freeze()
        try:
            drive.run(stop=stop, duration_s=args.duration)
        finally:
            drive.stop()
            if args.log is not None and drive.log is not None:
                drive.log.save(args.log)
            if not args.quiet:
                print(f"{prog}: {drive.summary()}", file=sys.stderr)
    finally:
        bus.shutdown()
    return 0


def parse_args(argv: Optional[Sequence[str]] = None) -> argparse.Namespace:
    d = DriveConfig()
    ap = argparse.ArgumentParser(
        prog="sensaug-virtual-hi5",
        description="Virtual Hi5 drive on a python-can bus (default: loopback sensaug_udp). "
        "See docs/virtual_hi5.md.",
    )
    ap.add_argument("--node", type=int, default=d.node, help="node id 0..15 (default 1)")
    add_drive_args(ap, d)
    return ap.parse_args(argv)


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Console entry point. Exit code 0 on a clean stop (duration, SIGINT, SIGTERM)."""
    args = parse_args(argv)
    config = DriveConfig(**drive_config_fields(args))
    return serve("sensaug-virtual-hi5", args, config, lambda bus: VirtualHi5(bus, config, log=args.log is not None))


if __name__ == "__main__":
    sys.exit(main())
