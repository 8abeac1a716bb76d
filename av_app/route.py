"""The lane-level route and the lateral controller that follows it.

The route is a polyline of lane centres (from the config) whose corners are
rounded by circular arcs of a given radius, sampled every `ds` metres into
stations s with pose and curvature. The planner reads curvature for its speed
limits and the ego path for the collision estimator; pure pursuit (Coulter,
CMU-RI-TR-92-01) steers the rear axle toward a point one look-ahead distance
ahead on the route: delta = atan(2 L sin(alpha) / Ld).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from av_app.geometry import wrap


@dataclass(frozen=True)
class PathSamples:
    """Poses along a stretch of the route: stations s, rear-axle x, y, yaw, curvature."""

    s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    kappa: np.ndarray


class Route:
    """A rounded polyline sampled every `ds` metres."""

    def __init__(self, waypoints, corner_radius: float, ds: float = 0.1):
        pts = np.asarray(waypoints, float)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
            raise ValueError(f"route: need at least two [x, y] waypoints, got {waypoints!r}")
        self.waypoints, self.radius, self.ds = pts, float(corner_radius), float(ds)
        xs, ys, yaws, ks = [], [], [], []
        start = pts[0]
        self.radii: list[float] = []  # the radius each corner got (shortened where segments are short)
        for i in range(1, len(pts)):
            p = pts[i]
            if i == len(pts) - 1:
                self._line(start, p, xs, ys, yaws, ks)
                break
            d1 = (p - pts[i - 1]) / np.linalg.norm(p - pts[i - 1])
            d2 = (pts[i + 1] - p) / np.linalg.norm(pts[i + 1] - p)
            turn = math.atan2(d1[0] * d2[1] - d1[1] * d2[0], float(d1 @ d2))
            if abs(turn) < 1e-9:
                self._line(start, p, xs, ys, yaws, ks)
                start = p
                continue
            room = min(np.linalg.norm(p - start), np.linalg.norm(pts[i + 1] - p) / 2)
            r = min(self.radius, room / math.tan(abs(turn) / 2))
            self.radii.append(r)
            t = r * math.tan(abs(turn) / 2)
            a, b = p - d1 * t, p + d2 * t
            self._line(start, a, xs, ys, yaws, ks)
            self._arc(a, d1, turn, r, xs, ys, yaws, ks)
            start = b
        self.x, self.y = np.concatenate(xs), np.concatenate(ys)
        self.yaw, self.kappa = np.unwrap(np.concatenate(yaws)), np.concatenate(ks)
        seg = np.hypot(np.diff(self.x), np.diff(self.y))
        keep = np.concatenate([[True], seg > 1e-9])  # drop the duplicated joint points
        self.x, self.y, self.yaw, self.kappa = self.x[keep], self.y[keep], self.yaw[keep], self.kappa[keep]
        self.s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(self.x), np.diff(self.y)))])
        self.length = float(self.s[-1])

    def _line(self, a, b, xs, ys, yaws, ks) -> None:
        d = b - a
        n = max(1, int(math.ceil(np.linalg.norm(d) / self.ds)))
        u = np.linspace(0.0, 1.0, n + 1)
        xs.append(a[0] + u * d[0])
        ys.append(a[1] + u * d[1])
        yaws.append(np.full(n + 1, math.atan2(d[1], d[0])))
        ks.append(np.zeros(n + 1))

    def _arc(self, a, d1, turn, r, xs, ys, yaws, ks) -> None:
        side = 1.0 if turn > 0 else -1.0  # left turn: centre on the left
        centre = a + side * r * np.array([-d1[1], d1[0]])
        phi0 = math.atan2(a[1] - centre[1], a[0] - centre[0])
        n = max(2, int(math.ceil(r * abs(turn) / self.ds)))
        phi = phi0 + np.linspace(0.0, turn, n + 1)
        xs.append(centre[0] + r * np.cos(phi))
        ys.append(centre[1] + r * np.sin(phi))
        yaws.append(math.atan2(d1[1], d1[0]) + np.linspace(0.0, turn, n + 1))
        ks.append(np.full(n + 1, side / r))

    # -- queries --------------------------------------------------------------------------------
    def at(self, s) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(x, y, yaw, curvature) at station(s) s (clamped to the route; beyond its end: straight on)."""
        s = np.asarray(s, float)
        sc = np.clip(s, 0.0, self.length)
        x, y = np.interp(sc, self.s, self.x), np.interp(sc, self.s, self.y)
        yaw = np.interp(sc, self.s, self.yaw)
        beyond = s - sc  # extrapolate along the end's heading (and before the start)
        x, y = x + beyond * np.cos(yaw), y + beyond * np.sin(yaw)
        kappa = np.where(beyond == 0, np.interp(sc, self.s, self.kappa), 0.0)
        return x, y, yaw, kappa

    def samples(self, s0: float, length: float, ds: float) -> PathSamples:
        """The stretch [s0, s0 + length]: s0 itself, then the route's fixed grid of multiples of ds.

        A grid fixed to the route (not to the vehicle) keeps a conflict zone's first station where it
        is from one plan to the next; a grid that moved with the vehicle would shift it by up to ds
        each plan, and a stop point with it.
        """
        first = math.floor(s0 / ds + 1e-9) + 1
        s = np.concatenate([[s0], np.arange(first, math.floor((s0 + length) / ds + 1e-9) + 1) * ds])
        x, y, yaw, kappa = self.at(s)
        return PathSamples(s, x, y, yaw, kappa)

    def project(self, x: float, y: float, s_hint: float | None = None, window: float = 30.0) -> tuple[float, float]:
        """(station, lateral offset left of the route) of the point nearest to (x, y).

        With a hint only stations within `window` of it are searched, so a route that passes
        near itself (a loop) is not mistaken for its other part.
        """
        lo, hi = 0, len(self.s)
        if s_hint is not None and math.isfinite(s_hint):
            lo = int(np.searchsorted(self.s, s_hint - window))
            hi = int(np.searchsorted(self.s, s_hint + window)) + 1
            if hi - lo < 1 or lo >= len(self.s):  # a hint off the route (a stale or diverged estimate)
                lo, hi = 0, len(self.s)
        d2 = (self.x[lo:hi] - x) ** 2 + (self.y[lo:hi] - y) ** 2
        i = lo + int(np.argmin(d2))
        # refine on the neighbouring segment
        j = min(max(i, 1), len(self.s) - 1)
        ax, ay, bx, by = self.x[j - 1], self.y[j - 1], self.x[j], self.y[j]
        seg = math.hypot(bx - ax, by - ay)
        u = ((x - ax) * (bx - ax) + (y - ay) * (by - ay)) / (seg * seg) if seg > 0 else 0.0
        if not 0.0 <= u <= 1.0 and 0 < i < len(self.s) - 1:
            j = i + 1
            ax, ay, bx, by = self.x[j - 1], self.y[j - 1], self.x[j], self.y[j]
            seg = math.hypot(bx - ax, by - ay)
            u = ((x - ax) * (bx - ax) + (y - ay) * (by - ay)) / (seg * seg) if seg > 0 else 0.0
        if j == len(self.s) - 1 or j == 1:
            u_clip = u  # allow projecting beyond either end (straight extension)
        else:
            u_clip = min(max(u, 0.0), 1.0)
        s = float(self.s[j - 1] + u_clip * seg)
        px, py = ax + u_clip * (bx - ax), ay + u_clip * (by - ay)
        heading = math.atan2(by - ay, bx - ax)
        lateral = -(x - px) * math.sin(heading) + (y - py) * math.cos(heading)
        return s, float(lateral)


def pure_pursuit(route: Route, pose: tuple[float, float, float], speed: float, s_now: float, wheelbase: float,
                 lookahead_min: float, lookahead_time: float, max_steer: float) -> tuple[float, float]:
    """(front-wheel angle, look-ahead distance) that steers the rear axle at `pose` onto the route."""
    ld = max(lookahead_min, lookahead_time * abs(speed))
    tx, ty, _, _ = route.at(s_now + ld)
    x, y, yaw = pose
    alpha = math.atan2(float(ty) - y, float(tx) - x) - yaw
    alpha = float(wrap(alpha))
    dist = max(math.hypot(float(tx) - x, float(ty) - y), 1e-3)
    steer = math.atan2(2.0 * wheelbase * math.sin(alpha), dist)
    return float(min(max(steer, -max_steer), max_steer)), ld
