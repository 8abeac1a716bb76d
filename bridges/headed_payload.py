"""A payload made of a JSON header and binary body: 4-byte big-endian header length, header, body.

Shared by the camera and lidar streams, so an app on another machine can read
the metadata of a frame without knowing its binary layout first; and
`json_object`, the front door of the all-JSON ones (GNSS fixes, radar scans).
"""
from __future__ import annotations

import json
import struct


def pack(header: dict, body: bytes) -> bytes:
    head = json.dumps(header, separators=(",", ":")).encode()
    return struct.pack(">I", len(head)) + head + body


def unpack(payload: bytes, error: type[Exception], what: str) -> tuple[dict, bytes]:
    """(header, body); raises `error` naming `what` when the payload is truncated or not a JSON object."""
    if len(payload) < 4:
        raise error(f"{what}: truncated: {len(payload)} bytes, no header length")
    (n,) = struct.unpack_from(">I", payload)
    if 4 + n > len(payload):
        raise error(f"{what}: truncated: header says {n} bytes, {len(payload) - 4} follow")
    try:
        header = json.loads(payload[4:4 + n].decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise error(f"{what}: header: not JSON ({exc})") from None
    if not isinstance(header, dict):
        raise error(f"{what}: header: not a JSON object")
    return header, payload[4 + n:]


def json_object(payload: bytes, required, error: type[Exception], what: str) -> dict:
    """`payload` as a JSON object holding every key of `required`; raises `error` naming `what` and the
    reason (not JSON, not an object, the missing keys): the small sensor messages' common front door."""
    try:
        d = json.loads(payload)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise error(f"{what}: not JSON ({exc})") from None
    if not isinstance(d, dict):
        raise error(f"{what}: not a JSON object")
    missing = [k for k in required if k not in d]
    if missing:
        raise error(f"{what}: missing {', '.join(missing)}")
    return d
