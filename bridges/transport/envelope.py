"""The bridge envelope: what every transport carries around a payload (DESIGN §4: trace stamps
travel here, outside the J2735 bytes, so wire formats stay standard).

Layout, little-endian::

    offset  size  field
    0       4     magic b"V2IE"
    4       1     major  \\
    5       1     minor   | frozen for every major version, so a receiver can always
    6       1     sender length (1..255)  | say who speaks which version
    7       n     sender, UTF-8          /
    7+n     4     header length: bytes from offset 0 to the payload
            4     payload length
            4     session: random per bus, so a restarted sender's seq 0 is not a duplicate
            8     t_sim, float64 seconds (finite)
            8     seq, uint64
            2     key length, then the key (UTF-8, the full key with the run prefix)
            1     stamp count, then per stamp: name length (1 byte), name (UTF-8), int64 ns
            ...   fields a later minor version adds; older readers skip them (header length)
    header  ...   payload

Header length plus payload length must equal the size received exactly.
"""
from __future__ import annotations

import math
import struct
import time
from dataclasses import dataclass, field

from bridges.transport.errors import EnvelopeError, KeyExprError, VersionMismatch
from bridges.transport.keys import validate_key

__all__ = ["PROTOCOL_VERSION", "MAGIC", "DEFAULT_MAX_SIZE", "Message", "encode", "decode", "peek_size",
           "validate_sender", "encoded_size", "as_buffer"]

PROTOCOL_VERSION = (1, 0)  # (major, minor): majors must match to talk
MAGIC = b"V2IE"
DEFAULT_MAX_SIZE = 4 * 1024 * 1024

_FROZEN = struct.Struct("<4sBBB")     # magic, major, minor, sender length
_FIXED = struct.Struct("<IIIdQH")     # header length, payload length, session, t_sim, seq, key length
_STAMP_NS = struct.Struct("<q")
_U8 = struct.Struct("<B")
MAX_KEY_BYTES = 0xFFFF
MAX_NAME_BYTES = 255
MAX_STAMPS = 255
_I64 = (-(1 << 63), (1 << 63) - 1)


@dataclass(slots=True)
class Message:
    """One received (or to-be-sent) message. `key` is relative to the bus prefix once delivered."""

    key: str
    sender: str
    t_sim: float
    seq: int
    stamps: dict[str, int]
    payload: bytes
    received_ns: int = 0
    version: tuple[int, int] = PROTOCOL_VERSION
    session: int = 0  # the sending bus's random incarnation number
    extra: dict = field(default_factory=dict, repr=False)  # room for backends (e.g. the source address)


def validate_sender(sender: str) -> str:
    """A sender name is one key chunk (no '/', no wildcards) of at most 255 UTF-8 bytes."""
    validate_key(sender, "sender")
    if "/" in sender:
        raise KeyExprError(f"sender {sender!r} must be a single key chunk (no '/')")
    if len(sender.encode()) > MAX_NAME_BYTES:
        raise KeyExprError(f"sender {sender!r} is longer than {MAX_NAME_BYTES} UTF-8 bytes")
    return sender


def as_buffer(payload) -> bytes | bytearray | memoryview:
    """`payload` as a flat byte buffer: a numpy frame (480, 640, 3) counts 921,600 bytes, not 480."""
    if isinstance(payload, (bytes, bytearray)):
        return payload
    try:
        view = memoryview(payload)
        return view if view.ndim == 1 and view.itemsize == 1 else view.cast("B")
    except TypeError as exc:  # not a buffer, or not contiguous
        raise ValueError(f"payload must be a contiguous bytes-like object ({exc})") from None


def encode(sender: str, key: str, t_sim: float, seq: int, payload: bytes | bytearray | memoryview,
           stamps: dict[str, int] | None = None, *, session: int = 0,
           version: tuple[int, int] = PROTOCOL_VERSION) -> bytes:
    """The envelope bytes; ValueError (or KeyExprError) names the argument that cannot be encoded."""
    validate_sender(sender)
    sender_b = sender.encode()
    key_b = key.encode()
    if len(key_b) > MAX_KEY_BYTES:
        raise ValueError(f"key of {len(key_b)} bytes is over {MAX_KEY_BYTES}")
    t_sim = float(t_sim)
    if not math.isfinite(t_sim):
        raise ValueError(f"t_sim must be finite, got {t_sim}")
    if not 0 <= seq < 1 << 64:
        raise ValueError(f"seq {seq} is outside uint64")
    if not 0 <= session < 1 << 32:
        raise ValueError(f"session {session} is outside uint32")
    major, minor = version
    parts = []
    stamps = stamps or {}
    if len(stamps) > MAX_STAMPS:
        raise ValueError(f"{len(stamps)} stamps, at most {MAX_STAMPS}")
    for name, ns in stamps.items():
        name_b = name.encode()
        if not 1 <= len(name_b) <= MAX_NAME_BYTES:
            raise ValueError(f"stamp name {name!r} must be 1..{MAX_NAME_BYTES} UTF-8 bytes")
        if not isinstance(ns, int) or not _I64[0] <= ns <= _I64[1]:
            raise ValueError(f"stamp {name!r} = {ns!r} is not an int64 of nanoseconds")
        parts += (bytes((len(name_b),)), name_b, _STAMP_NS.pack(ns))
    stamp_bytes = b"".join(parts)
    header_len = _FROZEN.size + len(sender_b) + _FIXED.size + len(key_b) + 1 + len(stamp_bytes)
    payload = as_buffer(payload)
    payload_len = len(payload)
    if payload_len >= 1 << 32:
        raise ValueError(f"payload of {payload_len} bytes does not fit a uint32 length")
    return b"".join((
        _FROZEN.pack(MAGIC, major, minor, len(sender_b)), sender_b,
        _FIXED.pack(header_len, payload_len, session, t_sim, seq, len(key_b)), key_b,
        bytes((len(stamps),)), stamp_bytes, payload,
    ))


def _text(data: memoryview, at: int, n: int, what: str) -> str:
    if at + n > len(data):
        raise EnvelopeError(f"truncated in {what}: needs {n} bytes at offset {at}, {len(data) - at} present",
                            "truncated")
    try:
        return bytes(data[at:at + n]).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise EnvelopeError(f"bad UTF-8 in {what} at byte {exc.start}") from None


def _unpack(st: struct.Struct, data: memoryview, at: int, what: str) -> tuple:
    if at + st.size > len(data):
        raise EnvelopeError(f"truncated in {what}: needs {st.size} bytes at offset {at}, "
                            f"{max(0, len(data) - at)} present", "truncated")
    return st.unpack_from(data, at)


def peek_size(data: bytes | memoryview) -> int | None:
    """Header + payload length the envelope declares, or None if the bytes do not say yet."""
    mv = memoryview(data)
    try:
        _, _, _, n = _FROZEN.unpack_from(mv, 0)
        header_len, payload_len = struct.unpack_from("<II", mv, _FROZEN.size + n)
    except struct.error:
        return None
    return header_len + payload_len


def decode(data: bytes | bytearray | memoryview, *, received_ns: int | None = None,
           expected_major: int = PROTOCOL_VERSION[0]) -> Message:
    """The Message in `data`; EnvelopeError says what is wrong (never another exception)."""
    if received_ns is None:
        received_ns = time.time_ns()
    mv = memoryview(data).cast("B") if isinstance(data, memoryview) else memoryview(data)
    if len(mv) < 4:
        raise EnvelopeError(f"truncated in magic: {len(mv)} bytes", "truncated")
    if bytes(mv[:4]) != MAGIC:
        raise EnvelopeError(f"bad magic {bytes(mv[:4])!r} (expected {MAGIC!r})")
    _, major, minor, sender_len = _unpack(_FROZEN, mv, 0, "version/sender length")
    at = _FROZEN.size
    if sender_len == 0:
        raise EnvelopeError("empty sender")
    sender = _text(mv, at, sender_len, "sender")
    at += sender_len
    if major != expected_major:
        raise VersionMismatch(f"participant {sender} speaks bridge protocol {major}.{minor}, this side "
                              f"{expected_major}.{PROTOCOL_VERSION[1]}", (major, minor), sender)
    header_len, payload_len, session, t_sim, seq, key_len = _unpack(_FIXED, mv, at, "fixed fields")
    at += _FIXED.size
    declared = header_len + payload_len
    if len(mv) > declared:
        raise EnvelopeError(f"length mismatch: header {header_len} + payload {payload_len} = {declared} bytes "
                            f"declared, {len(mv)} received ({len(mv) - declared} trailing)")
    key = _text(mv, at, key_len, "key")
    at += key_len
    (n_stamps,) = _unpack(_U8, mv, at, "stamp count")
    at += 1
    stamps = {}
    for i in range(n_stamps):
        (n,) = _unpack(_U8, mv, at, f"stamp {i} name length")
        if n == 0:
            raise EnvelopeError(f"stamp {i} has an empty name")
        name = _text(mv, at + 1, n, f"stamp {i} name")
        at += 1 + n
        (stamps[name],) = _unpack(_STAMP_NS, mv, at, f"stamp {name!r} value")
        at += 8
    if header_len < at:
        raise EnvelopeError(f"header length {header_len} is shorter than its fields ({at} bytes)")
    if len(mv) < declared:
        where = "header extension" if len(mv) < header_len else "payload"
        raise EnvelopeError(f"truncated in {where}: {declared} bytes declared, {len(mv)} received",
                            "truncated")
    if not math.isfinite(t_sim):
        raise EnvelopeError(f"t_sim is not finite ({t_sim})")
    try:
        validate_sender(sender)
        validate_key(key, "envelope key")
    except KeyExprError as exc:
        raise EnvelopeError(str(exc)) from None
    return Message(key=key, sender=sender, t_sim=t_sim, seq=seq, stamps=stamps,
                   payload=bytes(mv[header_len:declared]), received_ns=received_ns,
                   version=(major, minor), session=session)



def encoded_size(sender: str, key: str, payload_len: int, stamps: dict[str, int] | None = None) -> int:
    """Bytes `encode` will produce, without building them (so a bus can refuse before a copy)."""
    stamp_bytes = sum(1 + len(name.encode()) + 8 for name in (stamps or {}))
    return _FROZEN.size + len(sender.encode()) + _FIXED.size + len(key.encode()) + 1 + stamp_bytes + payload_len
