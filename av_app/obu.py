"""The on-board unit: frames off the V2X air -> verified, decoded objects and signal states in local metres.

Each frame (a J2735 MessageFrame in the 1609.2-style signed envelope) passes:

1. verify (bridges.security.Verifier) against the scenario's trust anchor at the
   frame's simulated arrival time: forged (bad signature), altered, replayed,
   untrusted (another CA, expired), out of the time window, unknown signer,
   unsecured: rejected with that reason, counted, never acted on;
2. the PSID must fit the message: a BSM under 0x20 (a vehicle's own) or 0x7F
   (a surrogate BSM from an RSU), SPaT/MAP under 0x82, an SDSM under one of
   `obu.sdsm_psids` (deployments differ; 0x90 by default) (`psid-mismatch`);
3. decode (bridges.j2735), convert latitude/longitude to local metres with the
   world's origin (bridges.geo), heading (degrees clockwise from north) to yaw
   (radians counter-clockwise from east);
4. the measurement time is the BSM's secMark placed in the minute of the
   arrival; a BSM older than `obu.max_age_s` is dropped (`stale`).

The BSM position is the centre of the vehicle (SAE J2735 / J2945/1 reference
point), as the planner's boxes are.

An SDSM (SAE J3224, messageId 41) is an RSU's report of every object it
detects, so each of its objects becomes a V2X object like a surrogate BSM's
(`surrogate`: the self-recognition rules for an RSU's estimate apply, so the
ego's own entry is left out): the position is the reference point plus the
object's offsets east and north, at the message's timestamp plus the object's
measurementTime; the position confidence (a 95 % bound) gives the fusion's
noise as sigma = bound / 2.45 (the 95 % radius of a 2-D Gaussian), or
`position_sigma` when unavailable; the id is the sender's TemporaryID and the
objectID (stable while the sender tracks it); a vehicle whose BasicVehicleClass
is one of the emergency types (60-69) is an emergency vehicle. Objects that
are not vehicles or VRUs (obstacles, unknown) are left to the lidar.
"""
from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass, field

from bridges.geo import GeoOrigin
from bridges.j2735 import J2735Error, default_codec
from bridges.j2735.bsm import Bsm
from bridges.j2735.map import MapData
from bridges.j2735.sdsm import POSITION_CONFIDENCE, Sdsm
from bridges.j2735.spat import Spat
from bridges.security import (PSID_BSM, PSID_SPAT_MAP, PSID_SURROGATE_BSM, VerificationError, Verifier,
                              time64_us)
from bridges.security.certificates import EPOCH_1609
from bridges.v2x import unix_time

from av_app.config import ObuSection

BSM_ID, SPAT_ID, MAP_ID, SDSM_ID = 20, 19, 18, 41
_PSIDS = {BSM_ID: (PSID_BSM, PSID_SURROGATE_BSM), SPAT_ID: (PSID_SPAT_MAP,), MAP_ID: (PSID_SPAT_MAP,)}
KINDS = {BSM_ID: "bsm", SPAT_ID: "spat", MAP_ID: "map", SDSM_ID: "sdsm"}
EMERGENCY_CLASSES = range(60, 70)  # J2735 BasicVehicleClass: the emergency vehicle types
POSITION_95_SIGMAS = 2.45  # a 2-D Gaussian's 95 % radius in sigmas (the RSU app writes the bound so)
SDSM_KINDS = ("vehicle", "vru")


@dataclass(frozen=True)
class V2xObject:
    """A road user as a BSM describes it, in local metres at its measurement time."""

    id: str  # "v2x:<temporary id hex>"
    station: str  # the signing station (certificate name)
    t: float  # measurement time (sim s)
    x: float  # centre of the vehicle
    y: float
    yaw: float  # rad, CCW from east
    speed: float
    yaw_rate: float  # rad/s
    length: float
    width: float
    emergency: bool
    surrogate: bool  # signed as a surrogate BSM (an RSU's estimate), not the vehicle's own
    pos_std: float
    msg_count: int


@dataclass
class Accepted:
    """A frame that passed: its kind, its content, the charged stage times."""

    kind: str  # bsm | spat | map | sdsm
    station: str
    object: V2xObject | None = None
    objects: list[V2xObject] = field(default_factory=list)  # an SDSM's
    spat: Spat | None = None
    map: MapData | None = None
    object_id: str = ""
    wall_s: dict[str, float] = field(default_factory=dict)  # measured compute per stage


def yaw_of(heading_deg: float | None) -> float:
    """The local frame's yaw (rad from east, counter-clockwise, in [-pi, pi)) of a J2735 heading (degrees
    clockwise from north; None: unavailable, taken as east as the BSM and SDSM fusion always has)."""
    yaw = math.radians(90.0 - heading_deg) if heading_deg is not None else 0.0
    return (yaw + math.pi) % (2 * math.pi) - math.pi


class Rejected(Exception):
    """A frame not acted on; `reason` is the tally key."""

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason, self.detail = reason, detail


def unix_from_time64(us: int) -> float:
    return EPOCH_1609.timestamp() + us / 1e6


def measurement_time(sec_mark_ms: int | None, t_arrival: float, epoch: float,
                     generation_us: int | None) -> float:
    """Simulation time of a BSM's measurement: its secMark in the minute around the arrival.

    secMark counts whole milliseconds of UTC, so the measurement time is known to 1 ms; it is taken
    on the simulation's millisecond grid. Otherwise where the run's epoch falls within its millisecond
    (the wall clock at the start) would move it by up to half a millisecond from run to run, and a
    lockstep run would not repeat bit for bit.
    """
    if sec_mark_ms is None or sec_mark_ms >= 60000:
        if generation_us is None:
            return t_arrival
        t = unix_from_time64(generation_us) - epoch
    else:
        u = unix_time(t_arrival, epoch)
        minute = math.floor(u / 60.0) * 60.0
        candidates = [minute + k * 60.0 + sec_mark_ms / 1000.0 for k in (-1, 0, 1)]
        t = min(candidates, key=lambda c: abs(c - u)) - epoch
    return round(t, 3)


class Obu:
    """Receives frames for one station; counts every outcome by reason."""

    def __init__(self, cfg: ObuSection, origin: GeoOrigin, epoch_unix_s: float, verifier: Verifier | None):
        self.cfg, self.origin, self.epoch, self.verifier = cfg, origin, float(epoch_unix_s), verifier
        self.codec = default_codec()
        self.received = 0
        self.accepted: Counter = Counter()  # by kind
        self.rejected: Counter = Counter()  # by reason

    def receive(self, payload: bytes, t_arrival: float) -> Accepted:
        """Verify, decode and convert one frame that arrived at t_arrival; Rejected says why not."""
        self.received += 1
        try:
            out = self._receive(bytes(payload), t_arrival)
        except Rejected as exc:
            self.rejected[exc.reason] += 1
            raise
        self.accepted[out.kind] += 1
        return out

    def _receive(self, payload: bytes, t_arrival: float) -> Accepted:
        w0 = time.perf_counter()
        if not math.isfinite(t_arrival):
            raise Rejected("bad-time", f"arrival time {t_arrival!r}")
        if self.verifier is None:
            raise Rejected("no-trust-anchor", "no verifier configured")
        try:
            verified = self.verifier.verify(payload, time64_us(unix_time(t_arrival, self.epoch)))
        except VerificationError as exc:
            raise Rejected(exc.reason.value, exc.detail) from None
        except Exception as exc:  # the verifier must never take the app down: count it
            raise Rejected("malformed", f"{type(exc).__name__}: {exc}") from None
        w1 = time.perf_counter()
        try:
            frame = self.codec.decode(verified.payload)
        except J2735Error as exc:
            raise Rejected("undecodable", exc.reason) from None
        kind = KINDS.get(frame.message_id)
        if kind is None or frame.message is None:
            raise Rejected("unsupported", f"messageId {frame.message_id}")
        allowed = tuple(self.cfg.sdsm_psids) if frame.message_id == SDSM_ID else _PSIDS[frame.message_id]
        if verified.secured and verified.psid not in allowed:
            raise Rejected("psid-mismatch", f"{kind} signed under PSID {verified.psid:#x}")
        station = verified.signer or "unsecured"
        out = Accepted(kind, station)
        if frame.message_id == BSM_ID:
            try:
                bsm = Bsm.from_asn1(frame.message)
            except (J2735Error, KeyError, TypeError, ValueError) as exc:
                raise Rejected("undecodable", f"BSM: {exc}") from None
            out.object = self._object(bsm, verified, t_arrival, station)
            out.object_id = out.object.id
        elif frame.message_id == SDSM_ID:
            try:
                sdsm = Sdsm.from_asn1(frame.message)
            except (J2735Error, KeyError, TypeError, ValueError) as exc:
                raise Rejected("undecodable", f"SDSM: {exc}") from None
            out.objects = self._sdsm_objects(sdsm, t_arrival, station)
            out.object_id = ",".join(o.id for o in out.objects)
        elif frame.message_id == SPAT_ID:
            try:
                out.spat = Spat.from_asn1(frame.message)
            except (J2735Error, KeyError, TypeError, ValueError) as exc:
                raise Rejected("undecodable", f"SPaT: {exc}") from None
            out.object_id = ",".join(str(i.intersection_id) for i in out.spat.intersections)
        else:
            try:
                out.map = MapData.from_asn1(frame.message)
            except (J2735Error, KeyError, TypeError, ValueError) as exc:
                raise Rejected("undecodable", f"MAP: {exc}") from None
            out.object_id = ",".join(str(i.intersection_id) for i in out.map.intersections)
        w2 = time.perf_counter()
        out.wall_s = {"verify": w1 - w0, "decode": w2 - w1}
        return out

    def _object(self, bsm: Bsm, verified, t_arrival: float, station: str) -> V2xObject:
        if bsm.latitude is None or bsm.longitude is None:
            raise Rejected("incomplete", "BSM without a position")
        t_meas = measurement_time(bsm.sec_mark_ms, t_arrival, self.epoch, verified.generation_time_us)
        if t_arrival - t_meas > self.cfg.max_age_s:
            raise Rejected("stale", f"measured {t_arrival - t_meas:.3f} s before its arrival")
        x, y, _ = self.origin.to_local(bsm.latitude, bsm.longitude, bsm.elevation)
        speed = bsm.speed if bsm.speed is not None else 0.0
        yaw = yaw_of(bsm.heading)
        em = bsm.emergency
        emergency = em is not None and (em.siren == "inUse" or em.lightbar == "inUse" or em.response_type in (
            "emergency", "pursuit"))
        std = bsm.semi_major if bsm.semi_major is not None else self.cfg.position_sigma
        return V2xObject(
            id=f"v2x:{bytes(bsm.temporary_id).hex()}", station=station, t=t_meas, x=float(x), y=float(y),
            yaw=yaw, speed=float(speed), yaw_rate=-math.radians(bsm.yaw_rate or 0.0),
            length=bsm.length or self.cfg.default_length, width=bsm.width or self.cfg.default_width,
            emergency=emergency, surrogate=verified.psid == PSID_SURROGATE_BSM, pos_std=float(std),
            msg_count=bsm.msg_count)

    def _sdsm_objects(self, sdsm: Sdsm, t_arrival: float, station: str) -> list[V2xObject]:
        if sdsm.latitude is None or sdsm.longitude is None:
            raise Rejected("incomplete", "SDSM without a reference position")
        stamp = sdsm.timestamp.to_unix()
        if stamp is None:
            raise Rejected("incomplete", "SDSM without a full timestamp (year to second)")
        t_msg = stamp - self.epoch
        x0, y0, _ = self.origin.to_local(sdsm.latitude, sdsm.longitude, sdsm.elevation)
        source = bytes(sdsm.source_id).hex()
        out, stale = [], []
        for o in sdsm.objects:
            if o.object_type not in SDSM_KINDS:
                continue
            t_meas = round(t_msg + o.measurement_time, 3)
            if t_arrival - t_meas > self.cfg.max_age_s:
                # one object measured long ago (a track the sender coasts) says nothing of the others in
                # the message: it is left out and counted, the rest are fused
                stale.append(f"{o.object_id} ({t_arrival - t_meas:.3f} s)")
                continue
            bound = POSITION_CONFIDENCE.bound(o.position_confidence)
            d = o.details
            length = getattr(d, "length", None) or self.cfg.default_length
            width = getattr(d, "width", None) or self.cfg.default_width
            cls = getattr(d, "vehicle_class", None)
            out.append(V2xObject(
                id=f"sdsm:{source}:{o.object_id}", station=station, t=t_meas, x=float(x0 + o.offset_x),
                y=float(y0 + o.offset_y), yaw=yaw_of(o.heading),
                speed=float(o.speed or 0.0),
                yaw_rate=-math.radians(o.acceleration.yaw_rate) if o.acceleration is not None else 0.0,
                length=float(length), width=float(width), emergency=cls in EMERGENCY_CLASSES, surrogate=True,
                pos_std=bound / POSITION_95_SIGMAS if bound is not None else self.cfg.position_sigma,
                msg_count=sdsm.msg_count))
        if stale and not out:
            raise Rejected("stale", f"every object measured too long before arrival: {', '.join(stale)}")
        self.rejected["stale-object"] += len(stale)
        return out
