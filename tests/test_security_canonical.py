"""Canonical encodings only: each other spelling of a valid signed frame is refused with its own reason.

Every mutant here decodes (leniently) to the same value as the valid frame it
comes from, or verifies arithmetically with the same key, so before these
checks it was a second valid frame for one signed message.
"""
from __future__ import annotations

import copy
from datetime import datetime, timedelta, timezone

import pytest
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.asymmetric.utils import Prehashed, encode_dss_signature

from bridges.j2735.bsm import surrogate_bsm
from bridges.security import (PSID_SURROGATE_BSM, Certificate, Credentials, Rejection, ScenarioCA, SecurityFormatError,
                              Signer, VerificationError, Verifier, load_certificate, to_time64)
from bridges.security import oer
from bridges.security.certificates import signing_digest

CANONICAL_REASONS = {Rejection.TRAILING_BYTES, Rejection.NONZERO_PADDING, Rejection.NON_CANONICAL,
                     Rejection.SIGNATURE_FORM}
NOW = datetime.now(timezone.utc)
NOW_US = to_time64(NOW)
START = NOW - timedelta(hours=1)
N = int("FFFFFFFF00000000FFFFFFFFFFFFFFFFBCE6FAADA7179E84F3B9CAC2FC632551", 16)  # the P-256 group order
SIGNERS = ["certificate", "digest"]


@pytest.fixture(scope="module")
def pki():
    ca = ScenarioCA.create(start=START)
    return ca, ca.issue("rsu1", [PSID_SURROGATE_BSM], start=START)


def _payload() -> bytes:
    return surrogate_bsm(3, b"salt", latitude=42.0, longitude=-83.0, speed=10.0, heading=90.0).encode()


def _frame(pki, signer_identifier: str) -> bytes:
    return Signer(pki[1], signer_identifier=signer_identifier).sign(_payload(), PSID_SURROGATE_BSM, NOW_US)


def _verifier(pki) -> Verifier:
    """Knows the station certificate, so a digest-signed frame would verify."""
    return Verifier([pki[0].certificate], stations=[pki[1].certificate])


def _reason(pki, data: bytes) -> VerificationError:
    with pytest.raises(VerificationError) as info:
        _verifier(pki).verify(data, NOW_US)
    return info.value


@pytest.mark.parametrize("mode", SIGNERS)
def test_the_valid_frame_is_canonical_and_verifies(pki, mode):
    data = _frame(pki, mode)
    assert oer.encode("Ieee1609Dot2Data", oer.decode("Ieee1609Dot2Data", data)) == data
    assert _verifier(pki).verify(data, NOW_US).payload == _payload()


@pytest.mark.parametrize("extra", [b"\x00", b"\x03\x81", bytes(40)])
@pytest.mark.parametrize("mode", SIGNERS)
def test_trailing_bytes_are_refused(pki, mode, extra):
    data = _frame(pki, mode)
    mutant = data + extra
    assert oer.decode("Ieee1609Dot2Data", mutant) == oer.decode("Ieee1609Dot2Data", data)  # the same value
    error = _reason(pki, mutant)
    assert error.reason is Rejection.TRAILING_BYTES
    assert f"{len(extra)} trailing byte" in error.detail


def _ignored_bits(data: bytes):
    """Every (offset, bit) that, set in `data`, leaves the decoded value unchanged: bits the decoder ignores."""
    value = oer.decode("Ieee1609Dot2Data", data)
    for offset, byte in enumerate(data):
        for bit in range(8):
            if byte & (1 << bit):
                continue
            mutant = bytearray(data)
            mutant[offset] |= 1 << bit
            try:
                same = oer.decode("Ieee1609Dot2Data", bytes(mutant)) == value
            except SecurityFormatError:
                continue
            if same:
                yield offset, bit, bytes(mutant)


@pytest.mark.parametrize("mode", SIGNERS)
def test_every_padding_bit_set_is_refused(pki, mode):
    data = _frame(pki, mode)
    # byte 3 is SignedDataPayload's presence bitmap: extension bit 0, data present 1, extDataHash present 1,
    # then five padding bits (0x60 = 0b011_00000)
    assert data[:4] == bytes([3, 0x81, 0x00, 0x60])  # version 3, signedData, hashId sha256, the bitmap
    ignored = list(_ignored_bits(data))
    assert {(3, bit) for bit in range(5)} <= {(offset, bit) for offset, bit, _ in ignored}
    for offset, bit, mutant in ignored:
        error = _reason(pki, mutant)
        assert error.reason is Rejection.NONZERO_PADDING, (offset, bit, error)
        assert f"byte {offset} bits {1 << bit:#04x}" in error.detail


@pytest.mark.parametrize("mode", SIGNERS)
def test_a_long_form_length_is_refused(pki, mode):
    """The inner payload's length 0x2d re-spelt 0x81 0x2d (long form, one length byte): same value, one byte more."""
    data, payload = _frame(pki, mode), _payload()
    assert len(payload) < 128
    inner = bytes([3, 0x80, len(payload)]) + payload  # Ieee1609Dot2Data { 3, unsecuredData (payload) }
    at = data.index(inner) + 2
    mutant = data[:at] + b"\x81" + data[at:]
    assert oer.decode("Ieee1609Dot2Data", mutant) == oer.decode("Ieee1609Dot2Data", data)
    assert _reason(pki, mutant).reason is Rejection.NON_CANONICAL


def _with_r(data: bytes, form: str, r_shift: int = 0) -> bytes:
    envelope = oer.decode("Ieee1609Dot2Data", data)
    signature = envelope["content"][1]["signature"][1]
    kind, r = signature["rSig"]
    assert kind == "x-only"  # what the project signs
    signature["rSig"] = (form, (int.from_bytes(r, "big") + r_shift).to_bytes(32, "big"))
    return oer.encode("Ieee1609Dot2Data", envelope)


def _arithmetically_valid(pki, data: bytes) -> bool:
    """The mutant's (r mod n, s) is a valid ECDSA signature of the frame's signed content: only its form differs."""
    signed = oer.decode("Ieee1609Dot2Data", data)["content"][1]
    digest = signing_digest(oer.encode("ToBeSignedData", signed["tbsData"]), pki[1].certificate.encoded)
    r = int.from_bytes(signed["signature"][1]["rSig"][1], "big") % N
    s = int.from_bytes(signed["signature"][1]["sSig"], "big")
    pki[1].key.public_key().verify(encode_dss_signature(r, s), digest, ec.ECDSA(Prehashed(hashes.SHA256())))
    return True


@pytest.mark.parametrize("form", ["compressed-y-0", "compressed-y-1"])
@pytest.mark.parametrize("mode", SIGNERS)
def test_a_signature_r_relabelled_as_another_point_form_is_refused(pki, mode, form):
    mutant = _with_r(_frame(pki, mode), form)
    assert _arithmetically_valid(pki, mutant)
    error = _reason(pki, mutant)
    assert error.reason is Rejection.SIGNATURE_FORM and form in error.detail


def test_a_signature_r_not_reduced_modulo_n_is_refused(pki):
    """r + n spells the same r when it fits in 32 bytes (only for r < 2^256 - n, odds about 2^-32 per
    signature, so no valid mutant can be made here): any r >= n is refused for its form, not its arithmetic."""
    data = _frame(pki, "certificate")
    envelope = oer.decode("Ieee1609Dot2Data", data)
    signature = envelope["content"][1]["signature"][1]
    signature["rSig"] = ("x-only", (N + 5).to_bytes(32, "big"))
    error = _reason(pki, oer.encode("Ieee1609Dot2Data", envelope))
    assert error.reason is Rejection.SIGNATURE_FORM and "not reduced" in error.detail


def test_a_station_certificate_whose_ca_signature_r_is_relabelled_is_refused(pki):
    """The same r in another form would make another certificate (another digest) for the same station."""
    ca, station = pki
    fields = copy.deepcopy(station.certificate.fields)
    fields["signature"][1]["rSig"] = ("compressed-y-0", fields["signature"][1]["rSig"][1])
    relabelled = Credentials(Certificate(oer.encode("Certificate", fields), fields), station.key)
    data = Signer(relabelled).sign(b"x", PSID_SURROGATE_BSM, NOW_US)
    with pytest.raises(VerificationError) as info:
        Verifier([ca.certificate]).verify(data, NOW_US)
    assert info.value.reason is Rejection.SIGNATURE_FORM and "certificate 'rsu1'" in info.value.detail


def test_unsecured_frames_must_be_canonical_too(pki):
    lenient = Verifier([pki[0].certificate], allow_unsecured=True)
    data = oer.unsecured(b"\x00\x14abc")
    assert lenient.verify(data, NOW_US).payload == b"\x00\x14abc"
    with pytest.raises(VerificationError) as info:
        lenient.verify(data + b"\x00", NOW_US)
    assert info.value.reason is Rejection.TRAILING_BYTES


def test_certificate_files_must_be_canonical(pki, tmp_path):
    path = tmp_path / "rsu1.cert"
    path.write_bytes(pki[1].certificate.encoded + b"\x00")
    with pytest.raises(SecurityFormatError, match="rsu1.cert: not a 1609.2 certificate: .*1 trailing byte"):
        load_certificate(path)


def test_only_compressed_verification_keys_are_accepted(pki):
    """An uncompressed key would be a second encoding of the same certificate content."""
    from bridges.security.certificates import key_from_point

    numbers = pki[1].key.public_key().public_numbers()
    point = ("uncompressedP256", {"x": numbers.x.to_bytes(32, "big"), "y": numbers.y.to_bytes(32, "big")})
    with pytest.raises(SecurityFormatError, match="only the compressed forms"):
        key_from_point(point)
