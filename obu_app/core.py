"""The emergency vehicle's signal-request logic: pose + MAP in, SRMs out; SSM and SPaT read. Pure core.

No bus, no clock: `EvsCore.step(t, pose)` is told the vehicle's position,
heading and speed at simulated time t and answers the SRMs to send then.

* From the MAP (bridges.j2735.map.IntersectionGeometry) it finds the ingress
  lane it is on: the lane whose stop-line-ward direction matches its heading
  (within 45 deg) and whose centreline it is within half a lane of, before the
  stop line. Its approach, signal group and the distance to the stop line
  follow; ETA = distance / speed.
* When the ETA falls below `horizon_s` it sends a `priorityRequest` (role
  emergency, its inbound lane, the ETA, a duration), and renews it every
  `renew_s` (J2735's SRM rate: on change, else about 1 Hz) while the request
  stands, as a `priorityRequestUpdate`.
* Once it has crossed the stop line by `through_m` it sends a
  `priorityCancellation` (`cancel_repeats` times, one per renewal period, since
  a frame can be lost on the air) and stops.
* `on_ssm` keeps the status the intersection gave its request; `on_spat` the
  state of its signal group (for the log and the trace).
"""
from __future__ import annotations

import math
from datetime import datetime, timezone
from dataclasses import dataclass, field

from bridges.j2735.map import IntersectionGeometry
from bridges.j2735.signal_request import AccessPoint, Requestor, RequestorType, SignalRequest, Srm, Ssm
from bridges.j2735.spat import Spat

IDLE, REQUESTING, CANCELLING, DONE = "idle", "requesting", "cancelling", "done"


@dataclass(frozen=True)
class Pose:
    x: float          # m east of the MAP's reference point
    y: float          # m north
    heading: float    # deg clockwise from north
    speed: float      # m/s


@dataclass(frozen=True)
class OnLane:
    lane_id: int
    approach: int | None
    signal_group: int | None
    to_stop_line_m: float   # > 0 before the stop line


@dataclass
class EvsConfig:
    enabled: bool = True        # False: listen only (a baseline run without the request)
    vehicle_id: int = 0xE1
    role: str = "emergency"
    request_id: int = 1
    horizon_s: float = 12.0     # ask when the ETA to the stop line falls below this
    renew_s: float = 1.0        # renewal period of a standing request
    duration_s: float = 10.0    # how long the service is asked for (SRM duration)
    through_m: float = 15.0     # past the stop line by this: through the junction, cancel
    cancel_repeats: int = 3
    min_speed: float = 0.5      # m/s floor of the ETA's speed (a stopped vehicle has a finite ETA)

    def validate(self) -> None:
        for name in ("horizon_s", "renew_s", "duration_s", "through_m", "min_speed"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"evsp.{name} = {value!r}: must be a number > 0")
        if not 1 <= self.cancel_repeats <= 20:
            raise ValueError(f"evsp.cancel_repeats = {self.cancel_repeats!r}: must be 1..20")
        if not 0 <= self.request_id <= 255:
            raise ValueError(f"evsp.request_id = {self.request_id!r}: must be 0..255 (J2735 RequestID)")


def locate(geometry: IntersectionGeometry, pose: Pose, lane_width: float | None = None) -> OnLane | None:
    """The ingress lane the vehicle is on, before or after its stop line; None when it is on none."""
    hx, hy = math.sin(math.radians(pose.heading)), math.cos(math.radians(pose.heading))
    half = (lane_width or geometry.lane_width or 3.5) / 2.0
    best = None
    for lane in geometry.lanes:
        if not lane.ingress or len(lane.nodes) < 2:
            continue
        stop = next((n for n in lane.nodes if "stopLine" in n.local), lane.nodes[0])
        far = lane.nodes[-1] if lane.nodes[-1] is not stop else lane.nodes[0]
        dx, dy = stop.x - far.x, stop.y - far.y
        length = math.hypot(dx, dy)
        if length == 0:
            continue
        ux, uy = dx / length, dy / length                  # the direction traffic drives in
        if ux * hx + uy * hy < math.cos(math.radians(45.0)):
            continue
        lateral = abs((pose.x - stop.x) * -uy + (pose.y - stop.y) * ux)
        along = (stop.x - pose.x) * ux + (stop.y - pose.y) * uy   # > 0: before the stop line
        if lateral > half or along > length + half:
            continue
        if best is None or lateral < best[0]:
            group = next((c.signal_group for c in lane.connections if c.signal_group is not None), None)
            best = (lateral, OnLane(lane.lane_id, lane.ingress_approach, group, along))
    return None if best is None else best[1]


@dataclass
class EvsCore:
    cfg: EvsConfig
    geometry: IntersectionGeometry | None = None
    epoch_unix_s: float = 0.0    # Unix time of simulated time 0 (the master's join reply)
    state: str = IDLE
    lane: OnLane | None = None
    sequence: int = 0
    ssm_status: str | None = None
    signal_state: str | None = None
    t_first_request: float | None = None
    t_cancelled: float | None = None
    sent: dict[str, int] = field(default_factory=lambda: {"request": 0, "update": 0, "cancel": 0})
    _next_t: float = -math.inf
    _cancels_left: int = 0

    def on_map(self, geometry: IntersectionGeometry) -> None:
        if self.geometry is None or self.state == IDLE:
            self.geometry = geometry

    def on_ssm(self, ssm: Ssm) -> None:
        if self.geometry is None:
            return
        for ix in ssm.status:
            if ix.intersection_id != self.geometry.intersection_id:
                continue
            for st in ix.requests:
                r = st.requester
                if r is not None and r.vehicle_id == self.cfg.vehicle_id and r.request_id == self.cfg.request_id:
                    self.ssm_status = st.status

    def on_spat(self, spat: Spat) -> None:
        if self.geometry is None or self.lane is None or self.lane.signal_group is None:
            return
        for ix in spat.intersections:
            if ix.intersection_id == self.geometry.intersection_id:
                for m in ix.movements:
                    if m.signal_group == self.lane.signal_group:
                        self.signal_state = m.state

    def step(self, t: float, pose: Pose) -> list[tuple[str, Srm]]:
        """The SRMs to send at t: (kind, message) with kind request | update | cancel."""
        if self.geometry is None or self.state == DONE or not self.cfg.enabled:
            return []
        if self.state == IDLE:
            on = locate(self.geometry, pose)
            if on is None or on.to_stop_line_m <= 0:
                return []
            self.lane = on
            if on.to_stop_line_m / max(pose.speed, self.cfg.min_speed) > self.cfg.horizon_s:
                return []
            self.state, self.t_first_request, self._next_t = REQUESTING, t, t
        if self.state == REQUESTING:
            self._update_distance(pose)
            if self.lane.to_stop_line_m < -self.cfg.through_m:
                self.state, self._cancels_left, self._next_t, self.t_cancelled = CANCELLING, self.cfg.cancel_repeats, t, t
        if t + 1e-9 < self._next_t:
            return []
        self._next_t = t + self.cfg.renew_s
        if self.state == REQUESTING:
            kind = "request" if self.sent["request"] == 0 else "update"
            eta = t + max(self.lane.to_stop_line_m, 0.0) / max(pose.speed, self.cfg.min_speed)
            return [(kind, self._srm(t, eta, pose, "priorityRequest" if kind == "request" else "priorityRequestUpdate",
                                     kind))]
        self._cancels_left -= 1
        if self._cancels_left <= 0:
            self.state = DONE
        return [("cancel", self._srm(t, t, pose, "priorityCancellation", "cancel"))]

    def _update_distance(self, pose: Pose) -> None:
        stop = next(n for n in self._lane_obj().nodes if "stopLine" in n.local)
        far = self._lane_obj().nodes[-1]
        dx, dy = stop.x - far.x, stop.y - far.y
        length = math.hypot(dx, dy)
        along = ((stop.x - pose.x) * dx + (stop.y - pose.y) * dy) / length
        self.lane = OnLane(self.lane.lane_id, self.lane.approach, self.lane.signal_group, along)

    def _lane_obj(self):
        return next(l for l in self.geometry.lanes if l.lane_id == self.lane.lane_id)

    def _srm(self, t: float, eta_abs_s: float, pose: Pose, request_type: str, kind: str) -> Srm:
        """An SRM at simulated time t asking for service from eta_abs_s (simulated s) on."""
        self.sent[kind] += 1
        self.sequence = (self.sequence + 1) % 128
        minute, second = self.wire_time(t)
        eta_minute, eta_second = self.wire_time(eta_abs_s)
        request = SignalRequest(intersection_id=self.geometry.intersection_id, request_id=self.cfg.request_id,
                                inbound=AccessPoint("lane", self.lane.lane_id), request_type=request_type,
                                eta_minute=eta_minute, eta_second=eta_second,
                                duration=None if kind == "cancel" else self.cfg.duration_s)
        return Srm(Requestor(vehicle_id=self.cfg.vehicle_id, type=RequestorType(self.cfg.role),
                             heading=pose.heading % 360.0, speed=max(pose.speed, 0.0)),
                   [request], second=second, moy=minute, sequence_number=self.sequence)

    def wire_time(self, t: float) -> tuple[int, float]:
        """Simulated seconds -> (minute of the year, seconds within the minute) on the run's epoch (UTC)."""
        unix = self.epoch_unix_s + t
        year0 = datetime(datetime.fromtimestamp(unix, timezone.utc).year, 1, 1, tzinfo=timezone.utc).timestamp()
        ms = round((unix - year0) * 1000.0)
        return ms // 60000, (ms % 60000) / 1000.0
