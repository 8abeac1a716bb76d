"""A small scenario certificate authority: 1609.2 explicit certificates, ECDSA P-256.

The CA's self-signed root is what receivers trust; it issues one certificate
per station (RSU, vehicle) naming the PSIDs the station may sign for. Keys and
certificates are files: `<name>.cert` (the certificate's COER bytes) and
`<name>.key` (PKCS#8 PEM), so a real RSU box can be provisioned by copying two
files. Signatures follow 1609.2's construction: ECDSA over
SHA-256(SHA-256(tbs) || SHA-256(signer certificate, or empty for self-signed)).

Time, one convention for the whole package: a moment is 1609.2 Time64, an
`int` of microseconds since 2004-01-01 00:00:00, or an aware `datetime`,
converted exactly (`to_time64`). `ScenarioCA.create/issue(start=...)`,
`Signer.sign(..., generation_time)` and `Verifier.verify(..., now)` all take
either; what they return (`Verified.generation_time_us`) is Time64.
`time64_us(unix_seconds)` converts Unix time (what the simulation's clock
gives). Durations are seconds (`*_s`) or, for certificate lifetimes, hours.

Point forms (1609.2 EccP256CurvePoint), one per use, and only that one is
accepted: a signature's r is `x-only` (r itself, 0 < r < n); a verification
key is `compressed-y-0`/`compressed-y-1`. Another form of the same number
would be a second valid spelling of a signed message or certificate.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from numbers import Integral
from pathlib import Path
from typing import Any

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.asymmetric.utils import (Prehashed, decode_dss_signature,
                                                             encode_dss_signature)

from bridges.security import oer
from bridges.security.errors import SecurityError
from bridges.security.oer import SecurityFormatError

# 1609.2 Time32/Time64 count from 2004-01-01 00:00:00 (TAI). The simulation's
# clock has no leap seconds, so the offset to UTC is ignored here.
EPOCH_1609 = datetime(2004, 1, 1, tzinfo=timezone.utc)
_CURVE = ec.SECP256R1()
_N = int("FFFFFFFF00000000FFFFFFFFFFFFFFFFBCE6FAADA7179E84F3B9CAC2FC632551", 16)  # P-256 order

DURATION_SECONDS = {"microseconds": 1e-6, "milliseconds": 1e-3, "seconds": 1, "minutes": 60,
                    "hours": 3600, "sixtyHours": 216000, "years": 31556952}
DURATION_US = {"microseconds": 1, "milliseconds": 1000, "seconds": 10**6, "minutes": 60 * 10**6,
               "hours": 3600 * 10**6, "sixtyHours": 216000 * 10**6, "years": 31556952 * 10**6}
SIGNATURE_R_FORM = "x-only"  # the one EccP256CurvePoint form a signature's r may take
KEY_FORMS = ("compressed-y-0", "compressed-y-1")  # the forms a verification key may take


def time32(moment: datetime) -> int:
    """Seconds since the 1609.2 epoch."""
    return int((moment - EPOCH_1609).total_seconds())


def time64_us(unix_seconds: float) -> int:
    """Microseconds since the 1609.2 epoch, from Unix time."""
    return round((unix_seconds - EPOCH_1609.timestamp()) * 1e6)


def to_time64(moment: datetime | int) -> int:
    """A moment as Time64 (µs since the 1609.2 epoch): an int already is one; an aware datetime is converted.

    A float is refused rather than guessed at: Unix seconds and Time64
    microseconds are both plain numbers, and mixing them up would put a
    message decades off. Convert Unix time with time64_us().
    """
    if isinstance(moment, datetime):
        if moment.tzinfo is None or moment.utcoffset() is None:
            raise SecurityError(f"time {moment.isoformat()} has no time zone: give an aware datetime "
                                f"(e.g. tzinfo=timezone.utc)")
        return (moment - EPOCH_1609) // timedelta(microseconds=1)
    if isinstance(moment, Integral) and not isinstance(moment, bool):
        return int(moment)
    raise SecurityError(f"time {moment!r} ({type(moment).__name__}): expected an aware datetime or 1609.2 "
                        f"Time64 microseconds as an int (time64_us(unix_seconds) converts Unix time)")


def sha256(data: bytes) -> bytes:
    return hashlib.sha256(data).digest()


def hashed_id8(certificate_bytes: bytes) -> bytes:
    """HashedId8: the low-order 8 bytes of SHA-256 over the certificate's COER encoding."""
    return sha256(certificate_bytes)[-8:]


def signing_digest(tbs: bytes, signer_certificate: bytes | None) -> bytes:
    """1609.2 §5.3.1: H(H(data) || H(signer)); an empty signer input for self-signed data."""
    return sha256(sha256(tbs) + sha256(signer_certificate or b""))


def public_point(key: ec.EllipticCurvePublicKey) -> tuple[str, bytes]:
    """The key as a 1609.2 EccP256CurvePoint in compressed form."""
    raw = key.public_bytes(serialization.Encoding.X962, serialization.PublicFormat.CompressedPoint)
    return ("compressed-y-0" if raw[0] == 2 else "compressed-y-1", raw[1:])


def key_from_point(point: tuple[str, Any]) -> ec.EllipticCurvePublicKey:
    """The key of a compressed EccP256CurvePoint; SecurityFormatError for any other form (see KEY_FORMS)."""
    kind, value = point
    if kind not in KEY_FORMS:
        raise SecurityFormatError(f"verification key given as {kind!r}; only the compressed forms "
                                  f"({', '.join(KEY_FORMS)}) are accepted")
    raw = (b"\x02" if kind == "compressed-y-0" else b"\x03") + value
    try:
        return ec.EllipticCurvePublicKey.from_encoded_point(_CURVE, raw)
    except ValueError:
        raise SecurityFormatError("verification key is not a point on P-256") from None


def sign_digest(key: ec.EllipticCurvePrivateKey, digest: bytes) -> tuple[str, dict[str, Any]]:
    """An ecdsaNistP256Signature (r as x-only) over a precomputed SHA-256 digest."""
    r, s = decode_dss_signature(key.sign(digest, ec.ECDSA(Prehashed(hashes.SHA256()))))
    return ("ecdsaNistP256Signature", {"rSig": ("x-only", r.to_bytes(32, "big")),
                                       "sSig": s.to_bytes(32, "big")})


def signature_form_problem(signature: tuple[str, Any]) -> str | None:
    """Why an ecdsaNistP256Signature is not in the one form this project signs, or None.

    sign_digest writes r as x-only, reduced mod n. The same r labelled
    compressed-y-0/1 (or given as r + n) still verifies arithmetically, so
    accepting it would let anyone re-spell a signed message into new bytes.
    Other signature algorithms are not a form question: verify_digest refuses them.
    """
    kind, value = signature
    if kind != "ecdsaNistP256Signature":
        return None
    point_kind, r_bytes = value["rSig"]
    if point_kind != SIGNATURE_R_FORM:
        return f"signature r given as {point_kind}; only {SIGNATURE_R_FORM} is accepted"
    if int.from_bytes(r_bytes, "big") >= _N:
        return "signature r is not reduced modulo the group order"
    return None


def verify_digest(key: ec.EllipticCurvePublicKey, digest: bytes, signature: tuple[str, Any]) -> bool:
    kind, value = signature
    if kind != "ecdsaNistP256Signature" or signature_form_problem(signature) is not None:
        return False
    r = int.from_bytes(value["rSig"][1], "big")
    s = int.from_bytes(value["sSig"], "big")
    if not (0 < r < _N and 0 < s < _N):
        return False
    try:
        key.verify(encode_dss_signature(r, s), digest, ec.ECDSA(Prehashed(hashes.SHA256())))
        return True
    except InvalidSignature:
        return False


@dataclass
class Certificate:
    """A decoded 1609.2 explicit certificate with its COER bytes."""

    encoded: bytes
    fields: dict[str, Any] = field(repr=False)

    @classmethod
    def from_bytes(cls, data: bytes) -> "Certificate":
        """Only the canonical encoding: the certificate's digest (its HashedId8) is taken over these bytes."""
        return cls(bytes(data), oer.decode_canonical("Certificate", data))

    @property
    def digest(self) -> bytes:
        return hashed_id8(self.encoded)

    @property
    def name(self) -> str:
        kind, value = self.fields["toBeSigned"]["id"]
        return value if kind == "name" else f"<{kind}>"

    @property
    def psids(self) -> set[int]:
        return {p["psid"] for p in self.fields["toBeSigned"].get("appPermissions", ())}

    @property
    def self_signed(self) -> bool:
        return self.fields["issuer"][0] == "self"

    @property
    def issuer_digest(self) -> bytes | None:
        kind, value = self.fields["issuer"]
        return value if kind == "sha256AndDigest" else None

    def validity(self) -> tuple[float, float]:
        """(start, end) in seconds since the 1609.2 epoch."""
        period = self.fields["toBeSigned"]["validityPeriod"]
        unit, count = period["duration"]
        return float(period["start"]), period["start"] + count * DURATION_SECONDS[unit]

    def validity_us(self) -> tuple[int, int]:
        """(start, end) as Time64, exact: what a receiver's clock (Time64) is compared with."""
        period = self.fields["toBeSigned"]["validityPeriod"]
        unit, count = period["duration"]
        start = period["start"] * 10**6
        return start, start + count * DURATION_US[unit]

    def public_key(self) -> ec.EllipticCurvePublicKey:
        kind, value = self.fields["toBeSigned"]["verifyKeyIndicator"]
        if kind != "verificationKey" or value[0] != "ecdsaNistP256":
            raise SecurityFormatError(f"certificate {self.name!r} has no explicit P-256 verification key")
        return key_from_point(value[1])

    def tbs_bytes(self) -> bytes:
        return oer.encode("ToBeSignedCertificate", self.fields["toBeSigned"])

    def signed_by(self, issuer: "Certificate | None") -> bool:
        """True when this certificate's signature verifies with `issuer`'s key (None: self-signed)."""
        signature = self.fields.get("signature")
        if signature is None:
            return False
        signer = issuer or self
        digest = signing_digest(self.tbs_bytes(), None if issuer is None else issuer.encoded)
        return verify_digest(signer.public_key(), digest, signature)


@dataclass
class Credentials:
    """A station's (or the CA's) certificate and private key."""

    certificate: Certificate
    key: ec.EllipticCurvePrivateKey

    @property
    def name(self) -> str:
        return self.certificate.name

    def save(self, directory: str | Path) -> tuple[Path, Path]:
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        cert_path, key_path = directory / f"{self.name}.cert", directory / f"{self.name}.key"
        cert_path.write_bytes(self.certificate.encoded)
        key_path.write_bytes(self.key.private_bytes(serialization.Encoding.PEM,
                                                    serialization.PrivateFormat.PKCS8,
                                                    serialization.NoEncryption()))
        key_path.chmod(0o600)
        return cert_path, key_path


def load_certificate(path: str | Path) -> Certificate:
    path = Path(path)
    try:
        return Certificate.from_bytes(path.read_bytes())
    except OSError as exc:
        raise SecurityFormatError(f"{path}: cannot read certificate: {exc.strerror}") from None
    except SecurityFormatError as exc:
        raise SecurityFormatError(f"{path}: not a 1609.2 certificate: {exc.reason}") from None


def load_credentials(directory: str | Path, name: str) -> Credentials:
    """`<name>.cert` and `<name>.key` from `directory`; the key must match the certificate."""
    directory = Path(directory)
    certificate = load_certificate(directory / f"{name}.cert")
    key_path = directory / f"{name}.key"
    try:
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
    except OSError as exc:
        raise SecurityFormatError(f"{key_path}: cannot read key: {exc.strerror}") from None
    except (ValueError, TypeError) as exc:
        raise SecurityFormatError(f"{key_path}: not an unencrypted PEM private key: {exc}") from None
    if not isinstance(key, ec.EllipticCurvePrivateKey) or not isinstance(key.curve, ec.SECP256R1):
        raise SecurityFormatError(f"{key_path}: not a P-256 key")
    if public_point(key.public_key()) != certificate.fields["toBeSigned"]["verifyKeyIndicator"][1][1]:
        raise SecurityFormatError(f"{key_path}: key does not match {name}.cert")
    return Credentials(certificate, key)


def _certificate(name: str, key: ec.EllipticCurvePrivateKey, start_us: int, hours: int,
                 psids: list[int] | None, issuer: Credentials | None) -> Credentials:
    tbs: dict[str, Any] = {
        "id": ("name", name),
        "cracaId": b"\x00\x00\x00",
        "crlSeries": 0,
        "validityPeriod": {"start": start_us // 10**6, "duration": ("hours", hours)},  # Time32: whole seconds
        "verifyKeyIndicator": ("verificationKey", ("ecdsaNistP256", public_point(key.public_key()))),
    }
    if psids:
        tbs["appPermissions"] = [{"psid": int(p)} for p in psids]
    digest = signing_digest(oer.encode("ToBeSignedCertificate", tbs),
                            None if issuer is None else issuer.certificate.encoded)
    signer_key = key if issuer is None else issuer.key
    fields = {
        "version": 3,
        "type": "explicit",
        "issuer": ("self", "sha256") if issuer is None else ("sha256AndDigest", issuer.certificate.digest),
        "toBeSigned": tbs,
        "signature": sign_digest(signer_key, digest),
    }
    return Credentials(Certificate(oer.encode("Certificate", fields), fields), key)


class ScenarioCA:
    """Issues station certificates under one self-signed root."""

    def __init__(self, credentials: Credentials):
        self.credentials = credentials

    @classmethod
    def create(cls, name: str = "v2i-scenario-ca", start: datetime | int | None = None,
               hours: int = 24 * 365) -> "ScenarioCA":
        """A new root valid from `start` (a datetime or Time64; default now) for `hours`."""
        return cls(_certificate(name, ec.generate_private_key(_CURVE), _start_us(start), hours, None, None))

    @classmethod
    def load(cls, directory: str | Path, name: str = "v2i-scenario-ca") -> "ScenarioCA":
        return cls(load_credentials(directory, name))

    @property
    def certificate(self) -> Certificate:
        return self.credentials.certificate

    def issue(self, name: str, psids: list[int], start: datetime | int | None = None,
              hours: int = 24 * 30) -> Credentials:
        """A station certificate for `psids`, valid from `start` (a datetime or Time64; default now) for `hours`."""
        if not psids:
            raise SecurityError(f"station {name!r}: give at least one PSID it may sign for")
        return _certificate(name, ec.generate_private_key(_CURVE), _start_us(start), hours, psids,
                            self.credentials)


def _start_us(start: datetime | int | None) -> int:
    return to_time64(datetime.now(timezone.utc) if start is None else start)
