"""The RSU app's SDSM stage (issue 40): one signed SAE J3224 SDSM per slot with every broadcastable track.

In process, as test_rsu_app_core.py: the oracle detector sees the case study's vehicles exactly, the core
runs its simulated-time stages, and what it sends is decoded with the project's codec and compared with the
vehicles' true motion. The stage's per-object content (offsets, measurement time, confidences from the
covariance, the PSID) is checked on hand-made tracks.
"""
from __future__ import annotations

import math
import re
import time

import numpy as np
import pytest

from bridges.j2735 import Sdsm
from bridges.j2735.sdsm import HEADING_CONFIDENCE, POSITION_CONFIDENCE, SPEED_CONFIDENCE, VehicleDetails
from bridges.security import ScenarioCA, Signer, Verifier, open_unsecured, time64_us
from bridges.v2x import stamp_ns
from rsu_app.config import ConfigError, build_settings
from rsu_app.core import RsuCore
from rsu_app.envelope import Envelope
from rsu_app.perception.geo import VEHICLE_SIZE
from rsu_app.perception.tracker import TrackState
from rsu_app.perception_stage import TrackStamps
from rsu_app.sdsm_stage import Reference, SdsmStage, sdsm_source_id
from rsu_app.timing import LatencyModel
from test_rsu_app_core import EPOCH, ORIGIN, make_core, run

UNSECURED = {"security": {"mode": "unsecured"}}


def _with_sdsm(core: RsuCore, keep_bsm: bool, psid: int = 0x90, envelope=None) -> SdsmStage:
    stage = SdsmStage("rsu", ORIGIN, EPOCH, b"seed-salt", envelope or Envelope(None), core.latency, psid)
    core.sdsm = stage
    if not keep_bsm:
        core.bsm = None
    return stage


def _decoded(txs):
    return [(tx, Sdsm.decode(open_unsecured(tx.payload))) for tx in txs if tx.kind == "sdsm"]


def test_one_sdsm_per_slot_carries_every_track_the_bsms_of_that_slot_carry():
    core, _, vehicles = make_core()
    _with_sdsm(core, keep_bsm=True)
    out = run(core, vehicles, stop=4.0)
    sdsms = _decoded(out)
    bsms = [tx for tx in out if tx.kind == "bsm"]
    assert len(sdsms) >= 30 and bsms
    slots = sorted({round(Sdsm.decode(open_unsecured(tx.payload)).timestamp.to_unix() - EPOCH, 3)
                    for tx, _ in sdsms})
    assert len(slots) == len(sdsms)                                    # one per slot
    assert np.allclose(np.diff(slots), 0.1, atol=1e-6)                 # every 0.1 s
    for tx, sdsm in sdsms:
        assert sdsm.source_id == sdsm_source_id("rsu", b"seed-salt") and sdsm.equipment_type == "rsu"
        assert len(sdsm.objects) == len({o.object_id for o in sdsm.objects})
        assert all(o.object_type == "vehicle" and o.type_confidence == 90 for o in sdsm.objects)  # oracle 0.9
    # each slot's BSMs come first, then its SDSM, with as many objects as the slot had BSMs
    pending = 0
    for tx in out:
        if tx.kind == "bsm":
            pending += 1
        elif tx.kind == "sdsm":
            assert len(Sdsm.decode(open_unsecured(tx.payload)).objects) == pending
            pending = 0
    counts = [len(s.objects) for _, s in sdsms]
    assert max(counts) == 2    # both vehicles at once
    assert set(counts) <= {1, 2}


def test_sdsm_objects_are_where_the_vehicles_were_at_their_measurement_time():
    core, _, vehicles = make_core()
    _with_sdsm(core, keep_bsm=False)
    out = run(core, vehicles, stop=4.0)
    assert out and {tx.kind for tx in out} == {"sdsm"}   # sdsm only: no BSM at all
    errors = []
    for tx, sdsm in _decoded(out):
        t_msg = sdsm.timestamp.to_unix() - EPOCH
        for o in sdsm.objects:
            assert -0.3 <= o.measurement_time <= 0.0
            t_seen = t_msg + o.measurement_time
            truth = min((math.dist(v.at(t_seen), (o.offset_x, o.offset_y)), v) for v in vehicles)
            errors.append(truth[0])
            expected_heading = (90.0 - math.degrees(truth[1].yaw)) % 360.0
            if o.heading is not None:
                assert abs((o.heading - expected_heading + 180) % 360 - 180) < 5.0
            length, width, height = VEHICLE_SIZE[truth[1].label][:3]
            assert (o.details.length, o.details.width, o.details.height) == (length, width, height)
    assert np.median(errors) < 0.5 and max(errors) < 2.0, (np.median(errors), max(errors))


def _track(**kw) -> TrackState:
    cov = np.diag([0.04, 0.01, 0.25, 0.0025])  # x, y var; vx var 0.25 (sigma 0.5 m/s), vy var 0.0025
    fields = dict(id=70000, t=10.0, x=12.0, y=-3.0, vx=10.0, vy=0.0, speed=10.0, heading=0.0, label="emergency",
                  confirmed=True, missed=0, cov=cov)
    return TrackState(**{**fields, **kw})


def test_one_object_from_a_track_and_its_covariance():
    stage = SdsmStage("rsu", ORIGIN, EPOCH, b"salt", Envelope(None), LatencyModel("lockstep", "fixed", {}), 0x90)
    stage.scores[70000] = 0.876
    o = stage.detected_object(_track(), t=10.0, frame_t=9.9)
    assert o.object_id == 70000 - 65536 and o.object_type == "vehicle" and o.type_confidence == 88
    assert o.measurement_time == pytest.approx(-0.1)
    assert (o.offset_x, o.offset_y) == (pytest.approx(11.0), pytest.approx(-3.0))  # 12 - 10 m/s * 0.1 s
    assert o.heading == pytest.approx(90.0)   # east
    # position: semi-major 0.2 m (1 sigma) x 2.45 = 0.49 -> a50cm; speed sigma 0.5 x 1.96 = 0.98 -> prec1ms;
    # heading: across-track sigma 0.05 m/s / 10 m/s = 0.2865 deg x 1.96 = 0.56 -> prec01deg
    assert o.position_confidence == "a50cm" and POSITION_CONFIDENCE.bound(o.position_confidence) == 0.5
    assert o.speed_confidence == "prec1ms" and SPEED_CONFIDENCE.bound(o.speed_confidence) == 1
    assert o.heading_confidence == "prec01deg" and HEADING_CONFIDENCE.bound(o.heading_confidence) == 1
    # the class says emergency (BasicVehicleClass 60), with the box score as its confidence
    assert o.details == VehicleDetails(width=2.3, length=6.5, height=2.6, vehicle_class=60, class_confidence=88)
    slow = stage.detected_object(_track(vx=0.1, speed=0.1, heading=None), t=10.0, frame_t=None)
    assert slow.measurement_time == 0.0 and slow.heading is None and slow.heading_confidence == "unavailable"
    assert (slow.offset_x, slow.offset_y) == (12.0, -3.0)
    stale = stage.detected_object(_track(), t=10.0, frame_t=8.0)   # beyond the 1.5 s the wire carries
    assert stale.measurement_time == 0.0 and stale.offset_x == 12.0


def test_offsets_are_from_the_reference_point():
    reference = Reference(42.0, -83.0, 200.0, x=2.0, y=-1.0)
    stage = SdsmStage("rsu", ORIGIN, EPOCH, b"salt", Envelope(None), LatencyModel("lockstep", "fixed", {}), 0x90,
                      reference)
    sdsm = stage.sdsm([_track()], 10.0, {})
    assert (sdsm.latitude, sdsm.longitude, sdsm.elevation) == (42.0, -83.0, 200.0)
    assert (sdsm.objects[0].offset_x, sdsm.objects[0].offset_y) == (10.0, -2.0)
    assert Reference.of_origin(ORIGIN).latitude == pytest.approx(ORIGIN.to_geodetic(0, 0, 0)[0])


@pytest.mark.parametrize("psid", [0x90, 0x8010])
def test_the_sdsm_is_signed_under_the_configured_psid(psid):
    ca = ScenarioCA.create()
    credentials = ca.issue("rsu", [psid])
    latency = LatencyModel("lockstep", "fixed", {"encode": 0.001, "sign": 0.002})
    epoch = time.time()  # the certificate is valid from now on
    stage = SdsmStage("rsu", ORIGIN, epoch, b"salt", Envelope(Signer(credentials)), latency, psid)
    stamps = {70000: TrackStamps(9.9, 9.9, 9.95), 5: TrackStamps(9.8, 9.8, 9.85)}
    (tx,) = stage.send([_track(), _track(id=5, x=-20.0)], 10.0, stamps, start=10.004)
    verified = Verifier([ca.certificate]).verify(tx.payload, time64_us(epoch + 10.0))
    assert verified.psid == psid and verified.signer == "rsu"
    sdsm = Sdsm.decode(verified.payload)
    assert [o.object_id for o in sdsm.objects] == [5, 70000 - 65536]
    assert tx.stamps["frame"] == stamp_ns(9.8) and tx.kind == "sdsm"         # the oldest frame's stamps
    assert tx.stamps["encode"] == stamp_ns(10.005) and tx.stamps["send"] == stamp_ns(10.007)
    assert stage.send([], 10.1, {}) == []                                      # no tracks: nothing


def test_more_tracks_than_an_sdsm_holds_are_counted_not_sent():
    stage = SdsmStage("rsu", ORIGIN, EPOCH, b"salt", Envelope(None), LatencyModel("lockstep", "fixed", {}), 0x90)
    sdsm = stage.sdsm([_track(id=i, x=float(i % 50)) for i in range(300)], 10.0, {})
    assert len(sdsm.objects) == 256 and stage.objects_dropped == 44
    assert len(Sdsm.decode(sdsm.encode()).objects) == 256


def test_v2x_messages_config():
    assert build_settings(None, UNSECURED).v2x.messages == ["surrogate_bsm"]
    both = build_settings({"v2x.messages": "surrogate_bsm,sdsm", "v2x.sdsm_psid": "0x8010"}, UNSECURED)
    assert both.v2x.messages == ["surrogate_bsm", "sdsm"] and both.v2x.sdsm_psid == 0x8010
    for config, reason in (({"messages": ["sdms"]}, "v2x.messages: expected one of surrogate_bsm, sdsm, got 'sdms' "
                                                    "(did you mean 'sdsm'?)"),
                           ({"messages": []}, "v2x.messages: give each of surrogate_bsm, sdsm at most once, at least "
                                              "one, got []"),
                           ({"messages": ["sdsm", "sdsm"]}, "at most once"),
                           ({"sdsm_psid": -1}, "v2x.sdsm_psid: must be >= 0"),
                           ({"sdsm_pisd": 1}, "v2x.sdsm_pisd: unknown key (did you mean 'sdsm_psid'?)")):
        with pytest.raises(ConfigError, match=re.escape(reason)):
            build_settings(None, {"v2x": config, **UNSECURED})


def test_a_certificate_without_the_sdsm_psid_is_a_config_error(tmp_path):
    from rsu_app.app import RsuApp
    from test_rsu_app_support import make_pki

    keys = make_pki(tmp_path / "keys", {"rsu": "0x7f,0x82"})
    settings = build_settings(None, {"v2x": {"messages": ["sdsm"]},
                                     "security": {"mode": "signed", "pki_dir": str(keys)}})
    with pytest.raises(ConfigError, match=r"certificate 'rsu' may not sign 0x90 .* --station rsu:0x90,0x82"):
        RsuApp(settings, environ={})
