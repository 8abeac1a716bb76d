"""Transports: one Bus interface, backends chosen by name (the python-can way).

    bus = open_bus("zenoh", prefix="v2i/run42", sender="rsu1", connect=["tcp/192.168.1.10:7447"])
    bus.publish("v2x/tx/rsu1", payload, t_sim=1.25, stamps={"encoded": time.time_ns()})
    sub = bus.subscribe("v2x/tx/*")
    msg = sub.recv(timeout=1.0)   # Message(key, sender, t_sim, seq, stamps, payload, received_ns, version)

Every message travels in a versioned envelope (envelope.py) under the run prefix, so two runs on
one wire never hear each other. Backends: ``zenoh`` (default of the project), ``udp`` (multicast or
unicast peers, for boxes without Zenoh), ``memory`` (in-process, for tests).
"""
from __future__ import annotations

import importlib
import inspect

from bridges.transport.bus import COUNTERS, Bus, Subscription
from bridges.transport.envelope import DEFAULT_MAX_SIZE, PROTOCOL_VERSION, Message, decode, encode
from bridges.transport.errors import EnvelopeError, KeyExprError, TransportError, VersionMismatch

__all__ = ["open_bus", "register_backend", "backends", "Bus", "Subscription", "Message", "PROTOCOL_VERSION",
           "DEFAULT_MAX_SIZE", "COUNTERS", "TransportError", "KeyExprError", "EnvelopeError", "VersionMismatch",
           "encode", "decode"]

# name -> "module:Class", imported on first use so a missing optional dependency only hurts its backend
_BACKENDS: dict[str, str] = {
    "zenoh": "bridges.transport.zenoh_bus:ZenohBus",
    "udp": "bridges.transport.udp_bus:UdpBus",
    "memory": "bridges.transport.memory:MemoryBus",
}


def register_backend(name: str, target: str) -> None:
    """Make `open_bus(name, ...)` build `target` ("package.module:Class", a Bus subclass)."""
    if ":" not in target:
        raise TransportError(f"backend target {target!r} must look like 'package.module:Class'")
    _BACKENDS[name] = target


def backends() -> list[str]:
    return sorted(_BACKENDS)


def _load(name: str) -> type[Bus]:
    try:
        target = _BACKENDS[name]
    except KeyError:
        raise TransportError(f"unknown transport backend {name!r}; known: {', '.join(backends())}") from None
    module_name, _, class_name = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise TransportError(f"transport backend {name!r} ({target}) cannot be imported: {exc}") from exc
    try:
        return getattr(module, class_name)
    except AttributeError:
        raise TransportError(f"transport backend {name!r}: {module_name} has no {class_name}") from None


def open_bus(backend: str, *, prefix: str, sender: str, **options) -> Bus:
    """A connected Bus of the named backend; unknown backends and options are a TransportError."""
    cls = _load(backend)
    params = inspect.signature(cls.__init__).parameters
    if not any(p.kind is p.VAR_KEYWORD for p in params.values()):
        known = sorted(n for n, p in params.items() if p.kind is p.KEYWORD_ONLY and n not in ("prefix", "sender"))
        unknown = sorted(set(options) - set(known))
        if unknown:
            raise TransportError(f"transport backend {backend!r} has no option {', '.join(map(repr, unknown))}; "
                                 f"its options: {', '.join(known) or 'none'}")
    return cls(prefix=prefix, sender=sender, **options)
