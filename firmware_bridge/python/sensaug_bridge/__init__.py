"""Hi5 CAN bridge, Python side: the protocol (from ``hi5.dbc``, package data:
``sensaug_bridge.resources``), the loopback ``sensaug_udp`` python-can interface, and a virtual Hi5 drive.

See ``docs/virtual_hi5.md``. Importing the package (which python-can does to
open ``sensaug_udp``) needs no DBC: the protocol names below are loaded on
first use. The package never imports ``sensaug`` (which depends on it): the
virtual drives step their own copy of the controller's plant
(``sensaug_bridge.plant``, checked against the core's bit for bit).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from sensaug_bridge.udp_bus import UdpLoopbackBus, free_port

if TYPE_CHECKING:
    from sensaug_bridge import protocol
    from sensaug_bridge.protocol import FaultFlag, ProtocolError, State

__all__ = ["FaultFlag", "ProtocolError", "State", "UdpLoopbackBus", "free_port", "protocol"]

_LAZY = {"FaultFlag", "ProtocolError", "State"}


def __getattr__(name: str) -> Any:
    # The protocol reads hi5.dbc; only its users should need it.
    if name == "protocol":
        return importlib.import_module("sensaug_bridge.protocol")
    if name in _LAZY:
        return getattr(importlib.import_module("sensaug_bridge.protocol"), name)
    raise AttributeError(f"module 'sensaug_bridge' has no attribute {name!r}")
