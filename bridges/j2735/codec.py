"""J2735 UPER codec: compile the ASN.1 once, then decode and encode MessageFrames.

Decoding is two-stage, as with SAE's own information object sets: the frame
gives `messageId` and the open-type `value` octets; the inner type is chosen by
`messageId`. BSM part II values are decoded the same way by `partII-Id`.
Unknown ids stay as octets, so they re-encode to the same bytes.

Bytes come from the network: whatever they are, `decode` raises only
`J2735Error` (with a reason), never an asn1tools or Python error.

Editions (bridges.j2735.editions): `J2735Codec(edition="2016")` speaks J2735
2016, the default 2020 (or $V2I_J2735_EDITION). The built-in module carries
both editions' differences in two small modules and compiles the one asked
for. A user's licensed files are one edition: the codec tells which from the
compiled types (TimeMark's range, the SSP member's name) and refuses an
`edition` that says otherwise. Their load-time fixes are in licensed_asn1.py.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import asn1tools

from bridges.j2735 import _asn1tools_fixes, licensed_asn1
from bridges.j2735.editions import EDITION_ENV, EDITIONS, Edition, edition as edition_named
from bridges.j2735.errors import J2735Error

BUILTIN_MODULE = Path(__file__).with_name("v2i-j2735.asn")
BUILTIN_NAME = "V2I-J2735"      # the module that imports the edition's types from V2I-J2735-<edition>
ASN1_DIR_ENV = "V2I_J2735_ASN1_DIR"

# DSRCmsgID -> inner type name (SAE J2735 Table of message ids)
MESSAGE_TYPES: dict[int, str] = {
    18: "MapData",
    19: "SPAT",
    20: "BasicSafetyMessage",
    29: "SignalRequestMessage",
    30: "SignalStatusMessage",
    41: "SensorDataSharingMessage",   # SAE J3224 (SDSM)
}
MESSAGE_IDS: dict[str, int] = {name: mid for mid, name in MESSAGE_TYPES.items()}
# Ids whose type a user's licensed files may lack (the SDSM entered J2735 after 2016): decoded when the
# ASN.1 has the type, else carried as octets like any unknown id.
OPTIONAL_MESSAGE_IDS = frozenset({41})
# PartII-Id -> part II content type
PART_II_TYPES: dict[int, str] = {0: "VehicleSafetyExtensions", 1: "SpecialVehicleExtensions"}
PART_II_IDS: dict[str, int] = {name: pid for pid, name in PART_II_TYPES.items()}

MAX_FRAME_BYTES = 65535  # larger than any J2735 message over the air; bounds the work per frame
REQUIRED_TYPES = ("MessageFrame", *(t for i, t in MESSAGE_TYPES.items() if i not in OPTIONAL_MESSAGE_IDS),
                  *PART_II_TYPES.values())
OPTIONAL_TYPES = tuple(MESSAGE_TYPES[i] for i in sorted(OPTIONAL_MESSAGE_IDS))


@dataclass(frozen=True)
class Frame:
    """A decoded MessageFrame.

    `message` is the inner message as asn1tools values (dicts, tuples for
    CHOICE and BIT STRING, bytes for OCTET STRING), with known part II values
    decoded; None when the id is not one the codec knows. `length` is the
    number of bytes the frame occupies (trailing bytes are ignored).
    """

    message_id: int
    type_name: str | None
    value: bytes
    message: dict[str, Any] | None
    length: int


def asn1_sources(asn1_dir: str | os.PathLike | None = None) -> list[Path]:
    """The ASN.1 files to compile: a user's licensed J2735 files, or the built-in module."""
    directory = asn1_dir if asn1_dir is not None else os.environ.get(ASN1_DIR_ENV) or None
    if directory is None:
        return [BUILTIN_MODULE]
    path = Path(directory)
    if not path.is_dir():
        raise J2735Error(f"ASN.1 directory {str(path)!r} does not exist ({ASN1_DIR_ENV} / --asn1-dir)")
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in (".asn", ".asn1"))
    if not files:
        raise J2735Error(f"no .asn or .asn1 files in {str(path)!r}")
    return files


@dataclass(frozen=True)
class _Compiled:
    types: dict[str, Any]        # the codec's types by name (asn1tools compiled types)
    spec: Any                    # the asn1tools Specification
    notes: tuple[str, ...]       # what was changed at load time (licensed files)


@lru_cache(maxsize=4)
def _compile_builtin(edition_name: str) -> _Compiled:
    """The built-in module with `edition_name`'s types: V2I-J2735 imports them from V2I-J2735-<edition>."""
    chosen = f"{BUILTIN_NAME}-{edition_name}"
    parsed = asn1tools.parse_files([str(BUILTIN_MODULE)])
    for name in [m for m in parsed if m.startswith(BUILTIN_NAME + "-") and m != chosen]:
        del parsed[name]
    imports = parsed[BUILTIN_NAME]["imports"]
    for source in [s for s in imports if s.startswith(BUILTIN_NAME + "-")]:
        imports[chosen] = imports.pop(source)
    return _compile_parsed(parsed, [BUILTIN_MODULE], ())


@lru_cache(maxsize=4)
def _compile_licensed(sources: tuple[Path, ...]) -> _Compiled:
    try:
        text, notes = licensed_asn1.load(list(sources))
        parsed = asn1tools.parse_string(text)
    except (asn1tools.ParseError, OSError) as exc:
        raise J2735Error(f"cannot compile ASN.1 {[p.name for p in sources]}: {exc}") from None
    return _compile_parsed(parsed, sources, tuple(notes))


def _compile_parsed(parsed: dict[str, Any], sources, notes: tuple[str, ...]) -> _Compiled:
    imports = {name: {source: list(names) for source, names in module.get("imports", {}).items()}
               for name, module in parsed.items()}
    try:
        spec = asn1tools.compile_dict(parsed, "uper")
    except (asn1tools.ParseError, asn1tools.CompileError) as exc:
        raise J2735Error(f"cannot compile ASN.1 {[p.name for p in sources]}: {exc}") from None
    types, missing = {}, []
    for name in REQUIRED_TYPES:
        found = _resolve(spec.modules, imports, name)
        if found is None:
            missing.append(name)
        else:
            types[name] = found
    if missing:
        raise J2735Error(f"ASN.1 in {[p.name for p in sources]} lacks types {missing}")
    for name in OPTIONAL_TYPES:
        found = _resolve(spec.modules, imports, name)
        if found is not None:
            types[name] = found
    return _Compiled(types, spec, notes)


def _resolve(modules: dict[str, dict[str, Any]], imports: dict[str, dict[str, list[str]]], name: str):
    """The compiled type `name` as the messages see it. A name two modules define (SAE's 2016 AddGrpB and
    DSRC both define TimeMark) is not in asn1tools' `Specification.types`: it is looked up from the module
    that defines MessageFrame, following IMPORTS (breadth first) as asn1tools does for each reference."""
    holders = [m for m, types in modules.items() if name in types]
    if len(holders) <= 1:
        return modules[holders[0]][name] if holders else None
    start = [m for m, types in modules.items() if "MessageFrame" in types]
    seen, queue = set(), start[:1]
    while queue:
        module = queue.pop(0)
        if module in seen or module not in modules:
            continue
        seen.add(module)
        if name in modules[module]:
            return modules[module][name]
        sources = imports.get(module, {})
        chosen = next((source for source, names in sources.items() if name in names), None)
        queue = [chosen] if chosen else queue + list(sources)
    return None


def detect_edition(types: dict[str, Any]) -> Edition:
    """The edition of compiled J2735 types: TimeMark's upper bound (SPAT ... minEndTime) and the SSP member
    of SpecialVehicleExtensions.vehicleAlerts."""
    try:
        mark = _member(types["SPAT"], "intersections", "states", "state-time-speed", "timing", "minEndTime")
        alerts = _member(types["SpecialVehicleExtensions"], "vehicleAlerts")
        time_mark_max, ssp = mark.maximum, alerts.root_members[0].name
    except (KeyError, AttributeError, IndexError, StopIteration) as exc:
        raise J2735Error(f"cannot tell the J2735 edition of the ASN.1: no SPAT TimeMark or EmergencyDetails "
                         f"as J2735 defines them ({type(exc).__name__}: {exc})") from None
    for known in EDITIONS.values():
        if (known.time_mark_max, known.ssp_member) == (time_mark_max, ssp):
            return known
    raise J2735Error(f"the ASN.1 is no J2735 edition this codec knows: TimeMark 0..{time_mark_max}, "
                     f"EmergencyDetails.{ssp}; known: " + "; ".join(e.describe() for e in EDITIONS.values()))


def _member(compiled: Any, *path: str) -> Any:
    """The compiled member at `path` below a compiled SEQUENCE (through SEQUENCE OF elements)."""
    node = compiled.type
    for name in path:
        node = getattr(node, "element_type", node)
        members = list(node.root_members) + [m for m in (getattr(node, "additions", None) or ())
                                             if hasattr(m, "name")]
        node = next(m for m in members if m.name == name)
    return node


class J2735Codec:
    """UPER codec for the J2735 subset.

    `J2735Codec(asn1_dir, edition)`: the built-in module in `edition` ("2016",
    "2020"; None: $V2I_J2735_EDITION, else 2020), or a user's licensed files
    (their own edition; an `edition` that differs is refused). `edition` is
    the Edition in use, `asn1_notes` what was changed when loading the files.
    """

    def __init__(self, asn1_dir: str | os.PathLike | None = None, edition: str | int | Edition | None = None):
        self.sources = tuple(asn1_sources(asn1_dir))
        if self.sources == (BUILTIN_MODULE,):
            self.edition = edition_named(edition)
            compiled = _compile_builtin(self.edition.name)
        else:
            asked = edition_named(edition) if edition is not None or os.environ.get(EDITION_ENV) else None
            compiled = _compile_licensed(self.sources)
            self.edition = detect_edition(compiled.types)
            if asked is not None and asked != self.edition:
                raise J2735Error(f"edition {asked.name} asked for, but the ASN.1 in "
                                 f"{[p.name for p in self.sources]} is {self.edition.describe()}")
        self.spec, self._types, self.asn1_notes = compiled.spec, compiled.types, compiled.notes
        # the ids this codec decodes and encodes: every known id whose type its ASN.1 has
        self.message_types = {mid: name for mid, name in MESSAGE_TYPES.items() if name in self._types}

    # -- decoding -------------------------------------------------------------
    def decode(self, data: bytes) -> Frame:
        """Decode a MessageFrame and, for known ids, its inner message."""
        data = _as_bytes(data)
        frame = self._decode_type("MessageFrame", data)
        message_id, value = frame["messageId"], frame["value"]
        length = self._frame_length(data, frame)
        type_name = self.message_types.get(message_id)
        message = None
        if type_name is not None:
            message = self._decode_type(type_name, value, f"{type_name} (messageId {message_id})")
            self._decode_part_ii(message)
        return Frame(message_id, type_name, value, message, length)

    def _frame_length(self, data: bytes, frame: dict[str, Any]) -> int:
        """Bytes the frame occupies: 16 bits of extension bit + messageId, then the
        open type's length determinant (1 byte below 128, 2 below 16384) and octets."""
        size = len(frame["value"])
        if not data[0] & 0x80 and size < 16384:
            return 2 + (1 if size < 128 else 2) + size
        return len(self._encode_type("MessageFrame", frame))  # extension additions or fragmented

    def decode_message(self, type_name: str, data: bytes) -> dict[str, Any]:
        """Decode one inner message (no frame) of type `type_name`."""
        message = self._decode_type(type_name, _as_bytes(data))
        self._decode_part_ii(message)
        return message

    def _decode_part_ii(self, message: dict[str, Any]) -> None:
        for content in message.get("partII", ()) if isinstance(message, dict) else ():
            part_type = PART_II_TYPES.get(content["partII-Id"])
            if part_type is not None:
                content["partII-Value"] = self._decode_type(
                    part_type, content["partII-Value"], f"part II {part_type}")

    def _decode_type(self, type_name: str, data: bytes, what: str | None = None) -> Any:
        what = what or type_name
        if not data:
            raise J2735Error(f"{what}: no bytes")
        if len(data) > MAX_FRAME_BYTES:
            raise J2735Error(f"{what}: {len(data)} bytes, more than the {MAX_FRAME_BYTES} a frame may hold")
        try:
            compiled = self._type(type_name)
            decoded = compiled.decode(data)
            compiled.check_constraints(decoded)
            return decoded
        except asn1tools.DecodeError as exc:
            raise J2735Error(f"{what}: {_short(exc)}") from None
        except asn1tools.ConstraintsError as exc:
            raise J2735Error(f"{what}: value out of range: {_short(exc)}") from None
        except (ValueError, IndexError, KeyError, TypeError, NotImplementedError, OverflowError,
                RecursionError, asn1tools.Error) as exc:
            raise J2735Error(f"{what}: malformed ({type(exc).__name__}: {_short(exc)})") from None

    def _type(self, type_name: str) -> Any:
        compiled = self._types[type_name] if type_name in self._types else self.spec.types.get(type_name)
        if compiled is None:
            raise asn1tools.Error(f"type {type_name!r} is not in the ASN.1 (or is defined in two modules)")
        return compiled

    # -- encoding -------------------------------------------------------------
    def encode(self, message_id: int | str, message: dict[str, Any]) -> bytes:
        """Encode `message` (asn1tools values; part II values as dicts or octets) in a MessageFrame."""
        if isinstance(message_id, str):
            if message_id not in MESSAGE_IDS:
                raise J2735Error(f"unknown message type {message_id!r}; known: {sorted(MESSAGE_IDS)}")
            message_id = MESSAGE_IDS[message_id]
        type_name = self.message_types.get(message_id)
        if type_name is None:
            lacking = f" (its ASN.1 {[p.name for p in self.sources]} has no {MESSAGE_TYPES[message_id]})" \
                if message_id in MESSAGE_TYPES else ""
            raise J2735Error(f"messageId {message_id} is not one this codec encodes "
                             f"({sorted(self.message_types)}){lacking}")
        value = self.encode_message(type_name, message)
        return self._encode_type("MessageFrame", {"messageId": message_id, "value": value})

    def encode_raw(self, message_id: int, value: bytes) -> bytes:
        """A MessageFrame around already-encoded inner octets (any id)."""
        return self._encode_type("MessageFrame", {"messageId": message_id, "value": bytes(value)})

    def encode_message(self, type_name: str, message: dict[str, Any]) -> bytes:
        """Encode one inner message (no frame)."""
        if isinstance(message, dict) and message.get("partII"):
            message = dict(message)
            message["partII"] = [self._encode_part_ii(content) for content in message["partII"]]
        return self._encode_type(type_name, message)

    def _encode_part_ii(self, content: dict[str, Any]) -> dict[str, Any]:
        value = content.get("partII-Value")
        if isinstance(value, (bytes, bytearray)):
            return content
        part_type = PART_II_TYPES.get(content.get("partII-Id"))
        if part_type is None:
            raise J2735Error(f"partII-Id {content.get('partII-Id')!r} has no known type; give its value as octets")
        return {"partII-Id": content["partII-Id"], "partII-Value": self._encode_type(part_type, value)}

    def _encode_type(self, type_name: str, value: Any) -> bytes:
        try:
            compiled = self._type(type_name)
            compiled.check_types(value)
            compiled.check_constraints(value)
            return bytes(compiled.encode(value))
        except asn1tools.ConstraintsError as exc:
            raise J2735Error(f"{type_name}: value out of range: {_short(exc)}") from None
        except (asn1tools.EncodeError, asn1tools.Error) as exc:
            raise J2735Error(f"{type_name}: cannot encode: {_short(exc)}") from None
        except (ValueError, IndexError, KeyError, TypeError, AttributeError, NotImplementedError) as exc:
            raise J2735Error(f"{type_name}: cannot encode ({type(exc).__name__}: {_short(exc)})") from None


@lru_cache(maxsize=1)
def default_codec() -> J2735Codec:
    """The process-wide codec: the built-in module, or V2I_J2735_ASN1_DIR when set, in the edition
    V2I_J2735_EDITION names (default 2020; a licensed folder's own edition)."""
    return J2735Codec()


def _as_bytes(data: Any) -> bytes:
    if isinstance(data, (bytes, bytearray, memoryview)):
        return bytes(data)
    raise J2735Error(f"expected bytes, got {type(data).__name__}")


def _short(exc: BaseException, limit: int = 200) -> str:
    text = str(exc) or type(exc).__name__
    return text if len(text) <= limit else text[:limit] + "…"


_asn1tools_fixes.apply()
