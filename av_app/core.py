"""The AV app's pure core: inputs with their simulation times in, one command per AV_Status out.

No bus, no CAN adapter, no clock: the process shell (av_app.app) feeds it what
arrived, in time order, and gives it a `send` function; tests and the
benchmark drive it directly. Everything it decides for time t depends only on
inputs stamped <= t and on the stage clock (av_app.timing), so a lockstep run
under the `fixed` policy repeats bit for bit.

Per input:
* AV_Status (t, speed, yaw rate) and GNSS fixes -> the ego filter;
* a lidar scan (t, points in the vehicle frame) -> clusters and tracks with
  the ego pose at t; usable from t + perception;
* a V2X frame (arrival t_a) -> verified, decoded, in local metres; usable from
  its FUSE stamp; its trace record waits for the first command after that.
Per AV_Status of time t: fuse what is usable at t, plan, steer, send.
"""
from __future__ import annotations

import logging
import math
import time
from collections import Counter
from dataclasses import dataclass
from typing import Callable

from bridges.can.codec import AppState, Mode
from bridges.sensor_stream import GnssFix
from bridges.v2x import (AIR_ARRIVAL, CAN_COMMAND, DECODE, FUSE, PLAN, RECEIVE, VERIFY, stamp_ns, stamp_s)

from av_app.config import AvConfig
from av_app.ego import EgoFilter
from av_app.fusion import FusedObject, fuse
from av_app.geometry import to_frame
from av_app.health import Health
from av_app.lanes import LaneMap
from av_app.obu import Obu, Rejected, V2xObject
from av_app.perception import LidarObject, LidarTracker, detect
from av_app.planner import Plan, Planner, Stop
from av_app.route import Route
from av_app.selfid import EgoRecognizer, SelfCheck
from av_app.signals import SignalState
from av_app.timing import StageClock

log = logging.getLogger("av_app")


@dataclass
class _Pending:
    """A frame taken in, waiting for the first command computed after it was fused."""

    stamps: dict[str, int]
    station: str
    object: str
    kind: str
    fuse_t: float
    compute_s: float  # wall seconds of its verify + decode + fuse


class AvCore:
    def __init__(self, cfg: AvConfig, obu: Obu, clock: StageClock, world: dict | None = None):
        """`world`: what the master said of the world in its welcome (the intersection's geometry)."""
        self.cfg, self.obu, self.clock = cfg, obu, clock
        self.route = Route(cfg.route.waypoints, cfg.route.corner_radius)
        self.lanes = LaneMap.from_world(world)
        self.planner = Planner(cfg, self.route, self.lanes)
        self.ego = EgoFilter(cfg.ego)
        self.tracker = LidarTracker(cfg.perception, self.lanes.on_road if self.lanes is not None else None)
        self.signals = SignalState(cfg, obu.origin)
        self.health = Health()
        self.self_ids = EgoRecognizer(cfg.obu, cfg.vehicle)  # which BSMs describe the ego itself
        self._self_counted: dict[str, float] = {}  # object id -> measurement time of its last BSM counted as self
        self._self_now: list[tuple[str, str, float]] = []  # (id, rule, distance) left out of the last object list
        self._v2x: dict[str, list[list]] = {}  # object id -> [[usable from (FUSE), V2xObject], ...]
        self._heard_t: float | None = None  # when a V2X frame (the RSU's) was last accepted: phantoms need it
        self._lidar: list[tuple[float, list[LidarObject]]] = []
        self._lidar_now: list[LidarObject] = []
        self._pending: list[_Pending] = []
        self._speed: tuple[float, float] | None = None  # (t, speed) of the last AV_Status
        self.last_plan: Plan | None = None
        self.last_objects: list[FusedObject] = []

    # -- inputs ------------------------------------------------------------------------------------------
    def on_status(self, t: float, speed: float, yaw_rate: float) -> None:
        self.health.counts["statuses"] += 1
        if not self.ego.status(t, speed, yaw_rate):
            self.health.garbage["status"] += 1
        elif math.isfinite(speed):
            self._speed = (t, speed)  # the vehicle's own speed: what the longitudinal control tracks

    def on_gnss(self, fix: GnssFix) -> None:
        self.health.counts["gnss_fixes"] += 1
        if not self.ego.gnss(fix.t, fix.x, fix.y, fix.heading, fix.speed):
            self.health.garbage["gnss"] += 1

    def on_lidar(self, t: float, points) -> list[LidarObject] | None:
        """One scan of time t (points in the vehicle frame); its obstacles are usable from t + perception."""
        if not self.cfg.perception.enabled:
            return None
        state = self.ego.state(t)
        if state is None:
            self.health.counts["scans_before_ego"] += 1
            return None
        w0 = time.perf_counter()
        clusters = detect(points, state.pose, self.cfg.perception)
        objects = self.tracker.update(t, clusters)
        wall = time.perf_counter() - w0
        self.health.cluster_ms.append(wall * 1e3)
        self.health.counts["scans"] += 1
        self._lidar.append((self.clock.charge("perception", t, wall), objects))
        return objects

    def on_v2x(self, payload: bytes, t_arrival: float, stamps: dict | None = None,
               t_receive: float | None = None):
        """One frame off the air, arrived at t_arrival (taken at t_receive in realtime runs)."""
        t_rx = t_arrival if t_receive is None else t_receive
        try:
            acc = self.obu.receive(payload, t_rx)
        except Rejected as exc:
            self.health.mark(f"rejected:{exc.reason}", t_rx)
            return None
        self._heard_t = t_rx if self._heard_t is None else max(self._heard_t, t_rx)
        t_verify = self.clock.charge("verify", t_rx, acc.wall_s["verify"])
        t_decode = self.clock.charge("decode", t_verify, acc.wall_s["decode"])
        # fuse: the object joins the list the planner fuses from (association itself runs at plan time)
        w0 = time.perf_counter()
        carried = [acc.object] if acc.object is not None else acc.objects  # a BSM's one, an SDSM's all
        entries = [[math.inf, obj] for obj in carried]
        for entry in entries:
            self._v2x.setdefault(entry[1].id, []).append(entry)
        wall_fuse = time.perf_counter() - w0
        t_fuse = self.clock.charge("fuse", t_decode, wall_fuse)
        for entry in entries:
            entry[0] = t_fuse
            self.health.mark(f"v2x:{entry[1].id}", t_fuse)
        if acc.spat is not None:
            self.signals.take_spat(acc.spat, t_fuse)
        elif acc.map is not None:
            self.signals.take_map(acc.map, t_fuse)
        up = {k: int(v) for k, v in (stamps or {}).items()}
        up.setdefault(AIR_ARRIVAL, stamp_ns(t_arrival))
        up.update({RECEIVE: stamp_ns(t_rx), VERIFY: stamp_ns(t_verify), DECODE: stamp_ns(t_decode),
                   FUSE: stamp_ns(t_fuse)})
        self._pending.append(_Pending(up, acc.station, acc.object_id, acc.kind, t_fuse,
                                      acc.wall_s["verify"] + acc.wall_s["decode"] + wall_fuse))
        return acc

    # -- the object list at time t -----------------------------------------------------------------------
    def objects(self, t: float) -> list[FusedObject]:
        cfg = self.cfg
        v2x: list[V2xObject] = []
        state = self.ego.state(t)
        self._self_now = []
        for oid in sorted(self._v2x):
            entries = self._v2x[oid]
            usable = [e for e in entries if e[0] <= t + 1e-12]
            if not usable:
                continue
            newest = max(usable, key=lambda e: e[1].t)
            self._v2x[oid] = [newest] + [e for e in entries if e[0] > t + 1e-12]
            obj = newest[1]
            if t - obj.t > cfg.obu.max_age_s:
                self.health.counts["v2x_aged_out"] += 1
                del self._v2x[oid]
                self.self_ids.forget(obj)
                self._self_counted.pop(oid, None)
                continue
            if state is not None:
                check = self.self_ids.check(obj, state, t)
                if check.is_self:  # the ego itself: neither fused nor planned around
                    self._count_self(obj, check, t)
                    continue
            v2x.append(obj)
        while len(self._lidar) and self._lidar[0][0] <= t + 1e-12:
            self._lidar_now = self._lidar.pop(0)[1]
        return fuse(v2x, self._lidar_now, t, cfg.fusion) + self._phantoms(t)

    def _phantoms(self, t: float) -> list[FusedObject]:
        """A vehicle at each edge of the RSU's coverage (`coverage.edges`) at its approach's design speed, while
        the RSU is heard: beyond the edge the RSU cannot say the road is empty (issue 38, item 2). Each plan puts
        it at the edge again, so it costs the ego only what a vehicle just out of sight would."""
        cov = self.cfg.coverage
        if not cov.edges or self._heard_t is None or t - self._heard_t > cov.max_silence_s:
            return []
        return [FusedObject(f"phantom:{i}", "phantom", t, float(x), float(y), math.radians(h), float(v), 0.0,
                            cov.length, cov.width) for i, (x, y, h, v) in enumerate(cov.edges)]

    def _count_self(self, obj: V2xObject, check: SelfCheck, t: float) -> None:
        """`counts["v2x_self"]`: object lists that left a BSM out as the ego; `self_bsms[rule]`: distinct BSMs
        recognised as the ego, by the rule that first did (a BSM is checked at every plan until the next)."""
        h = self.health
        h.counts["v2x_self"] += 1
        self._self_now.append((obj.id, check.rule, check.distance))
        if self._self_counted.get(obj.id) != obj.t:
            self._self_counted[obj.id] = obj.t
            h.self_bsms[check.rule] += 1
            h.mark(f"v2x_self:{check.rule}", t)

    # -- one command per status -------------------------------------------------------------------------------
    def app_state(self, t: float) -> AppState:
        if not self.ego.ready:
            return AppState.INIT
        if self.health.errors:
            return AppState.FAULT
        if self.ego.stale(t):
            return AppState.DEGRADED
        return AppState.ENGAGED

    def decide(self, t: float) -> tuple[Plan | None, Mode]:
        """The plan for time t (None and MANUAL before the ego's first fix)."""
        state = self.ego.state(t)
        if state is None:
            return None, Mode.MANUAL
        objects = self.objects(t)
        stops: list[Stop] = self.signals.stops(t, state, self.route, self.planner)
        # the speed for control: the vehicle's own (AV_Status), fresh; the filter's when there is none
        v = self._speed[1] if self._speed is not None and t - self._speed[0] <= 0.1 else state.v
        plan = self.planner.plan(t, state.pose, v, objects, stops)
        self.last_plan, self.last_objects = plan, objects
        h = self.health
        h.objects_by_source = Counter("static" if o.static else o.source for o in objects)
        for source in h.objects_by_source:
            h.mark(f"source:{source}", t)
        if plan.decision != h.decision:
            h.mark(f"decision:{plan.decision}", t)
        h.decision, h.cause = plan.decision, plan.cause
        h.decisions[plan.decision] += 1
        return plan, Mode.AUTO

    def command(self, t: float, send: Callable[[float, float, Mode], int]) -> list[dict]:
        """Plan for the AV_Status of time t, send the command through `send(accel, steer, mode) -> counter`,
        and return the trace records of the frames this command is the first to use."""
        w0 = time.perf_counter()
        try:
            plan, mode = self.decide(t)
        except Exception as exc:  # a bug must not leave the vehicle without commands: stop, say so
            self.health.errors[type(exc).__name__] += 1
            log.exception("planning failed at t = %.3f s; braking", t)
            last = self.last_plan
            plan, mode = None, Mode.AUTO
            accel, steer = -self.cfg.control.decel_comfort, (last.steer if last else 0.0)
        else:
            if plan is None:
                accel, steer = 0.0, 0.0
            else:
                accel, steer = plan.accel, plan.steer
        wall_plan = time.perf_counter() - w0
        self.health.plan_ms.append(wall_plan * 1e3)
        t_plan = self.clock.charge("plan", t, wall_plan)
        w1 = time.perf_counter()
        counter = send(accel, steer, mode)
        wall_can = time.perf_counter() - w1
        t_can = self.clock.charge("can_command", t_plan, wall_can)
        self.health.counts["commands"] += 1
        if accel < -0.5 and plan is not None and plan.decision in ("yield", "slow", "brake_hard", "stop_red"):
            self.health.mark("first_brake", t)
        if plan is not None and plan.decision in ("go", "go_unsafe"):
            self.health.mark("first_go", t)  # went on through a conflict zone instead of yielding
        records, waiting = [], []
        for p in self._pending:
            if p.fuse_t > t + 1e-12:
                waiting.append(p)
                continue
            stamps = {**p.stamps, PLAN: stamp_ns(t_plan), CAN_COMMAND: stamp_ns(t_can)}
            records.append({"stamps": stamps, "can_counter": counter, "station": p.station, "object": p.object,
                            "kind": p.kind})
            self.health.stage3_sim_ms.append((stamps[CAN_COMMAND] - stamps[AIR_ARRIVAL]) / 1e6)
            self.health.stage3_compute_ms.append((p.compute_s + wall_plan + wall_can) * 1e3)
        self._pending = waiting
        return records

    def plan_record(self, t: float) -> dict:
        """What the last plan saw and decided (for the plan log)."""
        p, st = self.last_plan, self.ego.state(t)
        r = lambda v: round(float(v), 3)  # noqa: E731
        out: dict = {"t": r(t)}
        if st is not None:
            out["ego"] = [r(st.x), r(st.y), r(st.yaw), r(st.v)]
        if p is not None:
            out.update(decision=p.decision, cause=p.cause, accel=r(p.accel), steer=r(p.steer), s=r(p.s),
                       lateral=r(p.lateral), target=r(p.target_speed))
            out["conflicts"] = [[c.object_id, None if c.ttc is None else r(c.ttc), None if c.pet is None else r(c.pet),
                                 None if c.station_in is None else r(c.station_in)] for c in p.conflicts]
            if p.choices:  # commit or yield, per conflicting object:
                # [id, action, why, stop decel, go gap, zone, speed cap (slow_yield; else null)]
                out["choices"] = [[ch.object_id, ch.action, ch.why,
                                   None if not math.isfinite(ch.need_decel) else r(ch.need_decel),
                                   None if ch.go_gap is None else r(ch.go_gap), r(ch.zone_in),
                                   None if ch.cap is None else r(ch.cap)] for ch in p.choices]
        if self.signals.last:
            out["signal"] = dict(self.signals.last)
        objs = [o for o in self.last_objects if not o.static]
        if self._self_now:  # BSMs left out as the ego: [id, rule, distance from the ego's centre]
            out["self"] = [[oid, rule, r(d)] for oid, rule, d in self._self_now]
        out["objects"] = [[o.id, o.source, r(o.x), r(o.y), r(o.yaw), r(o.speed), r(o.length), r(o.width), r(o.age)]
                          for o in objs]
        if st is not None:  # the same objects in the ego frame: metres ahead, metres to the left
            out["ego_frame"] = [[o.id, *(r(c) for c in to_frame(o.x, o.y, st.pose))] for o in objs]
        out["lidar"] = [[o.id, r(o.t), r(o.x), r(o.y), r(o.yaw), r(o.speed), r(o.length), r(o.width)]
                        for o in self._lidar_now if not o.static]
        return out

    @staticmethod
    def record_time(record: dict) -> float:
        return stamp_s(record["stamps"][CAN_COMMAND])
