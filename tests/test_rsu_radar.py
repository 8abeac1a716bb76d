"""The RSU's roadside radar (issue 38: what the camera cannot see that far): the wire format, the ground geometry,
the tracker's coverage rule, and stage 1 turning scans into tracks the RSU broadcasts beyond the camera's range."""
from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest

from bridges.radar_stream import RadarObject, RadarScan, RadarStreamError, decode_scan, encode_scan
from bridges.transport import open_bus
from rsu_app.camera import RadarIngest
from rsu_app.perception.tracker import GroundDetection, Tracker, TrackerConfig
from rsu_app.perception_stage import RADAR, DetectionZone, PerceptionStage
from tests.test_rsu_app_core import CAM, EV, INTERSECTION, FakeFrame, Oracle, Pixels, Vehicle

POLE = (6.5, 6.5, 6.0)
LONG_ARMS = {**INTERSECTION, "arm_length": 250.0}  # the timing sweep's roads (a 45 mph ev 3 s late starts 200 m out)


def scan(objects=(), t=0.0, scan_id=0, fov_deg=16.0, **kw) -> RadarScan:
    args = dict(radar="west", scan_id=scan_id, t=t, position=POLE, heading=math.pi, fov=math.radians(fov_deg),
                min_range_m=5.0, max_range_m=250.0, sigma_range_m=0.25, sigma_azimuth=math.radians(0.25),
                sigma_speed=0.1, objects=list(objects))
    args.update(kw)
    return RadarScan(**args)


def observe(x, y, vx=0.0, vy=0.0) -> RadarObject:
    """What a noiseless radar on the pole reports of a vehicle centre at (x, y) moving at (vx, vy)."""
    dx, dy, dz = x - POLE[0], y - POLE[1], 0.75 - POLE[2]
    r = math.sqrt(dx * dx + dy * dy + dz * dz)
    az = (math.atan2(dy, dx) - math.pi + math.pi) % (2 * math.pi) - math.pi
    return RadarObject(r, az, (vx * dx + vy * dy) / r)


# -- the wire format ------------------------------------------------------------------------------------------
def test_a_scan_round_trips_and_its_ground_point_is_where_the_vehicle_is():
    s = scan([observe(-120.0, -1.75, 20.0), observe(-200.0, 1.75)], t=3.25, scan_id=65)
    back = decode_scan(encode_scan(s))
    assert back == s
    x, y = back.ground_point(back.objects[0])
    assert math.hypot(x + 120.0, y + 1.75) < 0.15  # mid-height centre vs ground: the pole's height is removed
    assert back.objects[0].radial_speed < 0  # approaching the radar reads negative
    assert back.covers(-120.0, -1.75) and not back.covers(1.75, -40.0) and not back.covers(-300.0, -1.75)


def test_the_ground_covariance_is_long_along_the_beam_at_close_range_and_wide_across_it_far_out():
    s = scan()
    near = s.ground_covariance(observe(-20.0, 4.0))
    far = s.ground_covariance(observe(-230.0, -1.75))
    # along the beam (x here) the range error; across it (y) the azimuth error times the range
    assert near[0] > near[2]
    assert far[2] > far[0]
    assert far[2] == pytest.approx((236.5 * math.radians(0.25)) ** 2, rel=0.02)


def test_a_bad_scan_is_refused_naming_every_bad_key():
    d = json.loads(encode_scan(scan([observe(-80.0, -1.75)])))
    d.update(t="soon", fov=-1.0, max_range_m=2.0, objects=[[0.0, 0.1, 1.0], ["x"]])
    with pytest.raises(RadarStreamError) as exc:
        decode_scan(json.dumps(d).encode())
    msg = str(exc.value)
    for key in ("t:", "fov:", "max_range_m:", "objects[0]", "objects[1]"):
        assert key in msg
    with pytest.raises(RadarStreamError, match="missing sigma_speed"):
        decode_scan(json.dumps({k: v for k, v in json.loads(encode_scan(scan())).items()
                                if k != "sigma_speed"}).encode())
    with pytest.raises(RadarStreamError, match="not JSON"):
        decode_scan(b"\xff\x00")


def test_the_ingest_counts_garbage_by_reason_and_hands_over_good_scans_in_time_order():
    pub = open_bus("memory", prefix="test/radar_ingest", sender="master")
    bus = open_bus("memory", prefix="test/radar_ingest", sender="rsu")
    ingest = RadarIngest(bus, ["west"], rate_hz=20.0, wait_s=0.5)
    try:
        pub.publish("radar/west", b"garbage", 0.0)
        pub.publish("radar/west", encode_scan(scan(t=0.05, scan_id=1)), 0.05)
        pub.publish("radar/west", encode_scan(scan(t=0.0, scan_id=0)), 0.0)
        pub.publish("radar/west", encode_scan(scan(t=0.1, scan_id=2, radar="east")), 0.1)
        time.sleep(0.3)  # the bus delivers on its own thread: let all four arrive (two out of order)
        got = ingest.collect(0.05, wait=True)
        assert [g.t for g in got] == [0.0, 0.05]
        stats = ingest.stats()
        assert stats["bad_by_reason"] == {"radar": 1, "radar name differs from its key": 1}
    finally:
        ingest.close()
        bus.close()
        pub.close()


# -- the tracker's coverage rule ------------------------------------------------------------------------------
def test_a_sensor_misses_only_the_tracks_it_could_have_seen():
    tr = Tracker(TrackerConfig(confirm_hits=2, confirm_window=3, max_missed=2, motion="cv"))
    for k in range(3):  # a far vehicle and a near one, both confirmed
        tr.update(k * 0.1, [GroundDetection(-150.0 + 2 * k, -1.75), GroundDetection(1.75, -20.0 + k)])
    assert len(tr.predict(0.2)) == 2
    far_only = lambda x, y: x < -50.0  # noqa: E731  a radar down the west approach
    for k in range(3, 10):  # the radar keeps seeing the far one; the near one is outside its beam
        tr.update(k * 0.1, [GroundDetection(-150.0 + 2 * k, -1.75)], sees=far_only)
    assert len(tr.predict(0.9)) == 2  # the near one was not missed by a sensor that cannot see it
    for k in range(10, 14):  # without the rule every frame misses every unmatched track
        tr.update(k * 0.1, [GroundDetection(-150.0 + 2 * k, -1.75)])
    assert len(tr.predict(1.3)) == 1


# -- stage 1 --------------------------------------------------------------------------------------------------
def stage(hits=3) -> PerceptionStage:
    return PerceptionStage(Oracle(), Tracker(TrackerConfig(confirm_hits=hits, confirm_window=5, max_missed=5,
                                                           motion="cv")),
                           DetectionZone(60.0, LONG_ARMS, True, 1.5, 80.0), 0.5)


def test_radar_objects_become_tracks_broadcast_far_beyond_the_cameras_range():
    p = stage()
    ev = Vehicle(-200.0, -1.75, 0.0, 20.1, "emergency")
    for k in range(6):
        t = k * 0.05
        x, y = ev.at(t)
        off_road = observe(-100.0, 30.0)  # a reflection off the road (a building's, a sign's) is not a vehicle
        r = p.process_radar(scan([observe(x, y, ev.v), off_road], t=t, scan_id=k), t)
        assert r.kind == RADAR and len(r.detections) == 1 and r.rejected == {"off the road": 1}
        p.apply([r])
    sent = p.broadcastable(p.tracker.predict(0.25))
    assert len(sent) == 1
    s = sent[0]
    assert math.hypot(s.x - ev.at(0.25)[0], s.y + 1.75) < 1.0
    assert s.speed == pytest.approx(20.1, abs=2.0) and s.label == "car"  # a radar does not know an ambulance
    assert math.hypot(s.x - CAM.position[0], s.y - CAM.position[1]) > 150.0  # the camera's zone ends at 60 m


def test_the_cameras_class_names_a_radar_track_and_the_track_carries_on_through_the_handover():
    p = stage()
    ev = Vehicle(-95.0, -1.75, 0.0, 16.667, "emergency")
    ids = set()
    for k in range(41):  # 2 s at 20 Hz, the camera at 10 Hz: from 100 m out to the junction's approach
        t = round(k * 0.05, 9)
        x, y = ev.at(t)
        results = []
        if k % 2 == 0:
            r = p.process(FakeFrame("rsu_cam", k // 2, t, Pixels(t, [ev])), t)
            if r is not None:
                results.append(r)
        results.append(p.process_radar(scan([observe(x, y, ev.v)] if scan().covers(x, y) else [], t=t,
                                            scan_id=k), t))
        for r in results:
            p.apply([r])
        ids |= {s.id for s in p.broadcastable(p.tracker.predict(t))}
    assert len(ids) == 1  # one vehicle, one track, from the radar's first report to the camera's last
    (s,) = p.broadcastable(p.tracker.predict(2.0))
    assert s.label == "emergency"


def test_without_a_radar_the_stage_behaves_as_a_camera_only_rsu():
    p = stage()
    assert p.sees([]) is None
    p.process_radar(scan(), 0.0)
    assert p.sees([]) is not None


def test_a_radar_scan_goes_through_the_core_and_out_as_bsms():
    from tests.test_rsu_app_core import bsms, make_core
    core, _, _ = make_core(vehicles=())  # the case study's roads: arms of 120 m
    ev = Vehicle(-115.0, -1.75, 0.0, 20.1, "emergency")
    out = []
    for k in range(101):
        t = round(k * 0.01, 9)
        samples = []
        if k % 5 == 0:
            x, y = ev.at(t)
            samples.append(scan([observe(x, y, ev.v)], t=t, scan_id=k // 5))
        out += core.step(t, samples, horizon=t + 0.01)
    sent = bsms(out)
    assert core.counters.radar_scans == 21 and core.counters.frames == 0
    assert len(sent) >= 8  # 10 Hz from the first ready scan on, once confirmed (3 scans)
    assert len({tx.t_sim for tx, _ in sent}) == len(sent)
    speeds = [b.speed for _, b in sent]
    assert np.all(np.isfinite(np.asarray([[b.latitude, b.longitude] for _, b in sent], float)))
    assert speeds[-1] == pytest.approx(20.1, abs=1.5)


def test_bsm_stamps_are_the_last_camera_frames_a_radar_scan_neither_restamps_nor_lends_its_own():
    """The run's latency chain is the camera's (the seed paper's stage 1): a radar scan that did not update a
    camera track leaves its stamps alone; a track the radar updated last carries none."""
    p = stage(hits=1)
    cav = Vehicle(1.75, -30.0, math.pi / 2, 8.0)
    r = p.process(FakeFrame("rsu_cam", 0, 0.0, Pixels(0.0, [cav])), 0.0)
    r.detect_start, r.detect_end = 0.0, 0.05
    p.apply([r])
    (cam_track,) = p.tracker.last_assignment
    assert p.track_stamps[cam_track].frame == 0.0
    ev = Vehicle(-150.0, -1.75, 0.0, 20.0)
    rs = p.process_radar(scan([observe(*ev.at(0.05), ev.v)], t=0.05, scan_id=1), 0.05)
    rs.detect_start = rs.detect_end = 0.05
    p.apply([rs])
    (radar_track,) = p.tracker.last_assignment
    assert radar_track != cam_track
    assert p.track_stamps[cam_track].frame == 0.0  # not restamped by a scan that could not see it
    assert radar_track not in p.track_stamps
