"""Speed planner and controller: cruise, slow for curves, yield to conflicts, stop at red, follow the route.

The speed profile over the ego path's stations is the classic forward-backward
pass: each station's limit is the cruise speed or the curve speed
sqrt(lateral_accel_max / |curvature|), zero at and beyond a stop point; a
backward pass lets the vehicle slow down in time (at `decel_curve` before
curves; before a stop at `decel_stop`, or harder when that no longer
suffices, up to the vehicle's `max_decel`); a forward pass from the current
speed limits acceleration. A plan that brakes harder than `decel_comfort`
says so: its decision is "brake_hard".

Yielding (per object, from the collision estimator): against the *free*
profile (route limits only), an object whose post-encroachment time at the
ego path is below `pet_margin_s` (`pet_margin_emergency_s` for an emergency
vehicle: give way) makes a stop point `stop_margin_m` before the first ego
station it occupies. Each plan re-decides from the current state, so the
vehicle resumes as soon as going on would clear the zone with the margin; a
yield is held until the margin is exceeded by `hysteresis_s`, so a decision
does not flicker. Objects following the ego in its lane are not yielded to.

The longitudinal command tracks the profile (its slope ahead, a proportional
term on the speed error, the road load fed forward); pure pursuit steers.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from av_app.config import AvConfig
from av_app.estimator import CollisionEstimator, Conflict
from av_app.fusion import FusedObject
from av_app.lanes import LaneMap
from av_app.route import PathSamples, Route, pure_pursuit

HYSTERESIS_S = 0.5
PREVIEW_S = 0.5  # the longitudinal controller follows the profile's slope over this much time ahead


@dataclass(frozen=True)
class Stop:
    s: float  # station (rear axle) where the vehicle must stand
    reason: str  # yield | red | route_end
    cause: str = ""  # object id / signal group


@dataclass
class Plan:
    t: float
    accel: float
    steer: float
    decision: str  # cruise | yield | stop_red | brake_hard | hold | route_end
    cause: str  # the object (or signal group) behind the decision
    target_speed: float
    s: float  # ego station on the route
    lateral: float  # ego offset left of the route, m
    conflicts: list[Conflict] = field(default_factory=list)
    stops: list[Stop] = field(default_factory=list)


def profile(path: PathSamples, v0: float, cfg: AvConfig, stops: list[Stop]) -> np.ndarray:
    """Planned speed at each station of `path` (starting at the ego's station)."""
    ctl, veh, route = cfg.control, cfg.vehicle, cfg.route
    s = path.s
    with np.errstate(divide="ignore"):
        v_curve = np.sqrt(route.lateral_accel_max / np.maximum(np.abs(path.kappa), 1e-9))
    lim = np.minimum(route.cruise_speed, v_curve)
    v2 = _backward(lim * lim, s, ctl.decel_curve)
    for stop in stops:
        dist = stop.s - s[0]
        need = v0 * v0 / (2 * dist) if dist > 0.05 else math.inf
        decel = min(max(ctl.decel_stop, need), veh.max_decel)
        v2 = np.minimum(v2, np.where(s >= stop.s, 0.0, 2 * decel * np.maximum(stop.s - s, 0.0)))
    # forward pass from the current speed: v_i^2 <= v_k^2 + 2 a (s_i - s_k) for every k <= i
    v2[0] = min(v0 * v0, v2[0])
    a2 = 2 * ctl.accel_comfort
    return np.sqrt(np.minimum.accumulate(v2 - a2 * s) + a2 * s)


def _backward(v2: np.ndarray, s: np.ndarray, decel: float) -> np.ndarray:
    """Squared speeds that can slow down to every later limit at `decel`: v_i^2 <= v_j^2 + 2 d (s_j - s_i)."""
    d2 = 2 * decel
    return np.minimum.accumulate((v2 + d2 * s)[::-1])[::-1] - d2 * s


def timing(path: PathSamples, v: np.ndarray) -> np.ndarray:
    """Time (s from now) at which the ego reaches each station on profile v (inf: never)."""
    ds = np.diff(path.s)
    avg = (v[1:] + v[:-1]) / 2
    with np.errstate(divide="ignore"):
        dt = np.where(avg > 1e-3, ds / np.maximum(avg, 1e-12), np.inf)
    return np.concatenate([[0.0], np.cumsum(dt)])


class Planner:
    """One plan per AV_Status: decision, acceleration and steering from the ego state and objects."""

    def __init__(self, cfg: AvConfig, route: Route, lanes: LaneMap | None = None):
        self.cfg, self.route = cfg, route
        self.lanes = lanes if cfg.planner.lane_prediction else None
        self.estimator = CollisionEstimator(cfg.planner, cfg.vehicle)
        self.s: float | None = None  # last station (hint for projection)
        self.yielding: set[str] = set()
        self.path_length = max(30.0, cfg.route.cruise_speed * cfg.planner.horizon_s * 1.5 + 10.0)

    def plan(self, t: float, pose: tuple[float, float, float], v: float, objects: list[FusedObject],
             extra_stops: list[Stop] = ()) -> Plan:
        cfg = self.cfg
        s0, lateral = self.route.project(pose[0], pose[1], self.s)
        self.s = s0
        path = self.route.samples(s0, self.path_length, cfg.planner.path_ds)
        v0 = max(v, 0.0)
        base_stops = list(extra_stops)
        end = self.route.length - cfg.planner.stop_margin_m
        if end < s0 + self.path_length:
            base_stops.append(Stop(end, "route_end"))
        free = profile(path, v0, cfg, base_stops)
        tau_free = timing(path, free)
        ego = self.estimator.ego_boxes(path)
        conflicts, stops = [], list(base_stops)
        yielding = set()
        for o in objects:
            if self.lanes is not None:
                o = self.lanes.snap(o)
            if self.estimator.follower(o, pose):
                continue
            occ = self.estimator.occupancy(o, ego)
            if not occ.any:
                continue
            c = self.estimator.assess(occ, tau_free, path)
            conflicts.append(c)
            margin = cfg.planner.pet_margin_emergency_s if o.emergency else cfg.planner.pet_margin_s
            if o.id in self.yielding:
                margin += HYSTERESIS_S
            if c.pet is not None and c.pet < margin and c.station_in is not None:
                stops.append(Stop(c.station_in - cfg.planner.stop_margin_m, "yield", o.id))
                yielding.add(o.id)
        self.yielding = yielding
        v_plan = profile(path, v0, cfg, stops)
        accel, target = self._longitudinal(path, v_plan, v0, [st for st in stops if st.s < s0 + self.path_length])
        steer, _ = pure_pursuit(self.route, pose, v0, s0, cfg.vehicle.wheelbase, cfg.control.lookahead_min_m,
                                cfg.control.lookahead_time_s, cfg.vehicle.max_steer)
        decision, cause = "cruise", ""
        active = [st for st in stops if st.s < s0 + self.path_length]
        if active:
            first = min(active, key=lambda st: st.s)
            decision = {"yield": "yield", "red": "stop_red", "route_end": "route_end"}[first.reason]
            cause = first.cause
            if accel < -cfg.control.decel_comfort and decision != "route_end":
                decision = "brake_hard"  # harder than comfortable: it had to
        if v0 < 0.3 and target < 0.3:
            accel = -cfg.control.hold_decel  # standing: hold the brake
            if decision == "cruise":
                decision = "hold"
        return Plan(t, accel, steer, decision, cause, target, s0, lateral, conflicts, stops)

    def _longitudinal(self, path: PathSamples, v_plan: np.ndarray, v0: float, stops: list[Stop]) -> tuple[float, float]:
        """Acceleration that follows the profile to its next station, brakes exactly for the nearest stop
        (the station grid does not hold the stop point), corrects a speed above the profile, and feeds the
        road load forward."""
        cfg = self.cfg
        # the profile's slope over the next half second: a small speed error is not corrected within
        # a few centimetres (that would turn sensor noise into jerk); stops are braked for exactly below
        ahead = max(cfg.planner.path_ds, PREVIEW_S * v0)
        k = int(min(len(path.s) - 1, max(1, np.searchsorted(path.s, path.s[0] + ahead - 1e-9))))
        a = (v_plan[k] ** 2 - v0 ** 2) / (2 * max(path.s[k] - path.s[0], 1e-3))
        margin = cfg.planner.stop_margin_m
        for st in stops:
            d = st.s - path.s[0]
            if d > 0.05 and v0 * v0 / (2 * d) >= cfg.control.decel_stop - 1e-9:
                a = min(a, -v0 * v0 / (2 * d))  # on (or past) the stop profile: exactly what stopping needs
            elif d <= 0.05 and v0 > 0.0:  # at or past the stop point: stop within the margin left
                a = min(a, -v0 * v0 / (2 * max(d + margin, 0.1)))
        a += cfg.control.speed_kp * min(v_plan[0] - v0, 0.0)  # only brakes: the profile starts at v0 otherwise
        road = cfg.vehicle.road_load_c0 + cfg.vehicle.road_load_c2 * v0 * v0 if v0 > 0.05 else 0.0
        accel = min(max(a + road, -cfg.vehicle.max_decel), cfg.vehicle.max_accel)
        return float(accel), float(v_plan[k])
