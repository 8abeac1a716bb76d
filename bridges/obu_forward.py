"""What an on-board unit forwards to its application processor, and how to find the J2735 frame in it.

An OBU hands each message it received over the air to the vehicle's computer
as a UDP datagram. Devices differ in what that datagram holds, so the format is
named in the scenario and the frame is found only the way that format says
(nothing is guessed from the bytes):

=============================  ===========================================================================
name                           the datagram
=============================  ===========================================================================
``bare``                       the UPER MessageFrame itself (the OBU verified and stripped the 1609.2 data)
``ieee1609dot2``               the Ieee1609Dot2Data as received (COER); the frame is its payload
``immediate-forward``          an Immediate-Forward-style text record (bridges.immediate_forward) whose
                               Payload is the bare MessageFrame
``immediate-forward-1609dot2`` the same record with the 1609.2 data as its Payload
=============================  ===========================================================================

Each format has a reader (datagram -> `Found`, or `ForwardError` with one
reason) and a writer (`OverTheAir` -> datagram) for the emulated box
(bridges.rsu_box). More formats are added with `register_format`. Nothing here
verifies a signature: the receiver (the AV app) does that.
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass
from typing import Callable

from bridges import immediate_forward as imf
from bridges.security import oer
from bridges.security.envelope import unverified_payload
from bridges.security.oer import SecurityFormatError

MAX_DATAGRAM_BYTES = 65507  # the largest UDP payload over IPv4


class ForwardError(ValueError):
    """A forwarded datagram the format cannot read; `reason` is a short word for counting."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


@dataclass(frozen=True)
class Found:
    """The J2735 frame of a forwarded datagram: the UPER MessageFrame, the 1609.2 data it came in when
    the format carries it, and the PSID (integer) when the datagram says one."""

    frame: bytes
    envelope: bytes | None = None
    psid: int | None = None


@dataclass(frozen=True)
class OverTheAir:
    """What a radio received: the 1609.2 data on the air, the MessageFrame inside, and the facts of the
    record it was sent with (record Type, p-encoded PSID, channel), for the writers."""

    envelope: bytes
    frame: bytes
    type: str
    psid: int
    channel: int
    signed: bool = False  # the 1609.2 data is signedData


@dataclass(frozen=True)
class ObuFormat:
    name: str
    description: str
    read: Callable[[bytes, imf.RouteTable], Found]
    write: Callable[[OverTheAir], bytes]


def open_envelope(data: bytes) -> tuple[bytes, int | None, bool]:
    """(payload, PSID or None, signed) of an Ieee1609Dot2Data, without verification; ForwardError otherwise."""
    try:
        envelope = oer.decode("Ieee1609Dot2Data", bytes(data))
        payload = unverified_payload(envelope)
    except SecurityFormatError as exc:
        raise ForwardError("not-1609dot2", exc.reason) from None
    if envelope["protocolVersion"] != oer.PROTOCOL_VERSION:
        raise ForwardError("not-1609dot2", f"protocol version {envelope['protocolVersion']}")
    kind, content = envelope["content"]
    psid = content["tbsData"]["headerInfo"]["psid"] if kind == "signedData" else None
    return bytes(payload), psid, kind == "signedData"


def _datagram(data: bytes) -> bytes:
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise ForwardError("not-bytes", f"expected bytes, got {type(data).__name__}")
    if not data:
        raise ForwardError("empty", "an empty datagram")
    if len(data) > MAX_DATAGRAM_BYTES:
        raise ForwardError("oversize", f"{len(data)} bytes")
    return bytes(data)


def _frame(frame: bytes, routes: imf.RouteTable) -> bytes:
    """A MessageFrame as far as its first octets tell (extension bit clear) of a message the table routes."""
    try:
        msg_id = imf.message_id(frame)
    except ValueError as exc:
        raise ForwardError("not-a-message-frame", str(exc)) from None
    if routes.for_frame(msg_id) is None:
        raise ForwardError("unknown-message", f"J2735 message id {msg_id} is in no route of the table "
                                              f"(first octets {bytes(frame[:4]).hex()})")
    return frame


def _record(data: bytes, routes: imf.RouteTable) -> imf.Record:
    try:
        return imf.parse(data, routes)
    except imf.RecordError as exc:
        raise ForwardError(f"record:{exc.reason.value}", exc.detail) from None


# -- the formats ------------------------------------------------------------------------------------------
def _read_bare(data: bytes, routes: imf.RouteTable) -> Found:
    return Found(_frame(_datagram(data), routes))


def _read_1609dot2(data: bytes, routes: imf.RouteTable) -> Found:
    data = _datagram(data)
    payload, psid, _ = open_envelope(data)
    return Found(_frame(payload, routes), envelope=data, psid=psid)


def _read_if(data: bytes, routes: imf.RouteTable) -> Found:
    record = _record(_datagram(data), routes)
    return Found(_frame(record.payload, routes), psid=record.psid_value)


def _read_if_1609dot2(data: bytes, routes: imf.RouteTable) -> Found:
    record = _record(_datagram(data), routes)
    payload, psid, _ = open_envelope(record.payload)
    return Found(_frame(payload, routes), envelope=record.payload, psid=psid if psid is not None else record.psid_value)


def _if_record(air: OverTheAir, payload: bytes) -> bytes:
    return imf.write(imf.Record(air.type, air.psid, payload, tx_channel=air.channel, signature=air.signed))


FORMATS: dict[str, ObuFormat] = {}


def register_format(fmt: ObuFormat) -> None:
    """Add (or replace) a named format."""
    FORMATS[fmt.name] = fmt


def formats() -> list[str]:
    return sorted(FORMATS)


def get_format(name: str) -> ObuFormat:
    """The format of that name; ValueError naming the known ones (with a "did you mean")."""
    try:
        return FORMATS[name]
    except (KeyError, TypeError):
        close = difflib.get_close_matches(str(name), FORMATS, n=2)
        hint = f"; did you mean {' or '.join(map(repr, close))}?" if close else ""
        raise ValueError(f"unknown OBU forward format {name!r} (known: {', '.join(formats())}){hint}") from None


for _fmt in (
    ObuFormat("bare", "the UPER MessageFrame itself", _read_bare, lambda air: air.frame),
    ObuFormat("ieee1609dot2", "the 1609.2 data as received; the frame is its payload", _read_1609dot2,
              lambda air: air.envelope),
    ObuFormat("immediate-forward", "an Immediate-Forward-style record, Payload = the MessageFrame", _read_if,
              lambda air: _if_record(air, air.frame)),
    ObuFormat("immediate-forward-1609dot2", "an Immediate-Forward-style record, Payload = the 1609.2 data",
              _read_if_1609dot2, lambda air: _if_record(air, air.envelope)),
):
    register_format(_fmt)
