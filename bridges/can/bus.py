"""Open a python-can bus from a small configuration, the same way in the master and in the apps.

``udp_multicast`` (default) carries CAN frames between processes and hosts over
IP multicast; ``virtual`` stays inside one process (tests); any other python-can
interface (``socketcan``, ``pcan``, ``kvaser``, ``vector``, ...) with its channel
and bitrate reaches a real bus, so an AV computer plugged into a CAN adapter
runs the same code. Like ``can.Bus(interface=..., channel=...)``, plus defaults
and a check that names the bad setting before any socket opens.
"""
from __future__ import annotations

import ipaddress
from dataclasses import dataclass, field
from typing import Any

import can

__all__ = ["BusConfig", "open_bus", "DEFAULT_INTERFACE", "DEFAULT_CHANNELS", "DEFAULT_UDP_PORT"]

DEFAULT_INTERFACE = "udp_multicast"
# python-can's IPv4 fallback group: IPv4 multicast on loopback works on more hosts than IPv6
DEFAULT_CHANNELS = {"udp_multicast": "239.74.163.2", "virtual": "v2i-can"}
DEFAULT_UDP_PORT = 43113


@dataclass(frozen=True)
class BusConfig:
    interface: str = DEFAULT_INTERFACE
    channel: str | int | None = None  # None: the interface's default (DEFAULT_CHANNELS)
    bitrate: int | None = None  # real buses; ignored by udp_multicast and virtual
    port: int | None = None  # udp_multicast only (default 43113): separate ports keep parallel runs apart
    fd: bool = False
    options: dict[str, Any] = field(default_factory=dict)  # passed to can.Bus as keywords

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
    return can.Bus(**cfg.kwargs())
