"""Multi-object tracking on the ground plane: one constant-velocity Kalman filter per vehicle.

State (x, y, vx, vy) in world metres and m/s (filterpy `KalmanFilter`),
process noise: white acceleration of `accel_std` m/s^2 (filterpy's
discrete white-noise model). Each `update(t, detections)` predicts every
track to t, associates with the Hungarian method (scipy) on the negative
log-likelihood of the innovation (Mahalanobis distance squared + ln |S|,
so an uncertain young track does not steal detections), gated at a chi-square
quantile. A track is confirmed after M hits in its first N frames and
dropped after `max_missed` frames without a detection. `predict(t)`
extrapolates confirmed tracks to any later time without changing them, so
the 10 Hz BSM clock does not need a detection every tick. Below
`min_speed` the heading is held at its last value: the direction of a
nearly-stopped vehicle's velocity is noise.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter
from scipy.optimize import linear_sum_assignment

H = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])


class TrackerError(ValueError):
    """Bad tracker input: time going backwards, non-finite positions, bad configuration."""


@dataclass(frozen=True)
class GroundDetection:
    x: float  # world metres (east)
    y: float  # world metres (north)
    label: str = "car"
    score: float = 1.0


@dataclass
class TrackerConfig:
    accel_std: float = 3.0  # m/s^2: how hard vehicles may manoeuvre between frames
    meas_std: float = 0.7  # m: per-axis error of a ground position from the camera
    init_speed_std: float = 10.0  # m/s: velocity uncertainty of a new track
    gate: float = 13.82  # chi-square 2 dof, 99.9 %: Mahalanobis^2 beyond it never associates
    confirm_hits: int = 3  # M ...
    confirm_window: int = 5  # ... of N frames to confirm a new track
    max_missed: int = 5  # consecutive frames without a detection before a confirmed track is dropped
    min_speed: float = 1.0  # m/s: below it the heading is held

    def __post_init__(self):
        if not 1 <= self.confirm_hits <= self.confirm_window:
            raise TrackerError(f"need 1 <= confirm_hits <= confirm_window, got {self.confirm_hits}, "
                               f"{self.confirm_window}")
        for k in ("accel_std", "meas_std", "init_speed_std", "gate"):
            if not getattr(self, k) > 0:
                raise TrackerError(f"{k} must be > 0, got {getattr(self, k)}")


@dataclass(frozen=True)
class TrackState:
    id: int
    t: float
    x: float
    y: float
    vx: float
    vy: float
    speed: float  # m/s
    heading: float | None  # rad CCW from east; None until the track has moved
    label: str
    confirmed: bool
    missed: int  # frames since the last detection (0: detected in the last frame)
    cov: np.ndarray = field(repr=False, compare=False)  # 4x4 state covariance


def _transition(dt: float, accel_std: float) -> tuple[np.ndarray, np.ndarray]:
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt
    Q = Q_discrete_white_noise(2, dt=dt, var=accel_std ** 2, block_size=2, order_by_dim=False)
    return F, Q


class _Track:
    def __init__(self, tid: int, det: GroundDetection, t: float, cfg: TrackerConfig):
        self.id, self.t = tid, t
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.x = np.array([[det.x], [det.y], [0.0], [0.0]])
        kf.P = np.diag([cfg.meas_std ** 2] * 2 + [cfg.init_speed_std ** 2] * 2)
        kf.H = H.copy()
        kf.R = np.eye(2) * cfg.meas_std ** 2
        self.kf = kf
        self.hits = deque([True], maxlen=cfg.confirm_window)
        self.frames = 1
        self.missed = 0
        self.confirmed = cfg.confirm_hits <= 1
        self.votes: dict[str, float] = {det.label: det.score}
        self.heading: float | None = None

    def label(self) -> str:
        return max(self.votes.items(), key=lambda kv: kv[1])[0]

    def state(self, t: float, x: np.ndarray, P: np.ndarray, min_speed: float) -> TrackState:
        vx, vy = float(x[2, 0]), float(x[3, 0])
        speed = math.hypot(vx, vy)
        heading = math.atan2(vy, vx) if speed >= min_speed else self.heading
        return TrackState(self.id, t, float(x[0, 0]), float(x[1, 0]), vx, vy, speed, heading, self.label(),
                          self.confirmed, self.missed, P.copy())


class Tracker:
    def __init__(self, config: TrackerConfig | None = None, **overrides):
        self.cfg = config or TrackerConfig(**overrides)
        self.tracks: list[_Track] = []
        self.t: float | None = None
        self._next_id = 1

    def _check_time(self, t: float) -> float:
        t = float(t)
        if not math.isfinite(t):
            raise TrackerError(f"time must be finite, got {t}")
        if self.t is not None and t < self.t - 1e-9:
            raise TrackerError(f"time went backwards: {t} after {self.t}")
        return t

    def update(self, t: float, detections) -> list[TrackState]:
        """Fold in the ground detections of one frame taken at time t; returns the confirmed tracks."""
        t = self._check_time(t)
        dets = [d if isinstance(d, GroundDetection) else GroundDetection(*d) for d in detections]
        for d in dets:
            if not (math.isfinite(d.x) and math.isfinite(d.y)):
                raise TrackerError(f"detection position must be finite, got ({d.x}, {d.y})")
        cfg = self.cfg
        for tr in self.tracks:
            dt = t - tr.t
            if dt > 0:
                F, Q = _transition(dt, cfg.accel_std)
                tr.kf.predict(F=F, Q=Q)
                tr.t = t
        pairs = self._associate(dets)
        matched_t = {i for i, _ in pairs}
        matched_d = {j for _, j in pairs}
        for i, j in pairs:
            tr, d = self.tracks[i], dets[j]
            tr.kf.update(np.array([[d.x], [d.y]]))
            tr.hits.append(True)
            tr.missed = 0
            tr.votes[d.label] = tr.votes.get(d.label, 0.0) + d.score
        for i, tr in enumerate(self.tracks):
            if i not in matched_t:
                tr.hits.append(False)
                tr.missed += 1
        keep = []
        for tr in self.tracks:
            tr.frames += 1
            if not tr.confirmed and sum(tr.hits) >= cfg.confirm_hits:
                tr.confirmed = True
            if tr.confirmed:
                if tr.missed <= cfg.max_missed:
                    keep.append(tr)
            elif sum(tr.hits) + (cfg.confirm_window - tr.frames) >= cfg.confirm_hits:
                keep.append(tr)  # can still make M hits within its first N frames
        self.tracks = keep
        for j, d in enumerate(dets):
            if j not in matched_d:
                self.tracks.append(_Track(self._next_id, d, t, cfg))
                self._next_id += 1
        for tr in self.tracks:
            s = tr.state(t, tr.kf.x, tr.kf.P, cfg.min_speed)
            tr.heading = s.heading
        self.t = t
        return self.predict(t)

    def _associate(self, dets: list[GroundDetection]) -> list[tuple[int, int]]:
        if not self.tracks or not dets:
            return []
        z = np.array([[d.x, d.y] for d in dets])
        cost = np.full((len(self.tracks), len(dets)), np.inf)
        for i, tr in enumerate(self.tracks):
            S = H @ tr.kf.P @ H.T + tr.kf.R
            Si = np.linalg.inv(S)
            y = z - (H @ tr.kf.x).ravel()
            d2 = np.einsum("ni,ij,nj->n", y, Si, y)
            ok = d2 <= self.cfg.gate
            cost[i, ok] = d2[ok] + math.log(np.linalg.det(S))
        big = 1e9
        rows, cols = linear_sum_assignment(np.where(np.isfinite(cost), cost, big))
        return [(int(r), int(c)) for r, c in zip(rows, cols) if np.isfinite(cost[r, c])]

    def predict(self, t: float, include_tentative: bool = False) -> list[TrackState]:
        """Tracks extrapolated to time t (>= the last update), without changing them."""
        t = self._check_time(t)
        out = []
        for tr in self.tracks:
            if not (tr.confirmed or include_tentative):
                continue
            dt = t - tr.t
            if dt > 0:
                F, Q = _transition(dt, self.cfg.accel_std)
                x, P = tr.kf.get_prediction(F=F, Q=Q)
            else:
                x, P = tr.kf.x, tr.kf.P
            out.append(tr.state(t, x, P, self.cfg.min_speed))
        return out
