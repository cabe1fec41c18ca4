"""Copied in as ``conftest.py`` at the root of python-can's unpacked source by
``tests/test_python_can_suite.py``: every bus python-can's tests open as
``interface="virtual"`` is a ``sensaug_udp`` bus (:mod:`sensaug_named_channel_bus`)."""

from __future__ import annotations

import can
import can.interfaces
import pytest


def pytest_configure(config: pytest.Config) -> None:
    can.interfaces.BACKENDS["virtual"] = ("sensaug_named_channel_bus", "NamedChannelBus")


@pytest.fixture(autouse=True)
def _every_virtual_bus_is_sensaug_udp(monkeypatch: pytest.MonkeyPatch):
    """Fail loudly if a test's bus is not ours (the substitution did not take)."""
    from sensaug_bridge.udp_bus import UdpLoopbackBus

    opened: list[can.BusABC] = []
    original = can.BusABC.__init__

    def record(self: can.BusABC, *args, **kwargs) -> None:
        opened.append(self)
        original(self, *args, **kwargs)

    monkeypatch.setattr(can.BusABC, "__init__", record)
    yield
    foreign = [type(b).__name__ for b in opened if not isinstance(b, UdpLoopbackBus)]
    assert not foreign, f"buses other than sensaug_udp were opened: {foreign}"
