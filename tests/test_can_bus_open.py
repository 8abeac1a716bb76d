"""Opening the udp_multicast CAN bus when its port is held: tried again for a moment (python-can's default port
lies in Linux's ephemeral range, where a short-lived socket of another program can sit), then an error that says
why (python-can's own says only "could not connect to a multicast IP network")."""
from __future__ import annotations

import socket
import threading
import time

import can
import pytest

from bridges.can.bus import BusConfig, open_bus


def held_port() -> socket.socket:
    """A UDP socket bound to a free port without SO_REUSEADDR/SO_REUSEPORT: nobody else can bind it."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("", 0))
    return s


def test_a_port_held_for_a_moment_is_waited_for():
    holder = held_port()
    port = holder.getsockname()[1]
    threading.Timer(0.5, holder.close).start()
    t0 = time.monotonic()
    bus = open_bus(BusConfig("udp_multicast", port=port))
    try:
        assert 0.4 < time.monotonic() - t0 < 3.0
    finally:
        bus.shutdown()


def test_a_port_held_for_good_fails_naming_the_reason():
    holder = held_port()
    port = holder.getsockname()[1]
    try:
        with pytest.raises(can.CanInitializationError, match=rf":{port} on 127\.0\.0\.1: .*[Aa]ddress already in use"):
            open_bus(BusConfig("udp_multicast", port=port))
    finally:
        holder.close()
