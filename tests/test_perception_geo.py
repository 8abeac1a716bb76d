"""Box -> ground -> WGS-84: round trips against the world's camera, rendered vehicles, bad cameras."""
from __future__ import annotations

import math

import numpy as np
import pytest

from bridges.geo import GeoOrigin
from rsu_app.perception.geo import CameraModel, GeoError, box_to_ground, near_ground_point

pytest.importorskip("pybullet")

from master.world.layout import Building, CameraSpec, VehicleSpec, WorldLayout  # noqa: E402
from master.world.world import World  # noqa: E402

POSES = [dict(x=6.5, y=6.5, z=6.0, yaw=225.0, pitch=-14.0, roll=0.0, fov_deg=100.0),
         dict(x=-10.0, y=-12.0, z=6.0, yaw=40.0, pitch=-12.0, roll=7.0, fov_deg=80.0),
         dict(x=0.0, y=30.0, z=12.0, yaw=-90.0, pitch=-35.0, roll=-3.0, fov_deg=60.0)]


def _spec(w=640, h=480, **pose) -> CameraSpec:
    return CameraSpec(name="c", width=w, height=h, **pose)


@pytest.mark.parametrize("pose", POSES)
def test_pixel_ground_round_trip_matches_world_camera(pose):
    with World(WorldLayout(cameras=[_spec(**pose)])) as w:
        cam = w.cameras["c"]
        frame = cam.render()
    model = CameraModel.from_frame(frame)
    assert np.allclose(model.P, frame.P, atol=1e-9)
    rng = np.random.default_rng(0)
    ground = np.column_stack([rng.uniform(-30, 30, 50), rng.uniform(-30, 30, 50), np.zeros(50)])
    uv, depth = model.project(ground)
    uv_world, _ = cam.project(ground)
    assert np.allclose(uv, uv_world, atol=1e-9)
    front = depth > 0.5
    back = model.pixel_to_ground(uv[front])
    assert np.allclose(back, ground[front], atol=1e-6)
    for (u, v) in uv[front][:10]:
        assert np.allclose(model.pixel_to_ground([[u, v]])[0], cam.pixel_to_ground(u, v), atol=1e-9)
    # the top row of a camera looking slightly down sees the sky: no ground point
    if pose["pitch"] > -20:
        assert np.isnan(model.pixel_to_ground([[320, 0]])).all()
        with pytest.raises(GeoError, match="horizon"):
            near_ground_point((300, 0, 340, 1), model)


def test_from_P_and_from_dict_recover_the_pose():
    with World(WorldLayout(cameras=[_spec(**POSES[1])])) as w:
        frame = w.cameras["c"].render()
    m = CameraModel.from_P(frame.P)
    assert np.allclose(m.K, frame.K, atol=1e-6) and np.allclose(m.R_wc, frame.R_wc, atol=1e-9)
    assert np.allclose(m.position, frame.position, atol=1e-6)
    d = {"P": frame.P.tolist(), "K": frame.K.tolist(), "R_wc": frame.R_wc.tolist(), "position": frame.position.tolist()}
    assert np.allclose(CameraModel.from_dict(d).P, frame.P)
    assert np.allclose(CameraModel.from_dict({"P": d["P"]}).position, frame.position, atol=1e-6)
    bad = dict(d, position=[0.0, 0.0, 9.0])
    with pytest.raises(GeoError, match="disagrees"):
        CameraModel.from_dict(bad)


K = [[300.0, 0, 320], [0, 300.0, 240], [0, 0, 1]]
R = np.eye(3).tolist()


@pytest.mark.parametrize("kw,match", [
    (dict(K=[[np.nan, 0, 320], [0, 300, 240], [0, 0, 1]], R_wc=R, position=[0, 0, 5]), "K: contains NaN"),
    (dict(K=[[0.0, 0, 320], [0, 0, 240], [0, 0, 1]], R_wc=R, position=[0, 0, 5]), "K: singular"),
    (dict(K=K, R_wc=(2 * np.eye(3)).tolist(), position=[0, 0, 5]), "not a rotation"),
    (dict(K=K, R_wc=R, position=[0, np.inf, 5]), "position: contains NaN or infinity"),
    (dict(K=K[:2], R_wc=R, position=[0, 0, 5]), r"K: expected shape \(3, 3\)"),
])
def test_bad_camera_matrices_are_named(kw, match):
    with pytest.raises(GeoError, match=match):
        CameraModel(**kw)


def test_singular_or_nan_P_rejected():
    with pytest.raises(GeoError, match="singular"):
        CameraModel.from_P(np.zeros((3, 4)))
    with pytest.raises(GeoError, match="NaN"):
        CameraModel.from_P(np.full((3, 4), np.nan))


def test_rendered_vehicle_box_to_ground_centre():
    """Boxes of rendered vehicles (from the segmentation mask) -> estimated centre within 0.4 m of the
    true body centre with the heading known, and mostly without it, out to ~40 m; two of the
    vehicles are cut by the image border."""
    from master.world.ground_truth import frame_truth

    spec = _spec(**POSES[0])
    car = VehicleSpec("car", 4.5, 1.8, 1.5, (0.1, 0.3, 0.85))
    ev = VehicleSpec("ev", 6.5, 2.3, 2.6, (0.9, 0.08, 0.08), kind="emergency", rear_overhang=1.42)
    cases = [(1.75, -15.0, math.pi / 2), (-20.0, -1.75, 0.0), (-1.75, -30.0, math.pi / 2), (12.0, -1.75, math.pi),
             (-30.0, 1.75, math.pi), (1.75, 8.0, -math.pi / 2)]
    errs_known, errs_unknown, errs_near = [], [], []
    with World(WorldLayout(buildings=[Building("sw", -30, -30, 48, 48, 15)], cameras=[spec],
                           vehicles={"car": car, "ev": ev})) as w:
        cam = w.cameras["c"]
        for k, (x, y, yaw) in enumerate(cases):
            name, spec_v = ("car", car) if k % 2 == 0 else ("ev", ev)
            other = "ev" if name == "car" else "car"
            w.pose_vehicle(other, 500.0, 500.0, 0.0)
            w.pose_vehicle(name, x, y, yaw)
            frame = cam.render()
            truth = next(t for t in frame_truth(w.scene, cam, frame, occlusion=False) if t.name == name)
            assert truth.visible_box is not None, (name, x, y)
            model = CameraModel.from_frame(frame)
            centre = np.array([x, y]) + spec_v.centre_offset * np.array([math.cos(yaw), math.sin(yaw)])
            label = "car" if name == "car" else "emergency"
            errs_known.append(np.linalg.norm(box_to_ground(truth.visible_box, model, label, heading=yaw) - centre))
            errs_unknown.append(np.linalg.norm(box_to_ground(truth.visible_box, model, label) - centre))
            errs_near.append(np.linalg.norm(near_ground_point(truth.visible_box, model) - centre))
    assert max(errs_known) < 0.4, errs_known
    assert np.median(errs_unknown) < 0.4 and max(errs_unknown) < 1.5, errs_unknown
    assert np.mean(errs_known) < 0.3 * np.mean(errs_near)  # the plain bottom-centre point is much worse


def test_enu_geodetic_round_trip():
    origin = GeoOrigin(42.3, -83.7, 250.0)  # Ann Arbor-ish
    x, y, z = np.array([0.0, 100.0, -250.0, 1234.5]), np.array([0.0, -50.0, 75.0, 800.0]), np.zeros(4)
    lat, lon, h = origin.to_geodetic(x, y, z)
    assert lat[0] == pytest.approx(42.3) and lon[0] == pytest.approx(-83.7) and h[0] == pytest.approx(250.0)
    # 100 m east at 42.3 deg N is ~ 100 / (111320 cos 42.3) deg of longitude
    assert lon[1] - lon[0] == pytest.approx(100 / (111320 * math.cos(math.radians(42.3))), rel=5e-3)
    assert lat[1] < lat[0] and lat[2] > lat[0]
    e, n, u = origin.to_local(lat, lon, h)
    assert np.allclose(e, x, atol=1e-6) and np.allclose(n, y, atol=1e-6) and np.allclose(u, z, atol=1e-6)


@pytest.mark.parametrize("args", [(np.nan, 0.0, 0.0), (91.0, 0.0, 0.0), (0.0, 181.0, 0.0)])
def test_bad_origin(args):
    with pytest.raises(GeoError):
        GeoOrigin(*args)


def test_bad_boxes():
    model = CameraModel(K, [[1, 0, 0], [0, 0, -1], [0, 1, 0]], [0, 0, 5])  # looking along +y, level
    with pytest.raises(GeoError, match="finite"):
        box_to_ground((np.nan, 0, 1, 1), model)
    with pytest.raises(GeoError, match="u1 >= u0"):
        box_to_ground((10, 0, 5, 300), model)
