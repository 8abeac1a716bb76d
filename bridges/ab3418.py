"""AB3418-like serial frames and messages: one implementation for the controller FMU and the RSU.

Frame on the wire (ANCHORS S4)::

    7E | addr | ctrl | C0 | type | data ... | FCS (2 bytes) | 7E

* ``addr = (station << 2) + 1`` (station 1 -> 0x05);
* ``ctrl``: 0x13 unnumbered information to one address, 0x03 broadcast, 0x33 poll;
* ``C0``: the IPI byte (NTCIP class B);
* FCS-16: CRC-16/X.25, the PPP FCS of RFC 1662 (reflected polynomial 0x8408, init 0xFFFF,
  complemented) over ``addr .. data`` (ANCHORS S5). Sources disagree on the byte order on the wire:
  :data:`LSB_FIRST` (RFC 1662, the default) reproduces ANCHORS S6, :data:`MSB_FIRST` is the other;
* byte stuffing: a 0x7E or 0x7D between the flags is sent as 0x7D followed by the byte XOR 0x20.

:class:`FrameDecoder` turns a byte stream into :class:`Frame` objects and :class:`FrameError` records
(garbage, truncated, FCS, oversize), so a receiver can count every kind of bad input and carry on.

Messages (:data:`GET_SHORT_STATUS`, :data:`GET_LONG_STATUS8`, :data:`SET_PREEMPT`): the two status
polls follow the UC Berkeley PATH AB3418 message layouts (GetShortStatus 0x84 -> 0xC4 with greens,
status and pattern; GetLongStatus8 0x8C -> 0xCC, a 40-byte frame). Responses are ``type | 0x40``,
error responses ``type | 0x60`` carrying an error number and an index (the PATH error layout).
``SET_PREEMPT`` (0x9B) is this project's own set request: AB3418 has none for preemption.

Standard library only: the controller FMU carries a private copy of this file (``fmus/builder.py``
stages ``bridges/<name>.py`` for ``fmus._bundled.<name>`` imports), so nothing else may be imported.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Iterable

__all__ = [
    "FLAG", "ESCAPE", "IPI", "CTRL_UI", "CTRL_BROADCAST", "CTRL_POLL", "LSB_FIRST", "MSB_FIRST",
    "MAX_FRAME", "GET_SHORT_STATUS", "GET_LONG_STATUS8", "SET_PREEMPT",
    "crc16_x25", "fcs_bytes", "fcs_ok", "stuff", "unstuff", "station_address", "response_type",
    "error_type", "is_request_type", "Frame", "FrameError", "FrameDecoder", "encode_frame", "request",
    "ShortStatus", "LongStatus8", "ErrorResponse", "tenths", "from_tenths",
]

FLAG = 0x7E
ESCAPE = 0x7D
ESCAPE_XOR = 0x20
IPI = 0xC0
CTRL_UI = 0x13         # unnumbered information, single address
CTRL_BROADCAST = 0x03  # broadcast: every station acts, none answers
CTRL_POLL = 0x33       # poll
CONTROLS = (CTRL_UI, CTRL_BROADCAST, CTRL_POLL)
LSB_FIRST = "lsb-first"  # RFC 1662 order; reproduces ANCHORS S6
MSB_FIRST = "msb-first"
FCS_ORDERS = (LSB_FIRST, MSB_FIRST)
MAX_FRAME = 256  # largest unstuffed frame between the flags (PATH MAXAB3418MSGSIZE)
HEADER_LEN = 4   # addr, ctrl, IPI, type
MIN_BODY = HEADER_LEN + 2  # a frame without data: header and FCS

FCS_INIT = 0xFFFF
FCS_GOOD = 0xF0B8  # RFC 1662 residue over data + FCS (low byte first)

# -- message types -------------------------------------------------------------
GET_SHORT_STATUS = 0x84  # -> 0xC4: greens, status, pattern
GET_LONG_STATUS8 = 0x8C  # -> 0xCC: 32 data bytes (LongStatus8)
SET_PREEMPT = 0x9B       # project extension: 1 data byte, bits 0-3 = preempt (EV) A-D call

# error numbers of the error response (PATH AB3418 error codes)
ERR_TOO_BIG = 1
ERR_NO_SUCH_NAME = 2
ERR_BAD_VALUE = 3
ERR_READ_ONLY = 4
ERR_GEN = 5
ERR_MESS_LEN = 6

# status byte bits (GetShortStatus / GetLongStatus8)
STATUS_PREEMPT = 0x01
STATUS_FLASH = 0x02
STATUS_LOCAL_ZERO = 0x04  # passed local zero since the last status request

UNKNOWN_TENTHS = 0xFFFF


def response_type(msg_type: int) -> int:
    """Type of the answer to a request (0x84 -> 0xC4)."""
    return msg_type | 0x40


def error_type(msg_type: int) -> int:
    """Type of the error answer to a request (0x84 -> 0xE4)."""
    return msg_type | 0x60


def is_request_type(msg_type: int) -> bool:
    """Requests are 0x80-0x9F (get 0x8x, set 0x9x); answers 0xC0-0xFF."""
    return 0x80 <= msg_type <= 0x9F


# Data bytes (between type and FCS) of every message this module knows, both directions.
DATA_LENGTHS: dict[int, int] = {
    GET_SHORT_STATUS: 0, response_type(GET_SHORT_STATUS): 3,
    GET_LONG_STATUS8: 0, response_type(GET_LONG_STATUS8): 32,
    SET_PREEMPT: 1, response_type(SET_PREEMPT): 0,
    **{t: 2 for t in range(0xE0, 0x100)},  # error responses: error number, index
}


# -- FCS-16 (RFC 1662) ---------------------------------------------------------------
def _fcs_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        v = byte
        for _ in range(8):
            v = (v >> 1) ^ 0x8408 if v & 1 else v >> 1
        table.append(v)
    return tuple(table)


_FCS_TABLE = _fcs_table()


def fcs16_update(fcs: int, data: Iterable[int]) -> int:
    """Run the RFC 1662 FCS register over `data` (no final complement)."""
    table = _FCS_TABLE
    for b in data:
        fcs = (fcs >> 8) ^ table[(fcs ^ b) & 0xFF]
    return fcs


def crc16_x25(data: bytes) -> int:
    """CRC-16/X.25 (PPP FCS-16): "123456789" -> 0x906E (ANCHORS S5)."""
    return fcs16_update(FCS_INIT, data) ^ 0xFFFF


def fcs_bytes(body: bytes, order: str = LSB_FIRST) -> bytes:
    """The two FCS bytes that follow `body` (addr .. data) on the wire."""
    v = crc16_x25(body)
    lo, hi = v & 0xFF, v >> 8
    if order == LSB_FIRST:
        return bytes((lo, hi))
    if order == MSB_FIRST:
        return bytes((hi, lo))
    raise ValueError(f"FCS byte order must be one of {FCS_ORDERS}, got {order!r}")


def fcs_ok(body_and_fcs: bytes, order: str = LSB_FIRST) -> bool:
    """Whether the last two bytes are the FCS of the bytes before them."""
    if len(body_and_fcs) < 2:
        return False
    if order == LSB_FIRST:  # RFC 1662 residue check
        return fcs16_update(FCS_INIT, body_and_fcs) == FCS_GOOD
    return fcs_bytes(body_and_fcs[:-2], order) == bytes(body_and_fcs[-2:])


# -- stuffing ------------------------------------------------------------------------
def stuff(data: bytes) -> bytes:
    """Escape 0x7E and 0x7D as 0x7D, byte ^ 0x20."""
    out = bytearray()
    for b in data:
        if b == FLAG or b == ESCAPE:
            out += bytes((ESCAPE, b ^ ESCAPE_XOR))
        else:
            out.append(b)
    return bytes(out)


def unstuff(data: bytes) -> bytes:
    """Undo :func:`stuff`; ValueError on a flag inside or a dangling escape."""
    out = bytearray()
    escape = False
    for b in data:
        if b == FLAG:
            raise ValueError("flag byte 0x7E inside a stuffed frame body")
        if escape:
            out.append(b ^ ESCAPE_XOR)
            escape = False
        elif b == ESCAPE:
            escape = True
        else:
            out.append(b)
    if escape:
        raise ValueError("stuffed frame body ends with an escape byte 0x7D")
    return bytes(out)


def station_address(station: int) -> int:
    """Address byte of a station: (station << 2) + 1; station 1 -> 0x05."""
    if not 0 <= station <= 63:
        raise ValueError(f"station must be 0..63, got {station!r}")
    return (station << 2) + 1


# -- frames --------------------------------------------------------------------------
@dataclass(frozen=True)
class Frame:
    """One decoded frame (FCS checked, stuffing removed)."""

    address: int
    control: int
    msg_type: int
    data: bytes = b""
    ipi: int = IPI

    @property
    def station(self) -> int:
        return self.address >> 2

    @property
    def broadcast(self) -> bool:
        return self.control == CTRL_BROADCAST

    def body(self) -> bytes:
        return bytes((self.address, self.control, self.ipi, self.msg_type)) + bytes(self.data)

    def encode(self, fcs_order: str = LSB_FIRST) -> bytes:
        body = self.body()
        return bytes((FLAG,)) + stuff(body + fcs_bytes(body, fcs_order)) + bytes((FLAG,))


def encode_frame(station: int, msg_type: int, data: bytes = b"", control: int = CTRL_UI,
                 fcs_order: str = LSB_FIRST) -> bytes:
    """A complete frame with flags, FCS and stuffing."""
    return Frame(station_address(station), control, msg_type, bytes(data)).encode(fcs_order)


def request(msg_type: int, station: int = 1, data: bytes = b"", control: int = CTRL_UI,
            fcs_order: str = LSB_FIRST) -> bytes:
    """A request frame: ``request(GET_SHORT_STATUS)`` is ``7E 05 13 C0 84 FE F0 7E`` (ANCHORS S6)."""
    return encode_frame(station, msg_type, data, control, fcs_order)


# error kinds reported by FrameDecoder
GARBAGE = "garbage"      # bytes that are not a frame: outside flags, or between flags without a valid header
TRUNCATED = "truncated"  # a frame cut short: shorter than its header + FCS, shorter than its type needs, or aborted
FCS = "fcs"              # a frame with a valid header whose FCS does not match
OVERSIZE = "oversize"    # more than max_frame bytes between two flags
ERROR_KINDS = (GARBAGE, TRUNCATED, FCS, OVERSIZE)


@dataclass(frozen=True)
class FrameError:
    """Input the decoder threw away, and why (one of ERROR_KINDS)."""

    kind: str
    raw: bytes = field(default=b"", repr=False)  # the unstuffed bytes (oversize: the first max_frame + 1)


_HUNT, _FRAME, _DISCARD = 0, 1, 2


class FrameDecoder:
    """Byte-stream deframer: feed bytes, get Frames and FrameErrors in order.

    * Bytes before the first flag are ``garbage`` (one error per run of bytes).
    * Everything between two flags is a candidate frame; a closing flag also opens
      the next frame, and back-to-back flags are idle fill.
    * A candidate whose first bytes are not a plausible header (address with low bits
      01, a known control byte, the IPI 0xC0) is ``garbage``; one shorter than a header
      and FCS, or than its (known) type needs, or ending in an escape, is ``truncated``;
      one whose FCS fails is ``fcs``; more than `max_frame` bytes is ``oversize`` and the
      rest up to the next flag is dropped.
    """

    def __init__(self, fcs_order: str = LSB_FIRST, max_frame: int = MAX_FRAME,
                 data_lengths: dict[int, int] | None = None):
        if fcs_order not in FCS_ORDERS:
            raise ValueError(f"fcs_order must be one of {FCS_ORDERS}, got {fcs_order!r}")
        if max_frame < MIN_BODY:
            raise ValueError(f"max_frame must be >= {MIN_BODY}, got {max_frame!r}")
        self.fcs_order = fcs_order
        self.max_frame = max_frame
        self.data_lengths = DATA_LENGTHS if data_lengths is None else data_lengths
        self._state = _HUNT
        self._buf = bytearray()
        self._escape = False

    def feed(self, data: bytes) -> list[Frame | FrameError]:
        out = []
        for b in data:
            event = self.feed_byte(b)
            if event is not None:
                out.append(event)
        return out

    def feed_byte(self, b: int) -> Frame | FrameError | None:
        """One byte in; at most one event out."""
        state = self._state
        if b == FLAG:
            buf, escape = bytes(self._buf), self._escape
            self._buf.clear()
            self._escape = False
            self._state = _FRAME
            if state == _HUNT:
                return FrameError(GARBAGE, buf) if buf else None
            if state == _DISCARD or not buf and not escape:
                return None
            if escape:  # 7D 7E: the sender aborted the frame
                return FrameError(TRUNCATED, buf)
            return self.parse(buf)
        if state == _DISCARD:
            return None
        if state == _HUNT:
            if len(self._buf) <= self.max_frame:  # keep a bounded sample of the garbage
                self._buf.append(b)
            return None
        if self._escape:
            b ^= ESCAPE_XOR
            self._escape = False
        elif b == ESCAPE:
            self._escape = True
            return None
        self._buf.append(b)
        if len(self._buf) > self.max_frame:
            raw = bytes(self._buf)
            self._buf.clear()
            self._state = _DISCARD
            return FrameError(OVERSIZE, raw)
        return None

    def parse(self, body: bytes) -> Frame | FrameError:
        """Classify one unstuffed candidate (the bytes between two flags)."""
        if not _plausible_header(body):
            return FrameError(GARBAGE, body)
        if len(body) < MIN_BODY:
            return FrameError(TRUNCATED, body)
        if not fcs_ok(body, self.fcs_order):
            expected = self.data_lengths.get(body[3])
            if expected is not None and len(body) - MIN_BODY < expected:
                return FrameError(TRUNCATED, body)
            return FrameError(FCS, body)
        return Frame(body[0], body[1], body[3], bytes(body[HEADER_LEN:-2]), body[2])


def _plausible_header(body: bytes) -> bool:
    if not body or body[0] & 0x03 != 0x01:
        return False
    if len(body) > 1 and body[1] not in CONTROLS:
        return False
    if len(body) > 2 and body[2] != IPI:
        return False
    return True


# -- message contents ------------------------------------------------------------------
def tenths(seconds: float | None) -> int:
    """A duration as an unsigned 16-bit count of tenths of a second; None -> 0xFFFF (unknown)."""
    if seconds is None or seconds != seconds:  # None or NaN
        return UNKNOWN_TENTHS
    return max(0, min(UNKNOWN_TENTHS - 1, int(round(seconds * 10.0))))


def from_tenths(value: int) -> float | None:
    return None if value == UNKNOWN_TENTHS else value / 10.0


@dataclass(frozen=True)
class ShortStatus:
    """GetShortStatus answer (0xC4): greens (bit k-1 = phase k), status bits, pattern."""

    greens: int = 0
    status: int = 0
    pattern: int = 0

    def encode(self) -> bytes:
        return bytes((self.greens & 0xFF, self.status & 0xFF, self.pattern & 0xFF))

    @classmethod
    def decode(cls, data: bytes) -> "ShortStatus":
        if len(data) != 3:
            raise ValueError(f"ShortStatus needs 3 data bytes, got {len(data)}")
        return cls(*data)


_LONG_PATH = struct.Struct(">9B4B3B")      # the PATH GetLongStatus8 layout up to seq_number (16 bytes)
_LONG_SPAT = struct.Struct(">5B5HB")       # this project's SPaT block in place of the system detectors


@dataclass(frozen=True)
class LongStatus8:
    """GetLongStatus8 answer (0xCC), 32 data bytes, 40 bytes framed (ANCHORS S7).

    Bytes 0-15 follow the PATH layout: flags, status, pattern, green/yellow overlaps,
    preemption (bits 0-3 EV A-D), phase calls, ped calls, active phases, interval
    (ring A low nibble, ring B high nibble), detector presence 1-28 (4 bytes), master
    cycle clock, local cycle clock (s), sequence number. The controller model has no
    system detectors, so bytes 16-31 (volume/occupancy of 8 system detectors in PATH)
    carry the SPaT view instead: greens, yellows (bit k-1 = phase k), preempt state
    (0 not active, 1 entry, 2 dwell, 3 exit), ring A and B phase (0 = none), time to
    change of ring A min/max and ring B min/max and the local cycle time (uint16
    big-endian, tenths of a second, 0xFFFF unknown), one spare byte.
    """

    flags: int = 0
    status: int = 0
    pattern: int = 0
    overlaps: int = 0
    preemption: int = 0
    phase_calls: int = 0
    ped_calls: int = 0
    active_phases: int = 0
    interval: int = 0
    presence: tuple[int, int, int, int] = (0, 0, 0, 0)
    master_clock: int = 0
    local_clock: int = 0
    seq_number: int = 0
    greens: int = 0
    yellows: int = 0
    preempt_state: int = 0
    phase_a: int = 0
    phase_b: int = 0
    ttc_a_min: int = UNKNOWN_TENTHS
    ttc_a_max: int = UNKNOWN_TENTHS
    ttc_b_min: int = UNKNOWN_TENTHS
    ttc_b_max: int = UNKNOWN_TENTHS
    cycle_time: int = 0
    spare: int = 0

    def encode(self) -> bytes:
        head = _LONG_PATH.pack(self.flags, self.status, self.pattern, self.overlaps, self.preemption,
                               self.phase_calls, self.ped_calls, self.active_phases, self.interval,
                               *self.presence, self.master_clock & 0xFF, self.local_clock & 0xFF,
                               self.seq_number & 0xFF)
        tail = _LONG_SPAT.pack(self.greens, self.yellows, self.preempt_state, self.phase_a, self.phase_b,
                               self.ttc_a_min, self.ttc_a_max, self.ttc_b_min, self.ttc_b_max,
                               self.cycle_time, self.spare)
        return head + tail

    @classmethod
    def decode(cls, data: bytes) -> "LongStatus8":
        if len(data) != _LONG_PATH.size + _LONG_SPAT.size:
            raise ValueError(f"LongStatus8 needs {_LONG_PATH.size + _LONG_SPAT.size} data bytes, got {len(data)}")
        h = _LONG_PATH.unpack(data[:_LONG_PATH.size])
        s = _LONG_SPAT.unpack(data[_LONG_PATH.size:])
        return cls(*h[:9], tuple(h[9:13]), *h[13:16], *s)


@dataclass(frozen=True)
class ErrorResponse:
    """Error answer (request type | 0x60): error number (ERR_*) and the index of the offending byte."""

    error: int
    index: int = 0

    def encode(self) -> bytes:
        return bytes((self.error & 0xFF, self.index & 0xFF))

    @classmethod
    def decode(cls, data: bytes) -> "ErrorResponse":
        if len(data) != 2:
            raise ValueError(f"ErrorResponse needs 2 data bytes, got {len(data)}")
        return cls(data[0], data[1])
