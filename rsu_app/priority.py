"""Signal preemption at the RSU: SRMs in, a preemption call for the controller and SSM statuses out. Pure core.

No bus, no serial port, no clock: `PriorityCore` is told what arrived and when
(simulated seconds) and answers what the controller should be asked and what
the SSM says, so every rule is testable on its own (tests/test_evsp_priority.py).
`PriorityStage` beside it is the thin part that verifies and decodes frames.

Rules (one request per approach, emergency first):

* a frame that fails the 1609.2 checks (unsigned, forged, untrusted, replayed,
  out of its time window) or is signed under another PSID than the SRM's
  (`PSID_SRM`) is never answered: it is counted by reason in `rejections`;
  so is a request for another intersection (its RSU answers it) and an SRM that
  does not decode;
* a request is answered in the SSM with `rejected` when its inbound lane or
  approach is not in this intersection's MAP, when the requestor's role is not
  an emergency role, when the controller's preemption does not serve its
  lane's signal group, or when another vehicle's request on another approach
  (or the same one) is active: the first active request keeps the controller;
* an accepted request is `requested` until the preemption call has gone out on
  the serial line, `processing` until the controller shows its signal group
  green in preemption, then `granted`; `priorityCancellation` or no renewal
  within `expire_s` ends it, and the call is released when none is left.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from bridges.j2735.signal_request import (AccessPoint, IntersectionStatus, Requester, RequestStatus, SignalRequest,
                                          Srm, Ssm)

EMERGENCY_ROLES = frozenset({"emergency", "police", "fire", "ambulance", "roadRescue"})
REJECTED_HOLD_S = 2.0  # a rejection stays in the SSM this long after the last SRM that asked


@dataclass(frozen=True)
class IngressLane:
    lane_id: int
    approach: int
    signal_group: int | None


@dataclass
class Request:
    """One vehicle's request as the RSU keeps it."""

    vehicle_id: int | bytes
    request_id: int
    sequence_number: int
    role: str | None
    inbound: AccessPoint
    outbound: AccessPoint | None
    approach: int | None
    signal_group: int | None
    status: str               # requested | processing | granted | rejected
    reason: str               # why rejected ("" otherwise)
    t_first: float
    t_last: float
    eta_minute: int | None = None
    eta_second: float | None = None
    duration: float | None = None
    t_granted: float | None = None

    @property
    def key(self) -> tuple:
        return (bytes(self.vehicle_id) if isinstance(self.vehicle_id, (bytes, bytearray)) else self.vehicle_id,
                self.request_id)


@dataclass
class PriorityEvents:
    """What happened in one `step`: the call to send (None: no change) and status changes, for traces."""

    preempt: bool | None = None
    changes: list[tuple[Request, str]] = field(default_factory=list)   # (request, new status)


class PriorityCore:
    def __init__(self, intersection_id: int, lanes: dict[int, IngressLane], preempt_groups: set[int] | frozenset,
                 *, expire_s: float = 2.5, roles: frozenset = EMERGENCY_ROLES):
        if expire_s <= 0:
            raise ValueError(f"expire_s = {expire_s!r}: must be > 0")
        self.intersection_id = intersection_id
        self.lanes = dict(lanes)
        self.preempt_groups = frozenset(preempt_groups)
        self.expire_s, self.roles = expire_s, frozenset(roles)
        self.requests: dict[tuple, Request] = {}
        self.rejections: Counter = Counter()   # frames / requests not answered, by reason
        self.answered_rejected: Counter = Counter()  # requests answered `rejected` in the SSM, by reason
        self.cancellations = 0
        self.expired = 0
        self.call = False                 # the preemption call the controller has been asked for
        self.sequence = 0                 # SSM sequence number: changes when a status changes
        self._pending: list[tuple[Request, str]] = []

    # -- input ----------------------------------------------------------------------------------------------
    def reject_frame(self, reason: str) -> None:
        """A frame that never became a request (verification, PSID, decoding): counted, never answered."""
        self.rejections[reason] += 1

    def on_srm(self, srm: Srm, t: float) -> None:
        """The requests of one verified, decoded SRM that arrived at t."""
        role = srm.requestor.role
        for req in srm.requests:
            if req.intersection_id != self.intersection_id:
                self.rejections["unknown-intersection"] += 1
                continue
            self._on_request(srm, req, role, t)

    def _on_request(self, srm: Srm, req: SignalRequest, role: str | None, t: float) -> None:
        vid = srm.requestor.vehicle_id
        key = (bytes(vid) if isinstance(vid, (bytes, bytearray)) else vid, req.request_id)
        old = self.requests.get(key)
        if req.request_type == "priorityCancellation":
            if old is not None:
                del self.requests[key]
                self.cancellations += 1
                self._changed(old, "cancelled")
            return
        lane = self._lane(req.inbound)
        approach = lane.approach if lane else None
        group = lane.signal_group if lane else None
        seq = srm.sequence_number or 0
        if old is not None and old.status != "rejected":
            old.t_last, old.sequence_number = t, seq
            old.eta_minute, old.eta_second, old.duration = req.eta_minute, req.eta_second, req.duration
            return
        reason = ""
        if lane is None:
            reason = "unknown-lane"
        elif role not in self.roles:
            reason = "not-emergency"
        elif group not in self.preempt_groups:
            reason = "not-served"
        elif any(r.status != "rejected" and r.key != key for r in self.requests.values()):
            busy = next(r for r in self.requests.values() if r.status != "rejected" and r.key != key)
            reason = "approach-busy" if busy.approach == approach else "other-approach-active"
        r = Request(vid, req.request_id, seq, role, req.inbound, req.outbound, approach, group,
                    "rejected" if reason else "requested", reason, t if old is None else old.t_first, t,
                    req.eta_minute, req.eta_second, req.duration)
        self.requests[key] = r
        if reason:
            self.answered_rejected[reason] += 1
        if old is None or old.status != r.status:
            self._changed(r, r.status)

    def _lane(self, point: AccessPoint) -> IngressLane | None:
        if point.kind == "lane":
            return self.lanes.get(point.id)
        if point.kind == "approach":
            return next((lane for lane in self.lanes.values() if lane.approach == point.id), None)
        return None

    def _changed(self, r: Request, status: str) -> None:
        self.sequence = (self.sequence + 1) % 128
        self._pending.append((r, status))

    # -- the controller's side -------------------------------------------------------------------------------
    def on_preempt_sent(self, on: bool, t: float) -> None:
        """The SetPreempt frame went out (acknowledged): requested requests are now being processed."""
        if on:
            for r in self.requests.values():
                if r.status == "requested":
                    r.status = "processing"
                    self._changed(r, "processing")

    def on_controller(self, greens: int, preempt_active: bool, t: float) -> None:
        """A controller status (greens: bit k-1 = phase k green) that described time t."""
        if not preempt_active:
            return
        for r in self.requests.values():
            if r.status == "processing" and r.signal_group and greens & (1 << (r.signal_group - 1)):
                r.status, r.t_granted = "granted", t
                self._changed(r, "granted")

    # -- stepping --------------------------------------------------------------------------------------------
    def step(self, t: float) -> PriorityEvents:
        """Expire what was not renewed by t; say whether the call must change and what changed since the last step."""
        for key, r in list(self.requests.items()):
            hold = REJECTED_HOLD_S if r.status == "rejected" else self.expire_s
            if t - r.t_last > hold:
                del self.requests[key]
                if r.status != "rejected":
                    self.expired += 1
                    self._changed(r, "expired")
        wanted = any(r.status != "rejected" for r in self.requests.values())
        events = PriorityEvents(changes=self._pending)
        self._pending = []
        if wanted != self.call:
            self.call = wanted
            events.preempt = wanted
        return events

    def ssm(self, *, second: float = 0.0, moy: int | None = None) -> Ssm | None:
        """The SSM of the requests known now (None when there are none)."""
        if not self.requests:
            return None
        statuses = [RequestStatus(r.inbound, r.status, Requester(r.vehicle_id, r.request_id, r.sequence_number,
                                                                  role=r.role),
                                  outbound=r.outbound, eta_minute=r.eta_minute, eta_second=r.eta_second,
                                  duration=r.duration)
                    for r in list(self.requests.values())[:32]]
        return Ssm([IntersectionStatus(self.intersection_id, statuses, sequence_number=self.sequence)],
                   second=second, moy=moy, sequence_number=self.sequence)


def ingress_lanes(geometry) -> dict[int, IngressLane]:
    """The ingress lanes of a typed MAP intersection (bridges.j2735.map.IntersectionGeometry) with their approach
    and the signal group of their first signalled connection."""
    out = {}
    for lane in geometry.lanes:
        if not lane.ingress:
            continue
        group = next((c.signal_group for c in lane.connections if c.signal_group is not None), None)
        out[lane.lane_id] = IngressLane(lane.lane_id, lane.ingress_approach, group)
    return out
