"""The IEEE 1609.2 subset in canonical OER: compile once, decode/encode with one error type.

COER gives every value exactly one encoding. asn1tools' decoder is lenient
(it stops where the value ends and ignores the padding bits of presence
bitmaps), so `decode_canonical` re-encodes what it decoded and refuses bytes
that differ from that one encoding: a frame an attacker pads or re-flags is
refused, not accepted as a second spelling of a signed message.
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any

import asn1tools

from bridges.security.errors import SecurityError

MODULE = Path(__file__).with_name("v2i-1609dot2.asn")
PROTOCOL_VERSION = 3
MAX_ENVELOPE_BYTES = 65535


class SecurityFormatError(SecurityError):
    """Bytes that are not a well-formed 1609.2 structure; `reason` says why."""


class NonCanonicalEncoding(SecurityFormatError):
    """Bytes that decode, but are not the canonical OER encoding of what they decode to; `kind` says how."""

    TRAILING_BYTES = "trailing-bytes"      # bytes after the end of the value
    NONZERO_PADDING = "nonzero-padding"    # bits the decoder ignores (presence-bitmap padding) are set
    OTHER = "non-canonical-encoding"       # any other spelling (long-form lengths, non-minimal integers, ...)

    def __init__(self, kind: str, reason: str):
        super().__init__(reason)
        self.kind = kind


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


def decode_canonical(type_name: str, data: bytes) -> Any:
    """decode(), refusing any encoding but the canonical one (NonCanonicalEncoding says which way)."""
    value = decode(type_name, data)
    require_canonical(type_name, data, value)
    return value


def require_canonical(type_name: str, data: bytes, value: Any) -> None:
    """NonCanonicalEncoding unless `data` is the canonical encoding of `value` (which it decoded to).

    The value passed decode()'s constraint checks, so it is encoded again
    without them: the same bytes at about half the cost.
    """
    try:
        canonical = spec().encode(type_name, value, check_constraints=False)
    except (asn1tools.Error, ValueError, IndexError, KeyError, TypeError, AttributeError) as exc:
        raise SecurityFormatError(f"{type_name}: cannot encode what was decoded: {str(exc)[:200]}") from None
    if bytes(data) != canonical:
        kind, where = canonical_difference(bytes(data), canonical)
        raise NonCanonicalEncoding(kind, f"{type_name}: {where}")


def canonical_difference(data: bytes, canonical: bytes) -> tuple[str, str]:
    """How `data` differs from `canonical`, the encoding of the value it decoded to: (kind, where).

    The decoder produced the same value from both, so a byte string of the
    same length that only has extra one-bits differs in bits the decoder
    ignored: padding. A correct prefix followed by more bytes has trailing
    bytes. Anything else is another spelling of the value.
    """
    head = data[:len(canonical)]
    if len(head) == len(canonical) and head != canonical:
        value, expected = int.from_bytes(head, "big"), int.from_bytes(canonical, "big")
        offsets = [i for i, (a, b) in enumerate(zip(head, canonical)) if a != b]
        if value & expected == expected:
            bits = ", ".join(f"byte {i} bits {head[i] & ~canonical[i] & 0xFF:#04x}" for i in offsets[:4])
            return NonCanonicalEncoding.NONZERO_PADDING, f"non-zero padding bits ({bits})"
        return NonCanonicalEncoding.OTHER, f"not the canonical encoding (first difference at byte {offsets[0]})"
    if head == canonical:
        extra = len(data) - len(canonical)
        return NonCanonicalEncoding.TRAILING_BYTES, f"{extra} trailing byte{'s' * (extra != 1)} after the " \
                                                    f"{len(canonical)}-byte value"
    return NonCanonicalEncoding.OTHER, f"not the canonical encoding ({len(data)} bytes where the value's " \
                                       f"encoding has {len(canonical)})"


def encode(type_name: str, value: Any) -> bytes:
    try:
        return spec().encode(type_name, value, check_constraints=True)
    except (asn1tools.Error, ValueError, IndexError, KeyError, TypeError, AttributeError) as exc:
        raise SecurityFormatError(f"{type_name}: cannot encode: {str(exc)[:200]}") from None


def unsecured(payload: bytes) -> bytes:
    """Ieee1609Dot2Data carrying `payload` as unsecuredData (what most vectors are)."""
    return encode("Ieee1609Dot2Data", {"protocolVersion": PROTOCOL_VERSION,
                                       "content": ("unsecuredData", bytes(payload))})
