"""The ego state: position, heading, speed and yaw rate from GNSS fixes and the vehicle's AV_Status.

An unscented Kalman filter (filterpy) over x = [x, y, yaw, v, yaw_rate] with a
constant-turn-rate-and-velocity process: GNSS fixes (x, y, heading, speed at
the rear axle, noisy) correct position and heading; AV_Status frames (speed and
yaw rate from the vehicle bus, precise and frequent) correct the motion. So the
app drives on whatever GNSS noise the world is set to, and between 10 Hz fixes
it dead-reckons on the 50 Hz status.

Time: the filter is advanced to each measurement's simulation time in order;
`state(t)` predicts to t without changing the filter.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from av_app.config import EgoSection

LATE_OK_S = 0.2  # a measurement at most this much older than the filter is still used


@dataclass(frozen=True)
class EgoState:
    t: float
    x: float
    y: float
    yaw: float
    v: float
    yaw_rate: float
    pos_std: float  # horizontal 1-sigma, m

    @property
    def pose(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.yaw)


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def _residual_x(a, b):
    d = np.subtract(a, b)
    d[2] = _wrap(d[2])
    return d


def _mean_x(sigmas, wm):
    x = np.dot(wm, sigmas)
    x[2] = math.atan2(float(np.dot(wm, np.sin(sigmas[:, 2]))), float(np.dot(wm, np.cos(sigmas[:, 2]))))
    return x


def _fx(s, dt):
    x, y, yaw, v, w = s
    if abs(w) > 1e-4:
        nx = x + v / w * (math.sin(yaw + w * dt) - math.sin(yaw))
        ny = y + v / w * (-math.cos(yaw + w * dt) + math.cos(yaw))
    else:
        nx = x + v * dt * math.cos(yaw)
        ny = y + v * dt * math.sin(yaw)
    return np.array([nx, ny, yaw + w * dt, v, w])


def _h_gnss(s):
    return np.array([s[0], s[1], s[2], s[3]])


def _h_status(s):
    return np.array([s[3], s[4]])


def _residual_gnss(a, b):
    d = np.subtract(a, b)
    d[2] = _wrap(d[2])
    return d


def _mean_gnss(sigmas, wm):
    z = np.dot(wm, sigmas)
    z[2] = math.atan2(float(np.dot(wm, np.sin(sigmas[:, 2]))), float(np.dot(wm, np.cos(sigmas[:, 2]))))
    return z


def _sqrt(P):
    """Cholesky square root, repaired if rounding left P slightly indefinite."""
    try:
        return np.linalg.cholesky(P).T
    except np.linalg.LinAlgError:
        w, v = np.linalg.eigh((P + P.T) / 2)
        return (v * np.sqrt(np.clip(w, 1e-12, None))).T


class EgoFilter:
    """Fuses GNSS fixes and AV_Status into an EgoState; initialised by the first fix."""

    def __init__(self, cfg: EgoSection):
        self.cfg = cfg
        self.t: float | None = None
        self.fixes = 0
        self.statuses = 0
        self.last_fix_t: float | None = None
        self.rejected = 0  # measurements refused (non-finite, much older than the filter)
        self.late = 0  # measurements a little older than the filter, taken as of its time (realtime)
        self.resets = 0  # times the filter was started again from a fix (its covariance broke down)
        points = MerweScaledSigmaPoints(5, alpha=0.5, beta=2.0, kappa=0.0, sqrt_method=_sqrt, subtract=_residual_x)
        self.ukf = UnscentedKalmanFilter(5, 4, 0.02, _h_gnss, _fx, points, sqrt_fn=_sqrt, x_mean_fn=_mean_x,
                                         residual_x=_residual_x)
        self.R_gnss = np.diag([cfg.gnss_sigma_h ** 2, cfg.gnss_sigma_h ** 2,
                               math.radians(cfg.gnss_sigma_heading_deg) ** 2, cfg.gnss_sigma_speed ** 2])
        self.R_status = np.diag([cfg.status_sigma_speed ** 2, cfg.status_sigma_yaw_rate ** 2])
        self._pending_status: tuple[float, float, float] | None = None  # before the first fix

    @property
    def ready(self) -> bool:
        return self.t is not None

    def _Q(self, dt: float) -> np.ndarray:
        qa, qw = self.cfg.accel_noise ** 2, self.cfg.yaw_accel_noise ** 2
        Q = np.zeros((5, 5))
        Q[3, 3] = qa * dt
        Q[4, 4] = qw * dt
        Q[0, 0] = Q[1, 1] = qa * dt ** 3 / 3 + 1e-6 * dt
        Q[2, 2] = qw * dt ** 3 / 3 + 1e-7 * dt
        return Q

    def _advance(self, t: float) -> bool:
        if self.t is None:
            return False
        dt = t - self.t
        if dt < -1e-9:
            # older than the state: a realtime run's fix may come in after a status stamped "now";
            # a little late it corrects the present, much later it is dropped (lockstep never does this)
            if dt < -LATE_OK_S:
                self.rejected += 1
                return False
            self.late += 1
            return True
        if dt > 1e-9:
            self.ukf.Q = self._Q(dt)
            self.ukf.predict(dt=dt)
            self.t = t
        return True

    def _healthy(self) -> bool:
        """A finite state and covariance (filterpy does not raise on NaN: it spreads them)."""
        return bool(np.all(np.isfinite(self.ukf.x)) and np.all(np.isfinite(self.ukf.P)))

    def _start(self, t: float, x: float, y: float, heading: float, speed: float) -> None:
        """The filter from one fix (and the last AV_Status's speed and yaw rate, when one came first)."""
        v, w = (self._pending_status[1], self._pending_status[2]) if self._pending_status else (speed, 0.0)
        self.ukf.x = np.array([x, y, heading, v, w], float)
        c = self.cfg
        self.ukf.P = np.diag([c.gnss_sigma_h ** 2, c.gnss_sigma_h ** 2,
                              math.radians(c.gnss_sigma_heading_deg) ** 2 * 4, 1.0, 0.1])
        self.t = t

    def gnss(self, t: float, x: float, y: float, heading: float, speed: float) -> bool:
        """Take a fix at simulation time t; False if it was not usable."""
        values = (t, x, y, heading, speed)
        if not all(math.isfinite(v) for v in values):
            self.rejected += 1
            return False
        if self.t is None:
            self._start(t, x, y, heading, speed)
        elif not self._advance(t):
            return False
        else:
            try:
                self.ukf.update(np.array([x, y, heading, speed]), R=self.R_gnss, hx=_h_gnss)
                healthy = self._healthy()
            except (np.linalg.LinAlgError, ValueError):
                healthy = False
            if not healthy:
                # a covariance that lost its positive definiteness (e.g. inputs far out of order in a run
                # that could not keep real time): start again from this fix rather than stop the vehicle
                self.resets += 1
                self._start(t, x, y, heading, speed)
        self.fixes += 1
        self.last_fix_t = t
        return True

    def status(self, t: float, speed: float, yaw_rate: float) -> bool:
        """Take an AV_Status (speed, yaw rate) at simulation time t."""
        if not all(math.isfinite(v) for v in (t, speed, yaw_rate)):
            self.rejected += 1
            return False
        if self.t is None:
            self._pending_status = (t, speed, yaw_rate)
            return True
        if not self._advance(t):
            return False
        # the status measures speed and yaw rate only: a 2-D measurement through the same UKF
        try:
            self.ukf.update(np.array([speed, yaw_rate]), R=self.R_status, hx=_h_status)
            healthy = self._healthy()
        except (np.linalg.LinAlgError, ValueError):
            healthy = False
        if not healthy:  # see gnss(): the next fix starts the filter again
            self.resets += 1
            self.t, self._pending_status = None, (t, speed, yaw_rate)
            return False
        self.statuses += 1
        return True

    def state(self, t: float | None = None) -> EgoState | None:
        """The estimate predicted to t (default: the filter's own time); None before the first fix."""
        if self.t is None:
            return None
        x = self.ukf.x.copy()
        if t is not None and t > self.t + 1e-9:
            x = _fx(x, t - self.t)
        else:
            t = self.t
        P = self.ukf.P
        return EgoState(float(t), float(x[0]), float(x[1]), float(_wrap(x[2])), float(x[3]), float(x[4]),
                        float(math.sqrt(max(P[0, 0] + P[1, 1], 0.0) / 2)))

    def stale(self, t: float) -> bool:
        return self.last_fix_t is None or t - self.last_fix_t > self.cfg.stale_s
