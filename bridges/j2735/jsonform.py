"""A JSON form of decoded messages that converts back to the same bytes.

asn1tools values map to JSON as: OCTET STRING -> {"octets": "BEA10000"},
BIT STRING -> {"bits": "10000"} (one character per bit, so the length is
kept), CHOICE -> {"choice": "lane", "value": 13}; numbers, strings, lists and
SEQUENCE dicts stay as they are. The markers cannot be confused with a
SEQUENCE, whose member names never are "octets"/"bits"/"choice"+"value" alone.
"""
from __future__ import annotations

from typing import Any

from bridges.j2735.codec import Frame, J2735Error


def to_json(value: Any) -> Any:
    if isinstance(value, (bytes, bytearray)):
        return {"octets": bytes(value).hex().upper()}
    if isinstance(value, tuple) and len(value) == 2:
        first, second = value
        if isinstance(first, (bytes, bytearray)) and isinstance(second, int):
            bits = "".join(f"{byte:08b}" for byte in first)[:second]
            return {"bits": bits.ljust(second, "0")}
        if isinstance(first, str):
            return {"choice": first, "value": to_json(second)}
    if isinstance(value, dict):
        return {key: to_json(item) for key, item in value.items()}
    if isinstance(value, list):
        return [to_json(item) for item in value]
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise J2735Error(f"cannot express {type(value).__name__} in JSON")


def from_json(value: Any, where: str = "$") -> Any:
    if isinstance(value, dict):
        keys = set(value)
        if keys == {"octets"}:
            try:
                return bytes.fromhex(value["octets"])
            except (TypeError, ValueError):
                raise J2735Error(f"{where}.octets: {value['octets']!r} is not a hex string") from None
        if keys == {"bits"}:
            bits = value["bits"]
            if not isinstance(bits, str) or set(bits) - {"0", "1"}:
                raise J2735Error(f"{where}.bits: {bits!r} is not a string of 0 and 1")
            padded = bits.ljust((len(bits) + 7) // 8 * 8, "0")
            return (bytes(int(padded[i:i + 8], 2) for i in range(0, len(padded), 8)), len(bits))
        if keys == {"choice", "value"}:
            if not isinstance(value["choice"], str):
                raise J2735Error(f"{where}.choice: {value['choice']!r} is not an alternative name")
            return (value["choice"], from_json(value["value"], f"{where}.{value['choice']}"))
        return {key: from_json(item, f"{where}.{key}") for key, item in value.items()}
    if isinstance(value, list):
        return [from_json(item, f"{where}[{index}]") for index, item in enumerate(value)]
    return value


def frame_to_json(frame: Frame, data_length: int | None = None) -> dict[str, Any]:
    """The document `v2i j2735 decode` prints and `v2i j2735 encode` reads."""
    document: dict[str, Any] = {"messageId": frame.message_id, "type": frame.type_name}
    if frame.message is None:
        document["value"] = to_json(frame.value)
    else:
        document["message"] = to_json(frame.message)
    if data_length is not None and data_length > frame.length:
        document["trailingBytes"] = data_length - frame.length
    return document
