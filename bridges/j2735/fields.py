"""What the typed messages share: field checks that name the field, and the untyped rest kept verbatim.

Typed where it matters, verbatim otherwise: a typed message (SPaT, SRM, SSM)
builds its asn1tools value from its typed fields; on decoding, whatever that
value lacks compared with the received one is kept in the message's `other`
dict (`residue`), and `fill` puts it back on encoding. That residue holds

* elements no typed field models (extension additions of a newer J2735
  edition, a regional extension's members, ...), and
* values a typed field reads as None: the 'unavailable' code of an OPTIONAL
  element (an advisory speed of 500, a time mark of 36001). The typed field
  says "not known"; the residue remembers that the sender did send the code.

So decode -> encode gives the received bytes back, while `Spat(...)` built by
hand carries no residue at all. A typed field the user sets wins over a kept
value at the same place (set the advisory speed of a decoded event and the
kept 'unavailable' code is not sent).
"""
from __future__ import annotations

import difflib
import math
from typing import Any, Iterable

from bridges.j2735.errors import J2735Error
from bridges.j2735.scales import Scale


def residue(received: dict[str, Any], typed: dict[str, Any]) -> dict[str, Any] | None:
    """The members of `received` that `typed` lacks or holds differently (nested SEQUENCEs compared member by
    member); None when the typed value carries everything."""
    out: dict[str, Any] = {}
    for key, value in received.items():
        if key not in typed:
            out[key] = value
        elif isinstance(value, dict) and isinstance(typed[key], dict):
            sub = residue(value, typed[key])
            if sub:
                out[key] = sub
        elif typed[key] != value:
            out[key] = value
    return out or None


def fill(typed: dict[str, Any], other: dict[str, Any] | None) -> dict[str, Any]:
    """`typed` with the kept members of `other` added where it has none (the typed value wins)."""
    for key, value in (other or {}).items():
        if key not in typed:
            typed[key] = value
        elif isinstance(typed[key], dict) and isinstance(value, dict):
            typed[key] = fill(dict(typed[key]), value)
    return typed


# -- checks that name the field -------------------------------------------------------------------------
def integer(value: Any, low: int, high: int, what: str) -> int:
    """`value` as an int within low..high, else J2735Error naming `what`."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise J2735Error(f"{what}: {value!r} is not an integer ({low}..{high})")
    if not low <= value <= high:
        raise J2735Error(f"{what}: {value} is outside {low}..{high}")
    return value


def optional_integer(value: Any, low: int, high: int, what: str) -> int | None:
    return None if value is None else integer(value, low, high, what)


def wire(scale: Scale, value: float | None, what: str) -> int:
    """The scale's wire value for `value` (None: its 'unavailable' code); the error names `what`."""
    try:
        return scale.to_wire(value)
    except J2735Error as exc:
        raise J2735Error(f"{what}: {exc.reason}") from None


def from_wire(scale: Scale, raw: int | None) -> float | None:
    """The SI value of a wire value; None for an absent element or the 'unavailable' code.

    Divides by the steps per unit where the step is 1/n (6433 tenths -> 643.3, not 643.3000000000001), so a
    decoded value prints as the decimal that was sent; `wire` gives the same integer back either way."""
    if raw is None or (scale.unavailable is not None and raw == scale.unavailable):
        return None
    reserved = getattr(scale, "reserved", None)
    if reserved is not None and reserved[0] <= raw <= reserved[1]:
        return scale.from_wire(raw)  # a code the standard reserves: scales.Reserved, sent back as received
    per_unit = round(1.0 / scale.step)
    if per_unit >= 1 and abs(per_unit * scale.step - 1.0) < 1e-12:
        return raw / per_unit
    return raw * scale.step


def name(value: Any, names: Iterable[str], what: str) -> str:
    """`value` if it is one of `names` (an ENUMERATED), else J2735Error naming `what`, with a hint."""
    names = tuple(names)
    if value in names:
        return value
    close = difflib.get_close_matches(str(value), names, n=3)
    hint = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else f" (one of {', '.join(names)})"
    raise J2735Error(f"{what} {value!r} is not a known value{hint}")


def text(value: Any, what: str, low: int = 1, high: int = 63) -> str:
    """A DescriptiveName-like IA5String: ASCII of low..high characters."""
    if not isinstance(value, str) or not value.isascii() or not low <= len(value) <= high:
        raise J2735Error(f"{what}: {value!r} is not ASCII text of {low}..{high} characters")
    return value


def finite(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise J2735Error(f"{what}: {value!r} is not a finite number")
    return float(value)


def bits_to_names(value: tuple[bytes, int], names: tuple[str, ...]) -> frozenset[str]:
    """The names of the bits set in an asn1tools BIT STRING (bit 0: the most significant of the first byte);
    a set bit the standard leaves unnamed reads as "bit<i>", so that it is sent again."""
    data, count = value
    return frozenset(names[i] if i < len(names) else f"bit{i}"
                     for i in range(count) if data[i // 8] >> (7 - i % 8) & 1)


def names_to_bits(selected: Iterable[str], names: tuple[str, ...], what: str,
                  size: int | None = None) -> tuple[bytes, int]:
    """A BIT STRING of `size` bits (default: one per name) with the named bits set ("bit<i>" for unnamed ones)."""
    size = len(names) if size is None else size
    known = names[:size] + tuple(f"bit{i}" for i in range(len(names), size))
    selected = set(selected)
    for unknown in sorted(selected - set(known)):
        name(unknown, names, what)
    buf = bytearray((size + 7) // 8)
    for i, bit in enumerate(known):
        if bit in selected:
            buf[i // 8] |= 0x80 >> (i % 8)
    return bytes(buf), size
