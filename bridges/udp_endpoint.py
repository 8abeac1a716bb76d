"""``HOST:PORT`` endpoints of plain UDP devices (an RSU's Immediate Forward port, an OBU's forward target).

Written as ``192.0.2.10:1516``, ``rsu.lab:1516`` or ``[2001:db8::10]:1516``.
Parsing is separate from resolving, so a scenario is checked when it is
loaded and a name is looked up only when the socket is opened. Receivers that
measure delays take the kernel's receive time (`recv_stamped`).
"""
from __future__ import annotations

import re
import socket
import struct
import sys
import time
from dataclasses import dataclass

_FORM = re.compile(r"^(?:\[(?P<v6>[0-9A-Fa-f:.]+)\]|(?P<host>[A-Za-z0-9._-]+)):(?P<port>[0-9]{1,5})$")


@dataclass(frozen=True)
class Endpoint:
    host: str
    port: int

    def __str__(self) -> str:
        return f"[{self.host}]:{self.port}" if ":" in self.host else f"{self.host}:{self.port}"


def parse_endpoint(text: object, *, allow_any_port: bool = False) -> Endpoint:
    """An endpoint from ``HOST:PORT``; ValueError saying what is wrong. Port 1..65535 (0 too with
    `allow_any_port`: "any free port", for a socket that listens)."""
    if not isinstance(text, str):
        raise ValueError(f"expected \"HOST:PORT\", got {text!r}")
    m = _FORM.match(text.strip())
    if m is None:
        raise ValueError(f"expected \"HOST:PORT\" (an IPv6 address in brackets: \"[::1]:1516\"), got {text!r}")
    port = int(m.group("port"))
    if not (0 if allow_any_port else 1) <= port <= 65535:
        raise ValueError(f"port {port} of {text!r} is outside {0 if allow_any_port else 1}..65535")
    return Endpoint(m.group("v6") or m.group("host"), port)


def resolve(endpoint: Endpoint) -> tuple[int, tuple]:
    """(address family, socket address) of an endpoint for a UDP socket; OSError when it cannot be resolved."""
    infos = socket.getaddrinfo(endpoint.host, endpoint.port, type=socket.SOCK_DGRAM)
    if not infos:
        raise OSError(f"{endpoint}: no address")
    family, _, _, _, sockaddr = infos[0]
    return family, sockaddr


def udp_socket(endpoint: Endpoint, *, bind: bool) -> tuple[socket.socket, tuple]:
    """A UDP socket of the endpoint's family and its resolved address (bound to it when `bind`)."""
    family, sockaddr = resolve(endpoint)
    sock = socket.socket(family, socket.SOCK_DGRAM)
    try:
        if bind:
            sock.bind(sockaddr)
    except OSError:
        sock.close()
        raise
    return sock, sockaddr


# -- kernel receive timestamps ----------------------------------------------------------------------------------
# A thread that reads a socket can run late (another thread holds the GIL through a long C call, the host is
# loaded); the kernel's own receive time does not. Linux gives it as SCM_TIMESTAMPNS ancillary data once
# SO_TIMESTAMPNS is set: a struct timespec on the realtime clock (time.time()). Python does not name the
# option; 35 is its value on Linux's generic socket ABI (x86, ARM, RISC-V), as asm-generic/socket.h says.
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35 if sys.platform.startswith("linux") else None)
_TIMESPEC = struct.Struct("@qq")


def enable_rx_timestamps(sock: socket.socket) -> bool:
    """Ask the kernel to stamp every datagram `sock` receives; False where it cannot (then `recv_stamped`
    stamps with time.time() when it reads the datagram)."""
    if _SO_TIMESTAMPNS is None:
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
    except OSError:
        return False
    return True


def recv_stamped(sock: socket.socket, bufsize: int = 65536) -> tuple[bytes, tuple, float]:
    """(datagram, source address, receive time on the time.time() clock): the kernel's time when
    `enable_rx_timestamps` worked, else the time it is read here."""
    data, ancillary, _, source = sock.recvmsg(bufsize, socket.CMSG_SPACE(_TIMESPEC.size))
    for level, kind, value in ancillary:
        if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(value) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(value)
            return data, source, sec + nsec * 1e-9
    return data, source, time.time()
