"""A virtual CiA 402 drive (CANopen, cyclic synchronous torque) on any python-can bus.

Built on python-canopen: a ``LocalNode`` with the object dictionary of
``firmware_bridge/cia402_drive.eds`` gives the SDO server, the NMT slave (boot-up,
heartbeat producer 0x1017), the PDO maps and the EMCY producer; this module adds
the CiA 402 power state machine, the heartbeat consumer 0x1016 (the watchdog),
and the load: the same plant, encoder, torque limit and fault rules as the
virtual Hi5 drive (``virtual_hi5.new_plant``, ``encoder_counts``,
``DriveConfig``). Run it with ``sensaug-virtual-cia402`` or
``python -m sensaug_bridge.virtual_cia402``; behaviour and reasons:
``docs/cia402.md``. In short:

* Boot: NMT boot-up, PRE-OPERATIONAL, heartbeat every 0x1017 ms; the CiA 402
  state SWITCH_ON_DISABLED. PDOs run only in NMT OPERATIONAL.
* Every SYNC (in OPERATIONAL): apply RPDO1's controlword (state transitions;
  fault reset on the rising edge of bit 7) and, in OPERATION_ENABLED, its target
  torque (per-mille of 0x6076) for one plant step; then TPDO1 (statusword,
  position in increments) and TPDO2 (velocity in increments/s, torque actual),
  each ending with the SYNC's counter byte (0x2000 SYNC counter echo; 0 for a
  SYNC without a counter), so the master can tell them from late or replayed ones.
  The plant's clock is the SYNC stream: one step per SYNC while enabled.
* A target torque beyond max torque 0x6072 is rejected, never clamped: torque 0
  for that cycle, counted, statusword bit 11, EMCY 0x8611 on the first of a run.
* Heartbeat consumer: once the producer named in 0x1016:01 has been heard, a
  gap longer than its time -> EMCY 0x8130 and, in OPERATION_ENABLED, FAULT.
  Overspeed after a step: FAULT, EMCY 0x8400. Quick stop: torque 0 at once,
  QUICK_STOP_ACTIVE until "disable voltage". NMT leaving OPERATIONAL while
  enabled: FAULT, EMCY 0x8100. Faults latch until a fault reset.
* ``standard=True`` (``--standard``): an off-the-shelf drive's dictionary, the EDS
  without 0x2000 (:func:`standard_eds`): the TPDOs carry no SYNC counter, and the
  master judges freshness from the bus (docs/cia402.md, "Freshness without 0x2000").
* The handle: outside OPERATION_ENABLED the plant keeps moving at zero torque
  in real time (``virtual_hi5.coast``); with ``log`` every step is recorded,
  commanded or free (``DriveLog``).
"""

from __future__ import annotations

import argparse
import configparser
import enum
import io
import math
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import can
import canopen
from canopen.sdo import SdoAbortedError

from sensaug_bridge.virtual_hi5 import (
    DriveConfig,
    VirtualDrive,
    add_drive_args,
    coast,
    drive_config_fields,
    encoder_counts,
    read_backlog,
    serve,
)

__all__ = [
    "PROFILE_NAME",
    "Cia402Config",
    "Cia402State",
    "Fault",
    "VirtualCia402",
    "main",
    "parse_args",
    "EDS_PATH",
    "standard_eds",
    "load_od",
]

#: The drive profile's name for people (this module is the virtual drive of
#: ``[rig] drive = "cia402"``, registered under the ``sensaug.virtual_drives``
#: entry points).
PROFILE_NAME = "CiA 402 (CANopen)"

#: The object dictionary, read from the source tree (editable install), like hi5.dbc.
EDS_PATH = Path(__file__).resolve().parents[2] / "cia402_drive.eds"

SYNC_COUNTER_ECHO = 0x2000
_TPDO_MAPPINGS = ("1A00", "1A01")


def standard_eds(eds_text: str) -> str:
    """The EDS of a standard drive: ``eds_text`` without the manufacturer object
    0x2000 (SYNC counter echo), its TPDOs mapping 2 objects (statusword and
    position; velocity and torque), the third mapping entry 0. Everything else
    as given (comments dropped)."""
    eds = configparser.RawConfigParser(inline_comment_prefixes=(";",))
    eds.optionxform = str  # type: ignore[assignment,method-assign]
    eds.read_string(eds_text)
    eds.remove_section("2000")
    eds.set("ManufacturerObjects", "SupportedObjects", "0")
    eds.remove_option("ManufacturerObjects", "1")
    for mapping in _TPDO_MAPPINGS:
        assert eds.get(f"{mapping}sub3", "DefaultValue").lower() == "0x20000008"
        eds.set(f"{mapping}sub0", "DefaultValue", "2")
        eds.set(f"{mapping}sub3", "DefaultValue", "0x00000000")
    out = io.StringIO()
    eds.write(out)
    return out.getvalue()


def load_od(node: int, standard: bool = False) -> Any:
    """The drive's object dictionary for ``node``: ``cia402_drive.eds``, or
    with ``standard`` that EDS without 0x2000 (:func:`standard_eds`), through
    canopen's EDS importer."""
    if not standard:
        return canopen.import_od(str(EDS_PATH), node)
    source = io.StringIO(standard_eds(EDS_PATH.read_text()))
    source.name = "cia402_drive_standard.eds"  # canopen picks the format by the name
    return canopen.import_od(source, node)


MODE_CST = 10  # 0x6060: cyclic synchronous torque
SYNC_COB_ID = 0x080
_I32 = (-(2**31), 2**31 - 1)
_COUNTER_MAX = 255


class Cia402State(enum.IntEnum):
    """CiA 402 power states; the value is the statusword sent (bit 9 remote, bit 4 voltage enabled)."""

    NOT_READY_TO_SWITCH_ON = 0x0200
    SWITCH_ON_DISABLED = 0x0240
    READY_TO_SWITCH_ON = 0x0231
    SWITCHED_ON = 0x0233
    OPERATION_ENABLED = 0x0237
    QUICK_STOP_ACTIVE = 0x0217
    FAULT = 0x0208


class Fault(enum.IntFlag):
    """Latched causes (the EMCY code sent for each is in ``EMCY_CODES``)."""

    NONE = 0
    HEARTBEAT = 1  # the master's heartbeat lost while enabled (the watchdog)
    OVERSPEED = 4
    COMMUNICATION = 8  # NMT left OPERATIONAL while enabled


EMCY_CODES = {Fault.HEARTBEAT: 0x8130, Fault.OVERSPEED: 0x8400, Fault.COMMUNICATION: 0x8100}
EMCY_TORQUE_LIMIT = 0x8611
STATUS_INTERNAL_LIMIT = 1 << 11


@dataclass
class Cia402Config(DriveConfig):
    """The virtual Hi5 drive's settings (plant, encoder, torque limit, heartbeat
    period) plus the CiA 402 ones. ``torque_limit_nm`` becomes max torque 0x6072,
    ``heartbeat_period_s`` the producer time 0x1017, ``encoder_counts_per_rev``
    0x608F:01."""

    rated_torque_mnm: int = 1000
    #: A standard drive: no 0x2000 in the dictionary (:func:`standard_eds`).
    standard: bool = False

    def _check_node(self) -> None:
        if not 1 <= self.node <= 127:
            raise ValueError(f"node: must be a CANopen node-ID in 1..127, got {self.node}")
        if not 1 <= self.rated_torque_mnm <= 2**32 - 1:
            raise ValueError(f"rated_torque_mnm: must be in 1..2**32-1, got {self.rated_torque_mnm}")
        limit = self.max_torque_per_mille()
        if not 1 <= limit <= 32767:
            raise ValueError(
                f"torque_limit_nm: {self.torque_limit_nm} N m is {limit} per-mille of the rated "
                f"{self.rated_torque_mnm} mN m; must be 1..32767 (0x6072)"
            )

    def max_torque_per_mille(self) -> int:
        return round(self.torque_limit_nm / (self.rated_torque_mnm * 1e-6)) if math.isfinite(self.torque_limit_nm) else 0


class _LoopTask:
    """A periodic frame (canopen's heartbeat producer) sent by the drive's own loop."""

    def __init__(self, owner: "VirtualCia402", can_id: int, data: bytes, period_s: float) -> None:
        self.owner, self.can_id, self.data, self.period_s = owner, can_id, bytes(data), period_s
        self.next_s = owner._clock()  # the first beat at once
        owner._tasks.append(self)

    def stop(self) -> None:
        if self in self.owner._tasks:
            self.owner._tasks.remove(self)

    def update(self, data: bytes) -> None:
        self.data = bytes(data)


class _DriveNetwork(canopen.Network):
    """A canopen network on the caller's bus, without canopen's notifier thread:
    the drive's loop feeds it received frames, and periodic frames are sent by
    that loop too."""

    def __init__(self, bus: can.BusABC, owner: "VirtualCia402") -> None:
        super().__init__(bus)
        self._owner = owner

    def send_periodic(self, can_id: int, data: bytes, period: float, remote: bool = False) -> Any:
        return _LoopTask(self._owner, can_id, data, period)


class VirtualCia402(VirtualDrive):
    """The drive on a python-can bus. Not thread-safe: one thread calls
    :meth:`start`, :meth:`run` (or :meth:`handle`/:meth:`poll`), :meth:`stop`.
    The bus is owned by the caller and not closed here."""

    config: Cia402Config

    def __init__(self, bus: can.BusABC, config: Optional[Cia402Config] = None, *, log: bool = False,
                 clock: Callable[[], float] = time.monotonic) -> None:
        cfg = config or Cia402Config()
        super().__init__(bus, cfg, log, clock)
        self._tasks: list[_LoopTask] = []
        self.network = _DriveNetwork(bus, self)
        self.node = canopen.LocalNode(cfg.node, load_od(cfg.node, cfg.standard))
        self.network.add_node(self.node)
        self._max_per_mille = cfg.max_torque_per_mille()
        self._store_config()
        self.node.add_write_callback(self._on_write)
        self.node.add_read_callback(self._on_read)
        self.node.rpdo.read(from_od=True)
        self.node.tpdo.read(from_od=True)
        self._rpdo = self.node.rpdo[1]
        self._tpdo1, self._tpdo2 = self.node.tpdo[1], self.node.tpdo[2]
        self._layouts = _PdoLayouts(self._rpdo, self._tpdo1, self._tpdo2)
        #: False while the loop handles a SYNC that a later SYNC in the same
        #: backlog supersedes (:meth:`run`): the plant steps, no TPDO is sent.
        self._answer_sync = True
        #: Set by an SDO write to a PDO parameter: the maps are re-read from
        #: the dictionary once canopen has stored the write.
        self._pdo_written = False
        self.network.subscribe(SYNC_COB_ID, self._on_sync)
        self.network.subscribe(0, self._after_nmt)  # after the NMT slave's own handler
        self.state = Cia402State.NOT_READY_TO_SWITCH_ON
        self.faults = Fault.NONE
        self.mode = 0
        self._controlword = 0
        #: Per-mille applied now (0 unless OPERATION_ENABLED and within 0x6072).
        self.torque_per_mille = 0
        self._limit_active = False
        # Heartbeat consumer (0x1016:01).
        self._consumer_id: Optional[int] = None
        self._consumer_s = 0.0
        self._last_master_hb: Optional[float] = None
        self.syncs = 0
        #: The counter of the SYNC being answered (0x2000; 0: the SYNC had none).
        self.sync_counter = 0
        self.steps = 0
        self.range_errors = 0
        self.heartbeat_events = 0
        self.emcy_sent = 0
        self.unknown_frames = 0
        #: Frames for this drive with a length its handler cannot take.
        self.length_errors = 0
        n = cfg.node
        self._lengths = {
            0x000: (2,),  # NMT command
            SYNC_COB_ID: (0, 1),  # with or without a counter
            0x200 + n: (self._rpdo.length // 8,),  # RPDO1
            0x600 + n: (8,),  # SDO request
        }
        #: What only this drive sends: EMCY, TPDO1, TPDO2, SDO response, heartbeat.
        self._own_ids = {0x080 + n, 0x180 + n, 0x280 + n, 0x580 + n, 0x700 + n}

    # -- dictionary --------------------------------------------------------------------

    def _store_config(self) -> None:
        """The config's values in the dictionary (SDO reads see them): the
        drive's stored parameters, which a reset restores."""
        cfg = self.config
        self._max_per_mille = cfg.max_torque_per_mille()
        self._store(0x6076, 0, cfg.rated_torque_mnm)
        self._store(0x6072, 0, self._max_per_mille)
        self._store(0x608F, 1, cfg.encoder_counts_per_rev)
        self._store(0x1017, 0, max(1, round(cfg.heartbeat_period_s * 1000.0)))

    def _store(self, index: int, sub: int, value: int) -> None:
        od = self.node.object_dictionary.get_variable(index, sub)
        assert od is not None
        self.node.data_store.setdefault(index, {})[sub] = od.encode_raw(value)

    def _on_read(self, index: int, subindex: int, od: Any) -> Optional[int]:
        """SDO reads of the PDO-mapped actual values see them as they are now
        (canopen calls this first; None: the stored value)."""
        return self._actual_values().get(index) if subindex == 0 else None

    def _on_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        """SDO writes (canopen calls this before storing; raising aborts the transfer)."""
        value = od.decode_raw(data)
        if index == 0x6060:
            if value not in (0, MODE_CST):
                raise SdoAbortedError(0x06090030)  # value range of parameter exceeded
            self.mode = value
            self._store(0x6061, 0, value)
        elif index == 0x1016 and subindex == 1:
            self._set_consumer(value)
        elif index == 0x6072:
            if not 1 <= value <= 32767:
                raise SdoAbortedError(0x06090030)
            self._max_per_mille = value
        elif index == 0x6040:
            self._apply_controlword(value)
        elif index in (0x1400, 0x1600, 0x1800, 0x1801, 0x1A00, 0x1A01):
            self._pdo_written = True

    def _reread_pdo_maps(self) -> None:
        """The PDO maps as the dictionary now holds them (after a master wrote
        a PDO's configuration over SDO, CiA 301's remapping sequence)."""
        self._pdo_written = False
        self.node.rpdo.read(from_od=False)
        self.node.tpdo.read(from_od=False)
        self._layouts = _PdoLayouts(self._rpdo, self._tpdo1, self._tpdo2)
        self._lengths[0x200 + self.config.node] = (self._rpdo.length // 8,)

    def _set_consumer(self, value: int) -> None:
        if self._consumer_id is not None:
            self.network.unsubscribe(0x700 + self._consumer_id, self._on_master_heartbeat)
        producer, time_ms = (value >> 16) & 0x7F, value & 0xFFFF
        self._last_master_hb = None  # armed by the next heartbeat heard
        if producer == 0 or time_ms == 0:
            self._consumer_id = None
            return
        self._consumer_id = producer
        self._consumer_s = time_ms / 1000.0
        self.network.subscribe(0x700 + producer, self._on_master_heartbeat)

    # -- life cycle --------------------------------------------------------------------

    def start(self) -> None:
        """NMT boot-up, PRE-OPERATIONAL (heartbeat producer on), SWITCH_ON_DISABLED."""
        self._t0 = self._clock()
        self._coast_s = self._t0
        if self.log is not None:
            self.log.t0_monotonic_s = self._t0
        self.node.nmt.state = "INITIALISING"  # sends the boot-up frame
        self.node.nmt.state = "PRE-OPERATIONAL"  # starts the heartbeat (0x1017)
        self._set_state(Cia402State.SWITCH_ON_DISABLED)
        self.poll(self._clock())

    def reset(self) -> None:
        """A restart of the drive (NMT reset node, or a power glitch: SIGUSR1 to
        the CLI): torque 0, faults cleared, every SDO-written value back to the
        EDS's and the config's (mode 0, heartbeat consumer off, 0x6072, PDO
        maps), then the boot of :meth:`start`: the boot-up message,
        PRE-OPERATIONAL with its heartbeat, SWITCH_ON_DISABLED. The handle
        (the plant) keeps its motion."""
        self.resets += 1
        self.torque_per_mille = 0
        self.faults = Fault.NONE
        self._limit_active = False
        self._controlword = 0
        self.mode = 0
        self.node.data_store.clear()
        self._store_config()
        self._set_consumer(0)
        self._reread_pdo_maps()  # the EDS's, the store being cleared
        self._rpdo.timestamp = None  # no RPDO1 received since
        self._set_state(Cia402State.NOT_READY_TO_SWITCH_ON)
        self.node.nmt.state = "INITIALISING"  # sends the boot-up frame
        self.node.nmt.state = "PRE-OPERATIONAL"  # restarts the heartbeat (0x1017)
        self._set_state(Cia402State.SWITCH_ON_DISABLED)

    def stop(self) -> None:
        """Torque 0; leave OPERATION_ENABLED for SWITCH_ON_DISABLED; a last TPDO1 with
        the final statusword and a last heartbeat (NMT STOPPED)."""
        self.torque_per_mille = 0
        if self.state != Cia402State.FAULT:
            self._set_state(Cia402State.SWITCH_ON_DISABLED)
        self._send_tpdos()
        self.node.nmt.state = "STOPPED"
        self.network.send_message(0x700 + self.config.node, bytes([0x04]))
        self.node.nmt.stop_heartbeat()

    def run(self, stop: Optional[threading.Event] = None, duration_s: Optional[float] = None) -> None:
        """Serve the bus until ``stop`` is set or ``duration_s`` has passed (blocking
        receive, cut to the next heartbeat or consumer deadline; no sleeps).

        After a stall of this process (the OS scheduled it out) the frames
        queued meanwhile are handled as one backlog: every SYNC in it steps
        the plant with the RPDO1 before it, in order, but only the last SYNC
        is answered; answers to SYNCs a later one has superseded would reach
        the master after that later SYNC, stale, and would only delay the
        answer it waits for (docs/cia402.md, "Backlog")."""
        end = math.inf if duration_s is None else self._clock() + duration_s
        for now in self._iterations(stop, end):
            self.poll(now)
            due = min([end, now + 0.01] + [t.next_s for t in self._tasks])
            if self._last_master_hb is not None:
                due = min(due, self._last_master_hb + self._consumer_s)
            msg = self.bus.recv(max(due - now, 0.0))
            if msg is not None:
                self._handle_backlog(read_backlog(self.bus, msg))

    def _handle_backlog(self, frames: list[can.Message]) -> None:
        """Handles ``frames`` in order, answering only the last SYNC among them."""
        syncs = [i for i, m in enumerate(frames) if m.arbitration_id == SYNC_COB_ID]
        superseded = set(syncs[:-1])
        # A master heartbeat queued while this process was stalled reached
        # the drive in time: it is heard before the backlog's other frames,
        # which check the consumer against this process's late clock (a real
        # drive's consumer runs on time; under emulation this one did not).
        beat = None if self._consumer_id is None else 0x700 + self._consumer_id
        if self._last_master_hb is not None and any(m.arbitration_id == beat for m in frames):
            self._last_master_hb = self._clock()
        for i, msg in enumerate(frames):
            self._answer_sync = i not in superseded
            self.handle(msg, self._clock())
        self._answer_sync = True

    def poll(self, now: float) -> None:
        """Heartbeat consumer check, the free handle and the heartbeat producer."""
        self._check_consumer(now)
        if self.state != Cia402State.OPERATION_ENABLED:
            self._coast_s = coast(self.plant, self._coast_s, now, self.config.dt_s, self.log, self._t0,
                                  self._encoder)
        for task in list(self._tasks):
            if now >= task.next_s:
                self.network.send_message(task.can_id, task.data)
                # Skip missed beats after a stall instead of bursting.
                task.next_s = max(task.next_s + task.period_s, now + 0.5 * task.period_s)

    def handle(self, msg: can.Message, now: float) -> None:
        """Act on one received frame. Never raises on bad input (extended,
        remote, error frames and frames on this drive's own COB-IDs count as
        ``unknown_frames``; wrong lengths as ``length_errors``)."""
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id or msg.is_fd:
            self.unknown_frames += 1
            return
        self._check_consumer(now)
        data = bytearray(msg.data[: msg.dlc])
        if msg.arbitration_id in self._own_ids:
            # Another node sending on this drive's COB-IDs (canopen's TPDO maps
            # would take the bytes in as their data): a bus conflict, dropped.
            self.unknown_frames += 1
            return
        allowed = self._lengths.get(msg.arbitration_id)
        if allowed is not None and len(data) not in allowed:
            # canopen's handlers assume these lengths (an NMT command of one
            # byte would raise in its NMT slave): dropped and counted.
            self.length_errors += 1
            return
        self.network.notify(msg.arbitration_id, data, now)
        if self._pdo_written:
            self._reread_pdo_maps()

    # -- NMT, heartbeat consumer -------------------------------------------------------

    def _after_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        nmt = self.node.nmt.state
        if nmt == "INITIALISING" and data[0] == 0x81:  # reset node: the whole drive
            self.reset()
            return
        if nmt == "INITIALISING":  # reset communication: boot-up, then back up
            self.node.nmt.state = "INITIALISING"  # canopen's handler sends no boot-up
            self.node.nmt.state = "PRE-OPERATIONAL"
        if nmt != "OPERATIONAL" and self.state == Cia402State.OPERATION_ENABLED:
            self._latch(Fault.COMMUNICATION)

    def _on_master_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self._last_master_hb = timestamp

    def _check_consumer(self, now: float) -> None:
        last = self._last_master_hb
        if last is None or now - last <= self._consumer_s:
            return
        # A heartbeat event: reported once, then the consumer waits for the next beat.
        self.heartbeat_events += 1
        self._last_master_hb = None
        if self.state == Cia402State.OPERATION_ENABLED:
            self._latch(Fault.HEARTBEAT)
        else:
            self._emcy(EMCY_CODES[Fault.HEARTBEAT])

    # -- the CiA 402 state machine -------------------------------------------------------

    def _apply_controlword(self, cw: int) -> None:
        edge = bool(cw & 0x80) and not self._controlword & 0x80
        self._controlword = cw
        s = self.state
        if s == Cia402State.FAULT:
            if edge:
                self.faults = Fault.NONE
                self._emcy(0x0000)  # error reset
                self._set_state(Cia402State.SWITCH_ON_DISABLED)
            return
        disable_voltage = not cw & 0x02
        quick_stop = cw & 0x06 == 0x02
        shutdown = cw & 0x87 == 0x06
        switch_on = cw & 0x8F == 0x07
        enable = cw & 0x8F == 0x0F
        S = Cia402State
        nxt = s
        if s == S.SWITCH_ON_DISABLED:
            nxt = S.READY_TO_SWITCH_ON if shutdown else s
        elif s == S.READY_TO_SWITCH_ON:
            if disable_voltage or quick_stop:
                nxt = S.SWITCH_ON_DISABLED
            elif switch_on:
                nxt = S.SWITCHED_ON
            elif enable:  # "switch on + enable operation": transitions 3 and 4
                nxt = S.OPERATION_ENABLED if self.mode == MODE_CST else S.SWITCHED_ON
        elif s == S.SWITCHED_ON:
            if disable_voltage or quick_stop:
                nxt = S.SWITCH_ON_DISABLED
            elif shutdown:
                nxt = S.READY_TO_SWITCH_ON
            elif enable and self.mode == MODE_CST:
                nxt = S.OPERATION_ENABLED
        elif s == S.OPERATION_ENABLED:
            if quick_stop:
                nxt = S.QUICK_STOP_ACTIVE
            elif disable_voltage:
                nxt = S.SWITCH_ON_DISABLED
            elif shutdown:
                nxt = S.READY_TO_SWITCH_ON
            elif switch_on:
                nxt = S.SWITCHED_ON
        elif s == S.QUICK_STOP_ACTIVE:
            nxt = S.SWITCH_ON_DISABLED if disable_voltage else s
        if nxt != s:
            self._set_state(nxt)

    def _set_state(self, state: Cia402State) -> None:
        if state != Cia402State.OPERATION_ENABLED:
            self.torque_per_mille = 0
            if self.state == Cia402State.OPERATION_ENABLED:
                self._coast_s = self._clock()  # the handle coasts from now
        self.state = state

    def _latch(self, fault: Fault) -> None:
        self.faults |= fault
        self.torque_per_mille = 0
        self._set_state(Cia402State.FAULT)
        self._emcy(EMCY_CODES[fault])

    def statusword(self) -> int:
        sw = int(self.state)
        if self._limit_active:
            sw |= STATUS_INTERNAL_LIMIT
        return sw

    def _emcy(self, code: int) -> None:
        register = 0 if code == 0 else 0x01 | (0x10 if code & 0xFF00 == 0x8100 else 0)
        self._store(0x1001, 0, register)
        self.node.emcy.send(code, register, int(self.faults).to_bytes(1, "little"))
        self.emcy_sent += 1

    # -- SYNC: the cycle -------------------------------------------------------------------

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.node.nmt.state != "OPERATIONAL":
            return
        t_rx = time.perf_counter()
        self.syncs += 1
        self.sync_counter = data[0] if data else 0
        cmd = 0
        if self._rpdo.timestamp is not None:  # an RPDO1 has arrived
            received = self._layouts.rpdo_values(self._rpdo)
            self._apply_controlword(received.get(0x6040, self._controlword))
            cmd = received.get(0x6071, 0)
        stepped = self.state == Cia402State.OPERATION_ENABLED
        if stepped:
            if abs(cmd) > self._max_per_mille:
                # Rejected and counted, never clamped.
                self.range_errors += 1
                if not self._limit_active:
                    self._limit_active = True
                    self._emcy(EMCY_TORQUE_LIMIT)
                self.torque_per_mille = 0
            else:
                self._limit_active = False
                self.torque_per_mille = cmd
            applied = self.torque_per_mille
            x, v = self.plant.step(self._to_nm(applied))
            self.steps += 1
            if abs(v) > self.config.max_velocity_rad_s:
                self._latch(Fault.OVERSPEED)
        else:
            self._limit_active = False
        if self._answer_sync:
            self._send_tpdos()
        if stepped and self.log is not None:
            self.log.add(timestamp - self._t0, self.syncs & 0xFF, self._to_nm(cmd), self._to_nm(applied),
                         self._encoder(x), v, time.perf_counter() - t_rx)

    def _to_nm(self, per_mille: int) -> float:
        """Per-mille of the rated torque 0x6076 (mN m) to N m."""
        return per_mille * self.config.rated_torque_mnm * 1e-6

    def _actual_values(self) -> dict[int, int]:
        """The values the TPDOs may carry, by index: statusword, position,
        velocity (increments, increments/s), torque actual, SYNC counter echo."""
        x, v = self.plant.x, self.plant.v
        return {
            0x6041: self.statusword(),
            0x6064: _saturate(encoder_counts(x, self.config.encoder_counts_per_rev), _I32),
            0x606C: _saturate(round(v * self.config.velocity_report_scale / self._rad_per_count), _I32),
            0x6077: self.torque_per_mille,
            0x2000: self.sync_counter,
        }

    def _send_tpdos(self) -> None:
        """TPDO1 and TPDO2 as their maps now stand (a master may have
        remapped them): each mapped object's current value."""
        values = self._actual_values()
        for tpdo in (self._tpdo1, self._tpdo2):
            self._layouts.fill(tpdo, values)
            tpdo.transmit()

    def summary(self) -> dict[str, Any]:
        """Counts for a one-line report at exit."""
        return self._with_latency({
            "state": self.state.name,
            "faults": int(self.faults),
            "nmt": self.node.nmt.state,
            "syncs": self.syncs,
            "steps": self.steps,
            "range_errors": self.range_errors,
            "heartbeat_events": self.heartbeat_events,
            "emcy_sent": self.emcy_sent,
            "unknown_frames": self.unknown_frames,
            "length_errors": self.length_errors,
            "resets": self.resets,
        })


class _PdoLayouts:
    """Where each mapped object sits in a PDO's bytes, from canopen's maps and
    the dictionary's data types, so that a cycle packs and unpacks them with
    one ``struct`` call each instead of canopen's per-variable encoding (a
    third of the drive's time per SYNC). A map with an entry that is not
    whole bytes of its type keeps canopen's own encoding."""

    def __init__(self, *pdos: Any) -> None:
        self._layout = {id(pdo): _byte_layout(pdo) for pdo in pdos}

    def fill(self, pdo: Any, values: dict[int, int]) -> None:
        """Writes ``values`` (0 for an index not given) into ``pdo.data``."""
        layout = self._layout.get(id(pdo))
        if layout is None:
            for var in pdo:
                var.raw = values.get(var.index, 0)
            return
        for index, packer, offset in layout:
            packer.pack_into(pdo.data, offset, values.get(index, 0))

    def rpdo_values(self, pdo: Any) -> dict[int, int]:
        """The mapped objects' values in the last received ``pdo``, by index."""
        layout = self._layout.get(id(pdo))
        if layout is None:
            return {var.index: var.raw for var in pdo}
        return {index: packer.unpack_from(pdo.data, offset)[0] for index, packer, offset in layout}


def _byte_layout(pdo: Any) -> Optional[list[tuple[int, Any, int]]]:
    """``(index, struct, byte offset)`` per mapped object, or None when one is
    not a whole-byte field of its dictionary type."""
    out = []
    for var in pdo:
        packer = var.od.STRUCT_TYPES.get(var.od.data_type)
        if packer is None or var.offset % 8 or var.length != 8 * packer.size:
            return None
        out.append((var.index, packer, var.offset // 8))
    return out


def _saturate(value: int, bounds: tuple[int, int]) -> int:
    return min(max(value, bounds[0]), bounds[1])


# -- command line ------------------------------------------------------------------------


def parse_args(argv: Optional[Sequence[str]] = None) -> argparse.Namespace:
    d = Cia402Config()
    ap = argparse.ArgumentParser(
        prog="sensaug-virtual-cia402",
        description="Virtual CiA 402 drive (CANopen, cyclic synchronous torque) on a python-can bus "
        "(default: loopback sensaug_udp). --torque-limit is max torque 0x6072, --heartbeat-hz "
        "0x1017, --encoder-counts-per-rev 0x608F:01; one plant step per SYNC. See docs/cia402.md.",
    )
    ap.add_argument("--node", type=int, default=d.node, help="CANopen node-ID 1..127 (default 1)")
    ap.add_argument("--rated-torque-mnm", type=int, default=d.rated_torque_mnm, help="0x6076, mN m (default 1000)")
    ap.add_argument(
        "--standard",
        action="store_true",
        help="a standard drive: the EDS without 0x2000 (no SYNC counter echo in the TPDOs)",
    )
    add_drive_args(ap, d)
    return ap.parse_args(argv)


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Console entry point. Exit code 0 on a clean stop, 2 for a bad option, 1 if the bus cannot be opened."""
    args = parse_args(argv)
    config = Cia402Config(
        **drive_config_fields(args), rated_torque_mnm=args.rated_torque_mnm, standard=args.standard
    )
    return serve("sensaug-virtual-cia402", args, config, lambda bus: VirtualCia402(bus, config, log=args.log is not None))


if __name__ == "__main__":
    sys.exit(main())
