"""Hi5 CAN bridge, Python side: the protocol (from ``firmware_bridge/hi5.dbc``),
the loopback ``sensaug_udp`` python-can interface, and a virtual Hi5 drive.

See ``docs/virtual_hi5.md``. ``virtual_hi5`` needs the project's Rust extension
(``sensaug``) and is not imported here.
"""

from sensaug_bridge import protocol
from sensaug_bridge.protocol import FaultFlag, ProtocolError, State
from sensaug_bridge.udp_bus import UdpLoopbackBus, free_port

__all__ = ["FaultFlag", "ProtocolError", "State", "UdpLoopbackBus", "free_port", "protocol"]
