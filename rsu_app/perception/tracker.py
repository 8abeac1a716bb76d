"""Multi-object tracking on the ground plane: one Kalman filter per vehicle.

Motion model `cv` (default): state (x, y, vx, vy) in world metres and m/s
(filterpy `KalmanFilter`), process noise: white acceleration of `accel_std`
m/s^2 (filterpy's discrete white-noise model). Motion model `ctrv`:
state (x, y, v, yaw, yaw_rate), constant turn rate and velocity, filterpy's
`UnscentedKalmanFilter` with yaw wrapped in residuals and averaged
circularly; process noise: longitudinal acceleration `accel_std` and yaw
acceleration `turn_accel_std` through the usual CTRV noise Jacobian. A new
track has no heading, which a UKF cannot start from, so every track starts
as a CV filter; a `ctrv` track switches to CTRV once its CV speed is at
least `min_speed` and its CV heading is known to `_HANDOVER_YAW_STD`
(v and yaw, with their covariance, linearised from the CV estimate;
yaw_rate 0 +- `_INIT_YAW_RATE_STD`).

Each `update(t, detections)` predicts every track to t, associates with the
Hungarian method (scipy) on the negative log-likelihood of the innovation
(Mahalanobis distance squared + ln |S|, so an uncertain young track does not
steal detections), gated at a chi-square quantile, in a matching cascade:
first the confirmed tracks against all detections, then the detections left
over against the tentative tracks. Why a cascade: a single innovation just
beyond the gate (0.1 % of them under a right noise model) starts a tentative
track beside a confirmed one; in one assignment over all tracks that track,
sitting on the outlier, pays a smaller d^2 for the next detections that err
to the same side than its larger ln |S| costs, takes them, and is confirmed
beside the real track or outlives it (a duplicate vehicle broadcast, or an id
switch). A tentative track only ever gets what no confirmed track can use.
Measurement noise: a `GroundDetection` may carry its own ground-plane covariance
(`cov`, from `geo.ground_fix`: a far vehicle's point is worth much less along
the camera ray than across it, a near one's is good to decimetres); without
it the isotropic `meas_std` is used. The same R starts a track's position
(its velocity starts at 0 +- `init_speed_std`), enters the gate's S and the
filter's update. A track is confirmed
after M hits in its first N frames and dropped after `max_missed` frames
without a detection. `predict(t)` extrapolates confirmed tracks to any later
time without changing them, so the 10 Hz BSM clock does not need a
detection every tick. Below `min_speed` the heading is held at its last
value: the direction of a nearly-stopped vehicle's velocity is noise.

After each `update`, `last_assignment[j]` is the id of the track the j-th
detection updated or started: what a trace of the frame needs to say which
box became which track (recorded only; it changes no tracking result).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter, unscented_transform
from scipy.linalg import LinAlgError, cholesky
from scipy.optimize import linear_sum_assignment

H = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])
MOTIONS = ("cv", "ctrv")
_HANDOVER_YAW_STD = 0.2  # rad: CV heading std below which a `ctrv` track switches to the UKF
_INIT_YAW_RATE_STD = 0.5  # rad/s: yaw-rate std at the switch (yaw rate starts at 0)


class TrackerError(ValueError):
    """Bad tracker input: time going backwards, non-finite positions, bad configuration."""


@dataclass(frozen=True)
class GroundDetection:
    x: float  # world metres (east)
    y: float  # world metres (north)
    label: str = "car"
    score: float = 1.0
    cov: tuple[float, float, float] | None = None  # (var_x, cov_xy, var_y) m^2; None: TrackerConfig.meas_std

    def R(self, meas_std: float) -> np.ndarray:
        """The measurement noise covariance of this detection."""
        if self.cov is None:
            return np.eye(2) * meas_std ** 2
        a, b, c = self.cov
        return np.array([[a, b], [b, c]], float)


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
    motion: str = "cv"  # "cv": constant velocity; "ctrv": constant turn rate and velocity
    turn_accel_std: float = 0.5  # rad/s^2: how hard the yaw rate may change (ctrv only)

    def __post_init__(self):
        if not 1 <= self.confirm_hits <= self.confirm_window:
            raise TrackerError(f"need 1 <= confirm_hits <= confirm_window, got {self.confirm_hits}, "
                               f"{self.confirm_window}")
        for k in ("accel_std", "meas_std", "init_speed_std", "gate", "turn_accel_std"):
            if not getattr(self, k) > 0:
                raise TrackerError(f"{k} must be > 0, got {getattr(self, k)}")
        if self.motion not in MOTIONS:
            raise TrackerError(f"motion must be one of {', '.join(map(repr, MOTIONS))}, got {self.motion!r}")


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
    cov: np.ndarray = field(repr=False, compare=False)  # 4x4 covariance of (x, y, vx, vy)
    yaw_rate: float | None = None  # rad/s CCW; None unless the track runs the CTRV filter


class _Estimate(NamedTuple):
    x: float
    y: float
    vx: float
    vy: float
    cov: np.ndarray  # 4x4 over (x, y, vx, vy)
    yaw_rate: float | None


def positive_definite(cov) -> bool:
    """Whether (var_x, cov_xy, var_y) is a covariance the filter can use: finite and positive definite."""
    try:
        a, b, c = (float(v) for v in cov)
    except (TypeError, ValueError):
        return False
    return all(math.isfinite(v) for v in (a, b, c)) and a > 0 and a * c - b * b > 0


def _transition(dt: float, accel_std: float) -> tuple[np.ndarray, np.ndarray]:
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt
    Q = Q_discrete_white_noise(2, dt=dt, var=accel_std ** 2, block_size=2, order_by_dim=False)
    return F, Q


class _CvFilter:
    """Constant velocity: linear, so the plain Kalman filter is exact."""

    def __init__(self, det: GroundDetection, cfg: TrackerConfig):
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.x = np.array([[det.x], [det.y], [0.0], [0.0]])
        kf.P = np.diag([0.0] * 2 + [cfg.init_speed_std ** 2] * 2)
        kf.P[:2, :2] = det.R(cfg.meas_std)
        kf.H = H.copy()
        kf.R = np.full((2, 2), np.nan)  # no default noise: every update passes its detection's own R
        self.kf, self.accel_std = kf, cfg.accel_std

    def predict(self, dt: float) -> None:
        F, Q = _transition(dt, self.accel_std)
        self.kf.predict(F=F, Q=Q)

    def update(self, z: np.ndarray, R: np.ndarray) -> None:
        self.kf.update(z.reshape(2, 1), R=R)

    def position_and_cov(self) -> tuple[np.ndarray, np.ndarray]:
        return (H @ self.kf.x).ravel(), H @ self.kf.P @ H.T

    def estimate(self, dt: float = 0.0) -> _Estimate:
        """The state extrapolated by dt (>= 0) without changing the filter."""
        if dt > 0:
            F, Q = _transition(dt, self.accel_std)
            x, P = self.kf.get_prediction(F=F, Q=Q)
        else:
            x, P = self.kf.x, self.kf.P
        return _Estimate(float(x[0, 0]), float(x[1, 0]), float(x[2, 0]), float(x[3, 0]), P.copy(), None)


def _wrap(a):
    """Angle(s) to (-pi, pi]."""
    return a - math.tau * np.ceil((a - math.pi) / math.tau)


def _residual_x(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = np.subtract(a, b)
    d[3] = _wrap(d[3])
    return d


def _add_x(x: np.ndarray, dx: np.ndarray) -> np.ndarray:
    s = np.add(x, dx)
    s[3] = _wrap(s[3])
    return s


def _mean_x(sigmas: np.ndarray, Wm: np.ndarray) -> np.ndarray:
    """Weighted mean with a circular mean for yaw (a plain mean of -179 and 179 deg is 0)."""
    x = Wm @ sigmas
    x[3] = math.atan2(Wm @ np.sin(sigmas[:, 3]), Wm @ np.cos(sigmas[:, 3]))
    return x


def _fx_ctrv(s: np.ndarray, dt: float) -> np.ndarray:
    px, py, v, yaw, w = s
    if abs(w) > 1e-6:
        px += v / w * (math.sin(yaw + w * dt) - math.sin(yaw))
        py += v / w * (math.cos(yaw) - math.cos(yaw + w * dt))
    else:  # straight line: the limit of the above as w -> 0
        px += v * math.cos(yaw) * dt
        py += v * math.sin(yaw) * dt
    return np.array([px, py, v, _wrap(yaw + w * dt), w])


def _hx(s: np.ndarray) -> np.ndarray:
    return s[:2]


def _sqrt_psd(A: np.ndarray) -> np.ndarray:
    """Upper Cholesky factor for the sigma points. Rounding in P - K S K^T can leave P a hair
    from positive definite; rather than crash a live tracker, retry with a growing diagonal jitter
    (1e-12 .. 1e-6 of the mean variance) and as a last resort clip the eigenvalues."""
    A = (A + A.T) / 2
    scale = max(float(np.trace(A)) / len(A), 1e-12)
    for jitter in (0.0, 1e-12, 1e-9, 1e-6):
        try:
            return cholesky(A + np.eye(len(A)) * jitter * scale)
        except LinAlgError:
            pass
    w, V = np.linalg.eigh(A)
    return np.sqrt(np.clip(w, 1e-12 * scale, None))[:, None] * V.T  # U with U.T @ U ~= A


class _CtrvFilter:
    """Constant turn rate and velocity, state (x, y, v, yaw, yaw_rate), unscented Kalman filter.
    alpha=1, kappa=0 keep every sigma-point weight >= 0, so the circular yaw mean is well behaved."""

    def __init__(self, x: np.ndarray, P: np.ndarray, cfg: TrackerConfig):
        self.points = MerweScaledSigmaPoints(5, alpha=1.0, beta=2.0, kappa=0.0, sqrt_method=_sqrt_psd,
                                             subtract=_residual_x)
        ukf = UnscentedKalmanFilter(5, 2, 0.1, _hx, _fx_ctrv, self.points, sqrt_fn=_sqrt_psd, x_mean_fn=_mean_x,
                                    residual_x=_residual_x, state_add=_add_x)
        ukf.x, ukf.P = np.asarray(x, float), np.asarray(P, float)
        ukf.R = np.full((2, 2), np.nan)  # as _CvFilter: every update passes its detection's own R
        self.ukf, self.accel_std, self.turn_accel_std = ukf, cfg.accel_std, cfg.turn_accel_std

    @classmethod
    def from_cv(cls, cv: _CvFilter, cfg: TrackerConfig, max_yaw_std: float) -> _CtrvFilter | None:
        """The CTRV filter taking over from a CV one: speed and yaw (and their covariance) linearised
        from its velocity; None while it is too slow or its heading too uncertain."""
        px, py, vx, vy = cv.kf.x.ravel()
        v = math.hypot(vx, vy)
        if v < cfg.min_speed:
            return None
        c, s = vx / v, vy / v
        J = np.zeros((5, 4))
        J[0, 0] = J[1, 1] = 1.0
        J[2, 2:] = c, s
        J[3, 2:] = -s / v, c / v
        P = J @ cv.kf.P @ J.T
        if P[3, 3] > max_yaw_std ** 2:
            return None
        P[4, 4] = _INIT_YAW_RATE_STD ** 2
        return cls(np.array([px, py, v, math.atan2(vy, vx), 0.0]), P, cfg)

    def _Q(self, dt: float) -> np.ndarray:
        """Piecewise-constant longitudinal and yaw accelerations over dt, through the noise Jacobian."""
        c, s = math.cos(self.ukf.x[3]), math.sin(self.ukf.x[3])
        G = np.array([[dt * dt / 2 * c, 0], [dt * dt / 2 * s, 0], [dt, 0], [0, dt * dt / 2], [0, dt]])
        return G @ np.diag([self.accel_std ** 2, self.turn_accel_std ** 2]) @ G.T

    def predict(self, dt: float) -> None:
        self.ukf.Q = self._Q(dt)
        self.ukf.predict(dt=dt)
        self.ukf.P = (self.ukf.P + self.ukf.P.T) / 2

    def update(self, z: np.ndarray, R: np.ndarray) -> None:
        # filterpy updates from the sigma points its last predict left; redraw them so an update
        # without a predict (dt == 0, or right after the switch) uses the current state
        self.ukf.sigmas_f = self.points.sigma_points(self.ukf.x, self.ukf.P)
        self.ukf.update(z, R=R)
        self.ukf.P = (self.ukf.P + self.ukf.P.T) / 2

    def position_and_cov(self) -> tuple[np.ndarray, np.ndarray]:
        return self.ukf.x[:2].copy(), self.ukf.P[:2, :2].copy()

    def estimate(self, dt: float = 0.0) -> _Estimate:
        """The state extrapolated by dt (>= 0) with one sigma-point pass, without changing the filter;
        the (x, y, vx, vy) covariance is linearised at the mean."""
        x, P = self.ukf.x, self.ukf.P
        if dt > 0:
            sigmas = np.array([_fx_ctrv(s, dt) for s in self.points.sigma_points(x, P)])
            x, P = unscented_transform(sigmas, self.points.Wm, self.points.Wc, self._Q(dt), _mean_x, _residual_x)
        v, c, s = x[2], math.cos(x[3]), math.sin(x[3])
        J = np.zeros((4, 5))
        J[0, 0] = J[1, 1] = 1.0
        J[2, 2:4] = c, -v * s
        J[3, 2:4] = s, v * c
        return _Estimate(float(x[0]), float(x[1]), float(v * c), float(v * s), J @ P @ J.T, float(x[4]))


class _Track:
    def __init__(self, tid: int, det: GroundDetection, t: float, cfg: TrackerConfig):
        self.id, self.t = tid, t
        self.filter: _CvFilter | _CtrvFilter = _CvFilter(det, cfg)
        self.hits = deque([True], maxlen=cfg.confirm_window)
        self.frames = 1
        self.missed = 0
        self.confirmed = cfg.confirm_hits <= 1
        self.votes: dict[str, float] = {det.label: det.score}
        self.heading: float | None = None

    def maybe_switch(self, cfg: TrackerConfig) -> None:
        """A `ctrv` track leaves its starting CV filter once the heading is known."""
        if cfg.motion == "ctrv" and isinstance(self.filter, _CvFilter):
            self.filter = _CtrvFilter.from_cv(self.filter, cfg, _HANDOVER_YAW_STD) or self.filter

    def label(self) -> str:
        return max(self.votes.items(), key=lambda kv: kv[1])[0]

    def state(self, t: float, e: _Estimate, min_speed: float) -> TrackState:
        speed = math.hypot(e.vx, e.vy)
        heading = math.atan2(e.vy, e.vx) if speed >= min_speed else self.heading
        return TrackState(self.id, t, e.x, e.y, e.vx, e.vy, speed, heading, self.label(),
                          self.confirmed, self.missed, e.cov, e.yaw_rate)


class Tracker:
    def __init__(self, config: TrackerConfig | None = None, **overrides):
        self.cfg = config or TrackerConfig(**overrides)
        self.tracks: list[_Track] = []
        self.t: float | None = None
        self._next_id = 1
        self.last_assignment: list[int] = []  # per detection of the last update: the track it updated or started

    def _check_time(self, t: float) -> float:
        t = float(t)
        if not math.isfinite(t):
            raise TrackerError(f"time must be finite, got {t}")
        if self.t is not None and t < self.t - 1e-9:
            raise TrackerError(f"time went backwards: {t} after {self.t}")
        return t

    def update(self, t: float, detections, sees=None) -> list[TrackState]:
        """Fold in the ground detections of one frame taken at time t; returns the confirmed tracks.

        `sees(x, y)`: whether the frame's sensor could have seen a track at (x, y), predicted to t; a track it
        could not see is left exactly as it is: not predicted, not associated, no miss, no frame towards
        confirmation (one sensor's silence says nothing of a vehicle in another sensor's coverage, and a
        camera-only track evolves as it would without the radar). None: the frame saw everything, every
        track left unmatched misses."""
        self.last_assignment = []  # a refused update associates nothing
        t = self._check_time(t)
        dets = [d if isinstance(d, GroundDetection) else GroundDetection(*d) for d in detections]
        for d in dets:
            if not (math.isfinite(d.x) and math.isfinite(d.y)):
                raise TrackerError(f"detection position must be finite, got ({d.x}, {d.y})")
            if d.cov is not None and not positive_definite(d.cov):
                raise TrackerError(f"detection covariance (var_x, cov_xy, var_y) must be finite and positive "
                                   f"definite, got {d.cov}")
        cfg = self.cfg
        unseen: set[int] = set()  # tracks this frame's sensor could not see: left exactly as they are
        if sees is not None:
            for tr in self.tracks:
                e = tr.filter.estimate(max(t - tr.t, 0.0))
                if not sees(e.x, e.y):
                    unseen.add(id(tr))
        for tr in self.tracks:
            dt = t - tr.t
            if dt > 0 and id(tr) not in unseen:
                tr.filter.predict(dt)
                tr.t = t
        pairs = self._associate(dets, unseen)
        matched_t = {i for i, _ in pairs}
        matched_d = {j for _, j in pairs}
        assignment = [0] * len(dets)
        for i, j in pairs:
            tr, d = self.tracks[i], dets[j]
            assignment[j] = tr.id
            tr.filter.update(np.array([d.x, d.y]), d.R(cfg.meas_std))
            tr.hits.append(True)
            tr.missed = 0
            tr.votes[d.label] = tr.votes.get(d.label, 0.0) + d.score
        for i, tr in enumerate(self.tracks):
            if i in matched_t or id(tr) in unseen:
                continue
            tr.hits.append(False)
            tr.missed += 1
        keep = []
        for tr in self.tracks:
            if id(tr) in unseen:
                keep.append(tr)
                continue
            tr.frames += 1
            tr.maybe_switch(cfg)
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
                assignment[j] = self._next_id
                self._next_id += 1
        self.last_assignment = assignment
        for tr in self.tracks:
            if id(tr) not in unseen:
                tr.heading = tr.state(t, tr.filter.estimate(), cfg.min_speed).heading
        self.t = t
        return self.predict(t)

    def _associate(self, dets: list[GroundDetection], unseen: set[int] = frozenset()) -> list[tuple[int, int]]:
        """(track index, detection index) pairs: a matching cascade, confirmed tracks first, then the
        detections they left against the tentative tracks (why: the module docstring). Tracks in `unseen`
        (ids of tracks the frame's sensor could not see) take no detection."""
        confirmed = [i for i, tr in enumerate(self.tracks) if tr.confirmed and id(tr) not in unseen]
        tentative = [i for i, tr in enumerate(self.tracks) if not tr.confirmed and id(tr) not in unseen]
        pairs = self._match(confirmed, list(range(len(dets))), dets)
        taken = {j for _, j in pairs}
        return pairs + self._match(tentative, [j for j in range(len(dets)) if j not in taken], dets)

    def _match(self, track_idx: list[int], det_idx: list[int],
               dets: list[GroundDetection]) -> list[tuple[int, int]]:
        """Hungarian assignment of the given tracks to the given detections on the negative
        log-likelihood d^2 + ln|S|, pairs beyond the gate excluded; indices into self.tracks and dets."""
        if not track_idx or not det_idx:
            return []
        z = np.array([[dets[j].x, dets[j].y] for j in det_idx])
        R = np.array([dets[j].R(self.cfg.meas_std) for j in det_idx])  # (M, 2, 2)
        cost = np.full((len(track_idx), len(det_idx)), np.inf)
        for r, i in enumerate(track_idx):
            pos, Ppos = self.tracks[i].filter.position_and_cov()
            S = Ppos[None] + R
            y = z - pos
            d2 = np.einsum("ni,ni->n", y, np.linalg.solve(S, y[:, :, None])[:, :, 0])
            ok = d2 <= self.cfg.gate
            cost[r, ok] = d2[ok] + np.log(np.linalg.det(S[ok]))
        big = 1e9
        rows, cols = linear_sum_assignment(np.where(np.isfinite(cost), cost, big))
        return [(track_idx[r], det_idx[c]) for r, c in zip(rows, cols) if np.isfinite(cost[r, c])]

    def predict(self, t: float, include_tentative: bool = False) -> list[TrackState]:
        """Tracks extrapolated to time t (>= the last update), without changing them."""
        t = self._check_time(t)
        return [tr.state(t, tr.filter.estimate(max(t - tr.t, 0.0)), self.cfg.min_speed)
                for tr in self.tracks if tr.confirmed or include_tentative]
