"""The IMA case study's world: the corner building blinds the cav's lidar; the RSU camera sees both.

Vehicles are posed at constant speed along their lanes from the scenario's own
start parameters (x0, y0, yaw0, v0; both FMUs hold their speed in this scenario).
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pybullet")

from master.scenario.loader import load_scenario  # noqa: E402
from master.world.ground_truth import frame_truth  # noqa: E402
from master.world.world import World  # noqa: E402

SCENARIO = Path(__file__).resolve().parent.parent / "scenarios" / "ima_world.toml"


@pytest.fixture(scope="module")
def case(fmu_dir):
    sc = load_scenario(SCENARIO)
    sc.world.cameras = [dataclasses.replace(c, width=160, height=120) for c in sc.world.cameras]  # small for speed
    w = World(sc.world)
    yield sc, w
    w.close()


def pose_at(sc, w, t):
    for name in ("cav", "ev"):
        p = sc.instances[name].parameters
        d = p["v0"] * t
        w.pose_vehicle(name, p["x0"] + d * math.cos(p["yaw0"]), p["y0"] + d * math.sin(p["yaw0"]), p["yaw0"], p["v0"])


def test_lidar_blind_until_shortly_before_conflict(case):
    """Scanning at the lidar's 10 Hz, the cav's first return from the ev is at t = 4.7 s
    (measured: 4.69 s at 0.01 s resolution), while the ev's front bumper reaches the
    cav's lane (x = 0.85 m) at 5.75 s and the cav's rear axle reaches the conflict point
    (1.75, -1.75) at 5.79 s: the lidar sees the ev about 1.05 s before the conflict.
    Before that the building is what blocks it: the sight line from the lidar to the
    ev crosses the building (2 walls) and the ev is well within the 100 m range."""
    sc, w = case
    ev = w.scene.vehicle_ids["ev"]
    lidar = w.lidars["cav"]
    first = None
    for k in list(range(0, 40, 5)) + list(range(40, 56)):  # 0.0..3.5 s every 0.5 s, then every 0.1 s
        t = k / lidar.spec.rate_hz
        pose_at(sc, w, t)
        hit = bool(np.any(w.scan("cav", t).body_ids == ev))
        if hit:
            first = t
            break
        if t >= 2.0:
            x, y, yaw, _ = w.scene.poses["cav"]
            mount = (x, y + sc.world.vehicles["cav"].centre_offset, 1.8)
            ex, ey, _, _ = w.scene.poses["ev"]
            blocked, walls, _ = w.line_of_sight(mount, (ex + 2.0, ey, 1.0))
            assert blocked and walls == 2 and math.dist(mount[:2], (ex, ey)) < lidar.spec.range, t
    assert first is not None, "the lidar never saw the ev before 5.5 s"
    cav, ev_p = sc.instances["cav"].parameters, sc.instances["ev"].parameters
    ev_spec = sc.world.vehicles["ev"]
    t_front_in_lane = (0.85 - (ev_spec.length - ev_spec.rear_overhang) - ev_p["x0"]) / ev_p["v0"]
    t_conflict = (-1.75 - cav["y0"]) / cav["v0"]
    assert t_front_in_lane == pytest.approx(5.75, abs=0.01) and t_conflict == pytest.approx(5.79, abs=0.01)
    lead = t_front_in_lane - first
    assert 0.8 <= lead <= 1.3, (first, lead)


@pytest.mark.parametrize("t", [2.0, 3.5, 5.0])
def test_rsu_camera_sees_both_approaches(case, t):
    """Ground-truth visible boxes are non-empty for the cav (south arm) and the ev (west arm),
    and each visible box lies inside the vehicle's projected 3D box (1 px slack)."""
    sc, w = case
    pose_at(sc, w, t)
    cam = w.cameras["rsu_cam"]
    frame = cam.render(t)
    truth = {v.name: v for v in frame_truth(w.scene, cam, frame)}
    for name in ("cav", "ev"):
        v = truth[name]
        assert v.visible_box is not None and v.visible_pixels > 0, (name, t)
        u0, v0, u1, v1 = v.visible_box
        b = v.box
        assert b[0] - 1 <= u0 < u1 <= b[2] + 1 and b[1] - 1 <= v0 < v1 <= b[3] + 1, (name, v.visible_box, b)
        assert 0.0 <= v.occlusion < 0.5
    assert truth["cav"].heading == pytest.approx(math.pi / 2) and truth["ev"].speed == pytest.approx(16.667)


def test_occlusion_fraction_when_hidden(case):
    """The ev parked beyond the building's far corner (-54, -54), on the camera's line through the
    building, is in the camera's field of view (projected box) but has no visible pixel: occlusion 1."""
    sc, w = case
    pose_at(sc, w, 0.0)
    w.pose_vehicle("ev", -62.0, -60.0, math.pi / 4)
    cam = w.cameras["rsu_cam"]
    frame = cam.render(0.0)
    truth = {v.name: v for v in frame_truth(w.scene, cam, frame)}
    assert truth["ev"].box is not None
    assert truth["ev"].visible_pixels == 0 and truth["ev"].occlusion == pytest.approx(1.0)
    assert truth["cav"].occlusion == pytest.approx(0.0)


def test_cosim_poses_vehicles_and_renders_at_rate(fmu_dir, tmp_path):
    """In the master's loop the world renders each camera at 10 Hz: 1 s gives frames at 0.0..1.0 s (11)."""
    from master.run.cosim import CoSimulation

    sc = load_scenario(SCENARIO)
    sc.time.stop = 1.0
    sc.world.cameras = [dataclasses.replace(c, width=160, height=120) for c in sc.world.cameras]
    result = CoSimulation(sc, run_dir=tmp_path / "run", quiet=True).run()
    assert result.status == "completed", result.error
    cam = result.metadata["world"]["cameras"]["rsu_cam"]
    assert cam["frames"] == 11 and cam["render_s"]["n"] == 11
    # bodies took the FMUs' poses: after 1 s at 30 km/h the cav's rear axle is ~8.3 m further north
    x, y, yaw = result.metadata["world"]["poses"]["cav"]
    assert (x, yaw) == (pytest.approx(1.75), pytest.approx(math.pi / 2))
    assert y == pytest.approx(-50.0 + 8.333, abs=0.05)
