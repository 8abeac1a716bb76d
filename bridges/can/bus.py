"""Open a python-can bus from a small configuration, the same way in the master and in the apps.

``udp_multicast`` (default) carries CAN frames between processes and hosts over
IP multicast; ``virtual`` stays inside one process (tests); any other python-can
interface (``socketcan``, ``pcan``, ``kvaser``, ``vector``, ...) with its channel
and bitrate reaches a real bus, so an AV computer plugged into a CAN adapter
runs the same code. Like ``can.Bus(interface=..., channel=...)``, plus defaults
and a check that names the bad setting before any socket opens.
"""
from __future__ import annotations

import errno
import ipaddress
import socket
import struct
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import can

__all__ = ["BusConfig", "open_bus", "DEFAULT_INTERFACE", "DEFAULT_CHANNELS", "DEFAULT_UDP_PORT", "DEFAULT_IFACE",
           "InterfaceUdpMulticastBus"]

_IP_MULTICAST_ALL = getattr(socket, "IP_MULTICAST_ALL", 49 if sys.platform.startswith("linux") else None)

DEFAULT_INTERFACE = "udp_multicast"
# python-can's IPv4 fallback group: IPv4 multicast on loopback works on more hosts than IPv6
DEFAULT_CHANNELS = {"udp_multicast": "239.74.163.2", "virtual": "v2i-can"}
DEFAULT_UDP_PORT = 43113
DEFAULT_IFACE = "127.0.0.1"


@dataclass(frozen=True)
class BusConfig:
    interface: str = DEFAULT_INTERFACE
    channel: str | int | None = None  # None: the interface's default (DEFAULT_CHANNELS)
    bitrate: int | None = None  # real buses; ignored by udp_multicast and virtual
    port: int | None = None  # udp_multicast only (default 43113): separate ports keep parallel runs apart
    fd: bool = False
    options: dict[str, Any] = field(default_factory=dict)  # passed to can.Bus as keywords
    # udp_multicast only: the interface (its IPv4 address) the group is joined and sent on. 127.0.0.1 keeps
    # every frame on this host; a box on the network uses its LAN address ("0.0.0.0": the routing default)
    iface: str = DEFAULT_IFACE

    def resolved_channel(self) -> str | int | None:
        return self.channel if self.channel is not None else DEFAULT_CHANNELS.get(self.interface)

    def problems(self) -> list[tuple[str, str]]:
        """(key, reason) for each bad setting; empty when the bus can be opened."""
        out = []
        if self.interface not in can.VALID_INTERFACES:
            out.append(("interface", f"unknown python-can interface {self.interface!r} "
                                     f"(known: {', '.join(sorted(can.VALID_INTERFACES))})"))
        channel = self.resolved_channel()
        if channel is None and self.interface in can.VALID_INTERFACES:
            out.append(("channel", f"interface {self.interface!r} needs a channel"))
        if self.interface == "udp_multicast" and channel is not None:
            try:
                if not ipaddress.ip_address(str(channel)).is_multicast:
                    out.append(("channel", f"{channel!r} is not a multicast address (e.g. 239.74.163.2)"))
            except ValueError:
                out.append(("channel", f"{channel!r} is not an IP address (udp_multicast channels are "
                                       "multicast groups, e.g. 239.74.163.2)"))
        if self.port is not None and (isinstance(self.port, bool) or not isinstance(self.port, int)
                                      or not 1 <= self.port <= 65535):
            out.append(("port", f"expected 1..65535, got {self.port!r}"))
        if self.interface == "udp_multicast":
            try:
                ipaddress.IPv4Address(str(self.iface))
            except ValueError:
                out.append(("iface", f"expected the IPv4 address of an interface (e.g. 127.0.0.1), got {self.iface!r}"))
            if channel is not None and ":" in str(channel):
                out.append(("channel", "an IPv6 group cannot be confined to an interface here; use an IPv4 "
                                       "group such as 239.74.163.2"))
        elif self.iface != DEFAULT_IFACE:
            out.append(("iface", "only udp_multicast has an interface"))
        if self.port is not None and self.interface != "udp_multicast":
            out.append(("port", "only udp_multicast has a port"))
        if self.bitrate is not None and (isinstance(self.bitrate, bool) or not isinstance(self.bitrate, int)
                                         or self.bitrate <= 0):
            out.append(("bitrate", f"expected a positive integer (bit/s), got {self.bitrate!r}"))
        return out

    def kwargs(self) -> dict[str, Any]:
        """Keyword arguments for can.Bus."""
        kw: dict[str, Any] = {"interface": self.interface, "channel": self.resolved_channel()}
        if self.interface == "udp_multicast":
            kw["port"] = self.port or DEFAULT_UDP_PORT
            kw["fd"] = self.fd
        elif self.interface not in ("virtual",):
            if self.bitrate is not None:
                kw["bitrate"] = self.bitrate
            if self.fd:
                kw["fd"] = True
        kw.update(self.options)
        return kw

    def describe(self) -> str:
        kw = self.kwargs()
        extra = f":{kw['port']}" if "port" in kw else ""
        return f"{self.interface}:{kw['channel']}{extra}"


def open_bus(config: BusConfig | None = None, **overrides: Any) -> can.BusABC:
    """A python-can bus for `config` (fields may be overridden by keyword); ValueError names a bad field."""
    cfg = config or BusConfig()
    if overrides:
        cfg = BusConfig(**{**cfg.__dict__, **overrides})
    bad = cfg.problems()
    if bad:
        raise ValueError("; ".join(f"{key}: {reason}" for key, reason in bad))
    if cfg.interface == "udp_multicast":
        kw = cfg.kwargs()
        kw.pop("interface")
        return InterfaceUdpMulticastBus(iface=cfg.iface, **kw)
    return can.Bus(**cfg.kwargs())


# -- udp_multicast on one interface ---------------------------------------------------------------------
# python-can's udp_multicast joins its group on the routing default (here: the LAN interface, so every
# frame and the IGMP join leave the host). The two classes below speak the same wire format (python-can's
# own pack/unpack, so a box running plain python-can still hears us) but join and send on `iface`.
from can.interfaces.udp_multicast.bus import (SO_TIMESTAMPNS, GeneralPurposeUdpMulticastBus,  # noqa: E402
                                              UdpMulticastBus)


class _InterfaceMulticast(GeneralPurposeUdpMulticastBus):
    """python-can's multicast socket handler with the group joined on one IPv4 interface."""

    def __init__(self, group: str, port: int, hop_limit: int, iface: str, errors: list | None = None):
        self._iface = iface
        self._errors = errors if errors is not None else []  # why a socket could not be made (python-can logs
        super().__init__(group, port, hop_limit)               # it at INFO and raises without the reason)

    def _create_socket(self, address_family):
        if address_family != socket.AF_INET:
            raise OSError("only IPv4 groups are confined to an interface")
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            iface = socket.inet_aton(self._iface)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, struct.pack("@I", self.hop_limit))
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, iface)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if hasattr(socket, "SO_REUSEPORT"):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            try:  # receive timestamps as python-can's handler expects them
                sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
                self.timestamp_nanosecond = True
            except OSError:
                self.timestamp_nanosecond = False
            sock.bind(("", self.port))
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, socket.inet_aton(self.group) + iface)
            if _IP_MULTICAST_ALL is not None:  # Linux: only our group on this port, not every joined group
                try:
                    sock.setsockopt(socket.IPPROTO_IP, _IP_MULTICAST_ALL, 0)
                except OSError:
                    pass
        except OSError as exc:
            sock.close()
            self._errors.append(exc)
            raise
        return sock


def _open_multicast(group: str, port: int, hop_limit: int, iface: str, wait_s: float = 3.0):
    """The group's socket; a port another socket holds is tried again for `wait_s`, then the error says why.

    The default port (python-can's 43113) lies in Linux's ephemeral range (32768-60999), so a short-lived
    socket of another program can hold it for a moment (a clean-clone test run once failed here with no
    reason given)."""
    errors: list[OSError] = []
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return _InterfaceMulticast(group, port, hop_limit, iface, errors)
        except can.CanInitializationError:
            busy = bool(errors) and getattr(errors[-1], "errno", None) == errno.EADDRINUSE
            if not busy or time.monotonic() >= deadline:
                why = f"{errors[-1]}" if errors else "no reason given"
                raise can.CanInitializationError(
                    f"cannot join {group}:{port} on {iface}: {why}") from (errors[-1] if errors else None)
            time.sleep(0.2)


class InterfaceUdpMulticastBus(UdpMulticastBus):
    """python-can's udp_multicast bus, joined and sending on the interface `iface` (an IPv4 address)."""

    def __init__(self, channel: str = DEFAULT_CHANNELS["udp_multicast"], port: int = DEFAULT_UDP_PORT,
                 hop_limit: int = 1, fd: bool = True, iface: str = DEFAULT_IFACE, **kwargs: Any) -> None:
        can.BusABC.__init__(self, channel, **kwargs)
        self._multicast = _open_multicast(channel, port, hop_limit, iface)
        self._can_protocol = can.CanProtocol.CAN_FD if fd else can.CanProtocol.CAN_20

