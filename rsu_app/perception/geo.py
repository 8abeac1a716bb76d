"""From a detection box to the ground (local metres); `bridges.geo.GeoOrigin` takes it on to WGS-84.

Camera model: P = K [R | t] with R = R_wc^T, t = -R position (OpenCV axes:
x right, y down, z forward; world x east, y north, z up), as in the frames
the master publishes. A pixel's ray is R_wc K^-1 (u, v, 1) from the
optical centre; intersecting it with the plane z = 0 gives the ground point.

Which point touches the ground. Seen from a pole, the lowest pixel of a
vehicle (the box's bottom edge) is the corner of its footprint nearest the
camera, not the point under its centre: the bottom-centre pixel
back-projected (`near_ground_point`) lands 1-3 m short of the centre, more
for long vehicles seen end-on. `box_to_ground` therefore fits the vehicle's
3D box (class-typical length, width, height standing on z = 0) so that its
projection's bounding box matches the detected box (least squares on the
four edges, starting from the near point pushed back by half the
footprint), over the centre (x, y) and, when the tracker cannot supply the
heading, over a set of headings as well. Measured on rendered frames of the
case-study camera (tests/test_perception_geo.py), vehicles of the typical
size out to ~40 m: within 0.3 m of the true centre with the heading known,
also without it unless the vehicle is cut by the image border (then ~1.2 m),
against 0.5-3 m for the plain bottom-centre point. Not corrected: a vehicle of unusual size (the
class's typical size is assumed), and a vehicle whose lower part is
occluded (its visible box is not its full box: the fit is then off by
metres; the tracker's gating absorbs some of it). At long range one pixel
of the bottom edge is d^2 / (f h) metres along the ray (about 0.9 m at
40 m for the 6 m pole), which bounds any box-based method.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bridges.geo import GeoError  # one error type for camera models, pixels and origins

# length, width, height, ground clearance (m). The body's lowest edge, not the wheels' contact
# patch, bounds the box at the vehicle's ends (the wheels are inset), hence the clearance.
VEHICLE_SIZE = {"car": (4.5, 1.8, 1.5, 0.2), "emergency": (6.5, 2.3, 2.6, 0.27)}




def _finite(name: str, a, shape: tuple[int, ...]) -> np.ndarray:
    try:
        arr = np.asarray(a, dtype=float)
    except (TypeError, ValueError) as exc:
        raise GeoError(f"camera {name}: not numeric ({exc})") from exc
    if arr.shape != shape:
        raise GeoError(f"camera {name}: expected shape {shape}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise GeoError(f"camera {name}: contains NaN or infinity")
    return arr


@dataclass(frozen=True)
class CameraModel:
    K: np.ndarray  # 3x3 intrinsics
    R_wc: np.ndarray  # camera axes (columns) in world coordinates
    position: np.ndarray  # optical centre (m)

    def __post_init__(self):
        K = _finite("K", self.K, (3, 3))
        R = _finite("R_wc", self.R_wc, (3, 3))
        c = _finite("position", self.position, (3,))
        if abs(np.linalg.det(K)) < 1e-9 or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise GeoError(f"camera K: singular or without positive focal lengths: {K.tolist()}")
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise GeoError("camera R_wc: not a rotation (columns must be orthonormal, det +1)")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "R_wc", R)
        object.__setattr__(self, "position", c)

    @property
    def P(self) -> np.ndarray:
        R = self.R_wc.T
        return self.K @ np.hstack([R, (-R @ self.position)[:, None]])

    @classmethod
    def from_P(cls, P) -> "CameraModel":
        """Decompose a 3x4 projection matrix (RQ decomposition), e.g. when only P is known."""
        import cv2

        P = _finite("P", P, (3, 4))
        if np.linalg.matrix_rank(P[:, :3], tol=1e-9) < 3:
            raise GeoError("camera P: the left 3x3 block is singular")
        K, R, c_h = cv2.decomposeProjectionMatrix(P)[:3]
        K = K / K[2, 2]
        c = (c_h[:3] / c_h[3]).ravel()
        return cls(K, R.T, c)

    @classmethod
    def from_dict(cls, d: dict) -> "CameraModel":
        """From a frame's or a dataset image's camera: keys K, R_wc, position (P checked if present)."""
        if not isinstance(d, dict):
            raise GeoError(f"camera: expected a dict with K, R_wc, position, got {type(d).__name__}")
        if not all(k in d for k in ("K", "R_wc", "position")):
            if "P" in d:
                return cls.from_P(d["P"])
            raise GeoError(f"camera: needs K, R_wc and position (or P); has {sorted(d)}")
        cam = cls(d["K"], d["R_wc"], d["position"])
        if "P" in d:
            P = _finite("P", d["P"], (3, 4))
            if not np.allclose(P / np.linalg.norm(P), cam.P / np.linalg.norm(cam.P), atol=1e-6):
                raise GeoError("camera P disagrees with K [R | t] built from K, R_wc and position")
        return cam

    @classmethod
    def from_frame(cls, frame) -> "CameraModel":
        return cls(frame.K, frame.R_wc, frame.position)

    def project(self, points) -> tuple[np.ndarray, np.ndarray]:
        """World points (N, 3) -> pixels (N, 2) and depth along the optical axis (N,)."""
        pts = np.atleast_2d(np.asarray(points, float))
        cam = (pts - self.position) @ self.R_wc  # world -> camera axes
        depth = cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (cam @ self.K.T)[:, :2] / depth[:, None]
        return uv, depth

    def rays(self, uv) -> np.ndarray:
        """World directions (N, 3) of the rays through pixels (N, 2)."""
        uv = np.atleast_2d(np.asarray(uv, float))
        h = np.hstack([uv, np.ones((len(uv), 1))])
        return np.linalg.solve(self.K, h.T).T @ self.R_wc.T

    def pixel_to_ground(self, uv, z: float = 0.0) -> np.ndarray:
        """Pixels (N, 2) -> points (N, 3) on the plane at height z; NaN rows where the ray misses it."""
        d = self.rays(uv)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (z - self.position[2]) / d[:, 2]
        out = self.position + s[:, None] * d
        out[~(s > 0) | ~np.isfinite(s)] = np.nan
        return out


def near_ground_point(box, camera: CameraModel) -> np.ndarray:
    """The ground point (x, y) under the bottom-centre pixel of box (u0, v0, u1, v1)."""
    u0, v0, u1, v1 = (float(b) for b in box)
    if not all(math.isfinite(b) for b in (u0, v0, u1, v1)) or u1 < u0 or v1 < v0:
        raise GeoError(f"box must be finite with u1 >= u0, v1 >= v0, got {box!r}")
    p = camera.pixel_to_ground([[(u0 + u1) / 2, v1]])[0]
    if not np.isfinite(p).all():
        raise GeoError(f"box bottom ({(u0 + u1) / 2:.1f}, {v1:.1f}) is at or above the horizon: no ground point")
    return p[:2]


def _box_corners(x: float, y: float, yaw: float, L: float, W: float, H: float, clearance: float = 0.0) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    lx, ly, z = np.meshgrid([-L / 2, L / 2], [-W / 2, W / 2], [clearance, H], indexing="ij")
    lx, ly, z = lx.ravel(), ly.ravel(), z.ravel()
    return np.column_stack([x + c * lx - s * ly, y + s * lx + c * ly, z])


# A detector's box of a vehicle that leaves the picture often stops short of the border: on the
# validation set (data/val, both shipped networks) the median truly cut edge is on it, but a quarter stop
# 4 % of the box's extent short and a tenth 7-9 %; only 0.4 % of uncut edges lie within 10 %.
CUT_MARGIN_REL = 0.1


def cut_edges(box, width: float, height: float, border_px: float = 1.0) -> np.ndarray:
    """Which edges (u0, v0, u1, v1) of `box` are where the vehicle leaves a width x height picture rather than
    where it ends: within `border_px`, or `CUT_MARGIN_REL` of the box's width (u) or height (v), of the border."""
    u0, v0, u1, v1 = (float(b) for b in box)
    mu = max(border_px, CUT_MARGIN_REL * (u1 - u0))
    mv = max(border_px, CUT_MARGIN_REL * (v1 - v0))
    return np.array([u0 <= mu, v0 <= mv, u1 >= width - mu, v1 >= height - mv])


def _clipped(box: np.ndarray, camera: CameraModel, border_px: float, cut=None) -> np.ndarray:
    """`cut_edges` in the camera's picture (principal point at the image centre), or'ed with `cut`: edges
    known to be cut whatever the box shows (see `box_to_ground`)."""
    clipped = cut_edges(box, 2 * camera.K[0, 2], 2 * camera.K[1, 2], border_px)
    if cut is not None:
        cut = np.asarray(cut, dtype=bool)
        if cut.shape != (4,):
            raise ValueError(f"cut must be 4 flags (u0, v0, u1, v1), got shape {cut.shape}")
        clipped = clipped | cut
    return clipped


def outline(x: float, y: float, yaw: float, camera: CameraModel, label: str = "car",
            size: tuple[float, ...] | None = None) -> np.ndarray | None:
    """The image box (u0, v0, u1, v1) of a vehicle of the class's typical size (or `size`) centred at (x, y)
    with heading yaw, unclipped (it may reach past the picture's border); None when part of it is behind
    the camera (no box describes that)."""
    dims = size if size is not None else VEHICLE_SIZE.get(label, VEHICLE_SIZE["car"])
    uv, depth = camera.project(_box_corners(x, y, yaw, *dims))
    if np.any(depth <= 0.05):
        return None
    return np.concatenate([uv.min(axis=0), uv.max(axis=0)])


def leaving_edges(box, width: float, height: float) -> np.ndarray:
    """Which edges (u0, v0, u1, v1) of an unclipped image box (`outline`) lie past a width x height
    picture's border: where a vehicle there leaves the picture."""
    u0, v0, u1, v1 = (float(b) for b in box)
    return np.array([u0 < 0.0, v0 < 0.0, u1 > width, v1 > height])


def _residual_fn(box: np.ndarray, camera: CameraModel, yaw: float, dims, clipped: np.ndarray):
    """The fit's residual r(p) over the centre p = (x, y) for one heading and size: (projected box - box) /
    scale per edge (u0, v0, u1, v1). A `clipped` edge (`_clipped`) is where the vehicle leaves the picture:
    there the projection only has to reach at least as far out (residual 0 when it does)."""
    scale = max(box[2] - box[0], box[3] - box[1], 1.0)
    outward = np.array([-1.0, -1.0, 1.0, 1.0])  # the direction in which each edge leaves the image

    # the heading is fixed within one fit: rotate the corners once, then only translate them,
    # and project in camera axes directly (the residual runs a few dozen times per fit)
    local_cam = _box_corners(0.0, 0.0, yaw, *dims) @ camera.R_wc
    origin_cam = -camera.position @ camera.R_wc
    ex, ey = camera.R_wc[0], camera.R_wc[1]  # world x and y axes in camera axes
    K = camera.K

    def residual(p):
        cam = local_cam + (origin_cam + p[0] * ex + p[1] * ey)
        depth = cam[:, 2]
        if np.any(depth <= 0.05):
            return np.full(4, 1e3)
        uv = (cam @ K[:2].T) / depth[:, None]
        r = (np.concatenate([uv.min(axis=0), uv.max(axis=0)]) - box) / scale
        return np.where(clipped, np.minimum(0.0, r * outward), r)

    residual.scale = scale
    return residual


def _fit(box: np.ndarray, camera: CameraModel, start: np.ndarray, yaw: float, dims, clipped: np.ndarray):
    """Centre (x, y) whose projected 3D box best matches `box` at heading yaw, the squared cost, and the
    residual's Jacobian there (4x2, in the residual's units: pixels / scale)."""
    from scipy.optimize import least_squares

    r = least_squares(_residual_fn(box, camera, yaw, dims, clipped), start, method="trf", diff_step=1e-4,
                      max_nfev=60)
    return r.x, float(np.sum(r.fun ** 2)), r.jac


def rough_ground_point(box, camera: CameraModel, label: str = "car", size: tuple[float, ...] | None = None) -> np.ndarray:
    """Cheap first guess of the vehicle centre: the near ground point pushed back along the viewing ray by
    a quarter of (length + width); the start of `box_to_ground`'s fit (good to a metre or two)."""
    dims = size if size is not None else VEHICLE_SIZE.get(label, VEHICLE_SIZE["car"])
    L, W = dims[0], dims[1]
    near = near_ground_point(box, camera)
    ray = near - camera.position[:2]
    dist = float(np.hypot(*ray))
    return near + (L + W) / 4 * ray / dist if dist > 1e-6 else near


def box_to_ground(box, camera: CameraModel, label: str = "car", heading: float | None = None,
                  size: tuple[float, ...] | None = None, border_px: float = 1.0, cut=None) -> np.ndarray:
    """Estimated vehicle centre (x, y) on the ground from its box (see the module docstring).

    `size`: (length, width, height[, clearance]) in metres; default the class's typical size. `border_px`:
    an edge this close to the image border is where the vehicle leaves the picture, not where it ends.
    `cut`: 4 flags (u0, v0, u1, v1), edges known to be where the vehicle leaves the picture although the
    box stops short of the border (a detector's box of a vehicle mostly out of the picture often does:
    a track's predicted `outline` reaching past the border says so); None: only `border_px` decides."""
    dims = size if size is not None else VEHICLE_SIZE.get(label, VEHICLE_SIZE["car"])
    start = rough_ground_point(box, camera, label, size)
    b = np.array([float(v) for v in box])
    return _best_fit(b, camera, start, heading, dims, _clipped(b, camera, border_px, cut))[0][0]


def _best_fit(box: np.ndarray, camera: CameraModel, start: np.ndarray, heading: float | None, dims,
              clipped: np.ndarray):
    """(the fit at `heading`, or the best over a set of headings when it is None or not finite; its heading)."""
    if heading is not None and math.isfinite(heading):
        return _fit(box, camera, start, heading, dims, clipped), float(heading)
    fits = [(_fit(box, camera, start, yaw, dims, clipped), float(yaw))
            for yaw in np.linspace(0, math.pi, 6, endpoint=False)]
    return min(fits, key=lambda f: f[0][1])


@dataclass(frozen=True)
class BoxNoise:
    """What makes a box's ground point uncertain, each as a standard deviation; `ground_fix` propagates them
    through the fit to a covariance of the point.

    The defaults were chosen on the validation sets (data/val, never the held-out sets or the case study;
    `v2i eval-detector --ground` measures them): the shipped detectors' edge errors against the true
    visible boxes grow from 1 px for small boxes to 4-6 % of the box's width or height for large ones, and
    with these figures the normalised ground errors of their boxes average 1.8-2.8 with 79-89 % inside the
    2-sigma ellipse (2.0 and 86.5 % when the covariance is exactly right); the size term is what the
    validation set's spread of vehicle sizes about the class's typical size needs."""

    edge_px: float = 1.0             # each box edge, frame pixels ...
    edge_rel: float = 0.06           # ... plus this share of the box's width (u edges) or height (v edges)
    cut_edge_rel: float = 0.3        # ... or this share when the box is cut by the image border (the network
                                     # saw part of the vehicle: its other edges are guesses too)
    size_rel: float = 0.12           # the vehicle's length, width and height about its class's typical size
    heading_rad: float = 0.05        # a heading the caller supplies (a track's)
    search_heading_rad: float = 0.3  # a heading the fit had to search for itself (no track near)
    floor_m: float = 0.1             # per axis, for what the model leaves out (rendering, a flat-ground error)

    def __post_init__(self):
        bad = [f"{k} must be a finite number >= 0, got {getattr(self, k)!r}" for k in
               ("edge_px", "edge_rel", "cut_edge_rel", "size_rel", "heading_rad", "search_heading_rad", "floor_m")
               if not (isinstance(getattr(self, k), (int, float)) and math.isfinite(getattr(self, k))
                       and getattr(self, k) >= 0)]
        if not bad and self.edge_px == 0 and self.floor_m == 0:
            bad.append("edge_px and floor_m cannot both be 0: the covariance would be singular")
        if bad:
            raise ValueError("; ".join(bad))


_PRIOR_STD_M = 50.0  # a direction the box does not constrain at all (every edge on it clipped) keeps this much


def ground_fix(box, camera: CameraModel, label: str = "car", heading: float | None = None,
               size: tuple[float, ...] | None = None, noise: BoxNoise = BoxNoise(),
               border_px: float = 1.0, cut=None) -> tuple[np.ndarray, np.ndarray]:
    """`box_to_ground`'s centre (x, y) and its 2x2 covariance (m^2) (`cut` as there).

    Why a covariance per box rather than one figure for all: one pixel of a far vehicle's bottom edge is
    d^2 / (f h) metres along the viewing ray (about 0.9 m at 40 m for the 6 m pole) but only d / f across
    it, and an edge on the image border says nothing about where the vehicle ends. Linearised at the fit:
    with J = dr/dp the residual's Jacobian over the centre and W the edges' weights (1 / sigma^2, sigma
    growing with the box's size as the detector's edge errors do; edges on the border carry none: they
    only say the vehicle reaches at least that far), the edge noise gives (J^T W J)^-1; the size prior and
    the heading enter through the centre's sensitivity to them, -(J^T W J)^-1 J^T W dr/dq, and a floor is
    added on each axis."""
    dims = tuple(size if size is not None else VEHICLE_SIZE.get(label, VEHICLE_SIZE["car"]))
    start = rough_ground_point(box, camera, label, size)
    b = np.array([float(v) for v in box])
    clipped = _clipped(b, camera, border_px, cut)
    (p, _, J), yaw = _best_fit(b, camera, start, heading, dims, clipped)
    residual = _residual_fn(b, camera, yaw, dims, clipped)
    extent = np.array([b[2] - b[0], b[3] - b[1]] * 2)  # (w, h, w, h): width for u0, u1; height for v0, v1
    rel = noise.cut_edge_rel if clipped.any() else noise.edge_rel
    sigma_px = np.maximum(np.hypot(noise.edge_px, rel * extent), 1e-3)
    w = np.where(clipped, 0.0, (residual.scale / sigma_px) ** 2)  # per edge, 1/sigma_r^2
    # (J^T W J + I / prior^2)^-1 through the SVD of the whitened Jacobian, not by inverting the sum: when the
    # fitted outline reaches close to the camera the residual moves millions of pixels per metre one way and
    # hardly at all the other, and the direct inverse of so ill-conditioned a sum can have negative variances
    _, s, vt = np.linalg.svd(np.sqrt(w)[:, None] * J, full_matrices=False)
    cov_p = (vt.T / (s ** 2 + 1.0 / _PRIOR_STD_M ** 2)) @ vt
    gain = cov_p @ (J.T * w)  # d p / d r
    r0 = residual(p)

    def shift(dr_dq: np.ndarray, std: float) -> np.ndarray:
        s = -gain @ dr_dq
        return np.outer(s, s) * std ** 2

    cov = cov_p
    yaw_std = noise.heading_rad if heading is not None and math.isfinite(heading) else noise.search_heading_rad
    if yaw_std > 0:
        h = 1e-3
        cov = cov + shift((_residual_fn(b, camera, yaw + h, dims, clipped)(p) - r0) / h, yaw_std)
    if noise.size_rel > 0:
        for k in range(3):  # length, width, height
            d = list(dims)
            h = 1e-3 * d[k]
            d[k] += h
            cov = cov + shift((_residual_fn(b, camera, yaw, d, clipped)(p) - r0) / h, noise.size_rel * dims[k])
    cov = cov + np.eye(2) * noise.floor_m ** 2
    return p, (cov + cov.T) / 2
