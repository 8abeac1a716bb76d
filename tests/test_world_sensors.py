"""GNSS fixes (noise statistics, bias walk, determinism) and the lidar in the master's loop."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from master.errors import ScenarioError
from master.scenario.loader import load_scenario
from master.world.gnss import Gnss
from master.world.layout import GnssSpec

SCENARIO = Path(__file__).resolve().parent.parent / "scenarios" / "ima_world.toml"


def fixes(spec: GnssSpec, n: int, name: str = "cav", rate: float = 10.0, heading: float = 0.3, speed: float = 8.0):
    g = Gnss(spec, name)
    return np.array([dataclasses.astuple(g.fix(k / rate, 10.0, -20.0, 1.5, heading, speed)) for k in range(n)])


def test_white_noise_statistics():
    """20 000 fixes: means on the truth within 4 standard errors, stds within 3 %."""
    spec = GnssSpec(sigma_h=0.5, sigma_v=1.2, sigma_heading_deg=2.0, sigma_speed=0.1, seed=7)
    n = 20000
    f = fixes(spec, n)
    err = f[:, 1:6] - np.array([10.0, -20.0, 1.5, 0.3, 8.0])
    sigmas = np.array([0.5, 0.5, 1.2, math.radians(2.0), 0.1])
    assert np.all(np.abs(err.mean(axis=0)) < 4 * sigmas / math.sqrt(n)), err.mean(axis=0)
    assert np.allclose(err.std(axis=0), sigmas, rtol=0.03), err.std(axis=0)
    assert abs(np.corrcoef(err[:, 0], err[:, 1])[0, 1]) < 0.03  # independent axes
    assert np.allclose(f[:, 0], np.arange(n) / 10.0)


def test_noise_free_receiver_is_exact_and_speed_never_negative():
    exact = GnssSpec(sigma_h=0.0, sigma_v=0.0, sigma_heading_deg=0.0, sigma_speed=0.0)
    f = fixes(exact, 5, heading=3.5)  # heading wraps into [-pi, pi)
    assert np.allclose(f[:, 1:4], [10.0, -20.0, 1.5]) and np.allclose(f[:, 4], 3.5 - 2 * math.pi)
    slow = fixes(GnssSpec(sigma_speed=1.0), 2000, speed=0.0)
    assert slow[:, 5].min() == 0.0 and slow[:, 5].max() > 0.5


def test_bias_random_walk_grows_with_sqrt_time():
    """With bias_walk_h = 0.2 m/sqrt(s) and no white noise, after 25 s at 10 Hz the bias has
    std 0.2 * 5 = 1 m per axis across receivers; consecutive fixes differ by 0.2 * sqrt(0.1)."""
    spec = GnssSpec(sigma_h=0.0, sigma_v=0.0, bias_walk_h=0.2, bias_walk_v=0.0)
    ends, steps = [], []
    for i in range(400):
        f = fixes(dataclasses.replace(spec, seed=i), 251)
        ends.append(f[-1, 1] - 10.0)
        steps.extend(np.diff(f[:, 1]))
        assert np.allclose(f[:, 3], 1.5)  # no vertical walk
    assert np.std(ends) == pytest.approx(1.0, rel=0.12)
    assert np.std(steps) == pytest.approx(0.2 * math.sqrt(0.1), rel=0.03)


def test_deterministic_from_seed_and_vehicle():
    spec = GnssSpec(seed=3)
    a, b = fixes(spec, 50), fixes(spec, 50)
    assert np.array_equal(a, b)
    assert not np.allclose(a[:, 1], fixes(spec, 50, name="ev")[:, 1])  # another vehicle, same seed
    assert not np.allclose(a[:, 1], fixes(dataclasses.replace(spec, seed=4), 50)[:, 1])
    # changing one sigma does not shift the rest of the stream
    c = fixes(dataclasses.replace(spec, sigma_v=3.0), 50)
    assert np.array_equal(a[:, 1:3], c[:, 1:3])


@pytest.mark.parametrize("extra,expected", [
    ("sigma_h = -1.0", "world.vehicles.car.gnss.sigma_h: must be >= 0"),
    ("rate_hz = 0.0", "world.vehicles.car.gnss.rate_hz: must be > 0"),
    ("seed = 1.5", "world.vehicles.car.gnss.seed: expected an integer"),
    ("sigma = 1.0", "world.vehicles.car.gnss.sigma: unknown key"),
])
def test_bad_gnss_rejected_with_key(write_scenario, extra, expected):
    text = ('[time]\nstop = 1.0\nstep = 0.1\n[fmus.car]\nfmu = "{vehicle}"\n'
            f"[world.vehicles.car]\n[world.vehicles.car.gnss]\n{extra}\n")
    with pytest.raises(ScenarioError) as err:
        load_scenario(write_scenario(text))
    assert any(p.startswith(expected) for p in err.value.problems), err.value.problems


def test_gnss_defaults(write_scenario):
    sc = load_scenario(write_scenario('[time]\nstop = 1.0\nstep = 0.1\n[fmus.car]\nfmu = "{vehicle}"\n'
                                      "[world.vehicles.car.gnss]\nsigma_h = 2.0\n"))
    assert sc.world.vehicles["car"].gnss == GnssSpec(sigma_h=2.0)


def test_lidar_and_gnss_in_the_loop(fmu_dir, tmp_path):
    """The case study to 5 s: the cav's lidar scans at 10 Hz (51 scans at 0.0..5.0 s) and first hits
    the ev at 4.7 s (see test_world_case_study), then in every scan; its GNSS gives 51 fixes at 10 Hz
    whose horizontal error is near sigma_h * sqrt(2)."""
    pytest.importorskip("pybullet")
    from master.run.cosim import CoSimulation

    sc = load_scenario(SCENARIO)
    sc.time.stop = 5.0
    sc.world.cameras = [dataclasses.replace(c, width=64, height=48) for c in sc.world.cameras]
    sc.world.vehicles["cav"].gnss = GnssSpec(sigma_h=1.0, seed=1)
    result = CoSimulation(sc, run_dir=tmp_path / "run", quiet=True).run()
    assert result.status == "completed", result.error
    world = result.metadata["world"]
    lidar = world["lidars"]["cav"]
    assert lidar["scans"] == 51 and lidar["scan_s"]["n"] == 51 and lidar["rays_per_scan"] == 16 * 1024
    ev = lidar["vehicles"]["ev"]
    assert ev["first_hit_s"] == pytest.approx(4.7) and ev["scans_hit"] == 4 and ev["max_rays"] > 10
    assert set(lidar["vehicles"]) == {"ev"}  # never the carrier itself
    gnss = world["gnss"]["cav"]
    assert gnss["fixes"] == 51 and 0.9 < gnss["error_h_rms_m"] < 2.0
    assert world["speeds"]["cav"] == pytest.approx(8.333, abs=0.01)


def test_hits_by_vehicle_names_the_vehicles():
    pytest.importorskip("pybullet")
    from master.world.layout import LidarSpec, VehicleSpec, WorldLayout
    from master.world.world import World

    car = VehicleSpec("car", lidar=LidarSpec(channels=4, horizontal_samples=180, range=50.0))
    layout = WorldLayout(vehicles={"car": car, "van": VehicleSpec("van"), "far": VehicleSpec("far")})
    with World(layout) as w:
        w.pose_vehicle("car", 0.0, 0.0, 0.0)
        w.pose_vehicle("van", 10.0, 0.0, 0.0)  # 10 m ahead
        w.pose_vehicle("far", 0.0, 90.0, 0.0)  # out of range
        scan = w.scan("car", 1.0)
        hits = w.hits_by_vehicle(scan)
        assert set(hits) == {"van"} and hits["van"] == int(np.sum(scan.body_ids == w.scene.vehicle_ids["van"]))
        # the van's points, back in the world frame, lie in its bounding box, on the side facing the car
        pts = scan.world_points()[scan.body_ids == w.scene.vehicle_ids["van"]]
        box = np.array(w.scene.vehicle_box_corners("van"))
        assert np.all((pts >= box.min(axis=0) - 1e-6) & (pts <= box.max(axis=0) + 1e-6))
        assert pts[:, 0].max() < 12.0  # its rear half: x in [9.05, 13.55]


def test_every_ray_is_answered():
    """16 x 1024 = 16384 rays all pointing at the ground: 16384 points. (pybullet answers only
    16383 rays when given a batch of exactly 16384, so the lidar batches 16383.)"""
    pytest.importorskip("pybullet")
    from master.world.layout import LidarSpec, VehicleSpec, WorldLayout
    from master.world.world import World

    # 3 m above the roof, so that no ray between -40 and -30 deg meets the car itself first
    car = VehicleSpec("car", lidar=LidarSpec(channels=16, horizontal_samples=1024, fov_up=-30.0, fov_down=-40.0,
                                             mount_above_roof=3.0))
    with World(WorldLayout(vehicles={"car": car})) as w:
        w.pose_vehicle("car", 1.75, -20.0, 0.5)
        scan = w.scan("car")
        assert scan.n_rays == 16384 and len(scan.points) == 16384
        assert np.all(np.abs(scan.world_points()[:, 2]) < 0.16)  # ground, road, sidewalk (kerb 0.15 m)


def test_scan_points_are_bullets_own_hit_points_bit_for_bit():
    """The scan turns each hit's fraction into a point ((1 - f) from + f to, as Bullet does) instead of
    reading Bullet's per-hit position tuples: on the case-study scene (ground, roads, kerbs, the corner
    building, the ev in view) every point equals Bullet's hit position exactly, and the same rays hit."""
    pytest.importorskip("pybullet")
    from master.world.lidar import BATCH
    from master.world.quiet_pybullet import pybullet as pb
    from master.world.world import World

    layout = load_scenario(Path(__file__).resolve().parent.parent / "scenarios" / "ima_world.toml").world
    with World(dataclasses.replace(layout, cameras=[])) as w:
        w.pose_vehicle("cav", 1.75, -10.0, math.pi / 2)
        w.pose_vehicle("ev", -12.0, -1.75, 0.0)
        scan = w.scan("cav", 0.5)
        lidar = w.lidars["cav"]
        x, y, yaw = scan.pose
        c, s = math.cos(yaw), math.sin(yaw)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
        origin = np.array([x, y, 0.0]) + R @ lidar.mount
        ends = (origin + (lidar.directions @ R.T) * lidar.spec.range).tolist()
        hits = []
        for i in range(0, len(ends), BATCH):
            hits += pb.rayTestBatch([origin.tolist()] * len(ends[i:i + BATCH]), ends[i:i + BATCH],
                                    physicsClientId=w.scene.client)
        kept = [h for h in hits if h[0] >= 0 and h[0] != lidar.self_id]
        bullet = np.array([h[3] for h in kept])
        assert len(kept) == len(scan.points) > 8000
        assert np.array_equal(scan.body_ids, np.array([h[0] for h in kept], dtype=np.int32))
        assert np.array_equal(scan.points, (bullet - np.array([x, y, 0.0])) @ R)
        assert w.hits_by_vehicle(scan).get("ev", 0) > 0
