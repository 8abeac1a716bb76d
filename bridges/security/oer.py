"""The IEEE 1609.2 subset in canonical OER: compile once, decode/encode with one error type."""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any

import asn1tools

MODULE = Path(__file__).with_name("v2i-1609dot2.asn")
PROTOCOL_VERSION = 3
MAX_ENVELOPE_BYTES = 65535


class SecurityFormatError(ValueError):
    """Bytes that are not a well-formed 1609.2 structure; `reason` says why."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


@lru_cache(maxsize=1)
def spec():
    return asn1tools.compile_files(str(MODULE), "oer")


def decode(type_name: str, data: bytes) -> Any:
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise SecurityFormatError(f"{type_name}: expected bytes, got {type(data).__name__}")
    if not data:
        raise SecurityFormatError(f"{type_name}: no bytes")
    if len(data) > MAX_ENVELOPE_BYTES:
        raise SecurityFormatError(f"{type_name}: {len(data)} bytes, more than {MAX_ENVELOPE_BYTES}")
    try:
        return spec().decode(type_name, bytes(data), check_constraints=True)
    except (asn1tools.Error, ValueError, IndexError, KeyError, TypeError, NotImplementedError,
            OverflowError, RecursionError) as exc:
        raise SecurityFormatError(f"{type_name}: {str(exc)[:200] or type(exc).__name__}") from None


def encode(type_name: str, value: Any) -> bytes:
    try:
        return spec().encode(type_name, value, check_constraints=True)
    except (asn1tools.Error, ValueError, IndexError, KeyError, TypeError, AttributeError) as exc:
        raise SecurityFormatError(f"{type_name}: cannot encode: {str(exc)[:200]}") from None


def unsecured(payload: bytes) -> bytes:
    """Ieee1609Dot2Data carrying `payload` as unsecuredData (what most vectors are)."""
    return encode("Ieee1609Dot2Data", {"protocolVersion": PROTOCOL_VERSION,
                                       "content": ("unsecuredData", bytes(payload))})
