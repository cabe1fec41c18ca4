"""python-can's back-to-back suite on ``sensaug_udp``, the way python-can runs it on
its own interfaces: a subclass naming the interface and channel.

Copied into python-can's ``test`` package by ``tests/test_python_can_suite.py``.
"""

from sensaug_bridge.udp_bus import free_port

from . import back2back_test as upstream

_PORT = free_port()


class BasicTestSensaugUdp(upstream.Back2BackTestCase):
    INTERFACE_1 = "sensaug_udp"
    CHANNEL_1 = _PORT
    INTERFACE_2 = "sensaug_udp"
    CHANNEL_2 = _PORT


class ThreadSafeTestSensaugUdp(upstream.TestThreadSafeBus):
    INTERFACE_1 = "sensaug_udp"
    CHANNEL_1 = _PORT
    INTERFACE_2 = "sensaug_udp"
    CHANNEL_2 = _PORT
