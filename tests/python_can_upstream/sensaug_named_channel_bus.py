"""``sensaug_udp`` under python-can's ``virtual`` name, for python-can's own tests.

Copied next to python-can's test package by ``tests/test_python_can_suite.py``.
python-can's notifier, cyclic-send and producer/consumer tests open
``interface="virtual"`` with channel names such as ``"test"``, ``0`` or none.
:class:`NamedChannelBus` is ``UdpLoopbackBus`` itself; it only maps each distinct
channel name to its own free UDP port (the same name, the same bus), as the
virtual interface maps names to in-process channels, and gives received
messages the name as their ``channel``.
"""

from __future__ import annotations

from typing import Any, Optional

import can

from sensaug_bridge.udp_bus import UdpLoopbackBus, free_port

_PORTS: dict[str, int] = {}


def port_for(channel: Any) -> int:
    """The UDP port standing in for python-can's virtual channel ``channel``."""
    key = repr(channel)
    if key not in _PORTS:
        port = free_port()
        while port in _PORTS.values():
            port = free_port()
        _PORTS[key] = port
    return _PORTS[key]


class NamedChannelBus(UdpLoopbackBus):
    """``UdpLoopbackBus`` on the port :func:`port_for` gives ``channel``; received
    messages carry the channel name, as the virtual interface's do."""

    def __init__(self, channel: Any = None, *args: Any, **kwargs: Any) -> None:
        self._name = channel
        super().__init__(port_for(channel), *args, **kwargs)

    def _recv_internal(self, timeout: Optional[float]) -> tuple[Optional[can.Message], bool]:
        msg, filtered = super()._recv_internal(timeout)
        if msg is not None:
            msg.channel = self._name
        return msg, filtered
