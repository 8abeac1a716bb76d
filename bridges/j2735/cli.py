"""`v2i j2735 decode|encode`: read and write J2735 traffic by hand.

decode takes hex (spaces, newlines and a 0x prefix are fine) from the
argument or stdin and prints JSON; bytes that start with a 1609.2 envelope
(version 3) are unwrapped first and the envelope is described. encode reads
the JSON that decode prints and prints the hex of the MessageFrame.

`decode --trust DIR` also verifies the envelope against the folder `v2i pki
init DIR` wrote (its CA as trust anchor, its stations as known signers) with
the receiver's clock at the frame's generation time (`--at` changes that), and
adds `verification` (verdict, signer, reason, detail, checkedAt) to the JSON;
`ieee1609dot2.verified` is true only for an accepted envelope.

`--edition 2016|2020` (decode and encode; default $V2I_J2735_EDITION, else
2020) picks the J2735 edition of the built-in module: TimeMark's range and the
SSP member names differ (bridges/j2735/editions.py). `decode --header skip:N`
drops N transport-header bytes before the frame (or its 1609.2 envelope), and
`--header scan` looks for the MessageFrame that ends the packet, as some RSUs
forward raw UDP payloads; the JSON then says `headerBytes`.

Exit status: 0 done (with --trust: the envelope verified); 1 with --trust: the
message decoded but the envelope was refused (the JSON and one stderr line say
why); 2 bad input (not hex, not a message, not JSON, an unreadable file or
trust store) or usage, with a one-line error naming the reason; 141 the reader
of stdout went away (`| head -1`), quietly, as other command-line tools do.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

from bridges.j2735.codec import J2735Codec, J2735Error
from bridges.j2735.editions import EDITIONS, edition as edition_named
from bridges.j2735.jsonform import frame_to_json, from_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    j = sub.add_parser("j2735", help="decode or encode J2735 UPER messages (debugging V2X traffic)")
    j.add_argument("--asn1-dir", help="compile a licensed copy of SAE's J2735 ASN.1 files from this folder "
                                      "instead of the built-in module (also: V2I_J2735_ASN1_DIR)")
    jsub = j.add_subparsers(dest="j2735_command", required=True)
    d = jsub.add_parser("decode", help="hex (or - for stdin) -> JSON")
    d.add_argument("hex", help="the message as hex, or - to read it from stdin")
    d.add_argument("--compact", action="store_true", help="one line of JSON")
    d.add_argument("--trust", metavar="DIR", help="verify the 1609.2 envelope against the CA and station "
                                                  "certificates in DIR (as `v2i pki init DIR` writes them)")
    d.add_argument("--at", default="generation", metavar="WHEN",
                   help="the receiver's clock for --trust: 'generation' (the frame's own generation time, so a "
                        "capture verifies later; default), 'now', or an ISO 8601 time with its zone")
    d.add_argument("--header", type=_header_arg, metavar="skip:N|scan",
                   help="the bytes carry a transport header before the frame (raw RSU forwards): skip N bytes, "
                        "or scan for the MessageFrame that decodes to the end of the packet")
    d.set_defaults(func=_cmd_decode)
    e = jsub.add_parser("encode", help="JSON file (as decode prints it; - for stdin) -> hex")
    e.add_argument("file")
    e.set_defaults(func=_cmd_encode)
    for command in (d, e):
        command.add_argument("--edition", type=_edition_arg, default=None, metavar="|".join(EDITIONS),
                             help="J2735 edition of the built-in module (default $V2I_J2735_EDITION, else 2020); "
                                  "with --asn1-dir, the files' own edition, checked")


def _codec(args) -> J2735Codec:
    return J2735Codec(args.asn1_dir, getattr(args, "edition", None))


def _edition_arg(text: str) -> str:
    try:
        return edition_named(text).name
    except J2735Error as exc:
        raise argparse.ArgumentTypeError(exc.reason.removeprefix("edition: ")) from None


def _header_arg(text: str) -> str:
    from bridges.j2735.framing import parse_header

    try:
        parse_header(text)
    except J2735Error as exc:
        raise argparse.ArgumentTypeError(exc.reason.removeprefix("header: ")) from None
    return text


def decode_packet(data: bytes, header: str | None, codec: J2735Codec) -> tuple[bytes, dict[str, Any]]:
    """The bytes from the frame (or envelope) on, and their JSON document (with `headerBytes` when a
    header was given). Bytes that are no frame but end in one get a hint naming --header scan."""
    stripped, header_bytes = strip_header(data, header, codec)
    try:
        document = decode_document(stripped, codec)
    except J2735Error as exc:
        if header is None and data[:1] != b"\x03":
            from bridges.j2735.framing import find_message_frame

            try:
                found = find_message_frame(data, "scan", codec)
            except J2735Error:
                raise exc from None
            raise J2735Error(f"{exc.reason.rstrip('.')}; a {found.frame.type_name} frame ends the packet after "
                             f"{found.offset} header bytes: --header scan (or skip:{found.offset}) "
                             f"decodes it") from None
        raise
    if header is not None:
        document["headerBytes"] = header_bytes
    return stripped, document


def strip_header(data: bytes, header: str | None, codec: J2735Codec) -> tuple[bytes, int]:
    """`data` from where the frame (or its 1609.2 envelope) starts, and the header bytes dropped."""
    from bridges.j2735.framing import find_message_frame, parse_header

    if header is None:
        return data, 0
    skip = parse_header(header)
    if skip is not None and data[skip:skip + 1] == b"\x03":
        return data[skip:], skip  # a 1609.2 envelope: decode_document unwraps it
    found = find_message_frame(data, header, codec)
    return data[found.offset:], found.offset


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
        store = _trust_store(args.trust) if args.trust else None
        text = sys.stdin.read() if args.hex == "-" else args.hex
        data, document = decode_packet(parse_hex(text), args.header, _codec(args))
        verdict = verify_document(data, document, store, args.at) if store is not None else None
    except J2735Error as exc:
        return _bad_input("decode", exc.reason)
    if not _print_out(json.dumps(document, indent=None if args.compact else 2)):
        return EXIT_BROKEN_PIPE
    if verdict is not None and verdict["verdict"] != "accepted":
        print(f"v2i j2735 decode: envelope refused: {verdict['reason']}: {verdict['detail']}", file=sys.stderr)
        return 1
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
        return _bad_input("encode", f"{args.file}: {exc.strerror}")
    try:
        document = json.loads(text)
    except json.JSONDecodeError as exc:
        return _bad_input("encode", f"{args.file}: not JSON: {exc}")
    try:
        hex_text = encode_document(document, _codec(args)).hex().upper()
    except J2735Error as exc:
        return _bad_input("encode", f"{args.file}: {exc.reason}")
    return 0 if _print_out(hex_text) else EXIT_BROKEN_PIPE


EXIT_BAD_INPUT = 2
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE: what a shell tool killed by a closed pipe reports


def _bad_input(command: str, reason: str) -> int:
    """One line on stderr naming the reason; the bad-input exit status."""
    print(f"v2i j2735 {command}: {' '.join(str(reason).split())}", file=sys.stderr)
    return EXIT_BAD_INPUT


def _print_out(text: str) -> bool:
    """Print to stdout; False when the reader has gone (`| head -1`), without a traceback.

    Python ignores SIGPIPE, so a closed pipe is a BrokenPipeError here and
    again when the interpreter flushes stdout on exit; pointing stdout at
    /dev/null after the first one silences the second.
    """
    try:
        print(text)
        sys.stdout.flush()
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        return False
    return True


def _trust_store(directory: str):
    from bridges.security.errors import SecurityError
    from bridges.security.trust import load_trust_store

    try:
        store = load_trust_store(directory)
        store.verifier()  # the station certificates must chain to the anchors
    except SecurityError as exc:
        raise J2735Error(f"--trust {directory}: {exc.reason}") from None
    return store


def verify_document(data: bytes, document: dict[str, Any], store, at: str) -> dict[str, Any]:
    """Verify `data`'s envelope with `store`; the verdict (signer, reason) is also put into `document`.

    Only bad `--at` input raises (J2735Error); a refused envelope is a verdict.
    """
    from bridges.security.envelope import VerificationError

    envelope = _lenient_envelope(data)
    now_us = _receiver_clock(at, envelope)
    verdict: dict[str, Any] = {"verdict": "rejected", "signer": _signer_name(envelope, store),
                               "checkedAt": _iso(now_us)}
    document["verification"] = verdict
    if envelope is None:
        verdict.update(reason="unsecured-not-allowed", detail="a bare MessageFrame: no 1609.2 envelope to verify")
        return verdict
    try:
        verified = store.verifier().verify(data, now_us)
    except VerificationError as exc:
        verdict.update(reason=exc.reason.value, detail=exc.detail)
    else:
        verdict.update(verdict="accepted", signer=verified.signer)
    if isinstance(document.get("ieee1609dot2"), dict):
        document["ieee1609dot2"]["verified"] = verdict["verdict"] == "accepted"
    return verdict


def _lenient_envelope(data: bytes) -> dict[str, Any] | None:
    from bridges.security.oer import SecurityFormatError, decode as decode_1609

    if data[:1] != b"\x03":
        return None
    try:
        return decode_1609("Ieee1609Dot2Data", data)
    except SecurityFormatError:
        return None


def _receiver_clock(at: str, envelope: dict[str, Any] | None) -> int:
    """--at as Time64 µs: the frame's generation time, the wall clock, or an ISO 8601 time with its zone."""
    from datetime import datetime, timezone

    from bridges.security.certificates import to_time64

    if at == "generation":
        kind, content = envelope["content"] if envelope is not None else (None, None)
        generated = content["tbsData"]["headerInfo"].get("generationTime") if kind == "signedData" else None
        if generated is not None:
            return generated
        at = "now"  # nothing to take the time from: check validity today
    if at == "now":
        return to_time64(datetime.now(timezone.utc))
    try:
        moment = datetime.fromisoformat(at)
    except ValueError:
        raise J2735Error(f"--at {at!r}: expected 'generation', 'now' or an ISO 8601 time such as "
                         f"2026-06-01T12:00:00+00:00") from None
    if moment.tzinfo is None:
        raise J2735Error(f"--at {at!r}: give the time zone (e.g. +00:00 or Z)")
    return to_time64(moment)


def _iso(time64_us: int) -> str:
    from datetime import timedelta

    from bridges.security.certificates import EPOCH_1609

    return (EPOCH_1609 + timedelta(microseconds=time64_us)).isoformat()


def _signer_name(envelope: dict[str, Any] | None, store) -> str | None:
    """The signing certificate's name as the frame states it (a full certificate), or as the store knows it."""
    if envelope is None or envelope["content"][0] != "signedData":
        return None
    kind, value = envelope["content"][1]["signer"]
    if kind == "certificate" and value:
        identity = value[0]["toBeSigned"]["id"]
        return identity[1] if identity[0] == "name" else f"<{identity[0]}>"
    if kind == "digest":
        return next((c.name for c in store.stations if c.digest == value), None)
    return None
