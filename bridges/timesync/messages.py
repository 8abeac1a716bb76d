"""Payloads of the time protocol: small JSON objects, one dataclass per message type.

Why JSON: the messages are few per tick and tiny (< 200 bytes), a real box's
firmware can speak them without our code, and a capture is readable. Floats
are written with Python's shortest round-trip repr, so simulation times cross
the wire bit for bit.

Every payload is one UTF-8 JSON object::

    {"type": "tick", "v": [1, 0], "k": 42, "t": 0.42, "step": 0.01}

``type`` selects the dataclass below, ``v`` is the protocol version
``[major, minor]`` of the sender. A receiver accepts any minor of its own
major and ignores fields it does not know (so minors can add fields);
a different major is refused at join time with both versions named. Missing
or mistyped fields raise :class:`ProtocolError` naming the type and field, as do
non-finite floats (JSON has none; Python's reader takes NaN and Infinity) and
values a message cannot hold (a Mapping's rtf must be > 0).

Keys (relative to the run prefix; ``<name>`` is the participant)::

    time/join/<name>     participant -> master   Join (repeated until answered)
    time/welcome/<name>  master -> participant   Welcome (accepted or refused, with the reason)
    time/tick            master -> all           Tick(k, t): "simulation time t reached, do your work"
    time/ack/<name>      participant -> master   Ack(k): "finished everything up to tick k"
    time/hb/<name>       participant -> master   Heartbeat
    time/leave/<name>    participant -> master   Leave
    time/beat            master -> all           Beat (the master's heartbeat)
    time/map             master -> all           Mapping(t_sim0, wall0_ns, rtf) in realtime runs
    time/ping/<name>     participant -> master   Ping(t1)
    time/pong/<name>     master -> participant   Pong(t1, t2, t3)
    time/offset/<name>   participant -> master   Offset (the estimate, for the record)
    time/end             master -> all           End(status, reason): the run is over
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import MISSING, asdict, dataclass, field, fields
from typing import Any, ClassVar

from bridges.timesync.errors import ProtocolError

PROTOCOL_VERSION: tuple[int, int] = (1, 1)  # 1.1: Welcome.world
NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_-]{0,63}$")  # a participant name is one key chunk

JOIN, WELCOME, TICK, ACK, HEARTBEAT, LEAVE = "time/join", "time/welcome", "time/tick", "time/ack", "time/hb", "time/leave"
BEAT, MAPPING, PING, PONG, OFFSET, END = "time/beat", "time/map", "time/ping", "time/pong", "time/offset", "time/end"


def key(base: str, name: str | None = None) -> str:
    """The key of a message kind, per participant where it has one."""
    return f"{base}/{name}" if name else base


def name_of(msg_key: str) -> str:
    """The participant chunk of a received per-participant key (the last one)."""
    return msg_key.rstrip("/").rsplit("/", 1)[-1]


def version_text(v) -> str:
    return ".".join(str(x) for x in v)


def compatible(theirs, ours=PROTOCOL_VERSION) -> bool:
    return len(theirs) >= 1 and theirs[0] == ours[0]


# -- messages -----------------------------------------------------------------
@dataclass(frozen=True)
class Join:
    TYPE: ClassVar[str] = "join"
    name: str
    role: str
    session: str
    publishes: list = field(default_factory=list)
    version: list = field(default_factory=lambda: list(PROTOCOL_VERSION))
    pid: int = 0
    host: str = ""


@dataclass(frozen=True)
class Welcome:
    TYPE: ClassVar[str] = "welcome"
    name: str
    session: str
    accepted: bool
    reason: str = ""
    master_version: list = field(default_factory=lambda: list(PROTOCOL_VERSION))
    mode: str = "lockstep"
    latency_policy: str = "fixed"
    latencies: dict = field(default_factory=dict)
    sync_every: int = 1
    heartbeat_s: float = 0.5
    master_timeout_s: float = 10.0
    # what every app needs to know of the scenario's world (1.1): {"origin": {"lat", "lon", "alt"}, ...};
    # see bridges.geo and master.links.participants for the keys the master fills in
    world: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Tick:
    TYPE: ClassVar[str] = "tick"
    k: int
    t: float
    step: float = 0.0


@dataclass(frozen=True)
class Ack:
    TYPE: ClassVar[str] = "ack"
    name: str
    session: str
    k: int
    processing_s: float = -1.0  # the app's wall time on this tick, when it reports it


@dataclass(frozen=True)
class Heartbeat:
    TYPE: ClassVar[str] = "hb"
    name: str
    session: str
    n: int = 0


@dataclass(frozen=True)
class Leave:
    TYPE: ClassVar[str] = "leave"
    name: str
    session: str
    reason: str = ""


@dataclass(frozen=True)
class Beat:
    TYPE: ClassVar[str] = "beat"
    n: int = 0


@dataclass(frozen=True)
class Mapping:
    TYPE: ClassVar[str] = "map"
    t_sim0: float
    wall0_ns: int
    rtf: float = 1.0

    def __post_init__(self):
        # every participant's run clock divides and multiplies by it: 0 or less would stop or reverse time
        if not (math.isfinite(self.rtf) and self.rtf > 0):
            raise ValueError(f"field 'rtf' must be a finite number > 0 (simulated seconds per wall second), "
                             f"got {self.rtf!r}")


@dataclass(frozen=True)
class Ping:
    TYPE: ClassVar[str] = "ping"
    name: str
    id: int
    t1_ns: int


@dataclass(frozen=True)
class Pong:
    TYPE: ClassVar[str] = "pong"
    name: str
    id: int
    t1_ns: int
    t2_ns: int
    t3_ns: int


@dataclass(frozen=True)
class Offset:
    TYPE: ClassVar[str] = "offset"
    name: str
    session: str
    offset_ns: int
    rtt_ns: int
    samples: int = 0


@dataclass(frozen=True)
class End:
    TYPE: ClassVar[str] = "end"
    status: str
    reason: str = ""


TYPES: dict[str, type] = {c.TYPE: c for c in (Join, Welcome, Tick, Ack, Heartbeat, Leave, Beat, Mapping, Ping,
                                              Pong, Offset, End)}
_JSON_TYPES = {"str": str, "int": int, "float": (int, float), "bool": bool, "list": list, "dict": dict}


def encode(msg) -> bytes:
    """The payload of a message dataclass."""
    body = {"type": msg.TYPE, "v": list(PROTOCOL_VERSION), **asdict(msg)}
    return json.dumps(body, separators=(",", ":"), allow_nan=False).encode()


def decode(payload: bytes, expect: type | None = None):
    """A message dataclass from a payload; ProtocolError says exactly what is wrong."""
    try:
        body = json.loads(bytes(payload).decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise ProtocolError(f"time-protocol payload is not UTF-8 JSON: {exc}") from None
    if not isinstance(body, dict):
        raise ProtocolError(f"time-protocol payload must be a JSON object, got {type(body).__name__}")
    kind = body.get("type")
    cls = TYPES.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise ProtocolError(f"unknown time-protocol message type {kind!r} (known: {', '.join(TYPES)})")
    if expect is not None and cls is not expect:
        raise ProtocolError(f"expected a {expect.TYPE!r} message, got {kind!r}")
    v = body.get("v")
    if not (isinstance(v, list) and len(v) == 2 and all(type(x) is int for x in v)):
        raise ProtocolError(f"{kind}: field 'v' must be [major, minor], got {v!r}")
    if cls is not Join and not compatible(v):
        raise ProtocolError(f"{kind}: protocol version {version_text(v)} is not compatible with "
                            f"{version_text(PROTOCOL_VERSION)}")
    values: dict[str, Any] = {}
    for f in fields(cls):
        if f.name not in body:
            if f.default is MISSING and f.default_factory is MISSING:
                raise ProtocolError(f"{kind}: missing field {f.name!r}")
            continue
        value = body[f.name]
        want = _JSON_TYPES[f.type if isinstance(f.type, str) else f.type.__name__]
        if not isinstance(value, want) or (isinstance(value, bool) and f.type != "bool"):
            raise ProtocolError(f"{kind}: field {f.name!r} must be {f.type}, got {type(value).__name__} {value!r:.40}")
        if f.type == "float" and not math.isfinite(value):
            raise ProtocolError(f"{kind}: field {f.name!r} must be a finite number, got {value!r}")
        values[f.name] = float(value) if f.type == "float" else value
    try:
        msg = cls(**values)
    except ValueError as exc:
        raise ProtocolError(f"{kind}: {exc}") from None
    for name_field in ("name",):
        if hasattr(msg, name_field) and not NAME.match(getattr(msg, name_field)):
            raise ProtocolError(f"{kind}: participant name {getattr(msg, name_field)!r} is not a valid key chunk "
                                "(letters, digits, _ and -, at most 64)")
    return msg
