"""The AV app fuses an RSU's SDSM objects (SAE J3224) like its surrogate BSMs (issue 40, item 3), in process.

Each detected vehicle or VRU becomes a V2X object: position = the SDSM's reference point + the object's
offsets, at the message's timestamp + its measurementTime; the position confidence (a 95 % bound) as the
fusion's noise; BasicVehicleClass 60-69 (the emergency types) as an emergency vehicle; ids by (sender,
objectID); the RSU's report of the ego itself left out by the surrogate self-recognition rule. The SDSM is
accepted under the configured PSIDs only. Frames are built with the typed API and signed with the test CA.
"""
from __future__ import annotations

import math
from datetime import datetime, timedelta, timezone

import pytest

from bridges.j2735.sdsm import DateTime, DetectedObject, ObstacleDetails, Sdsm, VehicleDetails
from bridges.security import PSID_SURROGATE_BSM, ScenarioCA, Signer, Verifier
from bridges.v2x import unix_time
from av_app.config import ConfigError, build
from av_app.core import AvCore
from av_app.obu import Obu, Rejected
from av_app.timing import StageClock

from test_av_app_core import EPOCH, ORIGIN, feed_ego, signed

SDSM_PSID = 0x90
REF = (10.0, -20.0)  # the SDSM's reference point in local metres (not the origin: the offsets must be added)


@pytest.fixture(scope="module")
def pki():
    start = datetime.now(timezone.utc) - timedelta(hours=1)
    ca = ScenarioCA.create(start=start)
    return {"ca": ca, "rsu": Signer(ca.issue("rsu", [SDSM_PSID, 0x8010, PSID_SURROGATE_BSM], start=start), 0.0)}


def vehicle(oid, x, y, *, yaw=0.0, speed=16.667, back=0.05, vehicle_class=None, confidence="a50cm", kind="vehicle"):
    details = VehicleDetails(width=2.3, length=6.5, vehicle_class=vehicle_class) if kind == "vehicle" else None
    return DetectedObject(object_id=oid, object_type=kind, type_confidence=90, measurement_time=-back,
                          offset_x=x - REF[0], offset_y=y - REF[1], position_confidence=confidence, speed=speed,
                          heading=(90.0 - math.degrees(yaw)) % 360.0, details=details)


def sdsm(t, objects, source=b"\x0a\x0b\x0c\x0d"):
    lat, lon, h = ORIGIN.to_geodetic(REF[0], REF[1], 0.0)
    return Sdsm(source, objects, latitude=float(lat), longitude=float(lon), elevation=float(h),
                timestamp=DateTime.from_unix(unix_time(t, EPOCH)), msg_count=7, equipment_type="rsu").encode()


def make_obu(pki, **obu):
    cfg = build({"security": {"allow_unsecured": True}, "obu": obu})
    return Obu(cfg.obu, ORIGIN, EPOCH, Verifier([pki["ca"].certificate], max_age_s=0.5))


def test_each_detected_vehicle_is_an_object_at_its_measurement_time(pki):
    obu = make_obu(pki)
    frame = signed(pki["rsu"], sdsm(2.0, [vehicle(1, -40.0, -1.75, vehicle_class=60, back=0.05),
                                          vehicle(2, 1.75, -30.0, yaw=math.pi / 2, speed=8.3, vehicle_class=10,
                                                  back=0.1, confidence="unavailable")]), 2.0, SDSM_PSID)
    acc = obu.receive(frame, 2.004)
    assert acc.kind == "sdsm" and acc.station == "rsu" and acc.object is None
    ev, cav = acc.objects
    assert ev.id == "sdsm:0a0b0c0d:1" and cav.id == "sdsm:0a0b0c0d:2" and acc.object_id == f"{ev.id},{cav.id}"
    # reference + offsets, in local metres (offsets travel in 0.1 m, the reference in 1e-7 degree)
    assert (ev.x, ev.y) == pytest.approx((-40.0, -1.75), abs=0.06)
    assert (cav.x, cav.y) == pytest.approx((1.75, -30.0), abs=0.06)
    assert ev.t == pytest.approx(1.95, abs=1e-3) and cav.t == pytest.approx(1.9, abs=1e-3)
    assert ev.yaw == pytest.approx(0.0, abs=0.01) and cav.yaw == pytest.approx(math.pi / 2, abs=0.01)
    assert ev.speed == pytest.approx(16.667, abs=0.02) and (ev.length, ev.width) == pytest.approx((6.5, 2.3))
    assert ev.emergency and not cav.emergency  # BasicVehicleClass 60: emergency-TypeUnknown
    assert ev.surrogate and cav.surrogate  # an RSU's estimate: the surrogate self-recognition rules apply
    assert ev.pos_std == pytest.approx(0.5 / 2.45)  # a50cm is a 95 % bound
    assert cav.pos_std == obu.cfg.position_sigma  # unavailable: the configured default


def test_obstacles_unknown_objects_and_animals_are_left_to_the_lidar(pki):
    obu = make_obu(pki)
    cone = DetectedObject(object_id=5, object_type="unknown", offset_x=1.0, offset_y=2.0,
                          details=ObstacleDetails(width=0.4, length=0.4))
    frame = signed(pki["rsu"], sdsm(1.0, [cone, vehicle(6, 0.0, 0.0, kind="animal"),
                                          vehicle(7, -30.0, -1.75)]), 1.0, SDSM_PSID)
    assert [o.id for o in obu.receive(frame, 1.003).objects] == ["sdsm:0a0b0c0d:7"]


@pytest.mark.parametrize("psids, psid, ok", [([0x90], 0x90, True), ([0x90], PSID_SURROGATE_BSM, False),
                                             ([0x90], 0x8010, False), ([0x8010], 0x8010, True)])
def test_an_sdsm_is_accepted_under_the_configured_psids_only(pki, psids, psid, ok):
    obu = make_obu(pki, sdsm_psids=psids)
    frame = signed(pki["rsu"], sdsm(1.0, [vehicle(1, -30.0, -1.75)]), 1.0, psid)
    if ok:
        assert len(obu.receive(frame, 1.003).objects) == 1
    else:
        with pytest.raises(Rejected) as exc:
            obu.receive(frame, 1.003)
        assert exc.value.reason == "psid-mismatch"


def test_a_stale_or_placeless_sdsm_is_rejected_with_its_reason(pki):
    obu = make_obu(pki)
    old = signed(pki["rsu"], sdsm(1.0, [vehicle(1, -30.0, -1.75, back=1.2)]), 1.0, SDSM_PSID)
    with pytest.raises(Rejected) as exc:
        obu.receive(old, 1.01)
    assert exc.value.reason == "stale"
    nowhere = Sdsm(b"\x01\x02\x03\x04", [vehicle(1, -30.0, -1.75)],
                   timestamp=DateTime.from_unix(unix_time(1.0, EPOCH))).encode()
    with pytest.raises(Rejected) as exc:
        obu.receive(signed(pki["rsu"], nowhere, 1.0, SDSM_PSID), 1.01)
    assert exc.value.reason == "incomplete"
    assert obu.rejected == {"stale": 1, "incomplete": 1}


def test_a_stale_object_is_left_out_and_counted_the_rest_are_fused(pki):
    """A track the sender coasts (measured 1.2 s before) does not take the fresh objects of its message
    down with it: the stale one is left out and counted, the other fused."""
    obu = make_obu(pki)
    mixed = signed(pki["rsu"], sdsm(1.0, [vehicle(1, -30.0, -1.75, back=1.2), vehicle(2, -50.0, -1.75)]), 1.0,
                   SDSM_PSID)
    assert [o.id for o in obu.receive(mixed, 1.01).objects] == ["sdsm:0a0b0c0d:2"]
    assert obu.rejected == {"stale-object": 1}


def test_bad_sdsm_psids_are_named():
    for bad in ([], ["0x90"], [-1], [True]):
        with pytest.raises(ConfigError) as exc:
            build({"security": {"allow_unsecured": True}, "obu": {"sdsm_psids": bad}})
        assert any(p.startswith("obu.sdsm_psids:") for p in exc.value.problems)


def test_the_core_plans_around_the_sdsm_ev_and_leaves_its_own_entry_out(pki):
    cfg = build({"security": {"allow_unsecured": True}, "perception": {"enabled": False}})
    core = AvCore(cfg, Obu(cfg.obu, ORIGIN, EPOCH, Verifier([pki["ca"].certificate])), StageClock("fixed", None,
                  cfg.latency), {"intersection": {"road_width": 7.0}})
    feed_ego(core, 0.0)
    frame = signed(pki["rsu"], sdsm(0.0, [vehicle(1, -60.0, -1.75, vehicle_class=60, back=0.0),
                                          vehicle(2, 1.75, -30.0, yaw=math.pi / 2, speed=8.333, back=0.0)]), 0.0,
                   SDSM_PSID)
    assert core.on_v2x(frame, 0.003) is not None
    sent = []
    feed_ego(core, 0.04, -30.0 + 0.04 * 8.333)
    records = core.command(0.04, lambda accel, steer, mode: sent.append(accel) or len(sent))
    ids = [o.id for o in core.last_objects]
    assert ids == ["sdsm:0a0b0c0d:1"]  # object 2 sits on the ego: the RSU's report of the cav itself
    assert core.last_objects[0].emergency
    assert len(records) == 1 and records[0]["kind"] == "sdsm"
