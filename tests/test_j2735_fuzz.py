"""Bytes from the network: the decoder raises only J2735Error, never hangs or crashes.

Property-based round trips of generated messages (hypothesis: BSMs, SDSMs), a
mutation test that flips, truncates and extends every interop vector thousands
of times, and bad SDSMs built bit by bit (truncated, a field out of range, a
CHOICE index the message does not define, an extension of a later edition).
"""
from __future__ import annotations

import dataclasses
import random
import re
import time

import pytest

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bridges.j2735 import J2735Error, default_codec
from bridges.j2735 import sdsm as sd
from bridges.j2735.bsm import Bsm, EmergencyInfo
from bridges.security import Rejection, ScenarioCA, Signer, VerificationError, Verifier, time64_us
from test_j2735_sdsm import SDSM_VECTORS
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


# -- SDSMs (issue 40) ----------------------------------------------------------------------------------------------
def _names(scale: sd.ConfidenceScale):
    return st.sampled_from(scale.names)


def _opt_names(scale: sd.ConfidenceScale):
    return optional(_names(scale))


vehicle_details = st.builds(
    sd.VehicleDetails,
    lights=optional(st.frozensets(st.sampled_from(sd.EXTERIOR_LIGHTS))),
    attitude=optional(st.tuples(st.floats(-90, 90), st.floats(-180, 180), st.floats(-180, 180))),
    attitude_confidence=optional(st.tuples(*[_names(sd.HEADING_CONFIDENCE)] * 3)),
    angular_velocity=optional(st.tuples(st.floats(-327.67, 327.67), st.floats(-327.67, 327.67))),
    angular_velocity_confidence=optional(st.tuples(*[_opt_names(sd.ANGULAR_RATE_CONFIDENCE)] * 2)),
    width=optional(st.floats(0.01, 10.23)), length=optional(st.floats(0.01, 40.95)),
    height=optional(st.floats(0, 6.35)),
    size_confidence=optional(st.tuples(_names(sd.SIZE_CONFIDENCE), _names(sd.SIZE_CONFIDENCE),
                                       _opt_names(sd.SIZE_CONFIDENCE))),
    vehicle_class=optional(st.integers(0, 255)), class_confidence=optional(st.integers(0, 101)),
)
vru_details = st.builds(
    sd.VruDetails,
    basic_type=optional(st.sampled_from(sd.VRU_TYPES)),
    propulsion=optional(st.sampled_from(sorted(sd.PROPULSION)).flatmap(
        lambda kind: st.tuples(st.just(kind), st.sampled_from(sd.PROPULSION[kind])))),
    attachment=optional(st.sampled_from(sd.ATTACHMENTS)), radius=optional(st.floats(0, 20)),
)
obstacle_details = st.builds(
    sd.ObstacleDetails, width=st.floats(0, 102.3), length=st.floats(0, 102.3), height=optional(st.floats(0, 102.3)),
    width_confidence=_names(sd.SIZE_CONFIDENCE), length_confidence=_names(sd.SIZE_CONFIDENCE),
    height_confidence=_opt_names(sd.SIZE_CONFIDENCE),
)
detected_objects = st.builds(
    sd.DetectedObject,
    object_id=st.integers(0, 65535), object_type=st.sampled_from(sd.OBJECT_TYPES),
    type_confidence=st.integers(0, 101), measurement_time=st.floats(-1.5, 1.5),
    time_confidence=_names(sd.TIME_CONFIDENCE),
    offset_x=st.floats(-3276.7, 3276.7), offset_y=st.floats(-3276.7, 3276.7),
    offset_z=optional(st.floats(-3276.7, 3276.7)),
    position_confidence=_names(sd.POSITION_CONFIDENCE), elevation_confidence=_names(sd.ELEVATION_CONFIDENCE),
    speed=optional(st.floats(0, 163.8)), speed_confidence=_names(sd.SPEED_CONFIDENCE),
    speed_z=optional(st.floats(0, 163.8)), speed_z_confidence=_opt_names(sd.SPEED_CONFIDENCE),
    heading=optional(st.floats(-720, 720)), heading_confidence=_names(sd.HEADING_CONFIDENCE),
    acceleration=optional(st.builds(sd.Acceleration, long=optional(st.floats(-20, 20)),
                                    lat=optional(st.floats(-20, 20)), vert=optional(st.floats(-24.5, 24.5)),
                                    yaw_rate=st.floats(-327.67, 327.67))),
    accel_confidence_x=_opt_names(sd.ACCELERATION_CONFIDENCE),
    accel_confidence_y=_opt_names(sd.ACCELERATION_CONFIDENCE),
    accel_confidence_z=_opt_names(sd.ACCELERATION_CONFIDENCE),
    yaw_rate_confidence=_opt_names(sd.YAW_RATE_CONFIDENCE),
    details=st.one_of(st.none(), vehicle_details, vru_details, obstacle_details),
)
timestamps = st.builds(sd.DateTime, year=optional(st.integers(0, 4095)), month=optional(st.integers(0, 12)),
                       day=optional(st.integers(0, 31)), hour=optional(st.integers(0, 31)),
                       minute=optional(st.integers(0, 60)), second=optional(st.floats(0, 65.535)),
                       offset=optional(st.integers(-840, 840)))


def sdsms(objects):
    return st.builds(
        sd.Sdsm, source_id=st.binary(min_size=4, max_size=4), objects=objects,
        latitude=optional(st.floats(-90, 90)), longitude=optional(st.floats(-179.9999999, 180)),
        elevation=optional(st.floats(-409.5, 6143.9)), timestamp=timestamps, msg_count=st.integers(0, 127),
        equipment_type=st.sampled_from(sd.EQUIPMENT_TYPES), semi_major=optional(st.floats(0, 12.7)),
        semi_minor=optional(st.floats(0, 12.7)), orientation=optional(st.floats(0, 359.99)),
        elevation_confidence=_opt_names(sd.ELEVATION_CONFIDENCE))


def _round_trips(sdsm: sd.Sdsm) -> sd.Sdsm:
    data = sdsm.encode()
    back = sd.Sdsm.decode(data)
    assert back.encode() == data
    assert len(back.objects) == len(sdsm.objects)
    for sent, got in zip(sdsm.objects, back.objects):
        assert abs(got.offset_x - sent.offset_x) <= 0.05 + 1e-9 and abs(got.offset_y - sent.offset_y) <= 0.05 + 1e-9
        assert abs(got.measurement_time - sent.measurement_time) <= 0.0005 + 1e-12
        assert (got.object_id, got.object_type, got.type_confidence) == (sent.object_id, sent.object_type,
                                                                         sent.type_confidence)
        assert type(got.details) is type(sent.details)
        if isinstance(sent.details, sd.VruDetails):
            assert got.details.propulsion == sent.details.propulsion
    return back


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(sdsms(st.lists(detected_objects, min_size=1, max_size=8)))
def test_generated_sdsms_round_trip_to_identical_bytes(sdsm):
    _round_trips(sdsm)


def _fill_to(count: int):
    """`count` objects from a few generated ones (hypothesis cannot draw 256 objects of this size at once):
    each generated object repeated with ids of its own."""
    return st.lists(detected_objects, min_size=1, max_size=6).map(
        lambda objs: [dataclasses.replace(objs[i % len(objs)], object_id=i) for i in range(count)])


@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(sdsms(_fill_to(256)))
def test_generated_sdsms_of_256_objects_round_trip(sdsm):
    assert len(_round_trips(sdsm).objects) == 256


@settings(max_examples=60, deadline=None)
@given(sdsms(st.lists(detected_objects, min_size=1, max_size=1)))
def test_generated_sdsms_of_one_object_round_trip(sdsm):
    assert len(_round_trips(sdsm).objects) == 1


# bad SDSMs built bit by bit: two messages that differ in one field locate its bits in the encoding
def _bits(data: bytes) -> str:
    return "".join(f"{byte:08b}" for byte in data)


def _frame(bits: str) -> bytes:
    bits = bits.ljust((len(bits) + 7) // 8 * 8, "0")
    return default_codec().encode_raw(41, bytes(int(bits[i:i + 8], 2) for i in range(0, len(bits), 8)))


def _inner_bits(sdsm: sd.Sdsm) -> str:
    return _bits(default_codec().encode_message("SensorDataSharingMessage", sdsm.to_asn1()))


def _differing(a: sd.Sdsm, b: sd.Sdsm) -> tuple[str, list[int]]:
    bits_a, bits_b = _inner_bits(a), _inner_bits(b)
    return bits_a, [i for i in range(min(len(bits_a), len(bits_b))) if bits_a[i] != bits_b[i]]


def _one(**kw) -> sd.Sdsm:
    fields = {"object_type": "vehicle", "type_confidence": 90, "speed": 3.0, **kw}
    return sd.Sdsm(b"RSU1", [sd.DetectedObject(5, **fields)], latitude=42.3, longitude=-83.7)


def _refused(data: bytes, reason: str) -> None:
    """Refused by the codec, or decoded by it and refused by the typed message: a J2735Error either way."""
    try:
        default_codec().decode(data)
    except J2735Error as exc:
        assert re.search(reason, exc.reason), exc.reason
        with pytest.raises(J2735Error):
            sd.Sdsm.decode(data)
        return
    with pytest.raises(J2735Error, match=reason):
        sd.Sdsm.decode(data)


@pytest.mark.parametrize("vector", SDSM_VECTORS, ids=lambda v: v["name"])
def test_every_truncated_sdsm_is_refused_with_a_reason(vector):
    data = bytes.fromhex(vector["hex"])
    for end in range(1, len(data)):        # the frame cut short: its length determinant says more
        _refused(data[:end], r"^MessageFrame: .*out of data")
    inner = default_codec().decode(data).value
    for end in range(1, len(inner)):       # a whole frame around an SDSM cut short
        _refused(default_codec().encode_raw(41, inner[:end]), r"^SensorDataSharingMessage \(messageId 41\): ")


@pytest.mark.parametrize("field,low,high,reason", [
    # a field whose bits, all set, encode a value beyond its range (b's value has the first and last bit set)
    ("type_confidence", 0, 101, r"value out of range: .*objTypeCfd"),                # 7 bits: 127 > 101
    ("measurement_time", -1.5, 0.549, r"value out of range: .*measurementTime"),     # 12 bits: 2595 > 1500
])
def test_a_field_out_of_range_on_the_wire_is_refused(field, low, high, reason):
    bits, where = _differing(_one(**{field: low}), _one(**{field: high}))
    first, last = where[0], where[-1]
    _refused(_frame(bits[:first] + "1" * (last + 1 - first) + bits[last + 1:]), reason)


def test_a_choice_index_the_sdsm_does_not_define_is_refused():
    """detObjOptData has three alternatives in two bits: index 3 is none of them."""
    bits, where = _differing(_one(details=sd.VehicleDetails()), _one(details=sd.VruDetails()))
    index_lsb = where[0]                           # detVeh 00, detVRU 01
    _refused(_frame(bits[:index_lsb - 1] + "11" + bits[index_lsb + 1:]),
             r"detObjOptData: Expected choice index 0, 1 or 2, but got 3")


@pytest.mark.parametrize("a,b,reason", [
    (dict(details=sd.VruDetails(propulsion=("human", "unavailable"))),
     dict(details=sd.VruDetails(propulsion=("animal", "unavailable"))), r"propulsion: a CHOICE alternative this "
                                                                        r"edition does not define"),
])
def test_an_extension_of_a_later_edition_is_refused_by_the_typed_sdsm(a, b, reason):
    """An extensible CHOICE with the extension bit set and an alternative this edition lacks: the codec reads it
    (UPER allows it), the typed message cannot carry it on and says where it was."""
    bits, where = _differing(_one(**a), _one(**b))
    ext = where[0] - 2                              # extension bit, then the 2-bit index (human 00, animal 01)
    unknown = "1" + "0000011" + "00000001" + "00000000"   # alternative 3 (normally small), open type of 1 byte
    _refused(_frame(bits[:ext] + unknown + bits[ext + 3 + 3:]), reason)
    bits, where = _differing(sd.Sdsm(b"RSU1", [sd.DetectedObject(1)], equipment_type="unknown"),
                             sd.Sdsm(b"RSU1", [sd.DetectedObject(1)], equipment_type="obu"))
    ext = where[0] - 1                              # unknown 00, obu 10: the first differing bit is the index MSB
    _refused(_frame(bits[:ext] + "1" + "0000101" + bits[ext + 3:]), r"equipmentType: a value this edition does not")


def test_an_sdsm_of_no_objects_is_refused_both_ways():
    message = _one().to_asn1()
    with pytest.raises(J2735Error, match=r"objects: Expected a list of between 1 and 256 elements, but got 0"):
        default_codec().encode(41, {**message, "objects": []})
    with pytest.raises(J2735Error, match=r"^objects: 1\.\.256 detected objects, got 0"):
        sd.Sdsm(b"RSU1", []).encode()


def test_mutated_sdsm_vectors_never_crash_the_codec_or_the_typed_message():
    codec, rng = default_codec(), random.Random(40)
    outcomes = {"refused": 0, "typed": 0, "typed refused": 0}
    for vector in SDSM_VECTORS:
        for mutant in _mutants(bytes.fromhex(vector["hex"]), rng):
            try:
                frame = codec.decode(mutant)
                if frame.message_id != 41:
                    raise J2735Error("another message")
                typed = sd.Sdsm.decode(mutant)
            except J2735Error as exc:
                assert exc.reason
                outcomes["refused"] += 1
                continue
            try:
                typed.encode()
                outcomes["typed"] += 1
            except J2735Error as exc:   # e.g. a decoded 'unavailable' code in a place the typed field cannot send
                assert exc.reason
                outcomes["typed refused"] += 1
    assert sum(outcomes.values()) == len(SDSM_VECTORS) * MUTATIONS_PER_VECTOR
    assert outcomes["refused"] > 500 and outcomes["typed"] > 500, outcomes
