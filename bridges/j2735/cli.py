"""`v2i j2735 decode|encode`: read and write J2735 traffic by hand.

decode takes hex (spaces, newlines and a 0x prefix are fine) from the
argument or stdin and prints JSON; bytes that start with a 1609.2 envelope
(version 3) are unwrapped first and the envelope is described. encode reads
the JSON that decode prints and prints the hex of the MessageFrame.
Exit status: 0 done, 1 the bytes or JSON are not a valid message, 2 usage.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from bridges.j2735.codec import J2735Codec, J2735Error
from bridges.j2735.jsonform import frame_to_json, from_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    j = sub.add_parser("j2735", help="decode or encode J2735 UPER messages (debugging V2X traffic)")
    j.add_argument("--asn1-dir", help="compile a licensed copy of SAE's J2735 ASN.1 files from this folder "
                                      "instead of the built-in module (also: V2I_J2735_ASN1_DIR)")
    jsub = j.add_subparsers(dest="j2735_command", required=True)
    d = jsub.add_parser("decode", help="hex (or - for stdin) -> JSON")
    d.add_argument("hex", help="the message as hex, or - to read it from stdin")
    d.add_argument("--compact", action="store_true", help="one line of JSON")
    d.set_defaults(func=_cmd_decode)
    e = jsub.add_parser("encode", help="JSON file (as decode prints it; - for stdin) -> hex")
    e.add_argument("file")
    e.set_defaults(func=_cmd_encode)


def _codec(args) -> J2735Codec:
    return J2735Codec(args.asn1_dir)


def parse_hex(text: str) -> bytes:
    cleaned = "".join(text.split())
    if cleaned[:2].lower() == "0x":
        cleaned = cleaned[2:]
    try:
        return bytes.fromhex(cleaned)
    except ValueError:
        bad = next((c for c in cleaned if c not in "0123456789abcdefABCDEF"), None)
        reason = f"character {bad!r}" if bad else f"odd number of hex digits ({len(cleaned)})"
        raise J2735Error(f"input is not hex: {reason}") from None


def decode_document(data: bytes, codec: J2735Codec) -> dict[str, Any]:
    """JSON document for `data`: a bare MessageFrame, or one inside a 1609.2 envelope."""
    if data[:1] == b"\x03":
        from bridges.security.oer import SecurityFormatError, decode as decode_1609

        try:
            envelope = decode_1609("Ieee1609Dot2Data", data)
        except SecurityFormatError as exc:
            raise J2735Error(f"1609.2 envelope: {exc.reason}") from None
        payload, description = _envelope_payload(envelope)
        frame = codec.decode(payload)
        return {"ieee1609dot2": description, **frame_to_json(frame, len(payload))}
    frame = codec.decode(data)
    return frame_to_json(frame, len(data))


def _envelope_payload(envelope: dict[str, Any]) -> tuple[bytes, dict[str, Any]]:
    from bridges.security.envelope import unverified_payload
    from bridges.security.oer import SecurityFormatError

    kind, content = envelope["content"]
    if kind not in ("unsecuredData", "signedData"):
        raise J2735Error(f"1609.2 {kind} content is not supported")
    try:
        payload = unverified_payload(envelope)
    except SecurityFormatError as exc:
        raise J2735Error(f"1609.2 {exc.reason}") from None
    if kind == "unsecuredData":
        return payload, {"content": "unsecuredData"}
    header = content["tbsData"]["headerInfo"]
    signer_kind, signer = content["signer"]
    return payload, {
        "content": "signedData", "psid": header["psid"],
        "generationTime": header.get("generationTime"),
        "signer": {"digest": signer.hex().upper()} if signer_kind == "digest" else signer_kind,
        "signature": content["signature"][0], "verified": False,
    }


def _cmd_decode(args) -> int:
    try:
        text = sys.stdin.read() if args.hex == "-" else args.hex
        document = decode_document(parse_hex(text), _codec(args))
    except J2735Error as exc:
        print(f"v2i j2735 decode: {exc.reason}", file=sys.stderr)
        return 1
    print(json.dumps(document, indent=None if args.compact else 2))
    return 0


def encode_document(document: Any, codec: J2735Codec) -> bytes:
    if not isinstance(document, dict):
        raise J2735Error("the JSON must be an object with messageId and message")
    message_id = document.get("messageId")
    if not isinstance(message_id, int) or isinstance(message_id, bool):
        raise J2735Error(f"messageId: expected an integer, got {message_id!r}")
    if "message" in document:
        return codec.encode(message_id, from_json(document["message"], "$.message"))
    if "value" in document:
        value = from_json(document["value"], "$.value")
        if not isinstance(value, bytes):
            raise J2735Error("value: expected {\"octets\": HEX}")
        return codec.encode_raw(message_id, value)
    raise J2735Error("the JSON has neither 'message' nor 'value'")


def _cmd_encode(args) -> int:
    try:
        text = sys.stdin.read() if args.file == "-" else Path(args.file).read_text()
    except OSError as exc:
        print(f"v2i j2735 encode: {args.file}: {exc.strerror}", file=sys.stderr)
        return 2
    try:
        document = json.loads(text)
    except json.JSONDecodeError as exc:
        print(f"v2i j2735 encode: {args.file}: not JSON: {exc}", file=sys.stderr)
        return 1
    try:
        print(encode_document(document, _codec(args)).hex().upper())
    except J2735Error as exc:
        print(f"v2i j2735 encode: {args.file}: {exc.reason}", file=sys.stderr)
        return 1
    return 0
