"""Plain UDP backend: IP multicast by default, or a unicast peer list for boxes that cannot do multicast.

Multicast: every bus binds the group port with SO_REUSEADDR/SO_REUSEPORT (several processes on one
host can join) and joins the group on interface `iface`, 127.0.0.1 by default, so by default nothing
leaves this host (IP_MULTICAST_LOOP lets its processes hear each other); a box on the network sets
`iface` to the address of its LAN interface.
Unicast: each bus listens on its own `bind:port` and sends every datagram to each of `peers`.
Either way a bus hears its own messages (delivered locally, as Zenoh does), not through the network.

Envelopes larger than a datagram are split (fragments.py) and reassembled by the receive thread;
incomplete ones are dropped after `reassembly_timeout` and counted (`incomplete`). Garbage datagrams
are counted and logged, never raised.
"""
from __future__ import annotations

import itertools
import logging
import socket
import sys
import threading
import time

from bridges.transport.bus import Bus
from bridges.transport.envelope import DEFAULT_MAX_SIZE
from bridges.transport.errors import TransportError
from bridges.transport.fragments import FragmentError, Reassembler, split

__all__ = ["UdpBus", "DEFAULT_GROUP", "DEFAULT_PORT"]

log = logging.getLogger("bridges.transport")

DEFAULT_GROUP = "239.255.42.99"   # administratively scoped (RFC 2365): stays inside the site
DEFAULT_PORT = 47420
_IP_MULTICAST_ALL = getattr(socket, "IP_MULTICAST_ALL", 49 if sys.platform.startswith("linux") else None)


def _host_port(text: str, what: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise TransportError(f"{what} {text!r} must look like 'host:port'")
    try:
        return socket.gethostbyname(host), int(port)
    except OSError as exc:
        raise TransportError(f"{what} {text!r}: cannot resolve {host!r}: {exc}") from None


class UdpBus(Bus):
    """See the module docstring. `datagram_size` counts the UDP payload (20-byte fragment header
    included): 1400 fits a 1500-byte Ethernet MTU with room for tunnels; raise it (up to 65507) on
    loopback or jumbo-frame links for fewer, larger datagrams."""

    backend = "udp"

    def __init__(self, *, prefix: str, sender: str, group: str | None = DEFAULT_GROUP, port: int = DEFAULT_PORT,
                 peers: list[str] | tuple[str, ...] = (), bind: str = "0.0.0.0", ttl: int = 1,
                 iface: str = "127.0.0.1", loopback: bool = True, datagram_size: int = 1400,
                 reassembly_timeout: float = 1.0, rcvbuf: int = 4 * 1024 * 1024, max_size: int = DEFAULT_MAX_SIZE):
        super().__init__(prefix=prefix, sender=sender, max_size=max_size)
        if not 21 <= datagram_size <= 65507:
            raise TransportError(f"datagram_size {datagram_size} must be 21..65507 bytes")
        self.datagram_size = datagram_size
        self.peers = [_host_port(p, "peer") for p in peers]
        self.group = None if self.peers else group
        if self.group is None and not self.peers:
            raise TransportError("udp bus needs a multicast group or a list of unicast peers")
        self.port = int(port)
        self._msg_ids = itertools.count()
        self._reassembler = Reassembler(max_size, reassembly_timeout)
        self._sock = self._open_socket(bind, iface, ttl, loopback, rcvbuf)
        self.address = self._sock.getsockname()  # (host, port) actually bound; port 0 picks a free one
        self.port = self.address[1]
        self._dests = self.peers or [(self.group, self.port)]
        self._send_lock = threading.Lock()
        self._thread = threading.Thread(target=self._receive_loop, name=f"udp-bus-{sender}", daemon=True)
        self._thread.start()

    def _open_socket(self, bind: str, iface: str, ttl: int, loopback: bool, rcvbuf: int) -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
        try:
            if self.group:  # share the group port; a unicast port stays exclusive (a clash is an error)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                if hasattr(socket, "SO_REUSEPORT"):
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, rcvbuf)
            got = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
            if got < min(rcvbuf, 1 << 20):
                log.warning("udp bus: receive buffer is %d bytes (asked %d; see net.core.rmem_max): "
                            "bursts of fragments may be lost", got, rcvbuf)
            sock.bind((bind, self.port))
            if self.group:
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                                socket.inet_aton(self.group) + socket.inet_aton(iface))
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(iface))
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1 if loopback else 0)
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, ttl)
                if _IP_MULTICAST_ALL is not None:  # Linux: only the group we joined, not every group on the port
                    try:
                        sock.setsockopt(socket.IPPROTO_IP, _IP_MULTICAST_ALL, 0)
                    except OSError:
                        pass
            sock.settimeout(0.2)  # the receive loop wakes up to expire fragments and to notice close()
        except OSError as exc:
            sock.close()
            where = f"group {self.group} on {iface}" if self.group else "unicast"
            raise TransportError(f"udp bus cannot open {bind}:{self.port} ({where}): {exc}") from None
        return sock

    # -- sending -------------------------------------------------------------------------
    def _send(self, full_key: str, data: bytes) -> None:
        datagrams = split(data, self.session, next(self._msg_ids) & 0xFFFFFFFF, self.datagram_size)
        with self._send_lock:
            for dest in self._dests:
                for datagram in datagrams:
                    try:
                        self._sock.sendto(datagram, dest)
                    except OSError as exc:
                        self._count("send_errors")
                        raise TransportError(f"udp bus: sending {len(data)} bytes on {full_key!r} to "
                                             f"{dest[0]}:{dest[1]} failed: {exc}") from None
        self._on_envelope(data, source="self")  # our own subscriptions hear it, as on Zenoh

    # -- receiving -----------------------------------------------------------------------
    def _receive_loop(self) -> None:
        sock = self._sock
        last_expire = time.monotonic()
        while not self.closed:
            try:
                datagram, addr = sock.recvfrom(65535)
            except socket.timeout:
                datagram = None
            except OSError as exc:
                if self.closed:
                    break
                self._warn_once(("recv", exc.errno), "udp bus: receive error %s", exc)
                time.sleep(0.05)
                continue
            now = time.monotonic()
            if datagram is not None:
                self._on_datagram(datagram, addr, now)
            if now - last_expire > 0.1:
                last_expire = now
                self._reassembler.expire(now)
                dropped = self._reassembler.take_dropped()
                if dropped:
                    self._count("incomplete", dropped)
                    self._warn_once("incomplete", "udp bus: gave up on %d incomplete fragmented message(s) "
                                    "(lost datagrams? see stats()['incomplete'])", dropped)

    def _on_datagram(self, datagram: bytes, addr: tuple, now: float) -> None:
        try:
            if len(datagram) >= 8 and int.from_bytes(datagram[4:8], "little") == self.session \
                    and datagram[:4] == b"V2IF":
                return  # our own multicast echo: already delivered locally
            data = self._reassembler.add(datagram, addr, now)
        except FragmentError as exc:
            self._count(exc.kind)
            self._warn_once((exc.kind, addr), "udp bus: dropped datagram from %s:%s: %s", addr[0], addr[1], exc.reason)
            return
        except Exception:
            self._count("garbage")
            log.exception("udp bus: unexpected error on a datagram from %s", addr)
            return
        if data is not None:
            self._on_envelope(data, source=f"{addr[0]}:{addr[1]}")

    def _close(self) -> None:
        self._thread.join(timeout=1.0)
        self._sock.close()
