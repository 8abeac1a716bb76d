"""Nothing leaves the host unless a scenario says so: the multicast users stay on 127.0.0.1 by default.

python-can's udp_multicast, the UDP transport and zenoh's scouting all used the routing default
(the LAN interface) before; these check the socket and session settings that keep them on loopback,
and that frames still get through there.
"""
from __future__ import annotations

import socket
import time
import uuid

import can
import pytest

from bridges.can.bus import BusConfig, InterfaceUdpMulticastBus, open_bus
from bridges.transport import open_bus as open_transport

LOOPBACK = socket.inet_aton("127.0.0.1")


def _multicast_if(sock: socket.socket) -> bytes:
    return sock.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, 4)


def test_can_udp_multicast_joins_and_sends_on_loopback():
    port = 43000 + uuid.uuid4().int % 1000
    a, b = open_bus(BusConfig(port=port)), open_bus(BusConfig(port=port))
    try:
        assert isinstance(a, InterfaceUdpMulticastBus)
        assert _multicast_if(a._multicast._socket) == LOOPBACK
        for i in range(5):
            a.send(can.Message(arbitration_id=0x100 + i, data=bytes(8), is_extended_id=False))
        got = []
        while (msg := b.recv(0.5)) is not None:
            got.append(msg.arbitration_id)
        assert got == [0x100 + i for i in range(5)]
        assert msg is None and got and b.recv(0) is None
    finally:
        a.shutdown()
        b.shutdown()


def test_can_iface_is_checked():
    assert [k for k, _ in BusConfig(iface="eth0").problems()] == ["iface"]
    assert [k for k, _ in BusConfig("virtual", "x", iface="10.0.0.1").problems()] == ["iface"]
    with pytest.raises(ValueError, match="iface"):
        open_bus(BusConfig(iface="not-an-address"))


def test_udp_transport_multicast_stays_on_loopback():
    port = 46000 + uuid.uuid4().int % 1000
    a = open_transport("udp", prefix="test/lo", sender="a", port=port)
    b = open_transport("udp", prefix="test/lo", sender="b", port=port)
    try:
        assert _multicast_if(a._sock) == LOOPBACK
        sub = b.subscribe("x")
        a.publish("x", b"hello", 1.0)
        msg = sub.recv(timeout=2.0)
        assert msg is not None and msg.payload == b"hello"
    finally:
        a.close()
        b.close()


def test_zenoh_scouts_on_loopback_and_finds_its_peer():
    prefix = f"test/lo-{uuid.uuid4().hex[:8]}"
    a = open_transport("zenoh", prefix=prefix, sender="a")
    b = open_transport("zenoh", prefix=prefix, sender="b")
    try:
        sub = b.subscribe("x")
        deadline = time.monotonic() + 5.0
        msg = None
        while msg is None and time.monotonic() < deadline:  # scouting takes a moment
            a.publish("x", b"hello", 1.0)
            msg = sub.recv(timeout=0.2)
        assert msg is not None and msg.payload == b"hello"
        from bridges.transport.zenoh_bus import ZenohBus

        cfg = ZenohBus._config(None, "peer", [], [], True, "lo")  # what the two sessions above were given
        assert cfg.get_json("scouting/multicast/interface").strip('"') == "lo"
        assert "tcp/127.0.0.1:0" in cfg.get_json("listen/endpoints")
    finally:
        a.close()
        b.close()
