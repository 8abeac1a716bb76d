"""Signal priority and preemption: the SignalRequestMessage (SRM) and SignalStatusMessage (SSM), typed.

    srm = Srm(Requestor(vehicle_id=0x1234, type=RequestorType("publicTransport"), latitude=42.28,
                        longitude=-83.74, heading=90.0, speed=12.0),
              [SignalRequest(intersection_id=1201, request_id=4, inbound=AccessPoint("lane", 13),
                             outbound=AccessPoint("lane", 4), eta_minute=400000, eta_second=12.5, duration=10.0)],
              second=7.25, moy=400000, sequence_number=1)
    status = Ssm.decode(frame_bytes).status[0].requests[0].status     # e.g. "granted"

A vehicle (transit, emergency, freight) asks an intersection for priority on
the way in (`inbound`) and out (`outbound`), each a lane, an approach or a MAP
connection (`AccessPoint`); the RSU answers per request in an SSM.

Units: positions in degrees and metres, heading in degrees clockwise from
north, speed in m/s. Times follow the wire's split: a minute of the year
(`moy`, `eta_minute`) and **seconds within that minute** (`second`,
`eta_second`: DSecond milliseconds / 1000, 0..65.535 s; 60..60.999 during a
leap second, 65.535 is J2735's 'unavailable'); `duration` is in seconds.
`SignalRequest.eta_s` joins the two into seconds since the start of the UTC
year (set it to split them again). Vehicle ids are an int (StationID) or 4
bytes (TemporaryID, the BSM's id). Enumerations are their J2735 names.

Decoding then encoding gives the received bytes back (the deployed SRMs and
SSMs in tests/fixtures/interop/j2735_vectors.json and generated ones): what
the typed fields do not model is kept in each object's `other`, regional
extensions in `regional` (see bridges.j2735.fields).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from bridges.j2735 import fields as f
from bridges.j2735 import scales
from bridges.j2735.codec import J2735Error
from bridges.j2735.scales import Scale
from bridges.j2735.typed import Framed, Kept

SRM_ID, SSM_ID = 29, 30
DSECOND = Scale("DSecond", "s", 0.001, 0, 65535)  # ms within the minute; 60000..60999 leap second, 65535 unavailable
ACCESS_POINTS = {"lane": 255, "approach": 15, "connection": 255}  # IntersectionAccessPoint choice -> highest id
REQUEST_TYPES = ("priorityRequestTypeReserved", "priorityRequest", "priorityRequestUpdate", "priorityCancellation")
ROLES = ("basicVehicle", "publicTransport", "specialTransport", "dangerousGoods", "roadWork", "roadRescue",
         "emergency", "safetyCar", "none-unknown", "truck", "motorcycle", "roadSideSource", "police", "fire",
         "ambulance", "dot", "transit", "slowMoving", "stopNgo", "cyclist", "pedestrian", "nonMotorized", "military")
SUBROLES = ("requestSubRoleUnKnown", *(f"requestSubRole{i}" for i in range(1, 15)), "requestSubRoleReserved")
IMPORTANCE_LEVELS = ("requestImportanceLevelUnKnown", *(f"requestImportanceLevel{i}" for i in range(1, 15)),
                     "requestImportanceReserved")
VEHICLE_TYPES = ("none", "unknown", "special", "moto", "car", "carOther", "bus", "axleCnt2", "axleCnt3", "axleCnt4",
                 "axleCnt4Trailer", "axleCnt5Trailer", "axleCnt6Trailer", "axleCnt5MultiTrailer",
                 "axleCnt6MultiTrailer", "axleCnt7MultiTrailer")
TRANSMISSION_STATES = ("neutral", "park", "forwardGears", "reverseGears", "reserved1", "reserved2", "reserved3",
                       "unavailable")
# TransitVehicleStatus: 8 bits, the last two unnamed ("bit6", "bit7")
TRANSIT_STATUS = ("loading", "anADAuse", "aBikeLoad", "doorOpen", "charging", "atStopLine")
OCCUPANCIES = ("occupancyUnknown", "occupancyEmpty", "occupancyVeryLow", "occupancyLow", "occupancyMed",
               "occupancyHigh", "occupancyNearlyFull", "occupancyFull")
RESPONSE_STATUSES = ("unknown", "requested", "processing", "watchOtherTraffic", "granted", "rejected", "maxPresence",
                     "reserviceLocked")
TRANSIT_SCHEDULE_STEP_S = 10.0  # DeltaTime: 10 s per unit, -122..121


# -- shared pieces ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AccessPoint:
    """Where a request enters or leaves the intersection: a MAP lane id, an approach id or a connection id."""

    kind: str   # "lane", "approach" or "connection"
    id: int

    def to_asn1(self, what: str) -> tuple[str, int]:
        kind = f.name(self.kind, tuple(ACCESS_POINTS), f"{what}: kind")
        return kind, f.integer(self.id, 0, ACCESS_POINTS[kind], f"{what}: {kind} id")

    @classmethod
    def from_asn1(cls, value: tuple[str, int]) -> "AccessPoint":
        return cls(*value)


def _vehicle_id(value: int | bytes, what: str) -> tuple[str, Any]:
    if isinstance(value, (bytes, bytearray)):
        if len(value) != 4:
            raise J2735Error(f"{what}: a TemporaryID is 4 bytes, got {len(value)}")
        return "entityID", bytes(value)
    return "stationID", f.integer(value, 0, 4294967295, f"{what} (StationID)")


def _dsecond(value: float | None, what: str) -> int:
    if value is None:
        raise J2735Error(f"{what}: a value is required")
    return f.wire(DSECOND, value, what)


def _id_ref(intersection_id: int, region: int | None, where: str) -> dict[str, Any]:
    ref: dict[str, Any] = {}
    if region is not None:
        ref["region"] = f.integer(region, 0, 65535, f"{where}: region")
    ref["id"] = f.integer(intersection_id, 0, 65535, f"{where}: intersection_id")
    return ref


def _minute_second_duration(out: dict[str, Any], minute: int | None, second: float | None, duration: float | None,
                             where: str) -> None:
    if minute is not None:
        out["minute"] = f.integer(minute, 0, 527040, f"{where}: eta_minute")
    if second is not None:
        out["second"] = _dsecond(second, f"{where}: eta_second")
    if duration is not None:
        out["duration"] = _dsecond(duration, f"{where}: duration")


@dataclass
class RequestorType(Kept):
    """What kind of vehicle asks (RequestorType): its role and, optionally, finer classes."""

    role: str = "basicVehicle"              # BasicVehicleRole name
    subrole: str | None = None              # RequestSubRole name
    importance: str | None = None           # RequestImportanceLevel name (the wire's `request`)
    iso3883: int | None = None              # ISO 3833 vehicle type 0..100
    hpms_type: str | None = None            # VehicleType name (HPMS classes)
    regional: dict[str, Any] | None = None  # one RegionalExtension, verbatim
    other: dict[str, Any] | None = None

    def _typed(self, where: str = "type") -> dict[str, Any]:
        out: dict[str, Any] = {"role": f.name(self.role, ROLES, f"{where}: role")}
        if self.subrole is not None:
            out["subrole"] = f.name(self.subrole, SUBROLES, f"{where}: subrole")
        if self.importance is not None:
            out["request"] = f.name(self.importance, IMPORTANCE_LEVELS, f"{where}: importance")
        if self.iso3883 is not None:
            out["iso3883"] = f.integer(self.iso3883, 0, 100, f"{where}: iso3883")
        if self.hpms_type is not None:
            out["hpmsType"] = f.name(self.hpms_type, VEHICLE_TYPES, f"{where}: hpms_type")
        if self.regional is not None:
            out["regional"] = self.regional
        return out


    @classmethod
    def from_asn1(cls, v: dict[str, Any]) -> "RequestorType":
        t = cls(role=v["role"], subrole=v.get("subrole"), importance=v.get("request"), iso3883=v.get("iso3883"),
                hpms_type=v.get("hpmsType"), regional=v.get("regional"))
        return t._keep(v)


# -- SRM --------------------------------------------------------------------------------------------------
@dataclass
class Requestor(Kept):
    """The vehicle that sends the SRM (RequestorDescription)."""

    vehicle_id: int | bytes                  # StationID (int) or TemporaryID (4 bytes)
    type: RequestorType | None = None        # its role and classes; None: not sent
    latitude: float | None = None            # deg; the position is sent when any of these five is given
    longitude: float | None = None           # deg
    elevation: float | None = None           # m
    heading: float | None = None             # deg clockwise from north
    speed: float | None = None               # m/s; sent with `transmission`
    transmission: str = "unavailable"        # TransmissionState name, sent with the speed
    name: str | None = None
    route_name: str | None = None
    transit_status: frozenset[str] | None = None   # names from TRANSIT_STATUS
    transit_occupancy: str | None = None     # TransitVehicleOccupancy name
    transit_schedule: float | None = None    # s behind (+) or ahead of (-) schedule, 10 s steps
    regional: list[dict[str, Any]] | None = None
    other: dict[str, Any] | None = None

    @property
    def role(self) -> str | None:
        """The BasicVehicleRole name (type.role); None when no type is sent."""
        return None if self.type is None else self.type.role

    def _typed(self, where: str = "requestor") -> dict[str, Any]:
        out: dict[str, Any] = {"id": _vehicle_id(self.vehicle_id, f"{where}: vehicle_id")}
        if self.type is not None:
            out["type"] = self.type.to_asn1(f"{where}: type")
        if any(v is not None for v in (self.latitude, self.longitude, self.elevation, self.heading, self.speed)):
            # a heading or speed without a position sends the position as 'unavailable' (the wire's codes)
            position: dict[str, Any] = {"position": {
                "lat": f.wire(scales.LATITUDE, self.latitude, f"{where}: latitude"),
                "long": f.wire(scales.LONGITUDE, self.longitude, f"{where}: longitude")}}
            if self.elevation is not None:
                position["position"]["elevation"] = f.wire(scales.ELEVATION, self.elevation, f"{where}: elevation")
            if self.heading is not None:
                position["heading"] = f.wire(scales.HEADING, self.heading, f"{where}: heading")
            if self.speed is not None:
                position["speed"] = {"transmisson": f.name(self.transmission, TRANSMISSION_STATES,
                                                           f"{where}: transmission"),
                                     "speed": f.wire(scales.SPEED, self.speed, f"{where}: speed")}
            out["position"] = position
        if self.name is not None:
            out["name"] = f.text(self.name, f"{where}: name")
        if self.route_name is not None:
            out["routeName"] = f.text(self.route_name, f"{where}: route_name")
        if self.transit_status is not None:
            out["transitStatus"] = f.names_to_bits(self.transit_status, TRANSIT_STATUS, f"{where}: transit_status", 8)
        if self.transit_occupancy is not None:
            out["transitOccupancy"] = f.name(self.transit_occupancy, OCCUPANCIES, f"{where}: transit_occupancy")
        if self.transit_schedule is not None:
            units = round(f.finite(self.transit_schedule, f"{where}: transit_schedule") / TRANSIT_SCHEDULE_STEP_S)
            out["transitSchedule"] = f.integer(units, -122, 121, f"{where}: transit_schedule (10 s units)")
        if self.regional:
            out["regional"] = self.regional
        return out


    @classmethod
    def from_asn1(cls, v: dict[str, Any]) -> "Requestor":
        where = v.get("position") or {}
        position, motion = where.get("position") or {}, where.get("speed") or {}
        status = v.get("transitStatus")
        r = cls(vehicle_id=v["id"][1], type=RequestorType.from_asn1(v["type"]) if "type" in v else None,
                latitude=f.from_wire(scales.LATITUDE, position.get("lat")),
                longitude=f.from_wire(scales.LONGITUDE, position.get("long")),
                elevation=f.from_wire(scales.ELEVATION, position.get("elevation")),
                heading=f.from_wire(scales.HEADING, where.get("heading")),
                speed=f.from_wire(scales.SPEED, motion.get("speed")),
                transmission=motion.get("transmisson", "unavailable"),
                name=v.get("name"), route_name=v.get("routeName"),
                transit_status=None if status is None else f.bits_to_names(status, TRANSIT_STATUS),
                transit_occupancy=v.get("transitOccupancy"),
                transit_schedule=None if "transitSchedule" not in v else v["transitSchedule"] * TRANSIT_SCHEDULE_STEP_S,
                regional=v.get("regional"))
        return r._keep(v)


@dataclass
class SignalRequest(Kept):
    """One request (SignalRequestPackage): priority at an intersection, from `inbound` to `outbound`."""

    intersection_id: int
    request_id: int                            # RequestID 0..255, echoed in the SSM
    inbound: AccessPoint
    request_type: str = "priorityRequest"      # PriorityRequestType name
    outbound: AccessPoint | None = None
    region: int | None = None                  # road regulator id of the intersection id
    eta_minute: int | None = None              # minute of the year of the arrival
    eta_second: float | None = None            # s within that minute
    duration: float | None = None              # s the service is needed for
    regional: list[dict[str, Any]] | None = None          # the request's regional extensions
    package_regional: list[dict[str, Any]] | None = None  # the package's (SignalRequestPackage.regional)
    other: dict[str, Any] | None = None        # the package's untyped rest; the request's under "request"

    @property
    def eta_s(self) -> float | None:
        """The arrival in seconds since the start of the UTC year (None unless eta_minute and eta_second are set)."""
        if self.eta_minute is None or self.eta_second is None:
            return None
        return self.eta_minute * 60.0 + self.eta_second

    @eta_s.setter
    def eta_s(self, seconds: float) -> None:
        seconds = f.finite(seconds, "eta_s")
        ms = round(seconds * 1000.0)
        self.eta_minute, self.eta_second = ms // 60000, (ms % 60000) / 1000.0

    def _typed(self, where: str = "request") -> dict[str, Any]:
        where = f"{where} {self.request_id} to intersection {self.intersection_id}"
        request: dict[str, Any] = {
            "id": _id_ref(self.intersection_id, self.region, where),
            "requestID": f.integer(self.request_id, 0, 255, f"{where}: request_id"),
            "requestType": f.name(self.request_type, REQUEST_TYPES, f"{where}: request_type"),
            "inBoundLane": self._point(self.inbound, f"{where}: inbound"),
        }
        if self.outbound is not None:
            request["outBoundLane"] = self._point(self.outbound, f"{where}: outbound")
        if self.regional:
            request["regional"] = self.regional
        out: dict[str, Any] = {"request": request}
        _minute_second_duration(out, self.eta_minute, self.eta_second, self.duration, where)
        if self.package_regional:
            out["regional"] = self.package_regional
        return out

    @staticmethod
    def _point(point: AccessPoint, what: str) -> tuple[str, int]:
        if not isinstance(point, AccessPoint):
            raise J2735Error(f"{what}: an AccessPoint is required, got {point!r}")
        return point.to_asn1(what)


    @classmethod
    def from_asn1(cls, v: dict[str, Any]) -> "SignalRequest":
        r = v["request"]
        req = cls(intersection_id=r["id"]["id"], region=r["id"].get("region"), request_id=r["requestID"],
                  request_type=r["requestType"], inbound=AccessPoint.from_asn1(r["inBoundLane"]),
                  outbound=AccessPoint.from_asn1(r["outBoundLane"]) if "outBoundLane" in r else None,
                  eta_minute=v.get("minute"), eta_second=f.from_wire(DSECOND, v.get("second")),
                  duration=f.from_wire(DSECOND, v.get("duration")), regional=r.get("regional"),
                  package_regional=v.get("regional"))
        return req._keep(v)


@dataclass
class Srm(Kept, Framed):
    """SignalRequestMessage: one requestor, its requests (none: it only announces itself)."""

    MESSAGE_ID, WHAT = SRM_ID, "an SRM"

    requestor: Requestor
    requests: list[SignalRequest] = field(default_factory=list)
    second: float = 0.0                  # s within the minute of the message (DSecond)
    moy: int | None = None               # minute of the year (timeStamp)
    sequence_number: int | None = None   # MsgCount 0..127
    regional: list[dict[str, Any]] | None = None
    other: dict[str, Any] | None = None

    def _typed(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.moy is not None:
            out["timeStamp"] = f.integer(self.moy, 0, 527040, "moy")
        out["second"] = _dsecond(self.second, "second")
        if self.sequence_number is not None:
            out["sequenceNumber"] = f.integer(self.sequence_number, 0, 127, "sequence_number")
        if self.requests:
            if len(self.requests) > 32:
                raise J2735Error(f"requests: at most 32, got {len(self.requests)}")
            out["requests"] = [r.to_asn1(f"request[{i}]") for i, r in enumerate(self.requests)]
        if not isinstance(self.requestor, Requestor):
            raise J2735Error(f"requestor: a Requestor is required, got {self.requestor!r}")
        out["requestor"] = self.requestor.to_asn1()
        if self.regional:
            out["regional"] = self.regional
        return out

    @classmethod
    def from_asn1(cls, m: dict[str, Any]) -> "Srm":
        srm = cls(Requestor.from_asn1(m["requestor"]), [SignalRequest.from_asn1(r) for r in m.get("requests", ())],
                  second=f.from_wire(DSECOND, m["second"]), moy=m.get("timeStamp"),
                  sequence_number=m.get("sequenceNumber"), regional=m.get("regional"))
        return srm._keep(m)


# -- SSM --------------------------------------------------------------------------------------------------
@dataclass
class Requester(Kept):
    """Whose request a status answers (SignalRequesterInfo): the SRM's vehicle id, request id and sequence."""

    vehicle_id: int | bytes
    request_id: int
    sequence_number: int
    role: str | None = None                    # BasicVehicleRole name
    type: RequestorType | None = None          # typeData
    other: dict[str, Any] | None = None

    def _typed(self, where: str = "requester") -> dict[str, Any]:
        out: dict[str, Any] = {"id": _vehicle_id(self.vehicle_id, f"{where}: vehicle_id"),
                               "request": f.integer(self.request_id, 0, 255, f"{where}: request_id"),
                               "sequenceNumber": f.integer(self.sequence_number, 0, 127, f"{where}: sequence_number")}
        if self.role is not None:
            out["role"] = f.name(self.role, ROLES, f"{where}: role")
        if self.type is not None:
            out["typeData"] = self.type.to_asn1(f"{where}: type")
        return out


    @classmethod
    def from_asn1(cls, v: dict[str, Any]) -> "Requester":
        r = cls(vehicle_id=v["id"][1], request_id=v["request"], sequence_number=v["sequenceNumber"],
                role=v.get("role"), type=RequestorType.from_asn1(v["typeData"]) if "typeData" in v else None)
        return r._keep(v)


@dataclass
class RequestStatus(Kept):
    """The intersection's answer to one request (SignalStatusPackage)."""

    inbound: AccessPoint
    status: str = "unknown"                  # PrioritizationResponseStatus name: granted, rejected, ...
    requester: Requester | None = None
    outbound: AccessPoint | None = None
    eta_minute: int | None = None            # minute of the year of the (estimated) service
    eta_second: float | None = None          # s within that minute
    duration: float | None = None            # s
    regional: list[dict[str, Any]] | None = None
    other: dict[str, Any] | None = None

    eta_s = SignalRequest.eta_s

    def _typed(self, where: str = "status") -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.requester is not None:
            out["requester"] = self.requester.to_asn1(f"{where}: requester")
        out["inboundOn"] = SignalRequest._point(self.inbound, f"{where}: inbound")
        if self.outbound is not None:
            out["outboundOn"] = SignalRequest._point(self.outbound, f"{where}: outbound")
        _minute_second_duration(out, self.eta_minute, self.eta_second, self.duration, where)
        out["status"] = f.name(self.status, RESPONSE_STATUSES, f"{where}: status")
        if self.regional:
            out["regional"] = self.regional
        return out


    @classmethod
    def from_asn1(cls, v: dict[str, Any]) -> "RequestStatus":
        s = cls(inbound=AccessPoint.from_asn1(v["inboundOn"]), status=v["status"],
                requester=Requester.from_asn1(v["requester"]) if "requester" in v else None,
                outbound=AccessPoint.from_asn1(v["outboundOn"]) if "outboundOn" in v else None,
                eta_minute=v.get("minute"), eta_second=f.from_wire(DSECOND, v.get("second")),
                duration=f.from_wire(DSECOND, v.get("duration")), regional=v.get("regional"))
        return s._keep(v)


@dataclass
class IntersectionStatus(Kept):
    """One intersection's answers (SignalStatus)."""

    intersection_id: int
    requests: list[RequestStatus]
    sequence_number: int = 0                  # MsgCount: changes when the status changes
    region: int | None = None
    regional: list[dict[str, Any]] | None = None
    other: dict[str, Any] | None = None

    def _typed(self) -> dict[str, Any]:
        where = f"intersection {self.intersection_id}"
        if not 1 <= len(self.requests) <= 32:
            raise J2735Error(f"{where}: requests: 1..32 request statuses, got {len(self.requests)}")
        out: dict[str, Any] = {"sequenceNumber": f.integer(self.sequence_number, 0, 127, f"{where}: sequence_number"),
                               "id": _id_ref(self.intersection_id, self.region, where),
                               "sigStatus": [s.to_asn1(f"{where}: request status {i}")
                                             for i, s in enumerate(self.requests)]}
        if self.regional:
            out["regional"] = self.regional
        return out


    @classmethod
    def from_asn1(cls, v: dict[str, Any]) -> "IntersectionStatus":
        s = cls(intersection_id=v["id"]["id"], region=v["id"].get("region"), sequence_number=v["sequenceNumber"],
                requests=[RequestStatus.from_asn1(p) for p in v["sigStatus"]], regional=v.get("regional"))
        return s._keep(v)


@dataclass
class Ssm(Kept, Framed):
    """SignalStatusMessage: the status of the requests at one or more intersections."""

    MESSAGE_ID, WHAT = SSM_ID, "an SSM"

    status: list[IntersectionStatus]
    second: float = 0.0                  # s within the minute of the message (DSecond)
    moy: int | None = None
    sequence_number: int | None = None
    regional: list[dict[str, Any]] | None = None
    other: dict[str, Any] | None = None

    def _typed(self) -> dict[str, Any]:
        if not 1 <= len(self.status) <= 32:
            raise J2735Error(f"status: 1..32 intersections, got {len(self.status)}")
        out: dict[str, Any] = {}
        if self.moy is not None:
            out["timeStamp"] = f.integer(self.moy, 0, 527040, "moy")
        out["second"] = _dsecond(self.second, "second")
        if self.sequence_number is not None:
            out["sequenceNumber"] = f.integer(self.sequence_number, 0, 127, "sequence_number")
        out["status"] = [s.to_asn1() for s in self.status]
        if self.regional:
            out["regional"] = self.regional
        return out

    @classmethod
    def from_asn1(cls, m: dict[str, Any]) -> "Ssm":
        ssm = cls([IntersectionStatus.from_asn1(s) for s in m["status"]], second=f.from_wire(DSECOND, m["second"]),
                  moy=m.get("timeStamp"), sequence_number=m.get("sequenceNumber"), regional=m.get("regional"))
        return ssm._keep(m)
