"""Own perception: the roof lidar's scan -> obstacles with oriented boxes and velocities.

Pipeline per scan (Autoware's Euclidean-cluster chain, in bird's-eye view):

1. crop: drop ground returns (height above the road below `ground_z`; the road
   is flat, the kerb 0.15 m), overhead returns, and returns too near or far;
2. downsample: one point per `voxel` x `voxel` ground cell: the 16 channels
   hitting a wall at one azimuth land on (nearly) one spot of the ground
   plane, and without the grid every such column makes its own dense clique of
   neighbour pairs (measured: 20x the clustering time, benchmarks/av_app.py);
3. cluster: cells closer than `cluster_tolerance` are neighbours
   (scipy's cKDTree.query_pairs), clusters are the connected components of that
   graph (scipy.sparse.csgraph) - O(n log n), no hand-written n^2 loop;
4. boxes: the minimum-area rectangle of each cluster, in the world frame through
   the ego pose (from the ego filter, never the scan's ground-truth pose);
5. static structure: a cluster longer or wider than any vehicle (a building
   wall), or one off the roads (more than `road_margin_m` beyond the kerb: a
   building's wall seen at a grazing angle breaks into small pieces), is
   reported as static structure, never tracked as a moving obstacle;
6. tracking: clusters are associated with tracks by Hungarian assignment
   (scipy.optimize.linear_sum_assignment) on centre distance within a gate; a
   constant-velocity Kalman filter (filterpy) per track gives the velocity.

The scan's per-point hit labels are ground truth and are not read here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from filterpy.kalman import KalmanFilter
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from av_app.config import PerceptionSection
from av_app.geometry import min_area_rect, to_frame, wrap


@dataclass(frozen=True)
class Cluster:
    """One obstacle in one scan, world frame."""

    x: float
    y: float
    yaw: float
    length: float
    width: float
    height: float
    n: int  # points
    static: bool


@dataclass(frozen=True)
class LidarObject:
    """A tracked obstacle (or a piece of static structure) as perception reports it."""

    id: str
    t: float  # the scan time it describes
    x: float
    y: float
    yaw: float
    speed: float
    vx: float
    vy: float
    length: float
    width: float
    static: bool
    hits: int  # scans that saw it
    pos_std: float


def crop(points: np.ndarray, cfg: PerceptionSection) -> np.ndarray:
    """Above-ground, in-range returns (vehicle frame, N x 3)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(1)]
    r2 = p[:, 0] ** 2 + p[:, 1] ** 2
    keep = (p[:, 2] > cfg.ground_z) & (p[:, 2] < cfg.max_z) & (r2 >= cfg.min_range ** 2) & (r2 <= cfg.max_range ** 2)
    return p[keep]


def cluster_points(xyz: np.ndarray, cfg: PerceptionSection) -> list[tuple[np.ndarray, float]]:
    """Euclidean clusters of cropped points in the ground plane: [(their points (n, 2), top height)].

    The graph is built on occupied ground cells (`voxel`), the boxes later on the points themselves.
    """
    if len(xyz) == 0:
        return []
    cells = np.floor(xyz[:, :2] / cfg.voxel).astype(np.int64)
    key = cells[:, 0] * 2_000_003 + cells[:, 1]
    uniq, first, cell_of_point = np.unique(key, return_index=True, return_inverse=True)
    centres = (cells[first] + 0.5) * cfg.voxel
    n = len(centres)
    pairs = cKDTree(centres).query_pairs(cfg.cluster_tolerance, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs), bool), (pairs[:, 0], pairs[:, 1])), shape=(n, n)) if len(pairs) else \
        coo_matrix((n, n), dtype=bool)
    count, labels = connected_components(graph, directed=False)
    cells_per_cluster = np.bincount(labels, minlength=count)
    point_label = labels[cell_of_point.ravel()]
    order = np.argsort(point_label, kind="stable")
    bounds = np.r_[0, np.cumsum(np.bincount(point_label, minlength=count))]
    out = []
    for c in range(count):
        if cells_per_cluster[c] < cfg.min_points:
            continue
        pts = xyz[order[bounds[c]:bounds[c + 1]]]
        out.append((pts[:, :2], float(pts[:, 2].max())))
    return out


def detect(points: np.ndarray, pose: tuple[float, float, float], cfg: PerceptionSection) -> list[Cluster]:
    """The clusters of one scan (vehicle-frame points) as world-frame boxes, given the ego pose."""
    xyz = crop(points, cfg)
    x0, y0, yaw0 = pose
    c, s = math.cos(yaw0), math.sin(yaw0)
    out = []
    for pts, height in cluster_points(xyz, cfg):
        wx = x0 + pts[:, 0] * c - pts[:, 1] * s
        wy = y0 + pts[:, 0] * s + pts[:, 1] * c
        cx, cy, yaw, length, width = min_area_rect(np.column_stack([wx, wy]))
        static = length > cfg.static_length or width > cfg.static_width
        out.append(Cluster(cx, cy, yaw, length, width, height, len(pts), static))
    return out


class _Track:
    def __init__(self, tid: int, cl: Cluster, t: float, cfg: PerceptionSection):
        self.id, self.t, self.cfg = tid, t, cfg
        kf = KalmanFilter(4, 2)
        kf.x = np.array([cl.x, cl.y, 0.0, 0.0])
        kf.H = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])
        kf.R = np.eye(2) * cfg.measurement_sigma ** 2
        kf.P = np.diag([cfg.measurement_sigma ** 2] * 2 + [15.0 ** 2] * 2)  # speed unknown: up to ~15 m/s
        self.kf = kf
        self.hits, self.missed = 1, 0
        self.box = cl
        self.extent = self._extent(cl, (0.0, 0.0))  # the longest and widest box seen: the vehicle's size

    def _extent(self, cl: Cluster, seen: tuple[float, float]) -> tuple[float, float]:
        cap = (self.cfg.static_length, self.cfg.static_width)  # never larger than a vehicle
        return min(max(seen[0], cl.length), cap[0]), min(max(seen[1], cl.width), cap[1])

    def _FQ(self, dt: float):
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        q = self.cfg.accel_noise ** 2
        Q = np.zeros((4, 4))
        for i, j in ((0, 2), (1, 3)):
            Q[i, i] = q * dt ** 4 / 4
            Q[i, j] = Q[j, i] = q * dt ** 3 / 2
            Q[j, j] = q * dt ** 2
        return F, Q

    def predict(self, t: float) -> None:
        dt = t - self.t
        if dt > 0:
            F, Q = self._FQ(dt)
            self.kf.predict(F=F, Q=Q)
            self.t = t

    def update(self, cl: Cluster) -> None:
        self.kf.update(np.array([cl.x, cl.y]))
        self.hits += 1
        self.missed = 0
        self.box = cl
        self.extent = self._extent(cl, self.extent)

    def report(self) -> LidarObject:
        x, y, vx, vy = (float(v) for v in self.kf.x)
        if self.missed == 0:
            # seen in this scan: its box is where it is now; the filter's position lags behind a box
            # centre that moves unevenly (a vehicle coming out from behind a building grows its box)
            x, y = self.box.x, self.box.y
        speed = math.hypot(vx, vy)
        yaw = self.box.yaw  # the box axis (mod pi) while the object is (nearly) still
        if speed > 1.0:
            yaw = math.atan2(vy, vx)  # moving: the heading is the direction of motion
        elif speed > 0.2 and math.cos(yaw - math.atan2(vy, vx)) < 0:
            yaw = float(wrap(yaw + math.pi))
        std = math.sqrt(max(self.kf.P[0, 0] + self.kf.P[1, 1], 0.0) / 2)
        return LidarObject(f"lidar:{self.id}", self.t, x, y, yaw, speed, vx, vy, self.box.length, self.box.width,
                           False, self.hits, std)


class LidarTracker:
    """Clusters per scan -> tracks with velocity; static structure reported per scan, untracked.

    `on_road(x, y, margin)` (av_app.lanes.LaneMap.on_road) tells road from off-road; without it
    only size makes static structure.
    """

    def __init__(self, cfg: PerceptionSection, on_road=None):
        self.cfg, self.on_road = cfg, on_road
        self.tracks: list[_Track] = []
        self._next = 1
        self.t: float | None = None
        self.scans = 0
        self.last_clusters = 0
        self.last_static: list[LidarObject] = []
        self.fragments = 0  # clusters taken as pieces of a tracked vehicle (see _fragments)

    def update(self, t: float, clusters: list[Cluster]) -> list[LidarObject]:
        """Take one scan's clusters at time t; returns the confirmed tracks and the static structure."""
        cfg = self.cfg
        self.scans += 1
        self.last_clusters = len(clusters)
        if self.on_road is not None and cfg.road_margin_m > 0:
            clusters = [c if c.static or self.on_road(c.x, c.y, cfg.road_margin_m) else replace(c, static=True)
                        for c in clusters]
        moving = [c for c in clusters if not c.static]
        static = [c for c in clusters if c.static]
        for tr in self.tracks:
            tr.predict(t)
        pairs = []
        if self.tracks and moving:
            pred = np.array([tr.kf.x[:2] for tr in self.tracks])
            obs = np.array([[c.x, c.y] for c in moving])
            cost = np.linalg.norm(pred[:, None, :] - obs[None, :, :], axis=-1)
            # partially seen vehicles move their box centre: the gate grows with the box
            gate = np.array([cfg.gate_m + 0.5 * max(tr.box.length, 0.0) for tr in self.tracks])[:, None]
            big = 1e6
            rows, cols = linear_sum_assignment(np.where(cost <= gate, cost, big))
            pairs = [(r, c) for r, c in zip(rows, cols) if cost[r, c] <= gate[r, 0]]
        used_t, used_c = {r for r, _ in pairs}, {c for _, c in pairs}
        used_c |= self._fragments(pairs, moving, used_c)
        for r, c in pairs:
            self.tracks[r].update(moving[c])
        for i, tr in enumerate(self.tracks):
            if i not in used_t:
                tr.missed += 1
        self.tracks = [tr for tr in self.tracks if tr.missed <= cfg.max_missed]
        for c, cl in enumerate(moving):
            if c not in used_c:
                self.tracks.append(_Track(self._next, cl, t, cfg))
                self._next += 1
        self.t = t
        self.last_static = [LidarObject(f"static:{i}", t, c.x, c.y, c.yaw, 0.0, 0.0, 0.0, c.length, c.width, True,
                                        1, 0.1) for i, c in enumerate(static)]
        return self.objects()

    def _fragments(self, pairs, moving: list[Cluster], taken: set[int]) -> set[int]:
        """The unmatched clusters that are pieces of a vehicle whose other piece a track took this scan.

        An occluder between the lidar and a passing vehicle splits it in clusters; the track takes the
        nearest piece and, without this, another starts a track of its own whose velocity comes from a
        sliver's centre jumping as the split moves (measured: a 0.75 x 0.01 m piece of the ev that had just
        crossed, "moving" west at 5.4 m/s, braked the cav at 6 m/s^2). A piece is a cluster whose centre lies
        inside the footprint of a matched track - its longest and widest box so far, centred on its
        prediction, along its motion (its box axis when slow) - plus `fragment_margin_m`: the centre of
        another vehicle cannot be inside this one."""
        if not pairs or not self.cfg.fragments:
            return set()
        free = [c for c in range(len(moving)) if c not in taken]
        if not free:
            return set()
        margin = self.cfg.fragment_margin_m
        xs, ys = np.array([moving[c].x for c in free]), np.array([moving[c].y for c in free])
        piece = np.zeros(len(free), dtype=bool)
        for r, _ in pairs:
            tr = self.tracks[r]
            x, y, vx, vy = (float(v) for v in tr.kf.x)
            yaw = math.atan2(vy, vx) if math.hypot(vx, vy) > 1.0 else tr.box.yaw
            along, across = to_frame(xs, ys, (x, y, yaw))
            piece |= (np.abs(along) <= tr.extent[0] / 2 + margin) & (np.abs(across) <= tr.extent[1] / 2 + margin)
        out = {c for c, p in zip(free, piece) if p}
        self.fragments += len(out)
        return out

    def objects(self) -> list[LidarObject]:
        confirmed = [tr.report() for tr in self.tracks if tr.hits >= self.cfg.confirm_scans]
        return confirmed + list(self.last_static)
