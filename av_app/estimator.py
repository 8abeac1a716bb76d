"""Object collision estimator: where and when each object will be on the ego's path.

For every object the estimator predicts its pose every `dt_s` over `horizon_s`
(constant velocity, or constant turn rate and velocity from its yaw rate;
standing still below `stationary_speed`), and tests its footprint, grown by
the safety margin, against the ego's footprint (also grown) at every station of
the ego's planned path - a swept oriented-box test, vectorised: a cheap
bounding-circle pass, then the separating-axis test (av_app.geometry) on the
candidate pairs. The result per object is its *occupancy* of the ego path: for
each ego station i, the interval [a_i, b_i] of prediction times in which the
object's footprint overlaps the ego's footprint placed at that station.

Given the ego's timing along the path (tau_i: when the planned speed profile
reaches station i), the conflict measures are:

* time to conflict: the first tau_i that lies inside [a_i, b_i] (both would be
  there at once), or None;
* post-encroachment time (PET): over the stations the object occupies, the
  smallest gap between the ego's passage and the object's (positive: one clears
  before the other arrives; negative: they overlap in time).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from av_app.config import PlannerSection, VehicleSection
from av_app.fusion import FusedObject
from av_app.geometry import corners, overlap, to_frame, wrap
from av_app.route import PathSamples


@dataclass
class Occupancy:
    """When an object occupies each station of the ego path (times relative to the planning time)."""

    object: FusedObject
    a: np.ndarray  # (n_stations,) first time of overlap, +inf where never
    b: np.ndarray  # (n_stations,) last time of overlap, -inf where never

    @property
    def any(self) -> bool:
        return bool(np.isfinite(self.a).any())

    @property
    def first_station(self) -> int | None:
        idx = np.flatnonzero(np.isfinite(self.a))
        return int(idx[0]) if len(idx) else None


@dataclass(frozen=True)
class Conflict:
    object_id: str
    emergency: bool
    ttc: float | None  # s until both would occupy the same place, on the given ego timing
    pet: float | None  # s (negative: simultaneous occupancy)
    station_in: float | None  # first ego station (rear axle, m along the route) the object occupies
    object_in: float | None  # when the object first occupies any station (s from now)
    object_out: float | None  # when it last does


class CollisionEstimator:
    def __init__(self, planner: PlannerSection, vehicle: VehicleSection):
        self.cfg, self.vehicle = planner, vehicle
        self.tau = np.arange(0.0, planner.horizon_s + 1e-9, planner.dt_s)

    # -- geometry -------------------------------------------------------------------------------------
    def ego_boxes(self, path: PathSamples) -> tuple[np.ndarray, np.ndarray]:
        """Footprints (n, 4, 2) of the ego at each path station (grown by the margin) and their centres."""
        v, m = self.vehicle, self.cfg.margin_m
        off = v.length / 2 - v.rear_overhang
        cx, cy = path.x + off * np.cos(path.yaw), path.y + off * np.sin(path.yaw)
        # swept: each box also covers half a station step before and after its station
        length = v.length + 2 * m + self.cfg.path_ds
        return corners(cx, cy, path.yaw, length, v.width + 2 * m), np.column_stack([cx, cy])

    def predict(self, o: FusedObject) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, y, yaw) of the object's centre at each prediction time."""
        tau = self.tau
        if o.static or o.speed < self.cfg.stationary_speed:
            return np.full_like(tau, o.x), np.full_like(tau, o.y), np.full_like(tau, o.yaw)
        w = o.yaw_rate if self.cfg.motion == "ctrv" else 0.0
        if abs(w) < 1e-3:
            return o.x + o.speed * tau * math.cos(o.yaw), o.y + o.speed * tau * math.sin(o.yaw), np.full_like(tau, o.yaw)
        yaw = o.yaw + w * tau
        r = o.speed / w
        return o.x + r * (np.sin(yaw) - math.sin(o.yaw)), o.y - r * (np.cos(yaw) - math.cos(o.yaw)), yaw

    def follower(self, o: FusedObject, ego_pose: tuple[float, float, float]) -> bool:
        """An object behind the ego in its lane, going its way: its business to keep its distance."""
        v = self.vehicle
        u, lat = to_frame(o.x, o.y, ego_pose)
        front = float(u) + o.length / 2
        same_way = math.cos(float(wrap(o.yaw - ego_pose[2]))) > math.cos(math.radians(30))
        return (same_way and front < -v.rear_overhang - self.cfg.ignore_behind_m
                and abs(float(lat)) < (v.width + o.width) / 2 + 0.5)

    def occupancy(self, o: FusedObject, ego: tuple[np.ndarray, np.ndarray]) -> Occupancy:
        boxes, centres = ego
        m = self.cfg.margin_m
        ox, oy, oyaw = self.predict(o)
        n_s, n_t = len(boxes), len(ox)
        a = np.full(n_s, np.inf)
        b = np.full(n_s, -np.inf)
        # swept: each predicted box also covers half a time step of motion before and after its sample
        o_len = o.length + 2 * m + (0.0 if o.static or o.speed < self.cfg.stationary_speed
                                    else o.speed * self.cfg.dt_s)
        r_ego = 0.5 * math.hypot(self.vehicle.length + 2 * m + self.cfg.path_ds, self.vehicle.width + 2 * m)
        r_obj = 0.5 * math.hypot(o_len, o.width + 2 * m)
        # broad phase: bounding circles
        if (ox.min() - r_obj > centres[:, 0].max() + r_ego or ox.max() + r_obj < centres[:, 0].min() - r_ego
                or oy.min() - r_obj > centres[:, 1].max() + r_ego or oy.max() + r_obj < centres[:, 1].min() - r_ego):
            return Occupancy(o, a, b)
        d2 = (centres[:, 0:1] - ox[None]) ** 2 + (centres[:, 1:2] - oy[None]) ** 2
        si, tj = np.nonzero(d2 <= (r_ego + r_obj) ** 2)
        if len(si) == 0:
            return Occupancy(o, a, b)
        obj_boxes = corners(ox, oy, oyaw, o_len, o.width + 2 * m)
        hit = overlap(boxes[si], obj_boxes[tj])
        si, tj = si[hit], tj[hit]
        if len(si):
            np.minimum.at(a, si, self.tau[tj])
            np.maximum.at(b, si, self.tau[tj])
            if o.static or o.speed < self.cfg.stationary_speed:
                b[si] = np.inf  # a standing object stays beyond the horizon
        return Occupancy(o, a, b)

    # -- measures --------------------------------------------------------------------------------------
    @staticmethod
    def assess(occ: Occupancy, tau_ego: np.ndarray, path: PathSamples) -> Conflict:
        """TTC and PET of one object's occupancy against the ego's timing (tau_ego per station, inf: never)."""
        o = occ.object
        has = np.isfinite(occ.a)
        reached = has & np.isfinite(tau_ego)  # stations the ego reaches within its plan
        if not reached.any():
            return Conflict(o.id, o.emergency, None, None, float(path.s[has][0]) if has.any() else None,
                            float(occ.a[has].min()) if has.any() else None,
                            float(occ.b[has].max()) if has.any() else None)
        # the ego occupies station i (its box swept half a station step either way) from halfway
        # between the previous station's time and its own to halfway to the next one
        mid = (tau_ego[1:] + tau_ego[:-1]) / 2
        lo = np.concatenate([tau_ego[:1], mid])[reached]
        hi = np.concatenate([mid, tau_ego[-1:]])[reached]
        a, b = occ.a[reached], occ.b[reached]
        start, end = np.maximum(lo, a), np.minimum(hi, b)
        inside = start <= end
        ttc = float(start[inside].min()) if inside.any() else None
        gap = np.where(hi < a, a - hi, np.where(lo > b, lo - b, -(end - start)))
        return Conflict(o.id, o.emergency, ttc, float(gap.min()), float(path.s[has][0]), float(occ.a[has].min()),
                        float(occ.b[has].max()))
