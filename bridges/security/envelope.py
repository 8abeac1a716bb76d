"""The 1609.2-style security envelope: sign J2735 payloads, verify what arrives.

Signed messages are real IEEE 1609.2 `Ieee1609Dot2Data` structures (COER):
signedData { hashId sha256, tbsData { payload { data = unsecuredData(payload),
extDataHash = SHA-256(payload) }, headerInfo { psid, generationTime } },
signer = certificate digest (or the full certificate, see below), signature
ecdsaNistP256 }.

Signer identifier (`Signer(..., signer_identifier=...)`, or per message in
`sign(..., signer_identifier=...)`): "periodic" (default) sends the full
certificate in the first message and then at most once per
`certificate_interval_s`, the digest (HashedId8) otherwise, as J2945/1 asks
of BSM senders; "certificate" sends it in every message (e.g. the reply to a
neighbour that does not know it yet); "digest" never does (for receivers
given the station certificate beforehand: `Verifier(..., stations=[...])`).

Time: every moment is 1609.2 Time64 (int µs since 2004-01-01) or an aware
datetime (see bridges.security.certificates): `sign(payload, psid,
generation_time)` and `verify(data, now)`, like `ScenarioCA.issue(start=)`.

Canonical only: the verifier accepts one encoding per message, the one this
project writes: canonical OER (no trailing bytes, zero padding bits, minimal
lengths) with the signature's r as x-only. Any other spelling of a signed
message is refused with its own reason (`trailing-bytes`, `nonzero-padding`,
`non-canonical-encoding`, `non-canonical-signature`) before any signature
is checked.

Carrying the payload's SHA-256 next to the payload is this project's choice
(1609.2 defines extDataHash for data sent elsewhere): the signature covers
both, and a receiver can tell a payload altered in transit (digest mismatch)
from a forged or corrupted signature. Envelopes without it are still verified.
"""
from __future__ import annotations

import enum
import heapq
from dataclasses import dataclass
from datetime import datetime
from difflib import get_close_matches
from typing import Any, Iterable

from bridges.security import oer
from bridges.security.certificates import (Certificate, Credentials, sha256, sign_digest, signature_form_problem,
                                           signing_digest, to_time64, verify_digest)
from bridges.security.errors import PsidNotPermitted, SecurityError
from bridges.security.oer import PROTOCOL_VERSION, NonCanonicalEncoding, SecurityFormatError

PSID_BSM = 0x20            # SAE J2945/1 basic safety message
PSID_SURROGATE_BSM = 0x7F  # test PSID SAE J2945/8 names for surrogate BSMs (testing only)
PSID_SPAT_MAP = 0x82       # IEEE 1609.12 intersection safety and awareness (p-encoded 80-02): SPaT, MAP
PSID_SSM = 0x204095        # IEEE 1609.12 traffic signal priority status (2113685, p-encoded E0-00-00-15): SSM
PSID_SRM = 0x204096        # IEEE 1609.12 traffic signal request (2113686, p-encoded E0-00-00-16): SRM


class Rejection(str, enum.Enum):
    """Why a received envelope was refused: one distinct reason per check."""

    MALFORMED = "malformed"
    TRAILING_BYTES = NonCanonicalEncoding.TRAILING_BYTES      # "trailing-bytes"
    NONZERO_PADDING = NonCanonicalEncoding.NONZERO_PADDING    # "nonzero-padding"
    NON_CANONICAL = NonCanonicalEncoding.OTHER                # "non-canonical-encoding"
    SIGNATURE_FORM = "non-canonical-signature"
    UNSECURED = "unsecured-not-allowed"
    UNKNOWN_SIGNER = "unknown-signer"
    UNTRUSTED_SIGNER = "untrusted-signer"
    PSID_NOT_PERMITTED = "psid-not-permitted"
    OUTSIDE_TIME_WINDOW = "outside-time-window"
    REPLAYED = "replayed"
    ALTERED_PAYLOAD = "altered-payload"
    BAD_SIGNATURE = "bad-signature"


class VerificationError(SecurityError):
    """A received envelope refused; `reason` is the Rejection (the tally key), `detail` the human why."""

    def __init__(self, reason: Rejection, detail: str):
        super().__init__(f"{reason.value}: {detail}")
        self.reason = reason
        self.detail = detail


SIGNER_IDENTIFIERS = ("periodic", "certificate", "digest")


@dataclass(frozen=True)
class Verified:
    """An accepted envelope's content."""

    payload: bytes
    psid: int | None
    generation_time_us: int | None
    signer: str | None  # certificate name; None for unsecured data
    secured: bool


class Signer:
    """Signs payloads for one station with its credentials.

    `signer_identifier` chooses what identifies the signer in each message
    (see the module docstring): "periodic" (full certificate at most once per
    `certificate_interval_s`, its digest otherwise), "certificate" or "digest".
    """

    def __init__(self, credentials: Credentials, certificate_interval_s: float = 1.0, *,
                 signer_identifier: str = "periodic"):
        self.credentials = credentials
        self.certificate_interval_us = round(certificate_interval_s * 1e6)
        self.signer_identifier = _signer_identifier(signer_identifier)
        self._last_full_certificate_us: int | None = None

    def sign(self, payload: bytes, psid: int, generation_time: datetime | int, *,
             signer_identifier: str | None = None) -> bytes:
        """The signed Ieee1609Dot2Data; PsidNotPermitted when the certificate does not list `psid`.

        `generation_time` is Time64 (int µs) or an aware datetime;
        `signer_identifier` overrides the Signer's choice for this message.
        """
        certificate = self.credentials.certificate
        if psid not in certificate.psids:
            raise PsidNotPermitted(certificate.name, psid, certificate.psids)
        mode = self.signer_identifier if signer_identifier is None else _signer_identifier(signer_identifier)
        generation_time_us = to_time64(generation_time)
        tbs = {
            "payload": {"data": {"protocolVersion": PROTOCOL_VERSION,
                                 "content": ("unsecuredData", bytes(payload))},
                        "extDataHash": ("sha256HashedData", sha256(payload))},
            "headerInfo": {"psid": psid, "generationTime": generation_time_us},
        }
        digest = signing_digest(oer.encode("ToBeSignedData", tbs), certificate.encoded)
        signed = {"hashId": "sha256", "tbsData": tbs, "signer": self._signer_field(generation_time_us, mode),
                  "signature": sign_digest(self.credentials.key, digest)}
        return oer.encode("Ieee1609Dot2Data", {"protocolVersion": PROTOCOL_VERSION,
                                               "content": ("signedData", signed)})

    def _signer_field(self, now_us: int, mode: str) -> tuple[str, Any]:
        last = self._last_full_certificate_us
        if mode == "certificate" or (mode == "periodic" and (
                last is None or now_us - last >= self.certificate_interval_us or now_us < last)):
            self._last_full_certificate_us = now_us  # the next periodic one is due an interval after this
            return ("certificate", [self.credentials.certificate.fields])
        return ("digest", self.credentials.certificate.digest)


def _signer_identifier(mode: str) -> str:
    if mode not in SIGNER_IDENTIFIERS:
        close = get_close_matches(str(mode), SIGNER_IDENTIFIERS, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise SecurityError(f"signer_identifier {mode!r}: expected one of {', '.join(SIGNER_IDENTIFIERS)}{hint}")
    return mode


class Verifier:
    """Checks envelopes against trusted CA roots, a time window and replay.

    `max_age_s`/`max_future_s` bound the generation time against the
    receiver's clock (simulation time in a run). Station certificates arrive
    in envelopes, are checked against the roots once, and are remembered by
    digest, so later digest-signed messages verify without the chain; the
    validity periods of the station certificate and of its CA are checked
    against the receiver's clock on every message. `stations` are station
    certificates known beforehand (a trust store, bridges.security.trust):
    checked against the roots here, so digest-only messages verify at once.

    Replay memory is bounded by time, not by count: the signing digest of
    every accepted message is kept until its generation time falls out of the
    window, so it holds at most the messages accepted from trusted signers in
    the last `max_age_s + max_future_s` (e.g. 10 Hz senders: about 5.5 per
    sender with the defaults). Only messages that passed the signature check
    are remembered, so a sender without a trusted key cannot grow it.
    """

    def __init__(self, trust_anchors: Iterable[Certificate], *, max_age_s: float = 0.5,
                 max_future_s: float = 0.05, allow_unsecured: bool = False,
                 stations: Iterable[Certificate] = ()):
        self.anchors = {cert.digest: cert for cert in trust_anchors}
        for cert in self.anchors.values():
            if not cert.signed_by(None):  # verify_digest also refuses a non-canonical signature form
                raise SecurityError(f"trust anchor {cert.name!r} is not a valid self-signed certificate")
        self.max_age_us = round(max_age_s * 1e6)
        self.max_future_us = round(max_future_s * 1e6)
        self.allow_unsecured = allow_unsecured
        self._stations: dict[bytes, Certificate] = {}
        for cert in stations:  # provisioned: digest-signed messages verify from the first one
            try:
                self._check_chain(cert)
            except VerificationError as exc:
                raise SecurityError(f"station certificate {cert.name!r}: {exc.detail}") from None
            self._stations[cert.digest] = cert
        self._seen: set[bytes] = set()  # signing digests of accepted messages
        self._seen_frames: set[bytes] = set()  # SHA-256 of their received bytes
        self._expiry: list[tuple[int, bytes, bytes]] = []  # heap: (generation time, digest, frame hash)
        self._forgotten_before_us = -(1 << 63)  # digests of messages generated earlier were dropped

    @property
    def remembered(self) -> int:
        """How many accepted messages the replay check holds now (the memory bound is observable)."""
        return len(self._seen)

    def verify(self, data: bytes, now: datetime | int) -> Verified:
        """The content of an envelope accepted at `now` (Time64 or an aware datetime); VerificationError if not."""
        now_us = to_time64(now)
        self._forget_older_than(now_us - self.max_age_us)
        frame = sha256(data)
        if frame in self._seen_frames:  # a byte-for-byte replay costs one hash, not a decode
            raise VerificationError(Rejection.REPLAYED, "the same signed message was already accepted")
        try:
            envelope = oer.decode("Ieee1609Dot2Data", data)
        except SecurityFormatError as exc:
            raise VerificationError(Rejection.MALFORMED, exc.reason) from None
        if envelope["protocolVersion"] != PROTOCOL_VERSION:
            raise VerificationError(Rejection.MALFORMED, f"protocol version {envelope['protocolVersion']}, "
                                                         f"expected {PROTOCOL_VERSION}")
        try:
            oer.require_canonical("Ieee1609Dot2Data", data, envelope)
        except NonCanonicalEncoding as exc:
            raise VerificationError(Rejection(exc.kind), exc.reason) from None
        except SecurityFormatError as exc:  # decoded, yet cannot be encoded again
            raise VerificationError(Rejection.MALFORMED, exc.reason) from None
        kind, content = envelope["content"]
        if kind == "unsecuredData":
            if not self.allow_unsecured:
                raise VerificationError(Rejection.UNSECURED, "unsecured data and the policy requires signatures")
            return Verified(content, None, None, None, secured=False)
        if kind != "signedData":
            raise VerificationError(Rejection.MALFORMED, f"{kind} content is not supported")
        return self._verify_signed(content, now_us, frame)

    def _verify_signed(self, signed: dict[str, Any], now_us: int, frame: bytes) -> Verified:
        if signed["hashId"] != "sha256":
            raise VerificationError(Rejection.MALFORMED, f"hash algorithm {signed['hashId']} is not supported")
        problem = signature_form_problem(signed["signature"])
        if problem is not None:
            raise VerificationError(Rejection.SIGNATURE_FORM, problem)
        tbs = signed["tbsData"]
        payload = _inner_payload(tbs["payload"])
        header = tbs["headerInfo"]
        certificate = self._signer_certificate(signed["signer"], now_us)
        psid = header["psid"]
        if psid not in certificate.psids:
            raise VerificationError(Rejection.PSID_NOT_PERMITTED,
                                    f"{certificate.name!r} is not permitted to sign PSID {psid:#x}")
        generated = header.get("generationTime")
        if generated is None:
            raise VerificationError(Rejection.MALFORMED, "no generation time in the header")
        self._check_time_window(generated, now_us)
        ext_hash = tbs["payload"].get("extDataHash")
        if ext_hash is not None and ext_hash[1] != sha256(payload):
            raise VerificationError(Rejection.ALTERED_PAYLOAD, "payload does not match its signed digest")
        digest = signing_digest(oer.encode("ToBeSignedData", tbs), certificate.encoded)
        # Before the ECDSA check: a replay re-encoded or with another signature is
        # refused without a signature verification. Only accepted messages are
        # remembered, so this refuses nothing that could have been accepted.
        if digest in self._seen:
            raise VerificationError(Rejection.REPLAYED, "the same signed message was already accepted")
        if not verify_digest(certificate.public_key(), digest, signed["signature"]):
            raise VerificationError(Rejection.BAD_SIGNATURE, f"signature does not verify with {certificate.name!r}'s key")
        self._remember(digest, frame, generated)
        return Verified(payload, psid, generated, certificate.name, secured=True)

    def _check_time_window(self, generated: int, now_us: int) -> None:
        """Refuse generation times outside the window, and any the replay memory may have forgotten.

        With a clock that only moves forward the second test never fires: the
        memory forgets only what the window already refuses. If the receiver's
        clock steps back, a message older than what was forgotten could be a
        replay that can no longer be detected, so it is refused too.
        """
        age = now_us - generated
        if age > self.max_age_us or -age > self.max_future_us:
            raise VerificationError(Rejection.OUTSIDE_TIME_WINDOW,
                                    f"generated {age / 1e3:+.1f} ms before now; window "
                                    f"-{self.max_future_us / 1e3:g}..{self.max_age_us / 1e3:g} ms")
        if generated < self._forgotten_before_us:
            raise VerificationError(Rejection.OUTSIDE_TIME_WINDOW,
                                    f"generated {age / 1e3:+.1f} ms before now, earlier than the replay "
                                    f"memory reaches after the receiver's clock stepped back")

    def _signer_certificate(self, signer: tuple[str, Any], now_us: int) -> Certificate:
        kind, value = signer
        if kind == "digest":
            certificate = self._stations.get(value)
            if certificate is None:
                raise VerificationError(Rejection.UNKNOWN_SIGNER,
                                        f"no certificate known for digest {value.hex()} (it arrives with "
                                        f"the sender's next full-certificate message)")
        elif kind == "certificate":
            if len(value) != 1:
                raise VerificationError(Rejection.UNTRUSTED_SIGNER, "certificate chains longer than one "
                                                                    "are not accepted")
            try:
                certificate = Certificate(oer.encode("Certificate", value[0]), value[0])
            except SecurityFormatError as exc:
                raise VerificationError(Rejection.MALFORMED, exc.reason) from None
            if certificate.digest not in self._stations:
                self._check_chain(certificate)
                self._stations[certificate.digest] = certificate
        else:
            raise VerificationError(Rejection.UNTRUSTED_SIGNER, "self-signed data is not accepted")
        self._check_validity(certificate, now_us)
        return certificate

    def _check_validity(self, certificate: Certificate, now_us: int) -> None:
        """Both links of the chain must be valid now: an expired CA vouches for nobody.

        Checked per message, not once when the certificate is learnt, because a
        remembered station certificate (or its CA) expires while in use.
        """
        issuer = self.anchors[certificate.issuer_digest]  # _check_chain put only anchored ones in _stations
        for link, role in ((certificate, "certificate"), (issuer, "CA certificate")):
            start, end = link.validity_us()
            if not start <= now_us <= end:
                raise VerificationError(Rejection.UNTRUSTED_SIGNER,
                                        f"{role} {link.name!r} is not valid at this time")

    def _check_chain(self, certificate: Certificate) -> None:
        issuer = self.anchors.get(certificate.issuer_digest or b"")
        if issuer is None:
            raise VerificationError(Rejection.UNTRUSTED_SIGNER,
                                    f"certificate {certificate.name!r} is not issued by a trusted CA")
        signature = certificate.fields.get("signature")
        problem = signature_form_problem(signature) if signature is not None else None
        if problem is not None:
            raise VerificationError(Rejection.SIGNATURE_FORM, f"certificate {certificate.name!r}: {problem}")
        try:
            valid = certificate.signed_by(issuer)
        except SecurityFormatError as exc:
            raise VerificationError(Rejection.MALFORMED, exc.reason) from None
        if not valid:
            raise VerificationError(Rejection.UNTRUSTED_SIGNER,
                                    f"certificate {certificate.name!r} does not verify with CA {issuer.name!r}")

    def _remember(self, digest: bytes, frame: bytes, generated_us: int) -> None:
        self._seen.add(digest)
        self._seen_frames.add(frame)
        heapq.heappush(self._expiry, (generated_us, digest, frame))

    def _forget_older_than(self, horizon_us: int) -> None:
        """Drop digests of messages generated before `horizon_us`: the window refuses them anyway.

        The horizon never moves back, so `_check_time_window` can refuse what
        was forgotten even when the receiver's clock does.
        """
        if horizon_us <= self._forgotten_before_us:
            return
        self._forgotten_before_us = horizon_us
        while self._expiry and self._expiry[0][0] < horizon_us:
            _, digest, frame = heapq.heappop(self._expiry)
            self._seen.discard(digest)
            self._seen_frames.discard(frame)


def _inner_payload(payload: dict[str, Any]) -> bytes:
    data = payload.get("data")
    if data is None:
        raise VerificationError(Rejection.MALFORMED, "signed data carries no payload")
    if data["protocolVersion"] != PROTOCOL_VERSION or data["content"][0] != "unsecuredData":
        raise VerificationError(Rejection.MALFORMED, "signed payload is not version-3 unsecured data")
    return data["content"][1]


def unverified_payload(envelope: dict[str, Any]) -> bytes:
    """The payload of a decoded Ieee1609Dot2Data: unsecuredData, or signedData carrying it inline.

    Nothing is verified: for tools that look at what a frame says (the CLI's decoder, the simulator's
    air), never for a receiver acting on it. SecurityFormatError for anything else.
    """
    kind, content = envelope["content"]
    if kind == "unsecuredData":
        return content
    if kind == "signedData":
        inner = content["tbsData"]["payload"].get("data")
        if inner is not None and inner["content"][0] == "unsecuredData":
            return inner["content"][1]
        raise SecurityFormatError("signedData carries no inline payload")
    raise SecurityFormatError(f"{kind} carries no payload to read")


def open_unsecured(data: bytes) -> bytes:
    """The payload of an unsecured Ieee1609Dot2Data (no policy check); SecurityFormatError otherwise."""
    envelope = oer.decode("Ieee1609Dot2Data", data)
    kind, content = envelope["content"]
    if envelope["protocolVersion"] != PROTOCOL_VERSION or kind != "unsecuredData":
        raise SecurityFormatError(f"not version-{PROTOCOL_VERSION} unsecured data ({kind})")
    return content
