"""Bytes from the network: the decoder raises only J2735Error, never hangs or crashes.

Property-based round trips of generated messages (hypothesis), and a mutation
test that flips, truncates and extends every interop vector thousands of times.
"""
from __future__ import annotations

import random
import time

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bridges.j2735 import J2735Error, default_codec
from bridges.j2735.bsm import Bsm, EmergencyInfo
from bridges.security import Rejection, ScenarioCA, Signer, VerificationError, Verifier, time64_us
from test_j2735_vectors import VECTORS

MUTATIONS_PER_VECTOR = 400
optional = lambda strategy: st.one_of(st.none(), strategy)  # noqa: E731

bsms = st.builds(
    Bsm,
    temporary_id=st.binary(min_size=4, max_size=4),
    msg_count=st.integers(0, 127),
    sec_mark_ms=optional(st.integers(0, 60999)),
    latitude=optional(st.floats(-90, 90)),
    longitude=optional(st.floats(-179.9999999, 180)),
    elevation=optional(st.floats(-409.5, 6143.9)),
    speed=optional(st.floats(0, 163.8)),
    heading=optional(st.floats(-720, 720)),
    steering_angle=optional(st.floats(-189, 189)),
    accel_long=optional(st.floats(-20, 20)),
    yaw_rate=st.floats(-327.67, 327.67),
    transmission=st.sampled_from(["neutral", "park", "forwardGears", "reverseGears", "unavailable"]),
    width=optional(st.floats(0.01, 10.23)),
    length=optional(st.floats(0.01, 40.95)),
    emergency=optional(st.builds(EmergencyInfo, siren=st.sampled_from(["unavailable", "notInUse", "inUse"]),
                                 lightbar=st.sampled_from(["unavailable", "inUse", "freqStops"]),
                                 response_type=optional(st.sampled_from(["emergency", "pursuit"])))),
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(bsms)
def test_generated_bsms_round_trip_to_identical_bytes(bsm):
    data = bsm.encode()
    back = Bsm.decode(data)
    assert back.encode() == data
    if bsm.latitude is not None:
        assert abs(back.latitude - bsm.latitude) <= 0.5e-7 + 1e-12
    if bsm.speed is not None:
        assert abs(back.speed - bsm.speed) <= 0.01 + 1e-12


@settings(max_examples=500, deadline=None)
@given(st.binary(max_size=300))
def test_arbitrary_bytes_raise_only_the_codec_error(data):
    try:
        frame = default_codec().decode(data)
    except J2735Error as exc:
        assert exc.reason
    else:
        assert frame.length <= len(data)


def _mutants(data: bytes, rng: random.Random):
    for _ in range(MUTATIONS_PER_VECTOR):
        kind = rng.randrange(5)
        buf = bytearray(data)
        if kind == 0:  # flip 1..3 bits
            for _ in range(rng.randint(1, 3)):
                buf[rng.randrange(len(buf))] ^= 1 << rng.randrange(8)
        elif kind == 1:  # truncate
            del buf[rng.randrange(len(buf)):]
        elif kind == 2:  # extend
            buf += rng.randbytes(rng.randint(1, 64))
        elif kind == 3:  # overwrite a byte (length determinants, choice indexes)
            buf[rng.randrange(len(buf))] = rng.randrange(256)
        else:  # delete or insert a byte in the middle
            position = rng.randrange(len(buf))
            if rng.random() < 0.5:
                del buf[position]
            else:
                buf.insert(position, rng.randrange(256))
        yield bytes(buf)


def test_mutated_vectors_never_crash_the_decoder():
    codec, rng = default_codec(), random.Random(20261122)
    decoded = rejected = 0
    for vector in VECTORS:
        for mutant in _mutants(bytes.fromhex(vector["hex"]), rng):
            try:
                frame = codec.decode(mutant)
            except J2735Error as exc:
                assert exc.reason
                rejected += 1
                continue
            decoded += 1
            if frame.message is not None:  # what decodes must encode again, or fail with the codec's error
                try:
                    codec.encode(frame.message_id, frame.message)
                except J2735Error:
                    pass
    assert decoded + rejected == len(VECTORS) * MUTATIONS_PER_VECTOR >= 20000
    assert rejected > 1000 and decoded > 1000  # both paths were exercised


def test_mutated_envelopes_are_rejected_with_a_reason_never_a_crash():
    ca = ScenarioCA.create()
    rsu = ca.issue("rsu1", [0x7F])
    signer, rng = Signer(rsu), random.Random(7)
    now = time64_us(time.time())
    data = signer.sign(b"\x00\x14" + bytes(30), 0x7F, now)
    learn = Signer(rsu).sign(b"\x00\x14" + bytes(31), 0x7F, now)
    reasons = set()
    for mutant in _mutants(data, rng):
        # a receiver that knows the certificate (so a mutant may take the digest path) and has accepted
        # nothing with data's signed content: a mutant accepted earlier (trailing bytes are tolerated) would
        # make every later one with the same content a replay, refused before its signature is checked
        verifier = Verifier([ca.certificate])
        verifier.verify(learn, now)
        try:
            verifier.verify(mutant, now)
        except VerificationError as exc:
            reasons.add(exc.reason)
    assert Rejection.MALFORMED in reasons and Rejection.BAD_SIGNATURE in reasons
