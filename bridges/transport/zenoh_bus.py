"""Zenoh backend: one zenoh session per bus, envelopes as the payload of `prefix/key`.

Peer mode on one host needs no router: buses find each other by multicast scouting, or, faster and
without multicast, by explicit endpoints (one side `listen=["tcp/127.0.0.1:7447"]`, the others
`connect=[...]`). A real RSU box joins by connecting to the master's endpoint
(`connect=["tcp/192.168.1.10:7447"]`).

Subscription callbacks run on zenoh's receive thread (not one Python thread per subscriber), so a
participant's messages reach every subscription in the order they arrived: a lockstep ack never
overtakes the data sent before it. Zenoh's own Python callback threads would make the interpreter wait
at exit for an open session; every open bus is closed by a hook that runs before that wait anyway.
"""
from __future__ import annotations

import json
import logging
import threading
import weakref
from pathlib import Path

import zenoh
import zenoh.handlers

from bridges.transport.bus import Bus, Subscription
from bridges.transport.envelope import DEFAULT_MAX_SIZE
from bridges.transport.errors import TransportError

__all__ = ["ZenohBus"]

log = logging.getLogger("bridges.transport")

_OPEN: "weakref.WeakSet[ZenohBus]" = weakref.WeakSet()


def _close_all() -> None:
    for bus in list(_OPEN):
        try:
            bus.close()
        except Exception as exc:  # at exit, report and go on
            log.debug("closing %r at exit: %s", bus, exc)


# threading._register_atexit runs before the interpreter joins non-daemon threads (where an open
# zenoh session would hang it); plain atexit runs too late. Fall back to atexit where it is missing.
if hasattr(threading, "_register_atexit"):
    threading._register_atexit(_close_all)
else:  # pragma: no cover
    import atexit

    atexit.register(_close_all)

_CONGESTION = {"block": zenoh.CongestionControl.BLOCK, "drop": zenoh.CongestionControl.DROP}


class ZenohBus(Bus):
    """`connect`/`listen`: zenoh endpoints ("tcp/host:port", "udp/...", "tls/..."). `mode`: "peer" or
    "client" (client needs a router). `multicast_scouting`: find peers without endpoints, on the
    interface `scouting_interface` ("lo" by default: peers on this host only, nothing leaves it; a box
    on the network connects to an explicit endpoint, or name its interface, e.g. "eth0", to scout there).
    `congestion`: "block" (default: a lockstep tick must not vanish) or "drop" (a slow link drops).
    `express`: send at once instead of batching (lower latency, more packets). `config`: extra zenoh
    settings, a dict of {"path/in/config": value} or the path of a zenoh JSON5 config file."""

    backend = "zenoh"

    def __init__(self, *, prefix: str, sender: str, connect: list[str] | tuple[str, ...] = (),
                 listen: list[str] | tuple[str, ...] = (), mode: str = "peer", multicast_scouting: bool = True,
                 scouting_interface: str = "lo", congestion: str = "block", express: bool = True, config: dict | str | Path | None = None,
                 max_size: int = DEFAULT_MAX_SIZE):
        super().__init__(prefix=prefix, sender=sender, max_size=max_size)
        if mode not in ("peer", "client"):
            raise TransportError(f"zenoh mode must be 'peer' or 'client', got {mode!r}")
        if congestion not in _CONGESTION:
            raise TransportError(f"zenoh congestion must be one of {sorted(_CONGESTION)}, got {congestion!r}")
        self._congestion = _CONGESTION[congestion]
        self._express = bool(express)
        self.endpoints = {"connect": list(connect), "listen": list(listen)}
        try:
            cfg = self._config(config, mode, list(connect), list(listen), multicast_scouting, scouting_interface)
            self._session = zenoh.open(cfg)
        except (zenoh.ZError, ValueError, OSError) as exc:
            raise TransportError(f"zenoh could not open a {mode} session (listen {list(listen)}, connect "
                                 f"{list(connect)}): {exc}") from None
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._pub_lock = threading.Lock()
        _OPEN.add(self)

    @staticmethod
    def _config(config, mode, connect, listen, scouting, scouting_interface) -> "zenoh.Config":
        if isinstance(config, (str, Path)):
            cfg = zenoh.Config.from_file(str(config))
        else:
            cfg = zenoh.Config()
        cfg.insert_json5("mode", json.dumps(mode))
        if connect:
            cfg.insert_json5("connect/endpoints", json.dumps(connect))
        if listen:
            cfg.insert_json5("listen/endpoints", json.dumps(listen))
        cfg.insert_json5("scouting/multicast/enabled", json.dumps(bool(scouting)))
        if scouting:
            cfg.insert_json5("scouting/multicast/interface", json.dumps(str(scouting_interface)))
            if not listen:  # found by scouting on this host: listen on this host only
                cfg.insert_json5("listen/endpoints", json.dumps(["tcp/127.0.0.1:0"]))
        for path, value in (config.items() if isinstance(config, dict) else ()):
            cfg.insert_json5(path, json.dumps(value))
        return cfg

    def _send(self, full_key: str, data: bytes) -> None:
        pub = self._pubs.get(full_key)
        try:
            if pub is None:
                with self._pub_lock:
                    pub = self._pubs.get(full_key)
                    if pub is None:
                        pub = self._pubs[full_key] = self._session.declare_publisher(
                            full_key, congestion_control=self._congestion, express=self._express)
            pub.put(data)
        except zenoh.ZError as exc:
            self._count("send_errors")
            raise TransportError(f"zenoh put on {full_key!r} failed: {exc}") from None

    def _declare(self, sub: Subscription) -> None:
        on_envelope = self._on_envelope

        def on_sample(sample: "zenoh.Sample") -> None:
            try:
                data = sample.payload.to_bytes()
                wire_key = str(sample.key_expr)
            except Exception as exc:  # never let an exception into zenoh's thread
                self._count("garbage")
                self._warn_once(("sample",), "zenoh: unreadable sample: %s", exc)
                return
            on_envelope(data, subs=[sub], wire_key=wire_key, source=wire_key)

        try:
            # indirect=False: run on zenoh's receive thread, so messages reach all subscriptions in the
            # order they arrived (an ack never overtakes the data sent before it), as on the UDP backend
            sub.backend_handle = self._session.declare_subscriber(
                sub.full_expr, zenoh.handlers.Callback(on_sample, indirect=False))
        except zenoh.ZError as exc:
            raise TransportError(f"zenoh subscribe to {sub.full_expr!r} failed: {exc}") from None

    def _undeclare(self, sub: Subscription) -> None:
        handle, sub.backend_handle = sub.backend_handle, None
        if handle is not None and not self._session.is_closed():
            handle.undeclare()

    def _close(self) -> None:
        _OPEN.discard(self)
        for pub in self._pubs.values():
            try:
                pub.undeclare()
            except zenoh.ZError:
                pass
        self._pubs.clear()
        self._session.close()

    def zid(self) -> str:
        """This session's zenoh id (for logs and diagnostics)."""
        return str(self._session.zid())

    def peers(self) -> list[str]:
        """Zenoh ids of the peers this session is connected to right now."""
        return [str(z) for z in self._session.info.peers_zid()]
