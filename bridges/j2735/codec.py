"""J2735 UPER codec: compile the ASN.1 once, then decode and encode MessageFrames.

Decoding is two-stage, as with SAE's own information object sets: the frame
gives `messageId` and the open-type `value` octets; the inner type is chosen by
`messageId`. BSM part II values are decoded the same way by `partII-Id`.
Unknown ids stay as octets, so they re-encode to the same bytes.

Bytes come from the network: whatever they are, `decode` raises only
`J2735Error` (with a reason), never an asn1tools or Python error.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import asn1tools

from bridges.j2735 import _asn1tools_fixes

BUILTIN_MODULE = Path(__file__).with_name("v2i-j2735.asn")
ASN1_DIR_ENV = "V2I_J2735_ASN1_DIR"

# DSRCmsgID -> inner type name (SAE J2735 Table of message ids)
MESSAGE_TYPES: dict[int, str] = {
    18: "MapData",
    19: "SPAT",
    20: "BasicSafetyMessage",
    29: "SignalRequestMessage",
    30: "SignalStatusMessage",
}
MESSAGE_IDS: dict[str, int] = {name: mid for mid, name in MESSAGE_TYPES.items()}
# PartII-Id -> part II content type
PART_II_TYPES: dict[int, str] = {0: "VehicleSafetyExtensions", 1: "SpecialVehicleExtensions"}
PART_II_IDS: dict[str, int] = {name: pid for pid, name in PART_II_TYPES.items()}

MAX_FRAME_BYTES = 65535  # larger than any J2735 message over the air; bounds the work per frame


class J2735Error(ValueError):
    """A message that cannot be decoded or encoded; `reason` says why."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


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


@lru_cache(maxsize=4)
def _compile(sources: tuple[Path, ...]):
    try:
        return asn1tools.compile_files([str(p) for p in sources], "uper")
    except (asn1tools.ParseError, asn1tools.CompileError) as exc:
        raise J2735Error(f"cannot compile ASN.1 {[p.name for p in sources]}: {exc}") from None


class J2735Codec:
    """UPER codec for the J2735 subset; `J2735Codec(asn1_dir)` uses a user's licensed files."""

    def __init__(self, asn1_dir: str | os.PathLike | None = None):
        self.sources = tuple(asn1_sources(asn1_dir))
        self.spec = _compile(self.sources)
        missing = [name for name in ("MessageFrame", *MESSAGE_TYPES.values(), *PART_II_TYPES.values())
                   if name not in self.spec.types]
        if missing:
            raise J2735Error(f"ASN.1 in {[p.name for p in self.sources]} lacks types {missing}")

    # -- decoding -------------------------------------------------------------
    def decode(self, data: bytes) -> Frame:
        """Decode a MessageFrame and, for known ids, its inner message."""
        data = _as_bytes(data)
        frame = self._decode_type("MessageFrame", data)
        message_id, value = frame["messageId"], frame["value"]
        length = self._frame_length(data, frame)
        type_name = MESSAGE_TYPES.get(message_id)
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
            return self.spec.decode(type_name, data, check_constraints=True)
        except asn1tools.DecodeError as exc:
            raise J2735Error(f"{what}: {_short(exc)}") from None
        except asn1tools.ConstraintsError as exc:
            raise J2735Error(f"{what}: value out of range: {_short(exc)}") from None
        except (ValueError, IndexError, KeyError, TypeError, NotImplementedError, OverflowError,
                RecursionError, asn1tools.Error) as exc:
            raise J2735Error(f"{what}: malformed ({type(exc).__name__}: {_short(exc)})") from None

    # -- encoding -------------------------------------------------------------
    def encode(self, message_id: int | str, message: dict[str, Any]) -> bytes:
        """Encode `message` (asn1tools values; part II values as dicts or octets) in a MessageFrame."""
        if isinstance(message_id, str):
            if message_id not in MESSAGE_IDS:
                raise J2735Error(f"unknown message type {message_id!r}; known: {sorted(MESSAGE_IDS)}")
            message_id = MESSAGE_IDS[message_id]
        type_name = MESSAGE_TYPES.get(message_id)
        if type_name is None:
            raise J2735Error(f"messageId {message_id} is not one this codec encodes ({sorted(MESSAGE_TYPES)})")
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
            return self.spec.encode(type_name, value, check_constraints=True)
        except asn1tools.ConstraintsError as exc:
            raise J2735Error(f"{type_name}: value out of range: {_short(exc)}") from None
        except (asn1tools.EncodeError, asn1tools.Error) as exc:
            raise J2735Error(f"{type_name}: cannot encode: {_short(exc)}") from None
        except (ValueError, IndexError, KeyError, TypeError, AttributeError, NotImplementedError) as exc:
            raise J2735Error(f"{type_name}: cannot encode ({type(exc).__name__}: {_short(exc)})") from None


@lru_cache(maxsize=1)
def default_codec() -> J2735Codec:
    """The process-wide codec (built-in module, or V2I_J2735_ASN1_DIR when set)."""
    return J2735Codec()


def _as_bytes(data: Any) -> bytes:
    if isinstance(data, (bytes, bytearray, memoryview)):
        return bytes(data)
    raise J2735Error(f"expected bytes, got {type(data).__name__}")


def _short(exc: BaseException, limit: int = 200) -> str:
    text = str(exc) or type(exc).__name__
    return text if len(text) <= limit else text[:limit] + "…"


_asn1tools_fixes.apply()
