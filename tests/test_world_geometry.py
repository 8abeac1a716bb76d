"""Line of sight, camera projection and lidar frames against hand-computed geometry."""
from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("pybullet")

from master.world.ground_truth import mask_box, projected_box  # noqa: E402
from master.world.layout import Building, CameraSpec, LidarSpec, VehicleSpec, WorldLayout  # noqa: E402
from master.world.los import line_of_sight  # noqa: E402
from master.world.world import World  # noqa: E402

BOX = Building("b", 5.0, 5.0, 10.0, 10.0, 5.0)  # x, y in [0, 10], z in [0, 5]


@pytest.mark.parametrize("p,q,walls,inside", [
    ((-5, 5, 1), (15, 5, 1), 2, 10.0),                          # straight through: in and out
    ((5, 5, 1), (15, 5, 1), 1, 5.0),                            # starts inside: one wall
    ((-5, -5, 1), (15, 15, 1), 2, 10 * math.sqrt(2)),           # corner to corner diagonal
    ((-5, 5, 1), (15, 5, 11), 2, 3 * math.sqrt(1 + 0.25)),      # rises out through the roof at x = 3
    ((-5, 5, 6), (15, 5, 6), 0, 0.0),                           # over the roof
    ((-5, 12, 1), (15, 12, 1), 0, 0.0),                         # beside it
])
def test_line_of_sight_hand_computed(p, q, walls, inside):
    blocked, n, metres = line_of_sight(p, q, [BOX])
    assert (blocked, n) == (inside > 0, walls)
    assert metres == pytest.approx(inside, abs=1e-9)


def test_line_of_sight_sums_buildings():
    other = Building("c", 25.0, 5.0, 4.0, 10.0, 5.0)  # x in [23, 27]
    assert line_of_sight((-5, 5, 1), (35, 5, 1), [BOX, other]) == (True, 4, pytest.approx(14.0))


def _layout(**cam) -> WorldLayout:
    spec = dict(name="c", x=-10.0, y=-12.0, z=6.0, yaw=40.0, pitch=-12.0, roll=7.0, width=160, height=120,
                fov_deg=80.0)
    spec.update(cam)
    return WorldLayout(buildings=[Building("pillar", 20.0, 12.0, 2.0, 2.0, 4.0)], cameras=[CameraSpec(**spec)])


def test_projection_matches_rendered_pixels():
    """P = K[R|t] puts the pillar's centre on a pillar pixel in the segmentation mask, and its
    8 projected corners bound exactly the pillar's pixels (to a pixel), with pitch and roll."""
    with World(_layout()) as w:
        cam = w.cameras["c"]
        frame = cam.render(1.5)
        assert frame.rgb.shape == (120, 160, 3) and frame.rgb.dtype == np.uint8
        assert (frame.frame_id, frame.t, cam.frame_id) == (0, 1.5, 1)
        pillar = w.scene.building_ids["pillar"]
        ((u, v),), depth = cam.project(np.array([[20.0, 12.0, 2.0]]))
        assert depth[0] > 0
        assert frame.seg[int(v), int(u)] == pillar
        corners = [(x, y, z) for x in (19, 21) for y in (11, 13) for z in (0, 4)]
        expected = projected_box(cam, corners)
        seen = mask_box(frame.seg == pillar)
        assert seen is not None
        assert np.allclose(seen, expected, atol=1.0), (seen, expected)


def test_pixel_to_ground_inverts_projection():
    with World(_layout()) as w:
        cam = w.cameras["c"]
        (uv,), _ = cam.project(np.array([[15.0, 3.0, 0.0]]))
        assert np.allclose(cam.pixel_to_ground(*uv), (15.0, 3.0, 0.0), atol=1e-9)
        assert cam.pixel_to_ground(80.0, 0.0) is None or cam.pixel_to_ground(80.0, 0.0)[2] == pytest.approx(0)


def test_lidar_points_in_vehicle_frame():
    """A vehicle at rear axle (5, 25) heading 20 deg; its ray at azimuth -20 deg (sample 340 of 360)
    runs along world +x and hits the wall x = 20 of a building: the point in the vehicle frame is
    R(-20 deg) (20 - mount_x, 0). Another vehicle ahead is reported by body id; no self hits."""
    car = VehicleSpec("car", 4.0, 1.8, 1.5, rear_overhang=0.8,
                      lidar=LidarSpec(channels=3, horizontal_samples=360, range=60.0, fov_up=10.0, fov_down=-10.0))
    other = VehicleSpec("other", 4.0, 1.8, 1.5, rear_overhang=0.8)
    layout = WorldLayout(buildings=[Building("wall", 25.0, 25.0, 10.0, 30.0, 10.0)], vehicles={"car": car, "other": other})
    with World(layout) as w:
        yaw = math.radians(20)
        w.pose_vehicle("car", 5.0, 25.0, yaw)
        w.pose_vehicle("other", 5.0, 40.0, math.pi / 2)  # out of the ray's way
        scan = w.scan("car")
        assert scan.n_rays == 3 * 360
        assert w.scene.vehicle_ids["car"] not in scan.body_ids
        mount = np.array([5.0 + car.centre_offset * math.cos(yaw), 25.0 + car.centre_offset * math.sin(yaw)])
        hit_world = np.array([20.0, mount[1]])
        c, s = math.cos(yaw), math.sin(yaw)
        expected_xy = np.array([[c, s], [-s, c]]) @ (hit_world - [5.0, 25.0])
        z = car.height + car.lidar.mount_above_roof
        near = np.linalg.norm(scan.points[:, :2] - expected_xy, axis=1) < 1e-3
        assert np.any(near & (np.abs(scan.points[:, 2] - z) < 1e-3))
        assert w.scene.building_ids["wall"] in scan.body_ids[near]
        # put the other vehicle right in front: its id appears among the hits
        w.pose_vehicle("other", 12.0, 25.0 + 7.0 * math.tan(yaw) - 0.5, 0.0)
        assert w.scene.vehicle_ids["other"] in w.scan("car").body_ids


def test_each_world_has_its_own_client():
    import pybullet as pb

    a, b = World(_layout()), World(_layout())
    ids = (a.scene.client, b.scene.client)
    try:
        assert ids[0] != ids[1] and all(pb.isConnected(physicsClientId=i) for i in ids)
        assert pb.getNumBodies(physicsClientId=ids[0]) == pb.getNumBodies(physicsClientId=ids[1])
    finally:
        a.close()
        b.close()
    assert not any(pb.isConnected(physicsClientId=i) for i in ids)  # disconnected on close
