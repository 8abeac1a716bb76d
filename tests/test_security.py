"""The 1609.2-style envelope: each rejection reason has its own test."""
from __future__ import annotations

from datetime import datetime, timedelta, timezone

import pytest

from bridges.j2735.bsm import surrogate_bsm
from bridges.security import (PSID_BSM, PSID_SURROGATE_BSM, Rejection, ScenarioCA, SecurityFormatError, Signer,
                              VerificationError, Verifier, load_certificate, load_credentials, time64_us)
from bridges.security import oer

NOW = datetime(2026, 6, 1, 12, 0, tzinfo=timezone.utc)
NOW_US = time64_us(NOW.timestamp())
START = NOW - timedelta(days=1)


@pytest.fixture(scope="module")
def pki():
    ca = ScenarioCA.create(start=START)
    rsu = ca.issue("rsu1", [PSID_SURROGATE_BSM], start=START)
    return ca, rsu


@pytest.fixture
def verifier(pki):
    return Verifier([pki[0].certificate], max_age_s=0.5, max_future_s=0.05)


def _payload():
    return surrogate_bsm(3, b"salt", latitude=42.0, longitude=-83.0, speed=10.0, heading=90.0).encode()


def _reason(verifier, data, now=NOW_US):
    with pytest.raises(VerificationError) as info:
        verifier.verify(data, now)
    return info.value.reason


def test_signed_envelope_verifies_and_returns_the_payload(pki, verifier):
    payload = _payload()
    data = Signer(pki[1]).sign(payload, PSID_SURROGATE_BSM, NOW_US)
    result = verifier.verify(data, NOW_US + 20_000)
    assert (result.payload, result.psid, result.signer, result.secured) == (payload, PSID_SURROGATE_BSM, "rsu1", True)


def test_digest_signer_verifies_after_the_certificate_was_seen(pki, verifier):
    signer = Signer(pki[1], certificate_interval_s=1.0)
    first = signer.sign(b"a", PSID_SURROGATE_BSM, NOW_US)
    second = signer.sign(b"b", PSID_SURROGATE_BSM, NOW_US + 100_000)
    assert len(second) < len(first)  # digest only, within the certificate interval
    verifier.verify(first, NOW_US)
    assert verifier.verify(second, NOW_US + 100_000).payload == b"b"


def test_unknown_signer(pki, verifier):
    signer = Signer(pki[1])
    signer.sign(b"a", PSID_SURROGATE_BSM, NOW_US)  # the certificate went out in a message this receiver missed
    digest_only = signer.sign(b"b", PSID_SURROGATE_BSM, NOW_US + 1)
    assert _reason(verifier, digest_only) is Rejection.UNKNOWN_SIGNER


def test_untrusted_signer_from_another_ca(verifier):
    rogue_ca = ScenarioCA.create("rogue-ca", start=START)
    rogue = rogue_ca.issue("rsu1", [PSID_SURROGATE_BSM], start=START)
    assert _reason(verifier, Signer(rogue).sign(b"x", PSID_SURROGATE_BSM, NOW_US)) is Rejection.UNTRUSTED_SIGNER


def test_untrusted_signer_with_an_expired_certificate(pki, verifier):
    old = pki[0].issue("rsu-old", [PSID_SURROGATE_BSM], start=NOW - timedelta(days=10), hours=24)
    assert _reason(verifier, Signer(old).sign(b"x", PSID_SURROGATE_BSM, NOW_US)) is Rejection.UNTRUSTED_SIGNER


def test_psid_not_permitted(pki, verifier):
    """An RSU certified for surrogate BSMs (0x7F) cannot pass one off as a vehicle's own BSM (0x20)."""
    signer = Signer(pki[1])
    with pytest.raises(ValueError, match="may not sign PSID 0x20"):
        signer.sign(b"x", PSID_BSM, NOW_US)
    # a sender that ignores its own permissions is refused by the receiver
    forged = oer.decode("Ieee1609Dot2Data", signer.sign(b"x", PSID_SURROGATE_BSM, NOW_US))
    forged["content"][1]["tbsData"]["headerInfo"]["psid"] = PSID_BSM
    assert _reason(verifier, oer.encode("Ieee1609Dot2Data", forged)) is Rejection.PSID_NOT_PERMITTED


def test_altered_payload(pki, verifier):
    data = bytearray(Signer(pki[1]).sign(_payload(), PSID_SURROGATE_BSM, NOW_US))
    envelope = oer.decode("Ieee1609Dot2Data", bytes(data))
    inner = envelope["content"][1]["tbsData"]["payload"]["data"]
    inner["content"] = ("unsecuredData", inner["content"][1][:-1] + b"\x55")
    assert _reason(verifier, oer.encode("Ieee1609Dot2Data", envelope)) is Rejection.ALTERED_PAYLOAD


def test_bad_signature(pki, verifier):
    envelope = oer.decode("Ieee1609Dot2Data", Signer(pki[1]).sign(_payload(), PSID_SURROGATE_BSM, NOW_US))
    kind, signature = envelope["content"][1]["signature"]
    s = bytearray(signature["sSig"])
    s[5] ^= 0x01
    signature["sSig"] = bytes(s)
    assert _reason(verifier, oer.encode("Ieee1609Dot2Data", envelope)) is Rejection.BAD_SIGNATURE


def test_bad_signature_when_payload_and_its_digest_are_both_replaced(pki, verifier):
    import hashlib

    envelope = oer.decode("Ieee1609Dot2Data", Signer(pki[1]).sign(_payload(), PSID_SURROGATE_BSM, NOW_US))
    payload = envelope["content"][1]["tbsData"]["payload"]
    payload["data"]["content"] = ("unsecuredData", b"forged")
    payload["extDataHash"] = ("sha256HashedData", hashlib.sha256(b"forged").digest())
    assert _reason(verifier, oer.encode("Ieee1609Dot2Data", envelope)) is Rejection.BAD_SIGNATURE


@pytest.mark.parametrize("offset_us", [600_000, -60_000])
def test_generation_time_outside_the_window(pki, verifier, offset_us):
    data = Signer(pki[1]).sign(b"x", PSID_SURROGATE_BSM, NOW_US)
    assert _reason(verifier, data, now=NOW_US + offset_us) is Rejection.OUTSIDE_TIME_WINDOW
    # the window is configurable
    wide = Verifier([pki[0].certificate], max_age_s=1.0, max_future_s=0.1)
    assert wide.verify(data, NOW_US + offset_us).payload == b"x"


def test_replayed_message(pki, verifier):
    data = Signer(pki[1]).sign(b"x", PSID_SURROGATE_BSM, NOW_US)
    verifier.verify(data, NOW_US)
    assert _reason(verifier, data, now=NOW_US + 10_000) is Rejection.REPLAYED


@pytest.mark.parametrize("mutate", ["truncate", "version", "garbage", "empty"])
def test_malformed_envelope(pki, verifier, mutate):
    data = Signer(pki[1]).sign(b"x", PSID_SURROGATE_BSM, NOW_US)
    bad = {"truncate": data[:40], "version": b"\x02" + data[1:], "garbage": b"\xff" * 30, "empty": b""}[mutate]
    assert _reason(verifier, bad) is Rejection.MALFORMED


def test_unsecured_data_is_accepted_only_where_policy_allows(pki):
    data = oer.unsecured(b"\x00\x14payload")
    strict = Verifier([pki[0].certificate])
    assert _reason(strict, data) is Rejection.UNSECURED
    lenient = Verifier([pki[0].certificate], allow_unsecured=True)
    result = lenient.verify(data, NOW_US)
    assert result.payload == b"\x00\x14payload" and result.secured is False


def test_every_reason_has_a_test():
    tested = {Rejection.UNKNOWN_SIGNER, Rejection.UNTRUSTED_SIGNER, Rejection.PSID_NOT_PERMITTED,
              Rejection.ALTERED_PAYLOAD, Rejection.BAD_SIGNATURE, Rejection.OUTSIDE_TIME_WINDOW,
              Rejection.REPLAYED, Rejection.MALFORMED, Rejection.UNSECURED}
    from test_security_canonical import CANONICAL_REASONS  # each tested there with a mutant of a valid frame

    assert tested | CANONICAL_REASONS == set(Rejection)


def test_credentials_round_trip_through_files(pki, tmp_path):
    ca, rsu = pki
    ca.credentials.save(tmp_path)
    rsu.save(tmp_path)
    loaded = load_credentials(tmp_path, "rsu1")
    anchor = load_certificate(tmp_path / "v2i-scenario-ca.cert")
    data = Signer(loaded).sign(b"from files", PSID_SURROGATE_BSM, NOW_US)
    assert Verifier([anchor]).verify(data, NOW_US).payload == b"from files"
    assert (tmp_path / "rsu1.key").stat().st_mode & 0o077 == 0


def test_bad_credential_files_name_the_file_and_reason(pki, tmp_path):
    ca, rsu = pki
    rsu.save(tmp_path)
    (tmp_path / "other.cert").write_bytes(b"\x03\x00junk")
    with pytest.raises(SecurityFormatError, match="other.cert: not a 1609.2 certificate"):
        load_certificate(tmp_path / "other.cert")
    with pytest.raises(SecurityFormatError, match="missing.cert: cannot read"):
        load_credentials(tmp_path, "missing")
    other = ca.issue("rsu2", [PSID_SURROGATE_BSM], start=START)
    other.save(tmp_path)
    (tmp_path / "rsu2.cert").write_bytes(rsu.certificate.encoded)  # rsu2's key, rsu1's certificate
    with pytest.raises(SecurityFormatError, match="key does not match rsu2.cert"):
        load_credentials(tmp_path, "rsu2")
    (tmp_path / "rsu1.key").write_text("not a key")
    with pytest.raises(SecurityFormatError, match="rsu1.key: not an unencrypted PEM"):
        load_credentials(tmp_path, "rsu1")


def test_pki_cli_writes_a_ca_and_stations(tmp_path, capsys):
    from master.cli import main

    assert main(["pki", "init", str(tmp_path), "--station", "rsu1:0x7f,0x82", "--station", "cav:0x20"]) == 0
    assert load_credentials(tmp_path, "rsu1").certificate.psids == {0x7F, 0x82}
    assert main(["pki", "init", str(tmp_path)]) == 1  # never overwrites a CA
    assert main(["pki", "init", str(tmp_path / "x"), "--station", "rsu1"]) == 2
    assert "expected NAME:PSID" in capsys.readouterr().err
