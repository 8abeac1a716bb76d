"""The signed envelope under attack: expired CAs, forged chains, late joiners and replay memory."""
from __future__ import annotations

import copy
from datetime import datetime, timedelta, timezone

import pytest
from cryptography.hazmat.primitives.asymmetric import ec

from bridges.security import (PSID_SURROGATE_BSM, Certificate, Credentials, Rejection, ScenarioCA, Signer,
                              VerificationError, Verifier, time64_us)
from bridges.security import envelope, oer

NOW = datetime(2026, 6, 1, 12, 0, tzinfo=timezone.utc)
NOW_US = time64_us(NOW.timestamp())
START = NOW - timedelta(days=1)
MS = 1000  # microseconds


@pytest.fixture(scope="module")
def pki():
    ca = ScenarioCA.create(start=START)
    rsu = ca.issue("rsu1", [PSID_SURROGATE_BSM], start=START)
    return ca, rsu


def _reject(verifier, data, now_us):
    with pytest.raises(VerificationError) as info:
        verifier.verify(data, now_us)
    return info.value


# --- validity along the whole chain ---------------------------------------------------------------

@pytest.mark.parametrize("ca_start, ca_hours", [(NOW - timedelta(days=10), 24),  # expired
                                                (NOW + timedelta(days=1), 24)],  # not yet valid
                         ids=["expired", "not-yet-valid"])
def test_a_trust_anchor_outside_its_validity_vouches_for_nobody(ca_start, ca_hours):
    """The station certificate itself is valid now; only its CA is not."""
    ca = ScenarioCA.create(start=ca_start, hours=ca_hours)
    station = ca.issue("rsu1", [PSID_SURROGATE_BSM], start=START)
    error = _reject(Verifier([ca.certificate]), Signer(station).sign(b"x", PSID_SURROGATE_BSM, NOW_US), NOW_US)
    assert error.reason is Rejection.UNTRUSTED_SIGNER
    assert "CA certificate" in error.detail


def test_a_station_certificate_that_outlives_its_ca_stops_verifying_when_the_ca_expires():
    """Checked per message: a station certificate learnt while its CA was valid is refused afterwards."""
    ca = ScenarioCA.create(start=START, hours=25)  # expires one hour after NOW
    station = ca.issue("rsu1", [PSID_SURROGATE_BSM], start=START, hours=24 * 30)
    verifier = Verifier([ca.certificate])
    signer = Signer(station, certificate_interval_s=1e6)
    assert verifier.verify(signer.sign(b"a", PSID_SURROGATE_BSM, NOW_US), NOW_US).payload == b"a"
    later = NOW_US + 2 * 3600 * 10**6
    digest_signed = signer.sign(b"b", PSID_SURROGATE_BSM, later)
    assert _reject(verifier, digest_signed, later).reason is Rejection.UNTRUSTED_SIGNER


# --- a chain that names the trusted CA but does not verify with it --------------------------------

def _forged_by_another_key(ca: ScenarioCA) -> Credentials:
    """Issued with a key that is not the CA's, yet naming the trusted CA as issuer."""
    impostor = ScenarioCA(Credentials(ca.certificate, ec.generate_private_key(ec.SECP256R1())))
    return impostor.issue("rsu-forged", [PSID_SURROGATE_BSM], start=START)


def _signature_flipped(ca: ScenarioCA) -> Credentials:
    """A genuine station certificate with one bit of the CA's signature flipped."""
    genuine = ca.issue("rsu-flipped", [PSID_SURROGATE_BSM], start=START)
    fields = copy.deepcopy(genuine.certificate.fields)
    s = bytearray(fields["signature"][1]["sSig"])
    s[7] ^= 0x01
    fields["signature"][1]["sSig"] = bytes(s)
    return Credentials(Certificate(oer.encode("Certificate", fields), fields), genuine.key)


@pytest.mark.parametrize("forge", [_forged_by_another_key, _signature_flipped])
def test_a_station_certificate_naming_the_trusted_ca_with_a_bad_signature_is_untrusted(pki, forge):
    ca = pki[0]
    forged = forge(ca)
    assert forged.certificate.issuer_digest == ca.certificate.digest  # the right issuer digest
    verifier = Verifier([ca.certificate])
    signer = Signer(forged, certificate_interval_s=1.0)
    assert _reject(verifier, signer.sign(b"x", PSID_SURROGATE_BSM, NOW_US), NOW_US).reason \
        is Rejection.UNTRUSTED_SIGNER
    # ...and the refused certificate was not learnt: its digest-signed messages stay unverifiable
    follow_up = signer.sign(b"y", PSID_SURROGATE_BSM, NOW_US + 100 * MS)
    assert _reject(verifier, follow_up, NOW_US + 100 * MS).reason is Rejection.UNKNOWN_SIGNER


# --- once-a-second full-certificate re-send ---------------------------------------------------------

def test_a_late_joiner_verifies_from_the_next_full_certificate_message(pki):
    """10 Hz messages, full certificate once a second; the receiver joins at 0.3 s."""
    signer = Signer(pki[1], certificate_interval_s=1.0)
    frames = [(t, signer.sign(bytes([t // 100]), PSID_SURROGATE_BSM, NOW_US + t * MS)) for t in range(0, 1600, 100)]
    full = [t for t, data in frames if len(data) > len(frames[1][1])]
    assert full == [0, 1000]
    verifier = Verifier([pki[0].certificate])
    outcomes = {}
    for t, data in frames[3:]:
        try:
            outcomes[t] = verifier.verify(data, NOW_US + t * MS + 20 * MS).payload == bytes([t // 100])
        except VerificationError as exc:
            outcomes[t] = exc.reason
    assert outcomes == {**{t: Rejection.UNKNOWN_SIGNER for t in range(300, 1000, 100)},
                        **{t: True for t in range(1000, 1600, 100)}}


# --- replay memory: kept for the whole window, checked before ECDSA ---------------------------------

def test_a_replay_is_refused_after_thousands_of_other_messages_inside_the_window(pki):
    """The old memory held 4096 digests whatever the window; a busy channel flushed it."""
    verifier = Verifier([pki[0].certificate], max_age_s=10.0)
    signer = Signer(pki[1], certificate_interval_s=1e6)
    first = signer.sign(b"first", PSID_SURROGATE_BSM, NOW_US)
    verifier.verify(first, NOW_US)
    for i in range(1, 4200):
        verifier.verify(signer.sign(b"other", PSID_SURROGATE_BSM, NOW_US + i), NOW_US + i)
    assert _reject(verifier, first, NOW_US + 5 * 10**6).reason is Rejection.REPLAYED


def test_replay_memory_holds_only_the_window(pki):
    """10 Hz for 3 s with a 0.5 s window: at most the 6 messages generated in the last 0.5 s."""
    verifier = Verifier([pki[0].certificate], max_age_s=0.5)
    signer = Signer(pki[1])
    sent = []
    for t in range(0, 3000, 100):
        sent.append(signer.sign(b"x", PSID_SURROGATE_BSM, NOW_US + t * MS))
        verifier.verify(sent[-1], NOW_US + t * MS)
        assert verifier.remembered <= 6
    assert verifier.remembered == 6
    # a forgotten message is refused by the window it fell out of
    assert _reject(verifier, sent[0], NOW_US + 2900 * MS).reason is Rejection.OUTSIDE_TIME_WINDOW


def test_a_receiver_clock_stepping_back_does_not_reopen_forgotten_replays(pki):
    verifier = Verifier([pki[0].certificate], max_age_s=0.5)
    signer = Signer(pki[1])
    first = signer.sign(b"a", PSID_SURROGATE_BSM, NOW_US)
    verifier.verify(first, NOW_US)
    verifier.verify(signer.sign(b"b", PSID_SURROGATE_BSM, NOW_US + 2 * 10**6), NOW_US + 2 * 10**6)  # forgets `first`
    assert verifier.remembered == 1
    assert _reject(verifier, first, NOW_US + 10 * MS).reason is Rejection.OUTSIDE_TIME_WINDOW


def test_a_replay_is_refused_without_an_ecdsa_verification(pki, monkeypatch):
    """Byte-for-byte, or with the same signed content under another signature."""
    calls = []
    real = envelope.verify_digest
    monkeypatch.setattr(envelope, "verify_digest", lambda *args: calls.append(1) or real(*args))
    verifier = Verifier([pki[0].certificate])
    data = Signer(pki[1]).sign(b"x", PSID_SURROGATE_BSM, NOW_US)
    verifier.verify(data, NOW_US)
    assert len(calls) == 1
    assert _reject(verifier, data, NOW_US + 10 * MS).reason is Rejection.REPLAYED
    resigned = oer.decode("Ieee1609Dot2Data", data)
    signature = resigned["content"][1]["signature"][1]
    signature["sSig"] = bytes(31) + b"\x01"
    assert _reject(verifier, oer.encode("Ieee1609Dot2Data", resigned), NOW_US + 10 * MS).reason is Rejection.REPLAYED
    assert len(calls) == 1
