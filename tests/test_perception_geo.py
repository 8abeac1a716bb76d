"""Box -> ground -> WGS-84: round trips against the world's camera, rendered vehicles, bad cameras."""
from __future__ import annotations

import math

import numpy as np
import pytest

from bridges.geo import GeoOrigin
from rsu_app.perception.geo import (VEHICLE_SIZE, BoxNoise, CameraModel, GeoError, box_to_ground, cut_edges,
                                    ground_fix, leaving_edges, near_ground_point, outline)

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


# -- the covariance of a box's ground point --------------------------------------------------------------------
def _case_camera() -> CameraModel:
    """The case study's RSU camera (6 m pole at the north-east corner, looking south-west), no rendering."""
    with World(WorldLayout(cameras=[_spec(**POSES[0])])) as w:
        c = w.cameras["c"]
        return CameraModel(c.K, c.R_wc, c.position)


def _exact_box(cam: CameraModel, x: float, y: float, yaw: float, dims) -> np.ndarray:
    """The bounding box of the projected 3D box the fit models (the class's clearance kept)."""
    from rsu_app.perception.geo import _box_corners

    uv, depth = cam.project(_box_corners(x, y, yaw, *dims))
    assert (depth > 0).all()
    return np.concatenate([uv.min(axis=0), uv.max(axis=0)])


def _nees(cam, x, y, yaw, label, noise: BoxNoise, draws: int, seed: int, size_rel: float = 0.0,
          heading_std: float = 0.0) -> np.ndarray:
    """Normalised errors of `ground_fix` when the box's edges (and, with size_rel / heading_std, the vehicle's
    true size and the heading the caller passes) are drawn from exactly the noise the covariance assumes."""
    rng = np.random.default_rng(seed)
    typical = VEHICLE_SIZE[label]
    out = []
    for _ in range(draws):
        dims = (*(np.array(typical[:3]) * (1 + size_rel * rng.standard_normal(3))), typical[3])
        b = _exact_box(cam, x, y, yaw, dims)
        extent = np.array([b[2] - b[0], b[3] - b[1]] * 2)
        b = b + rng.standard_normal(4) * np.hypot(noise.edge_px, noise.edge_rel * extent)
        p, C = ground_fix(b, cam, label, heading=yaw + heading_std * rng.standard_normal(), noise=noise)
        e = p - np.array([x, y])
        out.append(e @ np.linalg.solve(C, e))
    return np.array(out)


@pytest.mark.parametrize("x, label", [(-20.0, "car"), (-50.0, "car"), (-40.0, "emergency")])
def test_ground_covariance_is_calibrated_for_edge_noise(x, label):
    """Box edges perturbed by the noise the model assumes: the normalised errors are chi-square with 2 degrees
    of freedom (mean 2, 86.5 % within 2 sigma). A covariance off by a factor 1.5 either way, or one that
    ignored the growth of the edge noise with the box, fails this."""
    cam = _case_camera()
    noise = BoxNoise(edge_px=1.0, edge_rel=0.06, size_rel=0.0, heading_rad=0.0, floor_m=0.0)
    n = _nees(cam, x, -1.75, 0.0, label, noise, 300, seed=int(-x))
    assert 1.6 < n.mean() < 2.45, n.mean()
    assert 0.80 < np.mean(n <= 4.0) < 0.92, np.mean(n <= 4.0)


def test_ground_covariance_is_calibrated_for_size_and_heading():
    """The vehicle's true size drawn about the class's typical one, and the heading the tracker passes off by
    a little: the size and heading terms of the covariance (the centre's sensitivity to them) account for it.
    Without those terms the errors are far beyond their covariance."""
    cam = _case_camera()
    noise = BoxNoise(edge_px=0.5, edge_rel=0.0, size_rel=0.08, heading_rad=0.05, floor_m=0.0)
    n = _nees(cam, -30.0, -1.75, 0.0, "car", noise, 300, seed=7, size_rel=0.08, heading_std=0.05)
    assert 1.6 < n.mean() < 2.45 and 0.80 < np.mean(n <= 4.0) < 0.92, (n.mean(), np.mean(n <= 4.0))
    blind = BoxNoise(edge_px=0.5, edge_rel=0.0, size_rel=0.0, heading_rad=0.0, floor_m=0.0)
    m = _nees(cam, -30.0, -1.75, 0.0, "car", blind, 300, seed=7, size_rel=0.08, heading_std=0.05)  # same draws
    assert m.mean() > 1.5 * n.mean() and np.mean(m <= 4.0) < np.mean(n <= 4.0) - 0.05, (m.mean(), n.mean())


def test_ground_covariance_follows_the_viewing_ray_and_grows_with_range():
    """One pixel of a far vehicle's bottom edge is d^2 / (f h) metres along the ray but only d / f across it:
    from pixel noise alone the covariance's major axis lies along the viewing ray and grows about with the
    square of the range, its minor axis about linearly."""
    cam = _case_camera()
    pixels = BoxNoise(edge_px=1.0, edge_rel=0.0, size_rel=0.0, heading_rad=0.0, floor_m=0.0)
    sig = {}
    for x in (-15.0, -45.0):
        p, C = ground_fix(_exact_box(cam, x, -1.75, 0.0, VEHICLE_SIZE["car"]), cam, "car", heading=0.0,
                          noise=pixels)
        w, V = np.linalg.eigh(C)
        ray = p - cam.position[:2]
        ray /= np.linalg.norm(ray)
        angle = math.degrees(math.acos(min(1.0, abs(float(V[:, 1] @ ray)))))
        assert angle < 15.0, (x, angle)
        sig[x] = (math.sqrt(w[1]), math.sqrt(w[0]))
    (a15, c15), (a45, c45) = sig[-15.0], sig[-45.0]  # ranges 22 and 52 m from the pole: ratio 2.4
    assert 4.0 < a45 / a15 < 8.0 and 1.5 < c45 / c15 < 3.5 and a45 > 3 * c45, sig


def test_a_fit_reaching_the_camera_keeps_a_positive_definite_covariance():
    """A box at the picture's bottom-right corner, past its border, fitted as a long emergency vehicle heading
    north (a nearby track's heading): the fitted outline reaches within centimetres of the camera's plane, so
    the residual moves millions of pixels per metre one way and hardly at all the other. Inverting that
    information matrix as it stood gave negative variances (found in the operating-point sweep, where the
    tracker then refused every box of the frame); the covariance must stay positive definite, the direction
    the box does not constrain keeping about the prior's spread."""
    cam = _case_camera()
    box = (403.5902019739151, 341.34539687633514, 671.7128216028214, 470.5259236097336)
    p, C = ground_fix(box, cam, "emergency", heading=1.5710333141220378, border_px=2.0,
                      cut=[False, False, True, True])
    assert np.all(np.isfinite(p)) and np.all(np.isfinite(C))
    eig = np.linalg.eigvalsh(C)
    assert eig.min() > 0, C
    assert 0.5 * 50.0 ** 2 < eig.max() < 2 * 50.0 ** 2, eig  # geo._PRIOR_STD_M: nothing learnt along it


def test_an_edge_on_the_border_says_only_where_the_vehicle_leaves_the_picture():
    """A vehicle passing under the pole, its box cut by the bottom of the image: the cut edge carries no
    information and the others are less sure (`cut_edge_rel`), so its point is far less certain than the
    same vehicle's uncut box would make it; `cut_edges` flags an edge within a tenth of the box's extent
    of the border (detectors stop short of it), not an edge well inside."""
    cam = _case_camera()
    whole = _exact_box(cam, 1.75, -12.0, math.pi / 2, VEHICLE_SIZE["car"])
    assert whole[3] < 479  # inside the picture
    cut = whole.copy()
    cut[3] = 480.0
    _, C_whole = ground_fix(whole, cam, "car", heading=math.pi / 2, border_px=2.0)
    _, C_cut = ground_fix(cut, cam, "car", heading=math.pi / 2, border_px=2.0)
    assert np.trace(C_cut) > 4 * np.trace(C_whole), (np.trace(C_cut), np.trace(C_whole))
    assert cut_edges((100, 100, 200, 150), 640, 480, 2.0).tolist() == [False] * 4
    assert cut_edges((100, 100, 200, 476), 640, 480, 2.0).tolist() == [False, False, False, True]  # 4 < 37.6 px
    assert cut_edges((0.5, 100, 10, 110), 640, 480, 2.0).tolist() == [True, False, False, False]
    assert cut_edges((3, 100, 13, 110), 640, 480, 2.0).tolist() == [False] * 4  # 3 px > max(2, 1)


def test_edges_a_predicted_outline_says_are_cut_decide_the_fit_where_the_box_stops_short():
    """A car 55 % out of the picture at its bottom-right: its exact clipped box, then the same box stopping
    30 % short of both borders (what detectors give). Fitted as the car's ends, the short edges put it metres
    off; with the edges the car's predicted `outline` takes past the border marked `cut`, the fit keeps to
    the other two and lands within half a metre, as with the exact box."""
    cam = _case_camera()
    x, y, yaw = 1.75, 7.0, math.pi / 2
    whole = outline(x, y, yaw, cam, "car")
    assert np.allclose(whole, _exact_box(cam, x, y, yaw, VEHICLE_SIZE["car"]))
    leaving = leaving_edges(whole, 640, 480)
    assert leaving.tolist() == [False, False, True, True], whole
    clipped = np.minimum(whole, [640, 480, 640, 480])
    short = clipped - np.array([0, 0, 0.3 * (clipped[2] - clipped[0]), 0.3 * (clipped[3] - clipped[1])])
    def err(box, cut):
        return float(np.hypot(*(box_to_ground(box, cam, "car", heading=yaw, border_px=2.0, cut=cut) - [x, y])))

    assert err(clipped, None) < 0.5 and err(short, leaving) < 0.5, (err(clipped, None), err(short, leaving))
    assert err(short, None) > 2.0, err(short, None)
    p, C = ground_fix(short, cam, "car", heading=yaw, border_px=2.0, cut=leaving)
    assert np.hypot(*(p - [x, y])) < 0.5 and np.isfinite(C).all()
    assert outline(8.0, 8.0, math.pi / 4, cam, "car") is None  # straddles the camera plane: no box describes it
    with pytest.raises(ValueError, match="4 flags"):
        box_to_ground(short, cam, "car", heading=yaw, cut=[True, False])


@pytest.mark.parametrize("kw, word", [(dict(edge_px=-1.0), "edge_px"), (dict(size_rel=math.nan), "size_rel"),
                                      (dict(edge_px=0.0, floor_m=0.0), "singular")])
def test_bad_box_noise_is_named(kw, word):
    with pytest.raises(ValueError, match=word):
        BoxNoise(**kw)
