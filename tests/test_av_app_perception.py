"""AV app perception: ground removal, Euclidean clustering, oriented boxes, static structure, tracks.

Synthetic scans (two cars and a wall, points on their faces, a ground plane)
check the pipeline alone; a real scan of the case-study world checks that the
corner building comes out as static structure and the emergency vehicle as an
obstacle where it really is. The scan's hit labels score the result here; the
app never reads them.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from av_app.config import PerceptionSection
from av_app.geometry import corners, min_area_rect, overlap, overlap_boxes
from av_app.perception import LidarTracker, cluster_points, crop, detect

ROOT = Path(__file__).resolve().parent.parent


def box_surface(cx, cy, yaw, length, width, height, step=0.1):
    """Points on the four vertical faces of a box (what a lidar around it would see, and more)."""
    c = corners(cx, cy, yaw, length, width)
    pts = []
    for a, b in zip(c, np.roll(c, -1, 0)):
        n = max(2, int(np.linalg.norm(b - a) / step))
        u = np.linspace(0, 1, n)
        for z in np.arange(0.2, height, 0.2):
            pts.append(np.column_stack([a[0] + u * (b[0] - a[0]), a[1] + u * (b[1] - a[1]), np.full(n, z)]))
    return np.vstack(pts)


def ground(extent=40.0, step=0.25):
    g = np.arange(-extent, extent, step)
    x, y = np.meshgrid(g, g)
    return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])


CARS = [(12.0, 3.0, 0.3, 4.5, 1.8, 1.5), (-8.0, -6.0, -1.2, 4.6, 1.9, 1.6)]
WALL = (5.0, 20.0, 0.0, 30.0, 0.4, 3.0)


def synthetic_scan():
    return np.vstack([ground(), box_surface(*WALL)] + [box_surface(*c) for c in CARS]).astype(np.float32)


def test_ground_is_removed_and_two_cars_and_a_wall_are_three_clusters():
    cfg = PerceptionSection()
    pts = synthetic_scan()
    kept = crop(pts, cfg)
    assert kept[:, 2].min() > cfg.ground_z and len(kept) < len(pts) - len(ground()) + 1
    clusters = detect(pts, (0.0, 0.0, 0.0), cfg)
    assert len(clusters) == 3
    wall = [c for c in clusters if c.static]
    cars = sorted((c for c in clusters if not c.static), key=lambda c: -c.x)
    assert len(wall) == 1 and len(cars) == 2
    assert wall[0].length == pytest.approx(30.0, abs=0.5) and abs(wall[0].y - 20.0) < 0.3
    for got, (cx, cy, yaw, length, width, height) in zip(cars, CARS):
        assert math.hypot(got.x - cx, got.y - cy) < 0.15
        assert abs(math.remainder(got.yaw - yaw, math.pi)) < math.radians(3)  # a box axis: mod pi
        assert got.length == pytest.approx(length, abs=0.3) and got.width == pytest.approx(width, abs=0.3)
        assert got.height == pytest.approx(height - 0.1, abs=0.15)


def test_clusters_come_out_in_the_world_frame_through_the_ego_pose():
    cfg = PerceptionSection()
    pose = (100.0, -20.0, 0.7)
    c, s = math.cos(pose[2]), math.sin(pose[2])
    pts = box_surface(*CARS[0])
    world = detect(pts, pose, cfg)
    assert len(world) == 1
    # the car's box centre, rotated and moved by the ego pose
    x, y = pose[0] + CARS[0][0] * c - CARS[0][1] * s, pose[1] + CARS[0][0] * s + CARS[0][1] * c
    assert math.hypot(world[0].x - x, world[0].y - y) < 0.15
    assert abs(math.remainder(world[0].yaw - (CARS[0][2] + pose[2]), math.pi)) < math.radians(3)


def test_clusters_closer_than_the_tolerance_merge_and_farther_ones_do_not():
    cfg = PerceptionSection(cluster_tolerance=0.7)
    a = box_surface(10.0, 0.0, 0.0, 4.0, 1.8, 1.4)
    near = box_surface(14.5, 0.0, 0.0, 4.0, 1.8, 1.4)  # 0.5 m gap: one cluster
    far = box_surface(15.0, 0.0, 0.0, 4.0, 1.8, 1.4)   # 1.0 m gap: two
    assert len(cluster_points(crop(np.vstack([a, near]), cfg), cfg)) == 1
    assert len(cluster_points(crop(np.vstack([a, far]), cfg), cfg)) == 2


def test_min_area_rect_of_a_rotated_rectangle():
    rng = np.random.default_rng(3)
    u = rng.uniform(-1, 1, (400, 2)) * [2.0, 0.5]
    yaw = 0.9
    pts = u @ np.array([[math.cos(yaw), math.sin(yaw)], [-math.sin(yaw), math.cos(yaw)]]) + [5.0, -3.0]
    cx, cy, got_yaw, length, width = min_area_rect(pts)
    assert (cx, cy) == pytest.approx((5.0, -3.0), abs=0.05)
    assert abs(math.remainder(got_yaw - yaw, math.pi)) < 0.02 and length == pytest.approx(4.0, abs=0.05)
    assert width == pytest.approx(1.0, abs=0.05)
    assert overlap(corners(0, 0, 0, 4, 2), corners(3.9, 0, 0.3, 4, 2))
    assert not overlap(corners(0, 0, 0, 4, 2), corners(6.1, 0, 0, 4, 2))


def test_the_half_extent_box_test_agrees_with_the_corner_test():
    rng = np.random.default_rng(11)
    n = 20000
    a = rng.uniform(-3, 3, (n, 2)), rng.uniform(-np.pi, np.pi, n), rng.uniform(0.5, 6, n), rng.uniform(0.5, 3, n)
    b = rng.uniform(-3, 3, (n, 2)), rng.uniform(-np.pi, np.pi, n), rng.uniform(0.5, 6, n), rng.uniform(0.5, 3, n)
    by_corners = overlap(corners(a[0][:, 0], a[0][:, 1], a[1], a[2], a[3]), corners(b[0][:, 0], b[0][:, 1], b[1], b[2], b[3]))
    by_halves = overlap_boxes(a[0][:, 0], a[0][:, 1], a[1], a[2] / 2, a[3] / 2, b[0][:, 0], b[0][:, 1], b[1], b[2] / 2,
                              b[3] / 2)
    assert 0.2 < by_corners.mean() < 0.8 and np.array_equal(by_corners, by_halves)


def test_a_moving_car_gets_a_track_with_its_velocity_and_the_wall_stays_static():
    cfg = PerceptionSection()
    tracker = LidarTracker(cfg)
    v, heading = 10.0, 0.4
    for k in range(8):
        t = 0.1 * k
        car = box_surface(-10 + v * t * math.cos(heading), -5 + v * t * math.sin(heading), heading, 4.5, 1.8, 1.5)
        objs = tracker.update(t, detect(np.vstack([ground(), box_surface(*WALL), car]), (0, 0, 0), cfg))
    moving = [o for o in objs if not o.static]
    static = [o for o in objs if o.static]
    assert len(moving) == 1 and len(static) == 1
    assert moving[0].speed == pytest.approx(v, abs=0.5)
    assert abs(math.remainder(moving[0].yaw - heading, 2 * math.pi)) < math.radians(4)
    assert static[0].speed == 0.0 and static[0].id.startswith("static:")


def test_a_new_track_is_reported_only_once_confirmed():
    cfg = PerceptionSection(confirm_scans=2)
    tracker = LidarTracker(cfg)
    car = box_surface(10, 0, 0, 4.5, 1.8, 1.5)
    assert tracker.update(0.0, detect(car, (0, 0, 0), cfg)) == []
    assert len(tracker.update(0.1, detect(car, (0, 0, 0), cfg))) == 1


def _moving(x, y, yaw, length, width):
    from av_app.perception import Cluster

    return Cluster(x, y, yaw, length, width, 1.5, 40, False)


def test_a_vehicle_split_by_an_occluder_stays_one_track():
    """Issue 38, 25 mph 0.75 s early: the ev that had just crossed, split by an occluder into its rear
    (tracked) and a 0.75 x 0.01 m sliver at its front, gave the sliver a track of its own "moving" west at
    5.4 m/s, and the cav braked at 6 m/s^2 for it. A piece inside the gate of a track that took the other
    piece, its centre inside that vehicle's footprint (the ev: 6.5 m), is part of it: one track, its speed."""
    cfg = PerceptionSection()
    tracker = LidarTracker(cfg)
    v = 11.2
    for k in range(6):  # a whole ev, eastbound
        objs = tracker.update(0.1 * k, [_moving(10 + v * 0.1 * k, -1.75, 0.0, 6.5, 2.3)])
    x = 10 + v * 0.6
    for k, (rear, sliver) in enumerate(((3.4, x + 2.85), (3.2, x + v * 0.1 + 2.7), (3.0, x + 2 * v * 0.1 + 2.4))):
        t, front = 0.6 + 0.1 * k, x + v * 0.1 * k
        objs = tracker.update(t, [_moving(front - 3.25 + rear / 2, -1.75, 0.0, rear, 2.0),
                                  _moving(sliver - 0.9 * k, -1.75, 0.0, 0.75, 0.01)])  # a sliver "moving" west
        assert len(objs) == 1 and objs[0].speed > 8.0 and math.cos(objs[0].yaw) > 0.9, objs
    assert tracker.fragments == 3
    off = LidarTracker(PerceptionSection(fragments=False))  # the rule off: the sliver's own track
    for k in range(6):
        off.update(0.1 * k, [_moving(10 + v * 0.1 * k, -1.75, 0.0, 6.5, 2.3)])
    for k in range(3):
        objs = off.update(0.6 + 0.1 * k, [_moving(x + v * 0.1 * k - 1.55, -1.75, 0.0, 3.4, 2.0),
                                          _moving(x + 2.85 - 0.9 * k, -1.75, 0.0, 0.75, 0.01)])
    assert len(objs) == 2 and off.fragments == 0


def test_two_vehicles_close_together_stay_two_tracks():
    """The fragment rule does not merge a queue: a 4.5 m car 1 m behind another (inside its gate, widened
    here) has its centre outside the first's footprint."""
    cfg = PerceptionSection(gate_m=4.0)
    tracker = LidarTracker(cfg)
    for k in range(4):
        x = 10 + 8.0 * 0.1 * k
        objs = tracker.update(0.1 * k, [_moving(x, -1.75, 0.0, 4.5, 1.8)] if k < 2 else
                              [_moving(x, -1.75, 0.0, 4.5, 1.8), _moving(x + 5.5, -1.75, 0.0, 4.5, 1.8)])
    assert len(objs) == 2 and tracker.fragments == 0


# -- the case-study world ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def world(fmu_dir):
    pytest.importorskip("pybullet")
    from master.scenario.loader import load_scenario
    from master.world.world import World

    text = (ROOT / "tests" / "scenarios" / "av_case_study.toml").read_text()
    text = text.replace('fmu = "VehicleDynamics"', f'fmu = "{fmu_dir / "VehicleDynamics.fmu"}"')
    path = fmu_dir.parent / "av_perception_world.toml"
    path.write_text(text)
    sc = load_scenario(path)
    with World(sc.world) as w:
        yield w


def _scan(world, cav, ev):
    world.pose_vehicle("cav", *cav)
    world.pose_vehicle("ev", *ev)
    scan = world.scan("cav", 0.0)
    labels = {body: name for name, body in world.scene.vehicle_ids.items()}
    return scan, np.array([labels.get(int(b), "other") for b in scan.body_ids])


def test_case_study_scan_building_is_static_structure_and_the_ev_an_obstacle(world):
    cfg = PerceptionSection()
    cav = (1.75, -9.0, math.pi / 2)
    ev = (-8.0, -1.75, 0.0)  # rear axle; its body spans x -9.42 .. -2.92: in the cav's view past the corner
    scan, labels = _scan(world, cav, ev)
    assert (labels == "ev").sum() > 50  # ground truth: the lidar does see it
    clusters = detect(scan.points, cav, cfg)
    static = [c for c in clusters if c.static]
    moving = [c for c in clusters if not c.static]
    # the corner building (x, y in -54 .. -6): static, its box inside the building's footprint
    assert any(-56 < c.x < -4 and -56 < c.y < -4 and c.length > 9.0 for c in static)
    assert not any(-54 < c.x < -6 and -54 < c.y < -6 for c in moving)
    # the ev: one obstacle whose box overlaps its true footprint (centre 1.83 m ahead of the rear axle)
    truth = corners(ev[0] + 1.83, ev[1], ev[2], 6.5, 2.3)
    hits = [c for c in moving if overlap(corners(c.x, c.y, c.yaw, c.length, c.width), truth)]
    assert len(hits) == 1 and hits[0].height > 2.0


def test_case_study_ev_behind_the_building_is_not_seen_and_nothing_moves(world):
    """Driving up to the junction with the ev hidden: the building stays static structure in every scan,
    and no track ever gets a speed (a changing view of a wall is not a moving obstacle)."""
    cfg = PerceptionSection()
    tracker = LidarTracker(cfg)
    for k in range(10):
        cav = (1.75, -30.0 + 0.8 * k, math.pi / 2)  # 8 m/s
        scan, labels = _scan(world, cav, (-60.0, -1.75, 0.0))
        assert (labels == "ev").sum() == 0
        objs = tracker.update(0.1 * k, detect(scan.points, cav, cfg))
        assert all(o.static or o.speed < 1.0 for o in objs), [o for o in objs if not o.static]
    assert any(o.static for o in objs)


def test_case_study_turn_with_the_road_map_the_building_never_becomes_an_obstacle(world):
    """Along the cav's route through the right turn (the building's east wall then seen at grazing angles,
    in small pieces), with the road map of the master's world: nothing but static structure."""
    from av_app.lanes import LaneMap
    from av_app.route import Route

    cfg = PerceptionSection()
    lanes = LaneMap.from_world({"intersection": {"road_width": 7.0, "arm_length": 120.0}})
    tracker = LidarTracker(cfg, lanes.on_road)
    route = Route([[1.75, -120.0], [1.75, -1.75], [120.0, -1.75]], 6.0)
    pieces = 0
    for k, s in enumerate(np.arange(100.0, 140.0, 0.5)):  # 5 m/s: 0.5 m per 0.1 s scan
        x, y, yaw, _ = route.at(s)
        pose = (float(x), float(y), float(yaw))
        scan, labels = _scan(world, pose, (-119.0, -1.75, 0.0))  # the ev parked far out of range
        clusters = detect(scan.points, pose, cfg)
        pieces += sum(1 for c in clusters if not c.static and not lanes.on_road(c.x, c.y, cfg.road_margin_m))
        objs = tracker.update(0.1 * k, clusters)
        assert all(o.static for o in objs), [o for o in objs if not o.static]
    assert pieces > 0  # there were small off-road pieces of wall to classify
