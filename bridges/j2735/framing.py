"""Find the J2735 MessageFrame in a packet that carries a transport header before it.

Some RSUs forward what they receive as raw UDP payloads: a vendor or 1609.3
(WSMP) header, often a 1609.2 wrapper, then the MessageFrame. The codec never
guesses where a frame starts; the caller says how to find it:

* `skip:N` the frame starts after N header bytes;
* `scan`   the first offset where a MessageFrame of a type the codec knows
  (MAP, SPaT, BSM, SRM, SSM, SDSM) starts and decodes, inner message included, to
  exactly the end of the packet. Header bytes often happen to read as a frame
  of some unknown id, so unknown ids are never taken, and a frame followed by
  anything (a signature) is not either: give `skip:N` for those.

`find_message_frame(data, "scan")` gives the offset and the decoded frame, or
a J2735Error saying why none was found.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from bridges.j2735.codec import Frame, J2735Codec, J2735Error, default_codec

HEADER_FORMS = ("skip:N", "scan")
_SKIP = re.compile(r"skip:(\d+)")


@dataclass(frozen=True)
class FoundFrame:
    offset: int      # header bytes before the frame
    frame: Frame


def parse_header(spec: str) -> int | None:
    """`skip:N` -> N, `scan` -> None; anything else is a J2735Error naming the forms."""
    text = spec.strip().lower() if isinstance(spec, str) else spec
    if text == "scan":
        return None
    match = _SKIP.fullmatch(text) if isinstance(text, str) else None
    if match is None:
        hint = " (did you mean 'skip:N' with N the header's length in bytes?)" \
            if isinstance(text, str) and text.startswith(("skip", "skp", "sk")) else ""
        raise J2735Error(f"header: {spec!r} is not one of {' or '.join(HEADER_FORMS)}{hint}")
    return int(match.group(1))


def find_message_frame(data: bytes, header: str, codec: J2735Codec | None = None) -> FoundFrame:
    """The MessageFrame in `data` after a transport header, found as `header` says (`skip:N` or `scan`);
    it must decode completely and end where `data` ends."""
    codec = codec or default_codec()
    data = bytes(data)
    skip = parse_header(header)
    if skip is not None:
        if skip >= len(data):
            raise J2735Error(f"header: skip:{skip} leaves no bytes of a {len(data)}-byte packet")
        try:
            frame = codec.decode(data[skip:])
        except J2735Error as exc:
            envelope = " (they start like a 1609.2 envelope, which `v2i j2735 decode` unwraps)" \
                if data[skip] == 0x03 else ""
            raise J2735Error(f"the bytes after {skip} header bytes are no MessageFrame{envelope}: "
                             f"{exc.reason}") from None
        if frame.length != len(data) - skip:
            raise J2735Error(f"the frame after {skip} header bytes ends {len(data) - skip - frame.length} bytes "
                             f"before the packet does")
        return FoundFrame(skip, frame)
    for offset in range(len(data) - 2):
        if data[offset] & 0x80 or int.from_bytes(data[offset:offset + 2], "big") not in codec.message_types:
            continue  # not the start of a root MessageFrame of a known id (extension bit 0, 15-bit id)
        try:
            frame = codec.decode(data[offset:])
        except J2735Error:
            continue
        if frame.length == len(data) - offset:
            return FoundFrame(offset, frame)
    raise J2735Error(f"scan: no MessageFrame of a known type ({', '.join(map(str, sorted(codec.message_types)))}) "
                     f"ends the {len(data)}-byte packet; if a signature follows the frame, give skip:N to "
                     f"the 1609.2 envelope")
