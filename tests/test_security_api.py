"""The security API's conventions: one way to give a time, a named signing mode, typed errors."""
from __future__ import annotations

from datetime import datetime, timedelta, timezone

import pytest

from bridges.security import (PSID_BSM, PSID_SURROGATE_BSM, PsidNotPermitted, Rejection, ScenarioCA, SecurityError,
                              Signer, VerificationError, Verifier, time64_us, to_time64)
from bridges.security import oer

NOW = datetime.now(timezone.utc).replace(microsecond=250_000)
NOW_US = to_time64(NOW)
START = NOW - timedelta(hours=1)
MS = 1000


@pytest.fixture(scope="module")
def pki():
    ca = ScenarioCA.create(start=START)
    return ca, ca.issue("rsu1", [PSID_SURROGATE_BSM], start=START)


def _signer_kind(data: bytes) -> str:
    return oer.decode("Ieee1609Dot2Data", data)["content"][1]["signer"][0]


# --- time: Time64 int or an aware datetime, everywhere ----------------------------------------------

def test_a_datetime_and_its_time64_are_the_same_moment():
    assert to_time64(NOW) == NOW_US == time64_us(NOW.timestamp())
    assert to_time64(datetime(2004, 1, 1, 0, 0, 1, 7, tzinfo=timezone.utc)) == 1_000_007  # exact, from the epoch
    assert to_time64(NOW.astimezone(timezone(timedelta(hours=-5)))) == NOW_US  # any zone


def test_issue_sign_and_verify_take_either_form(pki):
    ca = pki[0]
    by_datetime = ca.issue("a", [PSID_SURROGATE_BSM], start=START)
    by_time64 = ca.issue("b", [PSID_SURROGATE_BSM], start=to_time64(START))
    assert by_datetime.certificate.validity_us() == by_time64.certificate.validity_us()
    assert by_datetime.certificate.validity_us()[0] == to_time64(START) // 10**6 * 10**6  # Time32: whole seconds
    signer = Signer(by_datetime, signer_identifier="certificate")
    generated = lambda data: oer.decode("Ieee1609Dot2Data", data)["content"][1]["tbsData"]["headerInfo"][  # noqa
        "generationTime"]
    assert generated(signer.sign(b"x", PSID_SURROGATE_BSM, NOW)) == generated(
        signer.sign(b"x", PSID_SURROGATE_BSM, NOW_US)) == NOW_US
    verified = Verifier([ca.certificate]).verify(signer.sign(b"x", PSID_SURROGATE_BSM, NOW), NOW + timedelta(
        milliseconds=20))
    assert verified.generation_time_us == NOW_US  # what comes back is Time64
    # the same frame, verified with the clock as Time64
    again = Verifier([ca.certificate]).verify(signer.sign(b"y", PSID_SURROGATE_BSM, NOW_US), NOW_US + 20 * MS)
    assert again.generation_time_us == NOW_US


@pytest.mark.parametrize("moment, reason", [
    (datetime(2026, 6, 1, 12, 0), "no time zone"),
    (1_780_000_000.0, "time64_us"),  # Unix seconds as a float: refused, not guessed at
    ("2026-06-01", "expected an aware datetime"),
    (True, "expected an aware datetime"),
])
def test_a_time_in_another_form_is_refused_with_the_convention(pki, moment, reason):
    with pytest.raises(SecurityError, match=reason):
        Signer(pki[1]).sign(b"x", PSID_SURROGATE_BSM, moment)
    with pytest.raises(SecurityError, match=reason):
        Verifier([pki[0].certificate]).verify(b"\x03", moment)
    with pytest.raises(SecurityError, match=reason):
        pki[0].issue("c", [PSID_SURROGATE_BSM], start=moment)


# --- the signer identifier: periodic (default), certificate, digest --------------------------------

def test_periodic_is_the_default_full_certificate_once_per_interval(pki):
    signer = Signer(pki[1])
    assert signer.signer_identifier == "periodic"
    kinds = [_signer_kind(signer.sign(b"x", PSID_SURROGATE_BSM, NOW_US + t * MS)) for t in range(0, 2100, 100)]
    assert [t for t, k in zip(range(0, 2100, 100), kinds) if k == "certificate"] == [0, 1000, 2000]


@pytest.mark.parametrize("mode, kind", [("certificate", "certificate"), ("digest", "digest")])
def test_a_fixed_signer_identifier_is_used_for_every_message(pki, mode, kind):
    signer = Signer(pki[1], signer_identifier=mode)
    assert {_signer_kind(signer.sign(b"x", PSID_SURROGATE_BSM, NOW_US + t * MS)) for t in range(0, 1500, 100)} \
        == {kind}


def test_one_message_can_override_the_mode_and_a_forced_certificate_restarts_the_interval(pki):
    signer = Signer(pki[1])
    assert _signer_kind(signer.sign(b"a", PSID_SURROGATE_BSM, NOW_US)) == "certificate"
    assert _signer_kind(signer.sign(b"b", PSID_SURROGATE_BSM, NOW_US + 500 * MS,
                                    signer_identifier="certificate")) == "certificate"
    # the periodic one is next due 1 s after the forced one, not after the first
    assert _signer_kind(signer.sign(b"c", PSID_SURROGATE_BSM, NOW_US + 1000 * MS)) == "digest"
    assert _signer_kind(signer.sign(b"d", PSID_SURROGATE_BSM, NOW_US + 1500 * MS)) == "certificate"
    assert _signer_kind(signer.sign(b"e", PSID_SURROGATE_BSM, NOW_US + 3000 * MS, signer_identifier="digest")) \
        == "digest"


def test_digest_only_frames_verify_where_the_station_certificate_was_provisioned(pki):
    ca, station = pki
    frame = Signer(station, signer_identifier="digest").sign(b"x", PSID_SURROGATE_BSM, NOW_US)
    with pytest.raises(VerificationError) as info:
        Verifier([ca.certificate]).verify(frame, NOW_US)
    assert info.value.reason is Rejection.UNKNOWN_SIGNER
    assert Verifier([ca.certificate], stations=[station.certificate]).verify(frame, NOW_US).signer == "rsu1"


def test_a_provisioned_station_from_another_ca_is_refused_at_construction(pki):
    rogue = ScenarioCA.create("rogue", start=START).issue("rsu9", [PSID_SURROGATE_BSM], start=START)
    with pytest.raises(SecurityError, match="station certificate 'rsu9': .*not issued by a trusted CA"):
        Verifier([pki[0].certificate], stations=[rogue.certificate])


def test_a_misspelt_signer_identifier_says_what_it_may_be(pki):
    with pytest.raises(SecurityError, match="signer_identifier 'digets'.*did you mean 'digest'"):
        Signer(pki[1], signer_identifier="digets")
    with pytest.raises(SecurityError, match="periodic, certificate, digest"):
        Signer(pki[1]).sign(b"x", PSID_SURROGATE_BSM, NOW_US, signer_identifier="full")


# --- a typed error for a PSID the certificate does not permit ------------------------------------

def test_signing_under_a_psid_the_certificate_does_not_list_raises_psid_not_permitted(pki):
    with pytest.raises(PsidNotPermitted) as info:
        Signer(pki[1]).sign(b"x", PSID_BSM, NOW_US)
    error = info.value
    assert (error.certificate, error.psid, error.permitted) == ("rsu1", PSID_BSM, {PSID_SURROGATE_BSM})
    assert isinstance(error, SecurityError) and isinstance(error, ValueError)  # old handlers still catch it
    assert "'rsu1' may not sign PSID 0x20 (permitted: 0x7f)" in str(error)
