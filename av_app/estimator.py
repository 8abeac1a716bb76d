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
from av_app.geometry import corners, overlap_boxes, to_frame, wrap
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
    def ego_boxes(self, path: PathSamples) -> tuple[np.ndarray, ...]:
        """The ego at each path station: footprint centres x, y, headings (its box grown by the margin and
        swept half a station step before and after the station: half length, half width below)."""
        v = self.vehicle
        off = v.length / 2 - v.rear_overhang
        return path.x + off * np.cos(path.yaw), path.y + off * np.sin(path.yaw), path.yaw

    @property
    def ego_half(self) -> tuple[float, float]:
        v, m = self.vehicle, self.cfg.margin_m
        return (v.length + 2 * m + self.cfg.path_ds) / 2, (v.width + 2 * m) / 2

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

    def occupancy(self, o: FusedObject, ego: tuple[np.ndarray, ...]) -> Occupancy:
        ex, ey, eyaw = ego
        m = self.cfg.margin_m
        n_s = len(ex)
        a = np.full(n_s, np.inf)
        b = np.full(n_s, -np.inf)
        standing = o.static or o.speed < self.cfg.stationary_speed
        ox, oy, oyaw = self.predict(o)
        tau = self.tau
        if standing:  # one pose for the whole horizon
            ox, oy, oyaw, tau = ox[:1], oy[:1], oyaw[:1], tau[:1]
        # swept: each predicted box also covers half a time step of motion before and after its sample
        o_hl = (o.length + 2 * m + (0.0 if standing else o.speed * self.cfg.dt_s)) / 2
        o_hw = (o.width + 2 * m) / 2
        e_hl, e_hw = self.ego_half
        r = math.hypot(e_hl, e_hw) + math.hypot(o_hl, o_hw)
        # broad phase: the object's sweep against the path's bounding box, then bounding circles
        if (ox.min() - r > ex.max() or ox.max() + r < ex.min() or oy.min() - r > ey.max()
                or oy.max() + r < ey.min()):
            return Occupancy(o, a, b)
        d2 = (ex[:, None] - ox[None]) ** 2 + (ey[:, None] - oy[None]) ** 2
        si, tj = np.nonzero(d2 <= r * r)
        if len(si) == 0:
            return Occupancy(o, a, b)
        hit = overlap_boxes(ex[si], ey[si], eyaw[si], e_hl, e_hw, ox[tj], oy[tj], oyaw[tj], o_hl, o_hw)
        si, tj = si[hit], tj[hit]
        if len(si):
            np.minimum.at(a, si, tau[tj])
            np.maximum.at(b, si, tau[tj])
            if standing:
                b[si] = np.inf  # a standing object stays beyond the horizon
        return Occupancy(o, a, b)

    def blocked(self, o: FusedObject, pose: tuple[float, float, float], lane_shift: float = 0.0) -> float:
        """The fraction (0..1) of the object's corridor width that the ego, standing at rear-axle `pose`,
        would block: the corridor is the band the object sweeps ahead of its rear along its heading, its
        width wide (plus the margin on each side), its centre line `lane_shift` m to the object's left (the
        lane's centre where the map knows it: a lidar box's centre is biased toward the sensor). A lidar
        object's width is what its points showed (0 when they lie in a line, as a car seen end-on does), so
        the corridor is never narrower than the ego: a vehicle is at least a car wide. 0: the object passes
        the standing ego without touching it; 1: the ego stands across its whole way."""
        v, m = self.vehicle, self.cfg.margin_m / 2
        off = v.length / 2 - v.rear_overhang
        box = corners(pose[0] + off * math.cos(pose[2]), pose[1] + off * math.sin(pose[2]), pose[2], v.length,
                      v.width)
        u, lat = to_frame(box[:, 0], box[:, 1], (o.x, o.y, o.yaw))
        if float(np.max(u)) < -o.length / 2:
            return 0.0  # wholly behind the object
        half = max(o.width, v.width) / 2 + m
        lo, hi = lane_shift - half, lane_shift + half
        return max(0.0, min(float(np.max(lat)), hi) - max(float(np.min(lat)), lo)) / (2 * half)

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

    @staticmethod
    def go_gap(occ: Occupancy, tau_ego: np.ndarray, path: PathSamples, merge_heading: float,
               merge_length: float) -> "GoGaps":
        """The smallest time gaps between the ego's passage (on timing tau_ego) and the object's: over the
        stations of the conflict zone and of the merge into the object's lane (up to `merge_length` past the
        first station, from the zone on, where the path heads within `merge_heading` rad of the object),
        split by who passes first; and over the stations beyond (the object follows the ego in its lane, or
        the ego follows it). None where no such station is occupied (or the ego does not get there)."""
        o = occ.object
        has = np.isfinite(occ.a)
        mid = (tau_ego[1:] + tau_ego[:-1]) / 2
        lo = np.concatenate([tau_ego[:1], mid])
        hi = np.concatenate([mid, tau_ego[-1:]])
        has &= np.isfinite(lo)
        if not has.any():
            return GoGaps(None, None, None, False, None, False)
        first = int(np.flatnonzero(has)[0])
        aligned = np.abs(wrap(path.yaw - o.yaw)) <= merge_heading
        aligned[:first] = False
        through = has.copy()
        if aligned.any():
            through &= path.s <= path.s[int(np.flatnonzero(aligned)[0])] + merge_length
        start, end = np.maximum(lo, occ.a), np.minimum(hi, occ.b)
        with np.errstate(invalid="ignore"):
            gap = np.where(hi < occ.a, occ.a - hi, np.where(lo > occ.b, lo - occ.b, -(end - start)))
            behind = lo > occ.b  # the object has left the station before the ego gets there
        after = has & ~through
        pick = lambda m: float(gap[m].min()) if m.any() else None  # noqa: E731
        return GoGaps(pick(through & ~behind), pick(through & behind), pick(after), bool((after & ~behind).any()),
                      float(occ.b[through].max()) if through.any() else None, bool(aligned.any()))


@dataclass(frozen=True)
class GoGaps:
    """What going on would leave (CollisionEstimator.go_gap), s."""

    ahead: float | None  # through the zone and the merge, where the ego passes first (negative: together)
    behind: float | None  # ... where the object passes first and the ego follows it
    follow: float | None  # beyond the merge, in the object's lane
    leads: bool  # beyond the merge the ego is ahead of the object (which follows it)
    through_out: float | None  # when the object last occupies a station of the zone or the merge (s from now)
    joins: bool = False  # from the zone on, the ego's path heads the object's way: it joins its lane, not crosses it
