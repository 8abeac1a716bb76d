"""The Sensor Data Sharing Message (SAE J3224, messageId 41): wire compatibility with deployments, the typed
API's units, and a user's licensed files with and without the SDSM.

tests/fixtures/interop/sdsm_vectors.json holds 11 SDSMs published in public deployments' test data (JPO ODE,
V2X Hub, a field capture), each with its decoding by an independent asn1c build (XER). Every one must decode
to exactly those values and re-encode to the same bytes, through the codec and through the typed `Sdsm`.
Generated SDSMs and bad ones are in test_j2735_fuzz.py.
"""
from __future__ import annotations

import json
import re
import shutil
import xml.etree.ElementTree as ET

import pytest

from bridges.j2735 import (Acceleration, DateTime, DetectedObject, J2735Codec, J2735Error, ObstacleDetails, Sdsm,
                           VehicleDetails, VruDetails, default_codec)
from bridges.j2735 import sdsm as sdsm_module
from bridges.j2735.codec import BUILTIN_MODULE

from conftest import fixture_path

SDSM_VECTORS = json.loads(fixture_path("interop/sdsm_vectors.json").read_text())
BY_NAME = {v["name"]: v for v in SDSM_VECTORS}
NAMES = [v["name"] for v in SDSM_VECTORS]


# -- the published decoding, read from XER -----------------------------------------------------------------------
def _xer(element: ET.Element):
    """An XER element as plain values: numbers, OCTET STRING as bytes, an enumerated value (`<rsu/>`) as its
    name, a CHOICE as {alternative: value}, SEQUENCE OF as a list, SEQUENCE as a dict."""
    children = list(element)
    if not children:
        text = (element.text or "").strip()
        if element.tag == "sourceID":
            return bytes.fromhex(text.replace(" ", ""))
        if re.fullmatch(r"-?\d+", text):
            return int(text)
        if text == "":
            return {}
        raise AssertionError(f"unexpected XER text {text!r} in <{element.tag}>")
    if len(children) == 1 and not list(children[0]) and not (children[0].text or "").strip():
        return children[0].tag
    if element.tag == "objects":
        return [_xer(c) for c in children]
    return {c.tag: _xer(c) for c in children}


def _plain(value):
    """asn1tools values in the same form as `_xer` (a CHOICE of an empty SEQUENCE reads as its name there)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_plain(v) for v in value]
    if isinstance(value, tuple) and isinstance(value[0], str):
        return value[0] if value[1] == {} else {value[0]: _plain(value[1])}
    return value


def _published(vector) -> tuple[int, dict]:
    root = ET.fromstring(vector["decoded_xer"])
    (message,) = list(root.find("value"))
    assert message.tag == "SensorDataSharingMessage"
    return int(root.findtext("messageId")), _xer(message)


@pytest.mark.parametrize("name", NAMES)
def test_every_vector_decodes_to_its_published_values_and_reencodes_byte_identical(name):
    vector = BY_NAME[name]
    data = bytes.fromhex(vector["hex"])
    frame = default_codec().decode(data)
    message_id, published = _published(vector)
    assert (frame.message_id, frame.type_name, frame.length) == (message_id, "SensorDataSharingMessage", len(data))
    assert _plain(frame.message) == published, vector["notes"]
    assert default_codec().encode(41, frame.message) == data
    typed = Sdsm.decode(data)
    assert typed.encode() == data
    assert _plain(typed.to_asn1()) == published


def test_the_vectors_cover_every_kind_of_object_and_the_optional_fields():
    """What the byte-identical round trips above prove only if the vectors hold it."""
    details, common = set(), set()
    for vector in SDSM_VECTORS:
        for o in default_codec().decode(bytes.fromhex(vector["hex"])).message["objects"]:
            common |= set(o["detObjCommon"])
            if "detObjOptData" in o:
                details.add(o["detObjOptData"][0])
    assert details == {"detVeh", "detVRU", "detObst"}
    assert {"speedZ", "speedConfidenceZ", "accel4way", "accCfdX", "accCfdY", "accCfdZ", "accCfdYaw"} <= common


# -- the typed API's units ----------------------------------------------------------------------------------------
def test_typed_values_are_in_si_units():
    common = Sdsm.decode(bytes.fromhex(BY_NAME["v2xhub_common"]["hex"]))
    (o,) = common.objects
    # published: offsetX 4000, offsetY -720, offsetZ 20 (0.1 m); measurementTime -1100 (ms); speed 2100,
    # speedZ 1000 (0.02 m/s); heading 16000 (0.0125 deg); accel long 200, lat -500 (0.01 m/s2), yaw 400
    assert (o.offset_x, o.offset_y, o.offset_z) == (400.0, -72.0, 2.0)
    assert o.measurement_time == -1.1
    assert (o.speed, o.speed_z, o.heading) == (pytest.approx(42.0), pytest.approx(20.0), pytest.approx(200.0))
    assert o.acceleration.long == 2.0 and o.acceleration.lat == -5.0 and o.acceleration.yaw_rate == 4.0
    assert (o.object_type, o.type_confidence, o.object_id) == ("vehicle", 65, 12200)
    assert sdsm_module.TIME_CONFIDENCE.bound(o.time_confidence) == 50.0          # time-050-000
    assert sdsm_module.POSITION_CONFIDENCE.bound(o.position_confidence) == 200   # a200m
    assert sdsm_module.SPEED_CONFIDENCE.bound(o.speed_confidence) == 5           # prec5ms
    assert sdsm_module.ACCELERATION_CONFIDENCE.bound(o.accel_confidence_x) == 1.0  # accl-001-00
    ode = Sdsm.decode(bytes.fromhex(BY_NAME["ode_rsu"]["hex"]))
    assert (ode.latitude, ode.longitude) == (pytest.approx(42.3010070, abs=1e-9), pytest.approx(-83.6987660, abs=1e-9))
    assert ode.source_id == bytes.fromhex("010C0C0A") and ode.equipment_type == "rsu"
    assert ode.timestamp == DateTime(year=2024) and ode.timestamp.to_unix() is None
    assert (ode.semi_major, ode.semi_minor) == (pytest.approx(0.6), pytest.approx(2.6))


def test_obstacle_vru_and_vehicle_details():
    multi = Sdsm.decode(bytes.fromhex(BY_NAME["v2xhub_multi"]["hex"]))
    obstacle, vru, vehicle = (o.details for o in multi.objects)
    # published: obstSize 5, 20, 10 (0.1 m); the vehicle's size 50 x 50 (cm) and height 40 (5 cm)
    assert (obstacle.width, obstacle.length, obstacle.height) == (0.5, 2.0, 1.0)
    assert vru == VruDetails()
    assert (vehicle.width, vehicle.length, vehicle.height) == (0.5, 0.5, 2.0)
    assert [o.offset_z for o in multi.objects] == [-3.2] * 3
    walker = Sdsm.decode(bytes.fromhex(BY_NAME["v2xhub_vru"]["hex"])).objects[0].details
    assert walker.basic_type == "aPEDESTRIAN" and walker.propulsion == ("human", "onFoot")
    assert walker.attachment == "cart"


def test_confidence_scales_map_values_to_the_finest_covering_class():
    p = sdsm_module.POSITION_CONFIDENCE
    assert p.name_for(0.15) == "a20cm" and p.name_for(0.2) == "a20cm" and p.name_for(0.21) == "a50cm"
    assert p.name_for(None) == "unavailable" and p.name_for(501) == "unavailable"
    assert sdsm_module.TIME_CONFIDENCE.bound("time-000-000-5") == 0.0005
    assert sdsm_module.ELEVATION_CONFIDENCE.bound("elev-000-05") == 0.05
    assert sdsm_module.SIZE_CONFIDENCE.bound("size-100-00") == 100.0
    assert sdsm_module.YAW_RATE_CONFIDENCE.name_for(3.0) == "degSec-005-00"
    assert sdsm_module.HEADING_CONFIDENCE.name_for(0.01) == "prec0-01deg"
    with pytest.raises(J2735Error, match="position confidence 'a20 cm' is not a known value; did you mean 'a20cm'"):
        p.bound("a20 cm")


def test_datetime_round_trips_a_posix_time_to_the_millisecond():
    t = 1_733_847_538.125  # 2024-12-10 16:18:58.125 UTC
    stamp = DateTime.from_unix(t)
    assert stamp == DateTime(2024, 12, 10, 16, 18, 58.125)
    assert stamp.to_unix() == t
    assert DateTime(2024, 12, 10, 16, 18, 58.125, offset=60).to_unix() == t - 3600
    timtsp = Sdsm.decode(bytes.fromhex(BY_NAME["v2xhub_timtsp"]["hex"])).timestamp
    assert timtsp.to_unix() is not None


def _object(**kw) -> DetectedObject:
    return DetectedObject(1, "vehicle", 90, **kw)


def _sdsm(objects, **kw) -> Sdsm:
    return Sdsm(b"RSU1", objects, latitude=42.3, longitude=-83.7, **kw)


def test_typed_sdsm_encodes_what_it_was_given():
    sent = _sdsm([_object(offset_x=-12.3, offset_y=4.5, speed=8.5, heading=271.0, speed_confidence="prec1ms",
                          details=VehicleDetails(width=1.8, length=4.6, height=1.5)),
                  DetectedObject(2, "vru", 70, measurement_time=-0.05,
                                 details=VruDetails("aPEDALCYCLIST", ("motor", "bicycle"), radius=0.5)),
                  DetectedObject(3, "unknown", 40, details=ObstacleDetails(1.0, 0.5, height_confidence="size-000-50"))],
                 timestamp=DateTime.from_unix(1_700_000_000.0), msg_count=9)
    back = Sdsm.decode(sent.encode())
    assert back == sent
    value = sent.to_asn1()["objects"]
    assert value[0]["detObjCommon"]["pos"] == {"offsetX": -123, "offsetY": 45}
    assert value[0]["detObjOptData"] == ("detVeh", {"size": {"width": 180, "length": 460}, "height": 30})
    assert value[1]["detObjCommon"]["measurementTime"] == -50
    assert value[1]["detObjOptData"][1]["propulsion"] == ("motor", "bicycle")


@pytest.mark.parametrize("change,reason", [
    (lambda s: setattr(s, "objects", []), r"^objects: 1\.\.256 detected objects, got 0"),
    (lambda s: setattr(s, "objects", [_object()] * 257), r"^objects: 1\.\.256 detected objects, got 257"),
    (lambda s: setattr(s, "source_id", b"RSU"), r"^source_id: 4 bytes required"),
    (lambda s: setattr(s.objects[0], "offset_x", 3276.8), r"^objects\[0\] 1: offset_x: position offset: 3276\.8 m "
                                                          r"is outside -3276\.7\.\.3276\.7 m"),
    (lambda s: setattr(s.objects[0], "measurement_time", 1.6), r"measurement_time: .* outside -1\.5\.\.1\.5 s"),
    (lambda s: setattr(s.objects[0], "type_confidence", 102), r"type_confidence \(percent\): 102 is outside 0\.\.101"),
    (lambda s: setattr(s.objects[0], "object_type", "vehicel"), r"object_type 'vehicel' .* did you mean 'vehicle'"),
    (lambda s: setattr(s.objects[0], "speed_confidence", "prec1m"), r"did you mean 'prec1ms'"),
    (lambda s: setattr(s.objects[0], "details", "car"), r"details: a VehicleDetails, VruDetails or ObstacleDetails"),
    (lambda s: setattr(s.objects[0], "details", VruDetails(propulsion=("human", "bicycle"))),
     r"propulsion \(human\) 'bicycle' is not a known value"),
    (lambda s: setattr(s.objects[0], "details", VehicleDetails(attitude=(0.0, 181.0, 0.0))),
     r"roll: detected roll: 181 deg is outside -180\.\.180 deg"),
    (lambda s: setattr(s.objects[0], "acceleration", Acceleration(long=25.0)), r"acceleration: long: .* outside"),
    (lambda s: setattr(s, "timestamp", DateTime(month=13)), r"^timestamp: month: 13 is outside 0\.\.12"),
    (lambda s: setattr(s, "objects", [object()]), r"^objects\[0\]: a DetectedObject is required"),
])
def test_values_the_sdsm_cannot_carry_are_refused_naming_the_field(change, reason):
    sdsm = _sdsm([_object()])
    change(sdsm)
    with pytest.raises(J2735Error, match=reason):
        sdsm.encode()


def test_a_frame_of_another_message_is_not_an_sdsm():
    from test_j2735_vectors import VECTORS

    with pytest.raises(J2735Error, match=r"messageId 20 is not an SDSM \(41\)"):
        Sdsm.decode(bytes.fromhex(VECTORS[0]["hex"]))


# -- a user's licensed files -------------------------------------------------------------------------------------
_SDSM_SECTION = re.compile(r"\n-- == SensorDataSharingMessage.*?(?=\nEND\n)", re.S)


def _without_sdsm(text: str) -> str:
    text = _SDSM_SECTION.sub("\n", text)
    return text.replace(" |\n   { SensorDataSharingMessage IDENTIFIED BY 41 }", "")


def test_licensed_files_without_the_sdsm_still_load_and_carry_it_as_octets(tmp_path):
    """Files of an edition before the SDSM: the other messages work, id 41 stays octets (and re-encodes), and
    the typed API says what the files lack."""
    (tmp_path / "J2735.asn").write_text(_without_sdsm(BUILTIN_MODULE.read_text()))
    codec = J2735Codec(tmp_path)
    assert 41 not in codec.message_types and 20 in codec.message_types
    data = bytes.fromhex(BY_NAME["ode_rsu"]["hex"])
    frame = codec.decode(data)
    assert (frame.message_id, frame.type_name, frame.message) == (41, None, None)
    assert codec.encode_raw(41, frame.value) == data
    with pytest.raises(J2735Error, match=r"has no such type"):
        Sdsm.decode(data, codec)
    with pytest.raises(J2735Error, match=r"has no SensorDataSharingMessage"):
        Sdsm.decode(data).encode(codec)


def test_licensed_files_carrying_the_sdsm_in_a_module_of_its_own_decode_it(tmp_path):
    """As SAE's 2024 files lay it out: the SDSM in its own module, importing the common types, beside another
    module with a narrower PitchRate and RollRate of its own (J2945/6). Each module keeps its own names, so
    the SDSM's rates keep their -32767..32767 range."""
    text = BUILTIN_MODULE.read_text()
    section = _SDSM_SECTION.search(text).group(0)
    sdsm_types = re.findall(r"^([A-Z][\w-]*) ::=", section, re.M)
    section = section.replace("DetectedPitchRate", "PitchRate").replace("DetectedRollRate", "RollRate")
    sdsm_types = [t.replace("DetectedPitchRate", "PitchRate").replace("DetectedRollRate", "RollRate")
                  for t in sdsm_types]
    common = ["MsgCount", "TemporaryID", "DDateTime", "Position3D", "PositionalAccuracy", "ElevationConfidence",
              "TimeConfidence", "PositionConfidenceSet", "Speed", "SpeedConfidence", "Heading", "HeadingConfidence",
              "AccelerationSet4Way", "ExteriorLights", "VehicleSize", "VehicleHeight"]
    (tmp_path / "J2735-common.asn").write_text(_without_sdsm(text))
    (tmp_path / "J2735-SDSM.asn").write_text(
        "SDSM DEFINITIONS AUTOMATIC TAGS ::= BEGIN\nEXPORTS ALL;\nIMPORTS " + ", ".join(common)
        + " FROM V2I-J2735;\n" + section + "\nEND\n")
    (tmp_path / "J2735-CCM.asn").write_text(
        "CCM DEFINITIONS AUTOMATIC TAGS ::= BEGIN\nPitchRate ::= INTEGER (-3000..3001)\n"
        "RollRate ::= INTEGER (-3000..3001)\nCcmRates ::= SEQUENCE { pitchRate PitchRate, rollRate RollRate }\nEND\n")
    codec = J2735Codec(tmp_path)
    assert codec.message_types[41] == "SensorDataSharingMessage"
    for vector in SDSM_VECTORS:
        data = bytes.fromhex(vector["hex"])
        assert _plain(codec.decode(data).message) == _published(vector)[1]
        assert Sdsm.decode(data, codec).encode(codec) == data
    wide = _sdsm([_object(details=VehicleDetails(angular_velocity=(-300.0, 327.67)))])
    assert Sdsm.decode(wide.encode(codec), codec) == wide


def test_builtin_module_copy_as_licensed_folder_keeps_the_sdsm(tmp_path):
    shutil.copy(BUILTIN_MODULE, tmp_path / "J2735.asn")
    data = bytes.fromhex(BY_NAME["v2xhub_multi"]["hex"])
    assert Sdsm.decode(data, J2735Codec(tmp_path)).encode(J2735Codec(tmp_path)) == data
