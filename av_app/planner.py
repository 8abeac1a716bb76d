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
vehicle whose path the ego would cross ahead of it: give way;
`pet_margin_emergency_merge_s` where the ego would join its lane ahead of it)
makes a stop point `stop_margin_m` before the first ego
station it occupies. Each plan re-decides from the current state, so the
vehicle resumes as soon as going on would clear the zone with the margin; a
yield is held until the margin is exceeded by `hysteresis_s`, so a decision
does not flicker. Objects following the ego in its lane are not yielded to.

Commit or yield (issue 38): yielding is only a plan while the vehicle can
still stop *before* the conflict zone (the first ego station the object's
predicted footprint occupies), at `decel_stop` or as hard as that needs up
to the vehicle's `max_decel`: the last station from which it can is the
zone's commit point. `commit_or_yield` decides per conflicting object:
a comfortable yield (at most `decel_comfort`) when going on would leave less
than the PET margin; otherwise going on (a profile that accelerates at
`planner.escape_accel` within the route's limits) when the object, holding its speed,
reaches every station of the zone and of the merge into its lane at least
`merge_gap_s` (and `merge_gap_m`) after the ego has left it; otherwise a
hard yield when stopping before the zone is still possible; and past the
commit point with going on unsafe too, a stop only where braking at the limit
leaves the ego clear of the object's corridor ("stop_clear_of_path"), else
going on anyway: an object meets a standing ego at its full speed (the plan
log says "go_unsafe"). A vehicle
never stops with its footprint in a lane a reported vehicle is about to
reach, and a vehicle it has merged ahead of is a follower, not a reason to
brake.

The longitudinal command tracks the profile (its slope ahead, a proportional
term on the speed error, the road load fed forward); pure pursuit steers.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from av_app.config import AvConfig
from av_app.estimator import CollisionEstimator, Conflict, GoGaps
from av_app.fusion import FusedObject
from av_app.geometry import to_frame
from av_app.lanes import LaneMap
from av_app.route import PathSamples, Route, pure_pursuit

HYSTERESIS_S = 0.5
GO_HYSTERESIS_S = 0.3  # s of gap a decision to go may lose before it is reconsidered
PREVIEW_S = 0.5
STOP_SLACK_M = 0.2
FIT_ABOVE_REPORT = 1.0  # m/s an object's fitted speed may exceed its reported one (Planner._steady)
SLOW_STEP = 0.1  # m/s: the grid of speeds a slow-down yield chooses from
SLOW_BUFFER_S = 0.2  # s beyond the PET margin a slow-down is chosen for
SLOW_HOLD_SLACK_S = 0.25  # s under the PET margin a slow-down, once chosen, may be estimated before it is let go
ESCAPE_HOLD = 1.0  # m/s: ahead of a follower, the ego keeps its speed up to this much above the follower's


@dataclass(frozen=True)
class Stop:
    s: float  # station (rear axle) where the vehicle must stand
    reason: str  # yield | red | route_end
    cause: str = ""  # object id / signal group
    past: float | None = None  # how far past the point the vehicle may still come to rest (None: the stop margin)


@dataclass(frozen=True)
class Choice:
    """What to do about one conflicting object (see commit_or_yield)."""

    object_id: str
    action: str  # yield | slow | go | go_unsafe
    need_decel: float  # the deceleration that stops before the zone (inf: it no longer can)
    go_gap: float | None  # the smallest time gap through the zone and the merge if the ego goes on (None: none)
    zone_in: float  # the zone's first ego station
    why: str  # comfortable_yield | slow_yield | clear_ahead | merge_ahead | hard_yield | committed_unsafe
    cap: float | None = None  # slow_yield: the speed the ego holds to at most, m/s


def stop_decel(v0: float, s0: float, zone_in: float, stop_margin: float, grown: float = 0.0) -> float:
    """The deceleration that stops the ego (at v0, station s0) `stop_margin` before a zone that starts at
    zone_in, or within that margin once it is past the stop point (the controller stops there exactly);
    0 standing outside the zone (up to `grown` past its entry: the entry is where the footprints grown by
    the safety margins touch, so a standing vehicle that far in is still clear of the lane); inf when it
    can no longer stop outside the zone."""
    if v0 <= 0.05 and s0 < zone_in + grown:
        return 0.0
    room = zone_in - stop_margin - s0
    if room <= 0.05:
        room = zone_in - s0 - STOP_SLACK_M  # past the stop point: what is left of the margin
        if room <= 0.05:
            return math.inf
    return v0 * v0 / (2 * room)


def commit_or_yield(object_id: str, v0: float, s0: float, zone_in: float, go_gap: float | None, *,
                    pet_margin: float, merge_gap: float, stop_margin: float, decel_comfort: float,
                    max_decel: float, going: bool = False, follow_gap: float | None = None,
                    follow_need: float = 0.0, behind_gap: float | None = None, grown: float = 0.0,
                    blocked: float | None = None, stood: bool = False, slow: float | None = None) -> Choice:
    """Yield (stop before the zone) or go on (clear it), for one object whose PET on the free profile is short.

    In this order: a yield the vehicle can make comfortably is taken unless going on clears the object by
    the full PET margin anyway (or it has already decided to go and going on is still safe), and it is a
    slow-down rather than a stop where one exists (`slow`: the highest speed at which the object passes first
    and the PET margin holds; a slow-down at that margin also beats a merge at merge_gap or a hard brake); then going on
    where it is safe (gap >= merge_gap through the zone and the merge, and the object, not braking, stays
    `follow_need` s behind the ego speeding up ahead of it: follow_gap); then a yield as hard as the vehicle can brake, while stopping before
    the zone is possible at all. Past that commit point, with going on unsafe too: a stop where braking at the
    vehicle's limit leaves the ego, if it leaves the object's corridor free (`blocked`, the fraction of its
    corridor the standing ego would block, is 0); otherwise going on, because an object that meets a
    standing ego meets it at its full speed, one that meets it going on at the difference of their speeds
    (measured: the case study without the RSU, standing 16.7 m/s, going on 9.2 m/s).
    """
    need = stop_decel(v0, s0, zone_in, stop_margin, grown)
    slack = GO_HYSTERESIS_S if going else 0.0  # a decision to go is not undone by a gap a plan's noise shorter
    follows = follow_gap is None or follow_gap >= follow_need - slack
    # behind an object that has passed (behind_gap) merge_gap makes going on safe, but only the PET margin
    # makes it clear: following an ev into its lane 1 s behind it left the case study's PET at -0.05 s
    safe_go = (go_gap is None or go_gap >= merge_gap - slack) and follows and (
        behind_gap is None or behind_gap >= merge_gap - slack)
    clear = (go_gap is None or go_gap >= pet_margin) and follows and (behind_gap is None or behind_gap >= pet_margin)
    go_gap = go_gap if go_gap is not None else behind_gap  # what the plan log shows
    if clear:
        return Choice(object_id, "go", need, go_gap, zone_in, "clear_ahead")
    if slow is not None and not (going and safe_go):
        return Choice(object_id, "slow", need, go_gap, zone_in, "slow_yield", cap=slow)
    if need <= decel_comfort and not (going and safe_go):
        return Choice(object_id, "yield", need, go_gap, zone_in, "comfortable_yield")
    if safe_go:
        return Choice(object_id, "go", need, go_gap, zone_in, "merge_ahead")
    if need <= max_decel:
        return Choice(object_id, "yield", need, go_gap, zone_in, "hard_yield")
    # past the last commit point with going on unsafe: a stop that leaves the object's way free (and, once
    # stopping for it, standing until going on is safe: setting off toward its way while it passes never helps)
    if blocked is not None and (blocked <= 0.0 or stood):
        return Choice(object_id, "yield", need, go_gap, zone_in, "stop_clear_of_path")
    return Choice(object_id, "go", need, go_gap, zone_in, "committed_unsafe")


@dataclass
class Plan:
    t: float
    accel: float
    steer: float
    decision: str  # cruise | yield | stop_red | brake_hard | hold | route_end | go | go_unsafe | escape
    cause: str  # the object (or signal group) behind the decision
    target_speed: float
    s: float  # ego station on the route
    lateral: float  # ego offset left of the route, m
    conflicts: list[Conflict] = field(default_factory=list)
    stops: list[Stop] = field(default_factory=list)
    choices: list[Choice] = field(default_factory=list)


def profile(path: PathSamples, v0: float, cfg: AvConfig, stops: list[Stop], accel: float | None = None,
            cruise: float | None = None, slow_decel: float | None = None) -> np.ndarray:
    """Planned speed at each station of `path` (starting at the ego's station); speeding up at `accel`
    (default: control.accel_comfort) to `cruise` (default: route.cruise_speed), slowing down to it at
    `slow_decel` (default: control.decel_comfort) when above it."""
    ctl, veh, route = cfg.control, cfg.vehicle, cfg.route
    s = path.s
    with np.errstate(divide="ignore"):
        v_curve = np.sqrt(route.lateral_accel_max / np.maximum(np.abs(path.kappa), 1e-9))
    cap = route.cruise_speed if cruise is None else cruise
    # above a speed limit (a cruise speed just lowered: no follower to speed away from any more, or a slow-down
    # to give way) the ego slows at decel_comfort, not at once: an over-speed is not a hazard, a brake in front
    # of a follower is. The curves' limits are approached at decel_curve (the backward pass); the cruise
    # limit is flat, so it needs none, and passing it through one would brake for the lowered cruise speed
    # at decel_curve from where it is first reached, harder than decel_comfort now. (Below the cruise speed
    # this is the same as one backward pass over min(cruise, curve).)
    over = v0 * v0 - 2 * (ctl.decel_comfort if slow_decel is None else slow_decel) * (s - s[0])
    v2 = np.minimum(_backward(np.maximum(v_curve * v_curve, over), s, ctl.decel_curve),
                    np.maximum(cap * cap, over))
    for stop in stops:
        dist = stop.s - s[0]
        need = v0 * v0 / (2 * dist) if dist > 0.05 else math.inf
        decel = min(max(ctl.decel_stop, need), veh.max_decel)
        v2 = np.minimum(v2, np.where(s >= stop.s, 0.0, 2 * decel * np.maximum(stop.s - s, 0.0)))
    # forward pass from the current speed: v_i^2 <= v_k^2 + 2 a (s_i - s_k) for every k <= i
    v2[0] = min(v0 * v0, v2[0])
    a2 = 2 * (ctl.accel_comfort if accel is None else accel)
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


def passes_first(g: GoGaps) -> bool:
    """Whether, on the timing the gaps were taken on, the object leaves every station of the ego's path it
    occupies before the ego gets there (the ego neither crosses in front of it nor leads it in its lane)."""
    return g.ahead is None and not g.leads and (g.behind is not None or g.follow is not None)


class Planner:
    """One plan per AV_Status: decision, acceleration and steering from the ego state and objects."""

    def __init__(self, cfg: AvConfig, route: Route, lanes: LaneMap | None = None):
        self.cfg, self.route = cfg, route
        self.lanes = lanes if cfg.planner.lane_prediction else None
        self.estimator = CollisionEstimator(cfg.planner, cfg.vehicle)
        self.slow_estimator = CollisionEstimator(replace(cfg.planner, horizon_s=cfg.planner.slow_yield_horizon_s),
                                                 cfg.vehicle)  # the same objects, further ahead
        self.s: float | None = None  # last station (hint for projection)
        self.yielding: set[str] = set()
        self.zones: dict[str, float] = {}  # object id -> its conflict zone's first station, while in conflict
        self.going: set[str] = set()  # objects the ego has decided to go on ahead of (or clear the zone before)
        self.stands: dict[str, float] = {}  # object id -> where the ego stops clear of its way
        self.caps: dict[str, float] = {}  # object id -> the speed the ego slows to for it (slow_yield)
        self.tracks: dict[str, list[tuple[float, float, float]]] = {}  # object id -> its recent (t, x, y)
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
        pl = cfg.planner
        escape: list[float] = []  # the speeds of faster vehicles closing from behind in the ego's lane
        tau_go = None  # the ego's timing if it goes on (computed for the first conflict that needs it)
        ego = self.estimator.ego_boxes(path)
        conflicts, stops, choices = [], list(base_stops), []
        yielding, going, go_speed, zones, stands, caps, tracks = set(), set(), {}, {}, {}, {}, {}
        for o in objects:
            if self.lanes is not None:
                o = self.lanes.snap(o)
            self._remember(o, t, tracks)
            if self.estimator.follower(o, pose):
                behind = -float(to_frame(o.x, o.y, pose)[0])
                if not o.static and o.speed > v0 - ESCAPE_HOLD and behind < o.speed * pl.horizon_s:
                    escape.append(o.speed)  # as fast as the ego (or faster), within the horizon behind it
                continue
            occ = self.estimator.occupancy(o, ego)
            if not occ.any:
                continue
            c = self.estimator.assess(occ, tau_free, path)
            conflicts.append(c)
            # an emergency vehicle is given its wider margin where the ego would be in its way (ahead of it, or
            # with it); one that passes every station first is not obstructed by the ego behind it
            base = pl.pet_margin_s
            if o.emergency:
                free_gaps = self.estimator.go_gap(occ, tau_free, path, math.radians(pl.merge_heading_deg),
                                                  cfg.vehicle.length)
                if not passes_first(free_gaps):  # joining its lane ahead of it, the ego then speeds away
                    base = pl.pet_margin_emergency_merge_s if free_gaps.joins else pl.pet_margin_emergency_s
            margin = base + (HYSTERESIS_S if o.id in self.yielding else 0.0)
            if c.pet is None or c.pet >= margin or c.station_in is None:
                if o.id in self.going and c.pet is not None:
                    going.add(o.id)  # keep the decision while the object still crosses the path
                continue
            # going on: at escape_accel to the route's speeds through the zone, and once merged ahead of a
            # faster object in its lane, on to its speed (up to escape_speed_max)
            if tau_go is None:
                tau_go = timing(path, profile(path, v0, cfg, base_stops, accel=pl.escape_accel))
            cruise = max(cfg.route.cruise_speed, min(o.speed, pl.escape_speed_max))
            # the zone's entry as first seen while in conflict: a footprint grown by margins flickers by a
            # station step from plan to plan, and a vehicle standing at its stop point would find the zone
            # moved under its nose (and take itself for committed), or brake hard for a stop point moved back
            # by half a metre; so the first entry seen is kept
            # for good; it moves nearer only while the ego can still stop comfortably before the new entry
            # (the stop margin and the grown footprints absorb a station step of jitter), never further away
            zone_in = self.zones.get(o.id, c.station_in)
            room = c.station_in - pl.stop_margin_m - s0  # to the new stop point, its margin kept whole
            if c.station_in < zone_in and room > 0.5 and v0 * v0 / (2 * room) <= cfg.control.decel_comfort:
                zone_in = c.station_in
            zones[o.id] = zone_in
            merge = math.radians(pl.merge_heading_deg)
            gaps = self.estimator.go_gap(occ, tau_go, path, merge, cfg.vehicle.length)
            follow, leads = gaps.follow, gaps.leads
            if leads and cruise > cfg.route.cruise_speed:  # merged ahead of a faster object: speed up
                tau_esc = timing(path, profile(path, v0, cfg, base_stops, accel=pl.escape_accel, cruise=cruise))
                follow = self.estimator.go_gap(occ, tau_esc, path, merge, cfg.vehicle.length).follow
            need_gap = max(pl.merge_gap_s, pl.merge_gap_m / max(o.speed, 1.0))
            # a slow-down lets the object pass first, so its margin is the one behind an object (above); it is
            # chosen for the margin itself: the hysteresis is for when to let go of it
            slow = (self._slow_cap(path, v0, base_stops, self._steady(o, t, tracks[o.id]), ego, pl.pet_margin_s,
                                   self.caps.get(o.id))
                    if pl.slow_yield else None)
            ch = commit_or_yield(o.id, v0, s0, zone_in, gaps.ahead, pet_margin=margin, merge_gap=need_gap,
                                 stop_margin=pl.stop_margin_m, decel_comfort=cfg.control.decel_comfort,
                                 max_decel=cfg.vehicle.max_decel, going=o.id in self.going, follow_gap=follow,
                                 follow_need=pl.merge_gap_m / max(o.speed, 1.0), behind_gap=gaps.behind,
                                 grown=2 * pl.margin_m, slow=slow)
            if ch.why == "committed_unsafe":
                # where braking at the limit leaves it (a tenth of a second to react, the controller's slack);
                # once chosen the point is kept (recomputed each plan it would creep on by that slack)
                s_stand = self.stands.get(o.id, s0 + v0 * v0 / (2 * cfg.vehicle.max_decel) + v0 * pl.dt_s
                                          + STOP_SLACK_M)
                stand = self.route.at(np.array([s_stand]))
                shift = self.lanes.centre_shift(o) if self.lanes is not None else 0.0
                blocked = self.estimator.blocked(o, (float(stand[0][0]), float(stand[1][0]), float(stand[2][0])),
                                                 shift)
                ch = commit_or_yield(o.id, v0, s0, zone_in, gaps.ahead, pet_margin=margin, merge_gap=need_gap,
                                     stop_margin=pl.stop_margin_m, decel_comfort=cfg.control.decel_comfort,
                                     max_decel=cfg.vehicle.max_decel, going=o.id in self.going,
                                     follow_gap=follow, follow_need=pl.merge_gap_m / max(o.speed, 1.0),
                                     behind_gap=gaps.behind, grown=2 * pl.margin_m, blocked=blocked,
                                     stood=o.id in self.stands)
            go_speed[o.id] = cruise if leads else cfg.route.cruise_speed
            choices.append(ch)
            if ch.why == "stop_clear_of_path":
                stops.append(Stop(s_stand, "yield", o.id, past=STOP_SLACK_M))  # no margin beyond: the object's way
                stands[o.id] = s_stand
                yielding.add(o.id)
            elif ch.action == "yield":
                stops.append(Stop(zone_in - pl.stop_margin_m, "yield", o.id))
                yielding.add(o.id)
            elif ch.action == "slow":
                caps[o.id] = ch.cap
                yielding.add(o.id)
            else:
                going.add(o.id)
        self.yielding, self.going, self.zones, self.stands, self.caps = yielding, going, zones, stands, caps
        self.tracks = tracks
        go = bool(going) and not yielding
        fast = [go_speed.get(k, cfg.route.cruise_speed) for k in going] if go else []
        fast += [min(v, pl.escape_speed_max) for v in escape]
        cruise = max([cfg.route.cruise_speed, *fast])
        if caps:  # giving way by slowing down: the slowest any object needs
            cruise = min(cruise, *caps.values())
        v_plan = profile(path, v0, cfg, stops, accel=pl.escape_accel if go or escape else None, cruise=cruise,
                         slow_decel=cfg.control.decel_stop if caps else None)
        accel, target = self._longitudinal(path, v_plan, v0, [st for st in stops if st.s < s0 + self.path_length],
                                           pl.escape_accel if go or escape else cfg.vehicle.max_accel)
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
        elif caps:
            decision, cause = "slow", min(caps, key=caps.get)  # giving way by slowing down
        elif go:
            unsafe = [ch for ch in choices if ch.why == "committed_unsafe"]
            decision = "go_unsafe" if unsafe else "go"
            cause = (unsafe or [ch for ch in choices if ch.action == "go"] or [None])[0]
            cause = cause.object_id if cause is not None else sorted(going)[0]
        elif escape:
            decision = "escape"  # a faster vehicle closes from behind: speed up ahead of it, never brake
        if v0 < 0.3 and target < 0.3:
            accel = -cfg.control.hold_decel  # standing: hold the brake
            if decision == "cruise":
                decision = "hold"
        return Plan(t, accel, steer, decision, cause, target, s0, lateral, conflicts, stops, choices)

    def _remember(self, o: FusedObject, t: float, tracks: dict) -> None:
        """Put the object's position at t into `tracks` beside those of the last `speed_window_s`."""
        w = self.cfg.planner.speed_window_s
        seen = [h for h in self.tracks.get(o.id, []) if t - w - 1e-9 <= h[0] < t]
        seen.append((t, o.x, o.y))
        tracks[o.id] = seen

    def _steady(self, o: FusedObject, t: float, seen: list[tuple[float, float, float]]) -> FusedObject:
        """The object with its speed fitted (least squares) to its positions `seen` along its heading, once
        they span half of `speed_window_s`, but never more than FIT_ABOVE_REPORT above the reported speed
        (the fit lags a braking vehicle). A slow-down is judged on this speed: it places the object's passage
        seconds ahead, and the reported speed wanders (the RSU's tracker: 10.2-11.5 m/s for a vehicle holding
        11.2, 5th-95th percentile, measured; fitted over 2 s 10.5-11.4), so the speed chosen stepped down with
        each low reading and stayed there (issue 38)."""
        w = self.cfg.planner.speed_window_s
        if w <= 0.0 or o.static or len(seen) < 5 or t - seen[0][0] < w / 2:
            return o
        h = np.array(seen)
        along = h[:, 1] * math.cos(o.yaw) + h[:, 2] * math.sin(o.yaw)
        fitted = float(np.polyfit(h[:, 0] - t, along, 1)[0])
        return replace(o, speed=min(max(fitted, 0.0), o.speed + FIT_ABOVE_REPORT))

    def _slow_cap(self, path: PathSamples, v0: float, stops: list[Stop], o: FusedObject, ego, margin: float,
                  kept: float | None) -> float | None:
        """The highest speed (a step of the grid from `slow_yield_min_speed` by SLOW_STEP, below the cruise
        speed) that, held from now on (slowing to it at `decel_stop`, the planned stop's rate), lets the object
        pass every station first with `margin` + SLOW_BUFFER_S to spare; None where even the lowest does not.
        The object is predicted over `slow_yield_horizon_s` (a slower ego arrives later than the collision
        horizon looks) and must leave the zone and the merge within it: beyond it nothing is known. Slower is
        never worse here (every station is reached later), so the grid is bisected.

        `kept`, the speed chosen at the last plan, is held while it still gives the margin less
        SLOW_HOLD_SLACK_S and the new choice is less than two steps above it. A speed chosen 0.2 s above the
        margin and let go 0.25 s below it is a band as wide as the object's predicted passage wanders: with
        the RSU's tracking, the PET a fixed speed gives moved by 0.42-0.54 s over a few seconds for an ev
        holding its speed (issue 38, 25 mph 1.25 s early), and a speed let go at the margin itself (or 0.2 s
        under it) stepped down on a low reading (and on the vehicle's lag behind its profile) and stayed
        down: 4.2 -> 3.8 m/s where the ev passed 1.8 s ahead of the cav. The band is the slow-down's
        hysteresis, as GO_HYSTERESIS_S is going on's."""
        cfg, pl = self.cfg, self.cfg.planner
        merge = math.radians(pl.merge_heading_deg)
        occ = self.slow_estimator.occupancy(o, ego)

        def holds(cap: float, need: float) -> bool:
            tau = timing(path, profile(path, v0, cfg, stops, cruise=cap, slow_decel=cfg.control.decel_stop))
            g = self.slow_estimator.go_gap(occ, tau, path, merge, cfg.vehicle.length)
            if g.ahead is not None or g.through_out is None or g.through_out > pl.slow_yield_horizon_s - pl.dt_s / 2:
                return False
            pet = self.slow_estimator.assess(occ, tau, path).pet
            return pet is not None and pet >= need

        best = None
        grid = np.round(np.arange(pl.slow_yield_min_speed, cfg.route.cruise_speed - 1e-9, SLOW_STEP), 6)
        if len(grid) and holds(float(grid[0]), margin + SLOW_BUFFER_S):
            lo, hi = 0, len(grid)  # grid[lo] holds; grid[hi] (if any) does not
            while hi - lo > 1:
                mid = (lo + hi) // 2
                lo, hi = (mid, hi) if holds(float(grid[mid]), margin + SLOW_BUFFER_S) else (lo, mid)
            best = float(grid[lo])
        if kept is not None and (best is None or best < kept + 2 * SLOW_STEP) and holds(kept, margin - SLOW_HOLD_SLACK_S):
            return kept
        return best

    def _longitudinal(self, path: PathSamples, v_plan: np.ndarray, v0: float, stops: list[Stop],
                      a_max: float) -> tuple[float, float]:
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
                beyond = margin - STOP_SLACK_M if st.past is None else st.past
                a = min(a, -v0 * v0 / (2 * max(d + beyond, 0.1)))
        a += cfg.control.speed_kp * min(v_plan[0] - v0, 0.0)  # only brakes: the profile starts at v0 otherwise
        road = cfg.vehicle.road_load_c0 + cfg.vehicle.road_load_c2 * v0 * v0 if v0 > 0.05 else 0.0
        accel = min(max(a + road, -cfg.vehicle.max_decel), a_max)
        return float(accel), float(v_plan[k])
