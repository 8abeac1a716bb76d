"""The USDOT RSU Specification 4.1 *Immediate Forward* record: what a roadside unit is told to broadcast.

Commercial RSUs and the open RSU stacks take the messages they must send now
(not stored and repeated) as one short text record per UDP datagram, by
default on port 1516, one ``Key=Value`` per line::

    Version=0.7
    Type=SPAT
    PSID=0x8002
    Priority=7
    TxMode=CONT
    TxChannel=172
    TxInterval=0
    DeliveryStart=
    DeliveryStop=
    Signature=False
    Encryption=False
    Payload=00135F...

This module is the writer and the parser of that record (pure: bytes in,
bytes out), and the table of what each J2735 message is sent under: the record
``Type``, the PSID and the radio channel. It is tolerant where real devices
differ (whitespace around keys and values, lower-case keys, CRLF or CR line
ends, a byte-order mark, a missing trailing newline) and strict where a
mistake would put the wrong bytes on the air: the payload must be even-length
hex within `MAX_PAYLOAD_BYTES`, the PSID a valid p-encoded hex number that the
table allows for the record's type, each flag and number well-formed, no key
twice and none unknown. A refused record raises `RecordError` with one
`Refusal` reason and a detail naming the key.

PSIDs. IEEE 1609.12 assigns PSIDs as integers; on the wire (WSMP, and in this
record) they are written p-encoded: 0..0x7F in one octet, 0x80..0x407F as
0x8000 + (psid - 0x80) in two, 0x4080..0x20407F as 0xC00000 + (psid - 0x4080)
in three, and 0x204080.. as 0xE0000000 + (psid - 0x204080) in four. The
record's ``PSID`` is the p-encoded form (``0x8002`` is PSID 130); the 1609.2
envelope (bridges.security) carries the integer. The defaults (`DEFAULT_ROUTES`),
checked against the IEEE PSID registry:

=============  ======  ==============  =====================================================
kind           Type    PSID (p-enc.)   registry name (integer)
=============  ======  ==============  =====================================================
bsm            BSM     0x20            vehicle-to-vehicle safety and awareness (32, J2945/1)
surrogate_bsm  BSM     0x7F            the test PSID SAE J2945/8 names for surrogate BSMs (127)
spat           SPAT    0x8002          intersection safety and awareness (130)
map            MAP     0x8002          intersection safety and awareness (130); deployments
                                       that use map distribution send 0xE0000017 (2113687)
ssm            SSM     0xE0000015      traffic signal priority status (2113685)
srm            SRM     0xE0000016      traffic signal request (2113686)
=============  ======  ==============  =====================================================

Channel 172 (the US DSRC safety channel) for every kind by default; 183 where
the radio is C-V2X (`default_routes(channel=183)`). A scenario overrides PSID,
channel and priority per kind (`RouteTable.with_overrides`).
"""
from __future__ import annotations

import binascii
import difflib
import enum
import re
from dataclasses import dataclass, replace
from typing import Any, Callable, Iterable, Mapping

DEFAULT_PORT = 1516           # the RSU 4.1 Immediate Forward port
VERSION = "0.7"               # the record version RSU 4.1 devices expect
MAX_PAYLOAD_BYTES = 2302      # the largest 802.11 MSDU: no single WSM can carry more
MAX_RECORD_BYTES = 2 * MAX_PAYLOAD_BYTES + 1024  # the hex payload and generous room for the other lines
DSRC_CHANNEL = 172            # US DSRC safety channel (BSMs; SPaT and MAP in most DSRC deployments)
CV2X_CHANNEL = 183            # the C-V2X channel in the upper 5.9 GHz band
TX_MODES = ("CONT", "ALT")    # continuous, or alternating between control and service channel


class Refusal(str, enum.Enum):
    """Why a record was refused: one reason per check, so refusals can be counted by reason."""

    NOT_BYTES = "not-bytes"
    OVERSIZE = "oversize"
    NOT_TEXT = "not-text"
    MALFORMED_LINE = "malformed-line"
    DUPLICATE_KEY = "duplicate-key"
    UNKNOWN_KEY = "unknown-key"
    MISSING_KEY = "missing-key"
    BAD_VALUE = "bad-value"
    UNKNOWN_TYPE = "unknown-type"
    PSID_NOT_HEX = "psid-not-hex"
    PSID_NOT_P_ENCODED = "psid-not-p-encoded"
    WRONG_PSID = "wrong-psid"
    PAYLOAD_NOT_HEX = "payload-not-hex"
    PAYLOAD_EMPTY = "payload-empty"
    PAYLOAD_OVERSIZE = "payload-oversize"


class RecordError(ValueError):
    """A record that cannot be written or was refused when read; `reason` is a `Refusal`."""

    def __init__(self, reason: Refusal, detail: str):
        super().__init__(f"{reason.value}: {detail}")
        self.reason = reason
        self.detail = detail


# -- PSIDs --------------------------------------------------------------------------------------------------
# (first p-encoded value, last p-encoded value, first PSID) of each length, one to four octets
_P_RANGES = ((0x00, 0x7F, 0x00), (0x8000, 0xBFFF, 0x80), (0xC00000, 0xDFFFFF, 0x4080),
             (0xE0000000, 0xEFFFFFFF, 0x204080))


def psid_from_p(p: int) -> int:
    """The PSID (integer) a p-encoded value stands for; ValueError when `p` is no valid p-encoding."""
    for first, last, base in _P_RANGES:
        if first <= p <= last:
            return base + (p - first)
    raise ValueError(f"{p:#x} is not a p-encoded PSID (1-4 octets: 0x00-0x7F, 0x8000-0xBFFF, "
                     f"0xC00000-0xDFFFFF, 0xE0000000-0xEFFFFFFF)")


def p_from_psid(psid: int) -> int:
    """The p-encoded form of a PSID (integer); ValueError beyond what four octets hold."""
    for first, last, base in _P_RANGES:
        if 0 <= psid - base <= last - first:
            return first + (psid - base)
    raise ValueError(f"PSID {psid} cannot be p-encoded (0..{0x204080 + 0x0FFFFFFF})")


def format_psid(p: int) -> str:
    """A p-encoded PSID as the record writes it: ``0x8002``, ``0x20``, ``0xE0000015``."""
    return f"0x{p:X}"


def parse_psid(text: str) -> int:
    """A PSID as written in a record or a scenario (hex, ``0x`` optional) -> its p-encoded value.

    RecordError PSID_NOT_HEX or PSID_NOT_P_ENCODED; the detail of the latter says what the integer
    would p-encode to when the text looks like a PSID written plainly (``0x82`` for 130).
    """
    digits = text[2:] if text[:2].lower() == "0x" else text
    if not digits or len(digits) > 8 or not re.fullmatch(r"[0-9A-Fa-f]+", digits):
        raise RecordError(Refusal.PSID_NOT_HEX, f"PSID {text!r} is not a hexadecimal number of 1-8 digits")
    p = int(digits, 16)
    try:
        psid_from_p(p)
    except ValueError as exc:
        hint = ""
        try:
            hint = f"; PSID {p} (written plainly) is {format_psid(p_from_psid(p))} p-encoded"
        except ValueError:
            pass
        raise RecordError(Refusal.PSID_NOT_P_ENCODED, f"PSID {text!r}: {exc}{hint}") from None
    return p


# -- the J2735 message inside -------------------------------------------------------------------------------
def message_id(frame: bytes) -> int:
    """The DSRCmsgID of a UPER MessageFrame, read off its first two octets (no full decode).

    MessageFrame is an extensible SEQUENCE: one extension bit (0: no extensions present), then
    the 15-bit messageId (INTEGER 0..32767). ValueError for fewer than two octets or the bit set.
    """
    if not isinstance(frame, (bytes, bytearray, memoryview)) or len(frame) < 2:
        raise ValueError("a UPER MessageFrame has at least two octets")
    if frame[0] & 0x80:
        raise ValueError(f"not a UPER MessageFrame: extension bit set (first octet {frame[0]:#04x})")
    return int.from_bytes(bytes(frame[:2]), "big") & 0x7FFF


# -- the table: what each message is sent under ----------------------------------------------------------------
@dataclass(frozen=True)
class Route:
    """How one kind of message goes to the RSU: its record Type, J2735 message id, PSID and channel."""

    kind: str
    type: str            # the record's Type
    message_id: int      # J2735 DSRCmsgID of the MessageFrame
    psid: int            # p-encoded, as the record writes it
    channel: int = DSRC_CHANNEL
    priority: int = 7    # 802.11 user priority 0..7 (V2X Hub and most deployments send 7)

    @property
    def psid_value(self) -> int:
        """The PSID as an integer (what a 1609.2 envelope's header carries)."""
        return psid_from_p(self.psid)

    def describe(self) -> dict[str, Any]:
        return {"psid": format_psid(self.psid), "channel": self.channel, "priority": self.priority}


_DEFAULTS = (
    ("bsm", "BSM", 20, 0x20),
    ("surrogate_bsm", "BSM", 20, 0x7F),
    ("spat", "SPAT", 19, 0x8002),
    ("map", "MAP", 18, 0x8002),
    ("ssm", "SSM", 30, 0xE0000015),
    ("srm", "SRM", 29, 0xE0000016),
)
OVERRIDABLE = ("psid", "channel", "priority")


@dataclass(frozen=True)
class RouteTable:
    """The routes by kind, in a fixed order (the first route of a message id is its default)."""

    routes: tuple[Route, ...]

    def __post_init__(self) -> None:
        kinds = [r.kind for r in self.routes]
        if len(set(kinds)) != len(kinds):
            raise ValueError(f"a kind appears twice in the route table: {kinds}")

    def __getitem__(self, kind: str) -> Route:
        for route in self.routes:
            if route.kind == kind:
                return route
        raise KeyError(kind)

    @property
    def kinds(self) -> tuple[str, ...]:
        return tuple(r.kind for r in self.routes)

    @property
    def types(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(r.type for r in self.routes))

    def psids_of_type(self, record_type: str) -> dict[int, str]:
        """p-encoded PSID -> kind, for every route of a record Type."""
        return {r.psid: r.kind for r in self.routes if r.type == record_type}

    def for_frame(self, msg_id: int, psid_value: int | None = None) -> Route | None:
        """The route of a J2735 message: among those of its message id, the one whose PSID is
        `psid_value` (the integer of a 1609.2 header) when given and present, else the first; None for
        a message id the table does not carry."""
        candidates = [r for r in self.routes if r.message_id == msg_id]
        if not candidates:
            return None
        if psid_value is not None:
            for route in candidates:
                if route.psid_value == psid_value:
                    return route
        return candidates[0]

    def with_overrides(self, overrides: Mapping[str, Any], problem: Callable[[str, str], None]) -> RouteTable:
        """The table with a scenario's `{kind: {psid, channel, priority}}` laid over it.

        Every problem goes to `problem(key, reason)` with the key relative to the overrides' table
        (``map.psid``) and a "did you mean"; the routes with a problem keep their defaults.
        """
        routes = {r.kind: r for r in self.routes}
        if not isinstance(overrides, Mapping):
            problem("", f"expected a table of message kinds ({', '.join(routes)}), got {overrides!r}")
            return self
        for kind, values in overrides.items():
            if kind not in routes:
                hint = _did_you_mean(kind, routes)
                problem(str(kind), f"unknown message kind (expected one of: {', '.join(routes)})"
                        + (f"; {hint}" if hint else ""))
                continue
            if not isinstance(values, Mapping):
                problem(kind, f"expected a table with {', '.join(OVERRIDABLE)}, got {values!r}")
                continue
            changes: dict[str, Any] = {}
            for key, value in values.items():
                where = f"{kind}.{key}"
                if key == "psid":
                    if not isinstance(value, str):
                        problem(where, f"expected the p-encoded PSID as a hex string (e.g. \"0x8002\"), got {value!r}")
                        continue
                    try:
                        changes["psid"] = parse_psid(value)
                    except RecordError as exc:
                        problem(where, exc.detail)
                elif key == "channel":
                    if not _is_int(value) or not 1 <= value <= 255:
                        problem(where, f"expected a channel number 1..255 (DSRC 172-184, C-V2X 183), got {value!r}")
                        continue
                    changes["channel"] = int(value)
                elif key == "priority":
                    if not _is_int(value) or not 0 <= value <= 7:
                        problem(where, f"expected a user priority 0..7, got {value!r}")
                        continue
                    changes["priority"] = int(value)
                else:
                    hint = _did_you_mean(key, OVERRIDABLE)
                    problem(where, f"unknown key (expected one of: {', '.join(OVERRIDABLE)})"
                            + (f"; {hint}" if hint else ""))
            routes[kind] = replace(routes[kind], **changes)
        return RouteTable(tuple(routes[r.kind] for r in self.routes))

    def describe(self) -> dict[str, dict[str, Any]]:
        """{kind: {psid, channel, priority}}: what `with_overrides` reads back to this table."""
        return {r.kind: r.describe() for r in self.routes}


def default_routes(channel: int = DSRC_CHANNEL) -> RouteTable:
    """The default table, every kind on `channel` (172 for DSRC, 183 for C-V2X)."""
    return RouteTable(tuple(Route(kind, typ, mid, psid, channel) for kind, typ, mid, psid in _DEFAULTS))


DEFAULT_ROUTES = default_routes()


# -- the record ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Record:
    """One Immediate Forward record. `psid` is p-encoded; `signature`: the RSU is to sign the payload
    (it is a bare MessageFrame), False: it goes on the air as given (this project puts its own 1609.2
    envelope there)."""

    type: str
    psid: int
    payload: bytes
    tx_channel: int = DSRC_CHANNEL
    priority: int = 7
    tx_mode: str = "CONT"
    tx_interval: int = 0
    delivery_start: str = ""
    delivery_stop: str = ""
    signature: bool = False
    encryption: bool = False
    version: str = VERSION

    @property
    def psid_value(self) -> int:
        return psid_from_p(self.psid)


# the record's keys in the order RSU 4.1 lists them; lower-case name -> (key as written, Record field)
_KEYS = ("Version", "Type", "PSID", "Priority", "TxMode", "TxChannel", "TxInterval", "DeliveryStart",
         "DeliveryStop", "Signature", "Encryption", "Payload")
_FIELDS = dict(zip(_KEYS, ("version", "type", "psid", "priority", "tx_mode", "tx_channel", "tx_interval",
                           "delivery_start", "delivery_stop", "signature", "encryption", "payload")))
_LOWER = {k.lower(): k for k in _KEYS}
REQUIRED = ("Version", "Type", "PSID", "Payload")
_TEXT_VALUE = re.compile(r"[\x20-\x7e]{0,64}")


def write(record: Record, routes: RouteTable | None = None) -> bytes:
    """The record as bytes (LF line ends, keys in RSU 4.1 order, payload in upper-case hex).

    The same checks as `parse` (with `routes`: the PSID against the type's), so nothing is written
    that a strict reader would refuse: RecordError naming the field otherwise.
    """
    _check(record, routes)
    lines = [
        f"Version={record.version}", f"Type={record.type}", f"PSID={format_psid(record.psid)}",
        f"Priority={record.priority}", f"TxMode={record.tx_mode}", f"TxChannel={record.tx_channel}",
        f"TxInterval={record.tx_interval}", f"DeliveryStart={record.delivery_start}",
        f"DeliveryStop={record.delivery_stop}", f"Signature={record.signature}",
        f"Encryption={record.encryption}", f"Payload={bytes(record.payload).hex().upper()}",
    ]
    return ("\n".join(lines) + "\n").encode("ascii")


def parse(data: bytes, routes: RouteTable | None = DEFAULT_ROUTES) -> Record:
    """A record from a datagram; RecordError with the first problem found.

    `routes`: the table the PSID is checked against (the record's Type must be one of its types and
    its PSID one of that type's); None checks only that the PSID is p-encoded.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise RecordError(Refusal.NOT_BYTES, f"expected bytes, got {type(data).__name__}")
    data = bytes(data)
    if len(data) > MAX_RECORD_BYTES:
        raise RecordError(Refusal.OVERSIZE, f"{len(data)} bytes, more than {MAX_RECORD_BYTES}")
    try:
        text = data.decode("ascii") if not data.startswith(b"\xef\xbb\xbf") else data[3:].decode("ascii")
    except UnicodeDecodeError as exc:
        raise RecordError(Refusal.NOT_TEXT, f"not ASCII text (byte {exc.start}: {data[exc.start]:#04x})") from None
    values: dict[str, str] = {}
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line:
            continue
        key, sep, value = line.partition("=")
        key = key.strip()
        if not sep or not key:
            raise RecordError(Refusal.MALFORMED_LINE, f"line {n}: expected Key=Value, got {_short(line)!r}")
        name = _LOWER.get(key.lower())
        if name is None:
            hint = _did_you_mean(key, _KEYS, lower=True)
            raise RecordError(Refusal.UNKNOWN_KEY, f"line {n}: unknown key {_short(key)!r}"
                                                   + (f"; {hint}" if hint else ""))
        if name in values:
            raise RecordError(Refusal.DUPLICATE_KEY, f"line {n}: {name} given twice")
        values[name] = value.strip()
    missing = [k for k in REQUIRED if k not in values]
    if missing:
        raise RecordError(Refusal.MISSING_KEY, f"no {', '.join(missing)}")
    kwargs: dict[str, Any] = {}
    for name, value in values.items():
        kwargs[_FIELDS[name]] = _read_value(name, value)
    record = Record(**kwargs)
    _check(record, routes)
    return record


def _read_value(name: str, value: str) -> Any:
    if name == "PSID":
        return parse_psid(value)
    if name == "Payload":
        return _read_payload(value)
    if name == "Type":
        return value.upper()
    if name == "TxMode":
        return value.upper()
    if name in ("Priority", "TxChannel", "TxInterval"):
        if not re.fullmatch(r"[0-9]{1,6}", value):
            raise RecordError(Refusal.BAD_VALUE, f"{name}: expected a whole number, got {_short(value)!r}")
        return int(value)
    if name in ("Signature", "Encryption"):
        if value.lower() not in ("true", "false"):
            raise RecordError(Refusal.BAD_VALUE, f"{name}: expected True or False, got {_short(value)!r}")
        return value.lower() == "true"
    return value  # Version, DeliveryStart, DeliveryStop: checked by _check


def _read_payload(value: str) -> bytes:
    if not value:
        raise RecordError(Refusal.PAYLOAD_EMPTY, "Payload is empty")
    if len(value) > 2 * MAX_PAYLOAD_BYTES:
        raise RecordError(Refusal.PAYLOAD_OVERSIZE, f"Payload: {len(value) // 2} bytes, more than {MAX_PAYLOAD_BYTES}")
    if len(value) % 2:
        raise RecordError(Refusal.PAYLOAD_NOT_HEX, f"Payload: odd number of hex digits ({len(value)})")
    if not re.fullmatch(r"[0-9A-Fa-f]+", value):
        bad = re.search(r"[^0-9A-Fa-f]", value)
        raise RecordError(Refusal.PAYLOAD_NOT_HEX, f"Payload: {value[bad.start()]!r} at {bad.start()} is no hex digit")
    return binascii.unhexlify(value)


def _check(record: Record, routes: RouteTable | None) -> None:
    """Every field within its range (and the PSID the table's for the type); RecordError otherwise."""
    if not re.fullmatch(r"[0-9]{1,3}(\.[0-9]{1,3}){0,2}", str(record.version)):
        raise RecordError(Refusal.BAD_VALUE, f"Version: expected a version number such as 0.7, got {record.version!r}")
    if not isinstance(record.type, str) or not re.fullmatch(r"[A-Z0-9_-]{1,16}", record.type):
        raise RecordError(Refusal.BAD_VALUE, f"Type: expected a message type such as SPAT, got {record.type!r}")
    try:
        psid_from_p(record.psid)
    except (ValueError, TypeError) as exc:
        raise RecordError(Refusal.PSID_NOT_P_ENCODED, f"PSID: {exc}") from None
    if routes is not None:
        allowed = routes.psids_of_type(record.type)
        if not allowed:
            raise RecordError(Refusal.UNKNOWN_TYPE, f"Type {record.type!r} is not in the table (types: "
                                                    f"{', '.join(routes.types)})")
        if record.psid not in allowed:
            raise RecordError(Refusal.WRONG_PSID, f"PSID {format_psid(record.psid)} is not the table's for "
                                                  f"{record.type} ({', '.join(format_psid(p) for p in allowed)})")
    for name, value, low, high in (("Priority", record.priority, 0, 7), ("TxChannel", record.tx_channel, 1, 255),
                                   ("TxInterval", record.tx_interval, 0, 999999)):
        if not _is_int(value) or not low <= value <= high:
            raise RecordError(Refusal.BAD_VALUE, f"{name}: expected {low}..{high}, got {value!r}")
    if record.tx_mode not in TX_MODES:
        raise RecordError(Refusal.BAD_VALUE, f"TxMode: expected {' or '.join(TX_MODES)}, got {record.tx_mode!r}")
    for name, value in (("DeliveryStart", record.delivery_start), ("DeliveryStop", record.delivery_stop)):
        if not isinstance(value, str) or not _TEXT_VALUE.fullmatch(value):
            raise RecordError(Refusal.BAD_VALUE, f"{name}: expected empty or a short printable date, got {value!r}")
    for name, value in (("Signature", record.signature), ("Encryption", record.encryption)):
        if not isinstance(value, bool):
            raise RecordError(Refusal.BAD_VALUE, f"{name}: expected True or False, got {value!r}")
    payload = record.payload
    if not isinstance(payload, (bytes, bytearray)):
        raise RecordError(Refusal.PAYLOAD_NOT_HEX, f"Payload: expected bytes, got {type(payload).__name__}")
    if not payload:
        raise RecordError(Refusal.PAYLOAD_EMPTY, "Payload is empty")
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise RecordError(Refusal.PAYLOAD_OVERSIZE, f"Payload: {len(payload)} bytes, more than {MAX_PAYLOAD_BYTES}")


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _short(text: str, limit: int = 40) -> str:
    return text if len(text) <= limit else text[:limit] + "..."


def _did_you_mean(name: Any, candidates: Iterable[str], lower: bool = False) -> str | None:
    if not isinstance(name, str):
        return None
    candidates = list(candidates)
    pool = {c.lower(): c for c in candidates} if lower else {c: c for c in candidates}
    close = difflib.get_close_matches(name.lower() if lower else name, list(pool), n=2)
    return "did you mean " + " or ".join(repr(pool[c]) for c in close) + "?" if close else None
