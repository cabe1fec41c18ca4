"""A virtual drive of either profile (``VirtualHi5``, ``VirtualCia402``)
served on its own thread on a fresh loopback port, with the host's bus
opened before it boots: the fixture of tests/test_virtual_hi5.py and
tests/test_virtual_cia402.py, written once."""

from __future__ import annotations

import threading
from typing import Any, Callable, Generic, Iterator, TypeVar

import can
from sensaug_bridge.udp_bus import free_port

HostT = TypeVar("HostT")


class DriveThread(Generic[HostT]):
    """``drive``: the virtual drive (``make_drive(bus)``); ``host``: the
    host's side (``make_host(bus)`` of the host's bus); ``stop`` ends the
    drive's loop on ``thread``."""

    def __init__(self, make_drive: Callable[[can.BusABC], Any], make_host: Callable[[can.BusABC], HostT]) -> None:
        self.port = free_port()
        self.host_bus = can.Bus(interface="sensaug_udp", channel=self.port)
        self.drive_bus = can.Bus(interface="sensaug_udp", channel=self.port)
        self.host = make_host(self.host_bus)
        self.drive = make_drive(self.drive_bus)
        self.stop = threading.Event()
        self.drive.start()
        self.thread = threading.Thread(target=self.drive.run, kwargs={"stop": self.stop, "duration_s": 30.0},
                                       daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=5)
        self.drive.stop()
        self.drive_bus.shutdown()
        self.host_bus.shutdown()


def drive_factory(make: Callable[..., DriveThread[HostT]]) -> Iterator[Callable[..., DriveThread[HostT]]]:
    """The body of a ``start_drive`` fixture (``yield from``): a factory
    ``start_drive(**config)`` of drive threads (``make(**config)``), every
    one closed when the test ends."""
    started: list[DriveThread[HostT]] = []

    def factory(**config: Any) -> DriveThread[HostT]:
        started.append(make(**config))
        return started[-1]

    yield factory
    for drive in started:
        drive.close()
