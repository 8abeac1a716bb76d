"""The typed J2735 API: SI units and degrees, 'unavailable' as None, range errors at encode time."""
from __future__ import annotations

import math

import pytest

from bridges.j2735 import J2735Error, default_codec
from bridges.j2735 import scales
from bridges.j2735.bsm import Bsm, EmergencyInfo, surrogate_bsm, surrogate_temporary_id
from bridges.j2735.spat import IntersectionSignals, Movement, Spat


def _bsm(**fields):
    base = dict(temporary_id=b"\x01\x02\x03\x04", msg_count=5, sec_mark_ms=12345, latitude=42.3001234,
                longitude=-83.6987654, elevation=251.3, speed=16.66, heading=271.5, width=1.8, length=4.5)
    base.update(fields)
    return Bsm(**base)


def test_units_on_the_wire():
    """lat/lon 1e-7 deg, elevation 0.1 m, speed 0.02 m/s, heading 0.0125 deg, secMark ms."""
    core = _bsm().to_asn1()["coreData"]
    assert core["lat"] == 423001234 and core["long"] == -836987654
    assert core["elev"] == 2513 and core["speed"] == 833 and core["heading"] == 21720
    assert core["secMark"] == 12345
    assert core["size"] == {"width": 180, "length": 450}


def test_round_trip_through_the_wire_keeps_values_within_one_resolution_step():
    bsm = _bsm(accel_long=-3.21, yaw_rate=12.5, steering_angle=-45.0,
               emergency=EmergencyInfo(siren="inUse", lightbar="inUse", response_type="emergency"))
    back = Bsm.decode(bsm.encode())
    assert back.latitude == pytest.approx(bsm.latitude, abs=0.5e-7)
    assert back.longitude == pytest.approx(bsm.longitude, abs=0.5e-7)
    assert back.elevation == pytest.approx(bsm.elevation, abs=0.05)
    assert back.speed == pytest.approx(bsm.speed, abs=0.01)
    assert back.heading == pytest.approx(bsm.heading, abs=0.00625)
    assert back.accel_long == pytest.approx(-3.21) and back.yaw_rate == pytest.approx(12.5)
    assert back.emergency == bsm.emergency
    assert back.encode() == bsm.encode()


def test_unavailable_values_are_none_both_ways():
    bsm = Bsm(temporary_id=b"\0\0\0\1")
    core = bsm.to_asn1()["coreData"]
    assert (core["lat"], core["long"], core["elev"], core["speed"], core["heading"], core["secMark"]) == \
        (900000001, 1800000001, -4096, 8191, 28800, 65535)
    back = Bsm.decode(bsm.encode())
    assert back.latitude is None and back.speed is None and back.heading is None and back.sec_mark_ms is None
    assert back.width is None and back.accel_long is None


def test_heading_wraps_around_the_circle():
    assert scales.HEADING.to_wire(360.0) == 0
    assert scales.HEADING.to_wire(-90.0) == 21600
    assert scales.HEADING.to_wire(359.99999) == 0


@pytest.mark.parametrize("field,value,match", [
    ("latitude", 90.5, "latitude: 90.5 deg is outside -90..90 deg"),
    ("longitude", -180.5, "longitude"),
    ("speed", 163.9, "speed: 163.9 m/s is outside 0..163.8 m/s"),
    ("speed", -0.1, "speed"),
    ("elevation", 7000.0, "elevation"),
    ("sec_mark_ms", 61000, "secMark"),
    ("accel_long", 25.0, "acceleration"),
    ("width", 11.0, "vehicle width"),
    ("latitude", math.nan, "not a finite number"),
    ("speed", "fast", "not a finite number"),
    ("msg_count", 128, "msg_count"),
    ("temporary_id", b"\1\2\3", "temporary_id"),
    ("transmission", "drive", "transmission"),
])
def test_out_of_range_values_are_refused_at_encode_time(field, value, match):
    with pytest.raises(J2735Error, match=match):
        _bsm(**{field: value}).encode()


def test_emergency_fields_are_checked():
    with pytest.raises(J2735Error, match="emergency.siren"):
        _bsm(emergency=EmergencyInfo(siren="loud")).encode()


def test_typed_view_keeps_part_ii_it_does_not_type_in_place():
    codec = default_codec()
    bsm = _bsm(emergency=EmergencyInfo(siren="inUse", lightbar="inUse", response_type="emergency"))
    message = bsm.to_asn1()
    message["partII"].insert(0, {"partII-Id": 2, "partII-Value": b"\x34\x0d"})  # an id outside the subset
    frame = codec.decode(codec.encode(20, message))
    typed = Bsm.from_asn1(frame.message)
    assert typed.emergency.siren == "inUse" and len(typed.other_part_ii) == 1
    assert codec.encode(20, typed.to_asn1()) == codec.encode(20, frame.message)


def test_typed_view_of_a_deployed_bsm():
    """V2X-Hub's encoder test BSM (interop vector with SpecialVehicleExtensions and a CARMA region)."""
    from test_j2735_vectors import VECTORS

    (vector,) = [v for v in VECTORS if v["message"] == "BSM" and len(v["hex"]) == 226]
    data = bytes.fromhex(vector["hex"])
    bsm = Bsm.decode(data)
    assert bsm.latitude == pytest.approx(3.8954961e0) and bsm.longitude == pytest.approx(-7.7149303)
    assert bsm.speed == pytest.approx(2.0) and bsm.heading == pytest.approx(0.15)
    assert bsm.elevation == pytest.approx(7.2) and bsm.width == pytest.approx(3.0)
    assert bsm.emergency == EmergencyInfo(siren="inUse", lightbar="inUse", response_type="emergency")
    assert bsm.regional[0]["regionId"] == 128  # CARMA's private region, kept as octets
    assert bsm.encode() == data


def test_surrogate_bsm_id_is_stable_per_track_and_differs_between_tracks_and_sessions():
    a1 = surrogate_temporary_id(7, b"session-A")
    assert a1 == surrogate_temporary_id(7, b"session-A") and len(a1) == 4
    assert a1 != surrogate_temporary_id(8, b"session-A")
    assert a1 != surrogate_temporary_id(7, b"session-B")
    bsm = surrogate_bsm(7, b"session-A", latitude=42.0, longitude=-83.0, speed=16.7, heading=90.0)
    assert Bsm.decode(bsm.encode()).temporary_id == a1


def test_spat_typed_round_trip_with_time_marks_in_seconds():
    spat = Spat([IntersectionSignals(intersection_id=1201, revision=3, moy=400000, time_stamp_ms=1500, movements=[
        Movement(2, "protected-Movement-Allowed", min_end_s=1234.5, max_end_s=1240.0),
        Movement(4, "stop-And-Remain", min_end_s=1250.2),
        Movement(6, "dark")])])
    frame = default_codec().decode(spat.encode())
    timing = frame.message["intersections"][0]["states"][0]["state-time-speed"][0]["timing"]
    assert timing == {"minEndTime": 12345, "maxEndTime": 12400}
    back = Spat.decode(spat.encode())
    assert back.intersections[0].movements == spat.intersections[0].movements
    with pytest.raises(J2735Error, match="time mark"):  # 3600.1 s is a leap second's tenth in 2020, 3601 none
        Spat([IntersectionSignals(1, movements=[Movement(1, "dark", min_end_s=3601.0)])]).encode()
    with pytest.raises(J2735Error, match="state 'green'"):
        Spat([IntersectionSignals(1, movements=[Movement(1, "green")])]).encode()
