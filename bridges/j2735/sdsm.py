"""The Sensor Data Sharing Message (SDSM, SAE J3224; J2735 messageId 41) as a typed object.

    sdsm = Sdsm(source_id=b"RSU1", latitude=42.30, longitude=-83.70, timestamp=DateTime.from_unix(t),
                objects=[DetectedObject(7, "vehicle", type_confidence=92, offset_x=12.3, offset_y=-4.0,
                                        speed=8.5, heading=270.0, speed_confidence="prec1ms",
                                        details=VehicleDetails(width=1.8, length=4.5))])
    data = sdsm.encode()                      # UPER MessageFrame
    for obj in Sdsm.decode(data).objects:     # every object the sender detected in one cycle
        obj.object_type, obj.offset_x, obj.offset_y, obj.measurement_time

One message per sensing cycle carries every object a station (an RSU, a
vehicle) detects: vehicles, VRUs, animals, obstacles. Units in, wire units out:

* the reference point (`latitude`, `longitude` in degrees, `elevation` in m)
  and each object's position as offsets from it, `offset_x` east, `offset_y`
  north, `offset_z` up, in metres (0.1 m on the wire, +-3276.7 m);
* `measurement_time` in seconds relative to the message's `timestamp`
  (ms on the wire, -1.5..1.5 s); `timestamp` is a `DateTime` whose members
  are each optional, as the wire's DDateTime (`DateTime.from_unix(t)` fills
  them from a POSIX time, `to_unix()` reads one back);
* speeds in m/s (0.02 m/s), heading in degrees clockwise from north
  (0.0125 deg), accelerations in m/s2, rates in deg/s, attitude in degrees;
  vehicle width and length in m (1 cm on the wire: J2735's VehicleSize),
  vehicle height in m (5 cm), obstacle sizes and the VRU attachment radius in
  m (0.1 m);
* `type_confidence` (objTypeCfd) and `class_confidence` are percent as sent
  (0..101);
* every other confidence is the J2735 enumeration's name ("a20cm",
  "prec1ms", "time-000-010", ...). The names say a bound on the error;
  `POSITION_CONFIDENCE.bound("a20cm")` gives it in SI units (0.2 m), and
  `POSITION_CONFIDENCE.name_for(0.15)` the finest class whose bound still
  covers a value (each `ConfidenceScale` below: time s, position and
  elevation m, speed m/s, heading deg, acceleration m/s2, yaw and angular
  rate deg/s, size m). J2735 reads these bounds as a 95 % level; a sender
  with a 1-sigma estimate passes 2 sigma.

None reads as the wire's 'unavailable' where the element has that code (speed
8191, heading 28800, elevation -4096); detected pitch, roll and yaw and the
classification confidences have none. Decoding then encoding gives the
received bytes back (the 11 published SDSMs in tests/fixtures/interop/
sdsm_vectors.json, and generated ones): what the typed fields do not model
(a Position3D regional extension, extension additions of a newer edition,
'unavailable' codes of optional elements) is kept in each object's `other`.
"""
from __future__ import annotations

import calendar
import time
from dataclasses import dataclass, field
from typing import Any

from bridges.j2735 import fields as f
from bridges.j2735 import scales
from bridges.j2735.codec import J2735Error
from bridges.j2735.scales import Scale
from bridges.j2735.typed import Framed, Kept

SDSM_ID = 41
MAX_OBJECTS = 256
EQUIPMENT_TYPES = ("unknown", "rsu", "obu", "vru")
OBJECT_TYPES = ("unknown", "vehicle", "vru", "animal")
VRU_TYPES = ("unavailable", "aPEDESTRIAN", "aPEDALCYCLIST", "aPUBLICSAFETYWORKER", "anANIMAL")
PROPULSION = {  # PropelledInformation alternative -> its enumeration
    "human": ("unavailable", "otherTypes", "onFoot", "skateboard", "pushOrKickScooter", "wheelchair"),
    "animal": ("unavailable", "otherTypes", "animalMounted", "animalDrawnCarriage"),
    "motor": ("unavailable", "otherTypes", "wheelChair", "bicycle", "scooter", "selfBalancingDevice"),
}
ATTACHMENTS = ("unavailable", "stroller", "bicycleTrailer", "cart", "wheelchair", "otherWalkAssistAttachments", "pet")
EXTERIOR_LIGHTS = ("lowBeamHeadlightsOn", "highBeamHeadlightsOn", "leftTurnSignalOn", "rightTurnSignalOn",
                   "hazardSignalOn", "automaticLightControlOn", "daytimeRunningLightsOn", "fogLightOn",
                   "parkingLightsOn")

# -- scales of the SDSM's own elements ------------------------------------------------------------------
OFFSET = Scale("position offset", "m", 0.1, -32767, 32767)
MEASUREMENT_TIME = Scale("measurement time", "s", 0.001, -1500, 1500)
PITCH = Scale("detected pitch", "deg", 0.0125, -7200, 7200)
ROLL = Scale("detected roll", "deg", 0.0125, -14400, 14400)
YAW = Scale("detected yaw", "deg", 0.0125, -14400, 14400)
ANGULAR_RATE = Scale("angular rate", "deg/s", 0.01, -32767, 32767)
VEHICLE_HEIGHT = Scale("vehicle height", "m", 0.05, 0, 127)
SIZE_VALUE = Scale("obstacle size", "m", 0.1, 0, 1023)
ATTACHMENT_RADIUS = Scale("attachment radius", "m", 0.1, 0, 200)
DSECOND = Scale("second", "s", 0.001, 0, 65535)   # DDateTime.second: ms in the minute (60000.. leap, 65535 unknown)


class ConfidenceScale:
    """A J2735 confidence enumeration: names from coarsest to finest after 'unavailable', each a bound on the
    error in `unit`. `bound(name)` is that bound (None for 'unavailable'); `name_for(value)` the finest class
    whose bound is at least `value` ('unavailable' for None or a value beyond the coarsest class)."""

    def __init__(self, what: str, unit: str, names: tuple[str, ...], bounds: tuple[float, ...]):
        if len(names) != len(bounds) + 1 or names[0] != "unavailable":
            raise ValueError(f"{what}: 'unavailable' and one bound per other name")
        self.what, self.unit, self.names, self._bounds = what, unit, names, dict(zip(names[1:], bounds))

    def bound(self, name: str) -> float | None:
        f.name(name, self.names, self.what)
        return self._bounds.get(name)

    def name_for(self, value: float | None) -> str:
        if value is None:
            return "unavailable"
        value = f.finite(value, self.what)
        covering = [(bound, name) for name, bound in self._bounds.items() if bound >= value]
        return min(covering)[1] if covering else "unavailable"

    def __repr__(self) -> str:
        return f"ConfidenceScale({self.what!r}, {self.unit!r})"


def _decimal_names(prefix: str, groups: list[str]) -> tuple[float, ...]:
    """Bounds read from names such as time-000-000-5 (0.0005 s) or elev-020-00 (20 m): the first group is the
    integer part, the others the decimals."""
    out = []
    for g in groups:
        head, *tail = g.removeprefix(prefix).split("-")
        out.append(float(f"{int(head)}.{''.join(tail) or '0'}"))
    return tuple(out)


_TIME_NAMES = ("time-100-000", "time-050-000", "time-020-000", "time-010-000", "time-002-000", "time-001-000",
               "time-000-500", "time-000-200", "time-000-100", "time-000-050", "time-000-020", "time-000-010",
               "time-000-005", "time-000-002", "time-000-001", "time-000-000-5", "time-000-000-2", "time-000-000-1",
               "time-000-000-05", "time-000-000-02", "time-000-000-01", "time-000-000-005", "time-000-000-002",
               "time-000-000-001", "time-000-000-000-5", "time-000-000-000-2", "time-000-000-000-1",
               "time-000-000-000-05", "time-000-000-000-02", "time-000-000-000-01", "time-000-000-000-005",
               "time-000-000-000-002", "time-000-000-000-001", "time-000-000-000-000-5", "time-000-000-000-000-2",
               "time-000-000-000-000-1", "time-000-000-000-000-05", "time-000-000-000-000-02",
               "time-000-000-000-000-01")
TIME_CONFIDENCE = ConfidenceScale("time confidence", "s", ("unavailable", *_TIME_NAMES),
                                  _decimal_names("time-", list(_TIME_NAMES)))
POSITION_CONFIDENCE = ConfidenceScale(
    "position confidence", "m",
    ("unavailable", "a500m", "a200m", "a100m", "a50m", "a20m", "a10m", "a5m", "a2m", "a1m", "a50cm", "a20cm",
     "a10cm", "a5cm", "a2cm", "a1cm"),
    (500, 200, 100, 50, 20, 10, 5, 2, 1, 0.5, 0.2, 0.1, 0.05, 0.02, 0.01))
_ELEVATION_NAMES = ("elev-500-00", "elev-200-00", "elev-100-00", "elev-050-00", "elev-020-00", "elev-010-00",
                    "elev-005-00", "elev-002-00", "elev-001-00", "elev-000-50", "elev-000-20", "elev-000-10",
                    "elev-000-05", "elev-000-02", "elev-000-01")
ELEVATION_CONFIDENCE = ConfidenceScale("elevation confidence", "m", ("unavailable", *_ELEVATION_NAMES),
                                       _decimal_names("elev-", list(_ELEVATION_NAMES)))
SPEED_CONFIDENCE = ConfidenceScale(
    "speed confidence", "m/s",
    ("unavailable", "prec100ms", "prec10ms", "prec5ms", "prec1ms", "prec0-1ms", "prec0-05ms", "prec0-01ms"),
    (100, 10, 5, 1, 0.1, 0.05, 0.01))
HEADING_CONFIDENCE = ConfidenceScale(
    "heading confidence", "deg",
    ("unavailable", "prec10deg", "prec05deg", "prec01deg", "prec0-1deg", "prec0-05deg", "prec0-01deg",
     "prec0-0125deg"),
    (10, 5, 1, 0.1, 0.05, 0.01, 0.0125))
_ACCEL_NAMES = ("accl-100-00", "accl-010-00", "accl-005-00", "accl-001-00", "accl-000-10", "accl-000-05",
                "accl-000-01")
ACCELERATION_CONFIDENCE = ConfidenceScale("acceleration confidence", "m/s2", ("unavailable", *_ACCEL_NAMES),
                                          _decimal_names("accl-", list(_ACCEL_NAMES)))
_YAW_RATE_NAMES = tuple(n.replace("accl-", "degSec-") for n in _ACCEL_NAMES)
YAW_RATE_CONFIDENCE = ConfidenceScale("yaw rate confidence", "deg/s", ("unavailable", *_YAW_RATE_NAMES),
                                      _decimal_names("degSec-", list(_YAW_RATE_NAMES)))
ANGULAR_RATE_CONFIDENCE = ConfidenceScale(
    "angular rate confidence", "deg/s",
    ("unavailable", "prec100deg", "prec10deg", "prec5deg", "prec1deg", "prec0-1deg", "prec0-05deg", "prec0-01deg"),
    (100, 10, 5, 1, 0.1, 0.05, 0.01))
_SIZE_NAMES = ("size-100-00", "size-050-00", "size-020-00", "size-010-00", "size-005-00", "size-002-00",
               "size-001-00", "size-000-50", "size-000-20", "size-000-10", "size-000-05", "size-000-02",
               "size-000-01")
SIZE_CONFIDENCE = ConfidenceScale("size confidence", "m", ("unavailable", *_SIZE_NAMES),
                                  _decimal_names("size-", list(_SIZE_NAMES)))


def _conf(scale: ConfidenceScale, name: Any, what: str) -> str:
    return f.name(name, scale.names, what)


def _percent(value: Any, what: str) -> int:
    return f.integer(value, 0, 101, f"{what} (percent)")


# -- the message's time ------------------------------------------------------------------------------------
@dataclass
class DateTime:
    """DDateTime: each member optional, as on the wire. `second` is seconds within the minute (ms on the
    wire, 60..60.999 during a leap second); `offset` minutes from UTC (-840..840)."""

    year: int | None = None
    month: int | None = None
    day: int | None = None
    hour: int | None = None
    minute: int | None = None
    second: float | None = None
    offset: int | None = None

    @classmethod
    def from_unix(cls, unix_s: float) -> "DateTime":
        """The UTC date and time of a POSIX time, to the millisecond."""
        ms = round(f.finite(unix_s, "timestamp") * 1000)
        g = time.gmtime(ms // 60000 * 60)
        return cls(g.tm_year, g.tm_mon, g.tm_mday, g.tm_hour, g.tm_min, (ms % 60000) / 1000.0)

    def to_unix(self) -> float | None:
        """The POSIX time (UTC, less `offset`), or None unless year to second are all given."""
        parts = (self.year, self.month, self.day, self.hour, self.minute, self.second)
        if any(p is None for p in parts):
            return None
        minute = calendar.timegm((self.year, self.month, self.day, self.hour, self.minute, 0))
        return minute + self.second - 60.0 * (self.offset or 0)

    def to_asn1(self, where: str = "timestamp") -> dict[str, Any]:
        out: dict[str, Any] = {}
        for key, low, high in (("year", 0, 4095), ("month", 0, 12), ("day", 0, 31), ("hour", 0, 31),
                               ("minute", 0, 60)):
            value = getattr(self, key)
            if value is not None:
                out[key] = f.integer(value, low, high, f"{where}: {key}")
        if self.second is not None:
            out["second"] = f.wire(DSECOND, self.second, f"{where}: second")
        if self.offset is not None:
            out["offset"] = f.integer(self.offset, -840, 840, f"{where}: offset (minutes)")
        return out

    @classmethod
    def from_asn1(cls, v: dict[str, Any]) -> "DateTime":
        return cls(v.get("year"), v.get("month"), v.get("day"), v.get("hour"), v.get("minute"),
                   f.from_wire(DSECOND, v.get("second")), v.get("offset"))


# -- what is known of each kind of object ---------------------------------------------------------------------
@dataclass
class Acceleration:
    """AccelerationSet4Way: longitudinal, lateral, vertical (m/s2; None: unavailable) and yaw rate (deg/s)."""

    long: float | None = None
    lat: float | None = None
    vert: float | None = None
    yaw_rate: float = 0.0

    def to_asn1(self, where: str) -> dict[str, Any]:
        return {"long": f.wire(scales.ACCELERATION, self.long, f"{where}: long"),
                "lat": f.wire(scales.ACCELERATION, self.lat, f"{where}: lat"),
                "vert": f.wire(scales.VERTICAL_ACCELERATION, self.vert, f"{where}: vert"),
                "yaw": f.wire(scales.YAW_RATE, self.yaw_rate, f"{where}: yaw_rate")}

    @classmethod
    def from_asn1(cls, v: dict[str, Any]) -> "Acceleration":
        return cls(f.from_wire(scales.ACCELERATION, v["long"]), f.from_wire(scales.ACCELERATION, v["lat"]),
                   f.from_wire(scales.VERTICAL_ACCELERATION, v["vert"]), f.from_wire(scales.YAW_RATE, v["yaw"]))


@dataclass
class VehicleDetails(Kept):
    """detVeh: what is known of a detected vehicle; every member optional."""

    lights: frozenset[str] | None = None                      # ExteriorLights names (EXTERIOR_LIGHTS)
    attitude: tuple[float, float, float] | None = None        # pitch, roll, yaw in deg
    attitude_confidence: tuple[str, str, str] | None = None   # HEADING_CONFIDENCE names of the three
    angular_velocity: tuple[float, float] | None = None       # pitch rate, roll rate in deg/s
    angular_velocity_confidence: tuple[str | None, str | None] | None = None  # ANGULAR_RATE_CONFIDENCE names
    width: float | None = None      # m; the size is sent when width or length is given (the other as 0: unknown)
    length: float | None = None     # m
    height: float | None = None     # m
    size_confidence: tuple[str, str, str | None] | None = None  # SIZE_CONFIDENCE of width, length, height
    vehicle_class: int | None = None      # BasicVehicleClass 0..255
    class_confidence: int | None = None   # percent
    other: dict[str, Any] | None = None

    def _typed(self, where: str = "vehicle") -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.lights is not None:
            out["lights"] = f.names_to_bits(self.lights, EXTERIOR_LIGHTS, f"{where}: lights", 9)
        if self.attitude is not None:
            pitch, roll, yaw = _triple(self.attitude, f"{where}: attitude")
            out["vehAttitude"] = {"pitch": f.wire(PITCH, pitch, f"{where}: pitch"),
                                  "roll": f.wire(ROLL, roll, f"{where}: roll"),
                                  "yaw": f.wire(YAW, yaw, f"{where}: yaw")}
        if self.attitude_confidence is not None:
            names = _triple(self.attitude_confidence, f"{where}: attitude_confidence")
            out["vehAttitudeConfidence"] = {
                key: _conf(HEADING_CONFIDENCE, n, f"{where}: {key}")
                for key, n in zip(("pitchConfidence", "rollConfidence", "yawConfidence"), names)}
        if self.angular_velocity is not None:
            pitch_rate, roll_rate = _pair(self.angular_velocity, f"{where}: angular_velocity")
            out["vehAngVel"] = {"pitchRate": f.wire(ANGULAR_RATE, pitch_rate, f"{where}: pitch rate"),
                                "rollRate": f.wire(ANGULAR_RATE, roll_rate, f"{where}: roll rate")}
        if self.angular_velocity_confidence is not None:
            confidence = {}
            for key, n in zip(("pitchRateConfidence", "rollRateConfidence"),
                              _pair(self.angular_velocity_confidence, f"{where}: angular_velocity_confidence")):
                if n is not None:
                    confidence[key] = _conf(ANGULAR_RATE_CONFIDENCE, n, f"{where}: {key}")
            out["vehAngVelConfidence"] = confidence
        if self.width is not None or self.length is not None:
            out["size"] = {"width": f.wire(scales.VEHICLE_WIDTH, self.width, f"{where}: width"),
                           "length": f.wire(scales.VEHICLE_LENGTH, self.length, f"{where}: length")}
        if self.height is not None:
            out["height"] = f.wire(VEHICLE_HEIGHT, self.height, f"{where}: height")
        if self.size_confidence is not None:
            w, l, h = _triple(self.size_confidence, f"{where}: size_confidence")
            confidence = {"vehicleWidthConfidence": _conf(SIZE_CONFIDENCE, w, f"{where}: width confidence"),
                          "vehicleLengthConfidence": _conf(SIZE_CONFIDENCE, l, f"{where}: length confidence")}
            if h is not None:
                confidence["vehicleHeightConfidence"] = _conf(SIZE_CONFIDENCE, h, f"{where}: height confidence")
            out["vehicleSizeConfidence"] = confidence
        if self.vehicle_class is not None:
            out["vehicleClass"] = f.integer(self.vehicle_class, 0, 255, f"{where}: vehicle_class")
        if self.class_confidence is not None:
            out["classConf"] = _percent(self.class_confidence, f"{where}: class_confidence")
        return out

    @classmethod
    def from_asn1(cls, v: dict[str, Any]) -> "VehicleDetails":
        att, attc, vel, velc = (v.get(k) for k in ("vehAttitude", "vehAttitudeConfidence", "vehAngVel",
                                                    "vehAngVelConfidence"))
        size, sizec = v.get("size"), v.get("vehicleSizeConfidence")
        d = cls(lights=None if "lights" not in v else f.bits_to_names(v["lights"], EXTERIOR_LIGHTS),
                attitude=None if att is None else (f.from_wire(PITCH, att["pitch"]), f.from_wire(ROLL, att["roll"]),
                                                   f.from_wire(YAW, att["yaw"])),
                attitude_confidence=None if attc is None else (attc["pitchConfidence"], attc["rollConfidence"],
                                                               attc["yawConfidence"]),
                angular_velocity=None if vel is None else (f.from_wire(ANGULAR_RATE, vel["pitchRate"]),
                                                           f.from_wire(ANGULAR_RATE, vel["rollRate"])),
                angular_velocity_confidence=None if velc is None else (velc.get("pitchRateConfidence"),
                                                                       velc.get("rollRateConfidence")),
                width=None if size is None else f.from_wire(scales.VEHICLE_WIDTH, size["width"]),
                length=None if size is None else f.from_wire(scales.VEHICLE_LENGTH, size["length"]),
                height=f.from_wire(VEHICLE_HEIGHT, v.get("height")),
                size_confidence=None if sizec is None else (sizec["vehicleWidthConfidence"],
                                                            sizec["vehicleLengthConfidence"],
                                                            sizec.get("vehicleHeightConfidence")),
                vehicle_class=v.get("vehicleClass"), class_confidence=v.get("classConf"))
        return d._keep(v)


@dataclass
class VruDetails(Kept):
    """detVRU: what is known of a detected vulnerable road user; every member optional."""

    basic_type: str | None = None                 # PersonalDeviceUserType name (VRU_TYPES)
    propulsion: tuple[str, str] | None = None     # ("human" | "animal" | "motor", that enumeration's name)
    attachment: str | None = None                 # Attachment name (ATTACHMENTS)
    radius: float | None = None                   # m, of the attachment
    other: dict[str, Any] | None = None

    def _typed(self, where: str = "vru") -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.basic_type is not None:
            out["basicType"] = f.name(self.basic_type, VRU_TYPES, f"{where}: basic_type")
        if self.propulsion is not None:
            kind, value = _pair(self.propulsion, f"{where}: propulsion")
            kind = f.name(kind, tuple(PROPULSION), f"{where}: propulsion kind")
            out["propulsion"] = (kind, f.name(value, PROPULSION[kind], f"{where}: propulsion ({kind})"))
        if self.attachment is not None:
            out["attachment"] = f.name(self.attachment, ATTACHMENTS, f"{where}: attachment")
        if self.radius is not None:
            out["radius"] = f.wire(ATTACHMENT_RADIUS, self.radius, f"{where}: radius")
        return out

    @classmethod
    def from_asn1(cls, v: dict[str, Any]) -> "VruDetails":
        propulsion = v.get("propulsion")
        d = cls(basic_type=v.get("basicType"), propulsion=None if propulsion is None else tuple(propulsion),
                attachment=v.get("attachment"), radius=f.from_wire(ATTACHMENT_RADIUS, v.get("radius")))
        return d._keep(v)


@dataclass
class ObstacleDetails(Kept):
    """detObst: the size of a detected obstacle (m) and its confidences (SIZE_CONFIDENCE names)."""

    width: float
    length: float
    height: float | None = None
    width_confidence: str = "unavailable"
    length_confidence: str = "unavailable"
    height_confidence: str | None = None
    other: dict[str, Any] | None = None

    def _typed(self, where: str = "obstacle") -> dict[str, Any]:
        size = {"width": f.wire(SIZE_VALUE, self.width, f"{where}: width"),
                "length": f.wire(SIZE_VALUE, self.length, f"{where}: length")}
        if self.height is not None:
            size["height"] = f.wire(SIZE_VALUE, self.height, f"{where}: height")
        confidence = {"widthConfidence": _conf(SIZE_CONFIDENCE, self.width_confidence, f"{where}: width_confidence"),
                      "lengthConfidence": _conf(SIZE_CONFIDENCE, self.length_confidence,
                                                f"{where}: length_confidence")}
        if self.height_confidence is not None:
            confidence["heightConfidence"] = _conf(SIZE_CONFIDENCE, self.height_confidence,
                                                   f"{where}: height_confidence")
        return {"obstSize": size, "obstSizeConfidence": confidence}

    @classmethod
    def from_asn1(cls, v: dict[str, Any]) -> "ObstacleDetails":
        size, confidence = v["obstSize"], v["obstSizeConfidence"]
        d = cls(width=f.from_wire(SIZE_VALUE, size["width"]), length=f.from_wire(SIZE_VALUE, size["length"]),
                height=f.from_wire(SIZE_VALUE, size.get("height")), width_confidence=confidence["widthConfidence"],
                length_confidence=confidence["lengthConfidence"], height_confidence=confidence.get("heightConfidence"))
        return d._keep(v)


DETAILS = {"detVeh": VehicleDetails, "detVRU": VruDetails, "detObst": ObstacleDetails}


def _triple(value: Any, what: str) -> tuple:
    if not isinstance(value, (tuple, list)) or len(value) != 3:
        raise J2735Error(f"{what}: three values required, got {value!r}")
    return tuple(value)


def _pair(value: Any, what: str) -> tuple:
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise J2735Error(f"{what}: two values required, got {value!r}")
    return tuple(value)


# -- one detected object ---------------------------------------------------------------------------------------
@dataclass
class DetectedObject(Kept):
    """DetectedObjectData: the common data of one object, and what is known of its kind (`details`)."""

    object_id: int                                # ObjectID 0..65535, stable while the sender tracks it
    object_type: str = "unknown"                  # OBJECT_TYPES
    type_confidence: int = 0                      # objTypeCfd, percent
    measurement_time: float = 0.0                 # s relative to the message's timestamp (-1.5..1.5)
    time_confidence: str = "unavailable"          # TIME_CONFIDENCE name
    offset_x: float = 0.0                         # m east of the reference point
    offset_y: float = 0.0                         # m north
    offset_z: float | None = None                 # m up
    position_confidence: str = "unavailable"      # POSITION_CONFIDENCE name (horizontal)
    elevation_confidence: str = "unavailable"     # ELEVATION_CONFIDENCE name
    speed: float | None = None                    # m/s; None: unavailable
    speed_confidence: str = "unavailable"         # SPEED_CONFIDENCE name
    speed_z: float | None = None                  # m/s (vertical speed, a magnitude as sent)
    speed_z_confidence: str | None = None         # SPEED_CONFIDENCE name
    heading: float | None = None                  # deg clockwise from north; None: unavailable
    heading_confidence: str = "unavailable"       # HEADING_CONFIDENCE name
    acceleration: Acceleration | None = None
    accel_confidence_x: str | None = None         # ACCELERATION_CONFIDENCE names
    accel_confidence_y: str | None = None
    accel_confidence_z: str | None = None
    yaw_rate_confidence: str | None = None        # YAW_RATE_CONFIDENCE name
    details: VehicleDetails | VruDetails | ObstacleDetails | None = None
    other: dict[str, Any] | None = None           # the common data's untyped rest (see bridges.j2735.fields)

    def _typed(self, where: str = "object") -> dict[str, Any]:
        where = f"{where} {self.object_id!r}"
        c: dict[str, Any] = {
            "objType": f.name(self.object_type, OBJECT_TYPES, f"{where}: object_type"),
            "objTypeCfd": _percent(self.type_confidence, f"{where}: type_confidence"),
            "objectID": f.integer(self.object_id, 0, 65535, f"{where}: object_id"),
            "measurementTime": f.wire(MEASUREMENT_TIME, self.measurement_time, f"{where}: measurement_time"),
            "timeConfidence": _conf(TIME_CONFIDENCE, self.time_confidence, f"{where}: time_confidence"),
            "pos": {"offsetX": f.wire(OFFSET, self.offset_x, f"{where}: offset_x"),
                    "offsetY": f.wire(OFFSET, self.offset_y, f"{where}: offset_y")},
            "posConfidence": {
                "pos": _conf(POSITION_CONFIDENCE, self.position_confidence, f"{where}: position_confidence"),
                "elevation": _conf(ELEVATION_CONFIDENCE, self.elevation_confidence,
                                   f"{where}: elevation_confidence")},
            "speed": f.wire(scales.SPEED, self.speed, f"{where}: speed"),
            "speedConfidence": _conf(SPEED_CONFIDENCE, self.speed_confidence, f"{where}: speed_confidence"),
        }
        if self.offset_z is not None:
            c["pos"]["offsetZ"] = f.wire(OFFSET, self.offset_z, f"{where}: offset_z")
        if self.speed_z is not None:
            c["speedZ"] = f.wire(scales.SPEED, self.speed_z, f"{where}: speed_z")
        if self.speed_z_confidence is not None:
            c["speedConfidenceZ"] = _conf(SPEED_CONFIDENCE, self.speed_z_confidence, f"{where}: speed_z_confidence")
        c["heading"] = f.wire(scales.HEADING, self.heading, f"{where}: heading")
        c["headingConf"] = _conf(HEADING_CONFIDENCE, self.heading_confidence, f"{where}: heading_confidence")
        if self.acceleration is not None:
            if not isinstance(self.acceleration, Acceleration):
                raise J2735Error(f"{where}: acceleration: an Acceleration is required, got {self.acceleration!r}")
            c["accel4way"] = self.acceleration.to_asn1(f"{where}: acceleration")
        for key, value, scale in (("accCfdX", self.accel_confidence_x, ACCELERATION_CONFIDENCE),
                                  ("accCfdY", self.accel_confidence_y, ACCELERATION_CONFIDENCE),
                                  ("accCfdZ", self.accel_confidence_z, ACCELERATION_CONFIDENCE),
                                  ("accCfdYaw", self.yaw_rate_confidence, YAW_RATE_CONFIDENCE)):
            if value is not None:
                c[key] = _conf(scale, value, f"{where}: {key}")
        return c

    def to_asn1(self, where: str = "object") -> dict[str, Any]:
        out: dict[str, Any] = {"detObjCommon": f.fill(self._typed(where), self.other)}
        if self.details is not None:
            choice = next((key for key, kind in DETAILS.items() if isinstance(self.details, kind)), None)
            if choice is None:
                raise J2735Error(f"{where} {self.object_id!r}: details: a VehicleDetails, VruDetails or "
                                 f"ObstacleDetails is required, got {type(self.details).__name__}")
            out["detObjOptData"] = (choice, self.details.to_asn1(f"{where} {self.object_id!r}"))
        return out

    @classmethod
    def from_asn1(cls, v: dict[str, Any]) -> "DetectedObject":
        c = v["detObjCommon"]
        pos, confidence = c["pos"], c["posConfidence"]
        details = None
        if "detObjOptData" in v:
            choice, value = v["detObjOptData"]
            details = DETAILS[choice].from_asn1(value)
        accel = c.get("accel4way")
        o = cls(object_id=c["objectID"], object_type=c["objType"], type_confidence=c["objTypeCfd"],
                measurement_time=f.from_wire(MEASUREMENT_TIME, c["measurementTime"]),
                time_confidence=c["timeConfidence"],
                offset_x=f.from_wire(OFFSET, pos["offsetX"]), offset_y=f.from_wire(OFFSET, pos["offsetY"]),
                offset_z=f.from_wire(OFFSET, pos.get("offsetZ")),
                position_confidence=confidence["pos"], elevation_confidence=confidence["elevation"],
                speed=f.from_wire(scales.SPEED, c["speed"]), speed_confidence=c["speedConfidence"],
                speed_z=f.from_wire(scales.SPEED, c.get("speedZ")), speed_z_confidence=c.get("speedConfidenceZ"),
                heading=f.from_wire(scales.HEADING, c["heading"]), heading_confidence=c["headingConf"],
                acceleration=None if accel is None else Acceleration.from_asn1(accel),
                accel_confidence_x=c.get("accCfdX"), accel_confidence_y=c.get("accCfdY"),
                accel_confidence_z=c.get("accCfdZ"), yaw_rate_confidence=c.get("accCfdYaw"), details=details)
        o.other = f.residue(c, o._typed())
        return o


# -- the message ------------------------------------------------------------------------------------------------
@dataclass
class Sdsm(Kept, Framed):
    """SensorDataSharingMessage: the objects one station detected in one cycle, around its reference point."""

    MESSAGE_ID, WHAT = SDSM_ID, "an SDSM"

    source_id: bytes                       # the sender's TemporaryID, 4 bytes
    objects: list[DetectedObject]          # 1..256
    latitude: float | None = None          # deg, reference point; None: unavailable
    longitude: float | None = None         # deg
    elevation: float | None = None         # m; None: not sent
    timestamp: DateTime = field(default_factory=DateTime)
    msg_count: int = 0                     # MsgCount 0..127
    equipment_type: str = "rsu"            # EQUIPMENT_TYPES
    semi_major: float | None = None        # m, reference point's accuracy (PositionalAccuracy); None: unavailable
    semi_minor: float | None = None        # m
    orientation: float | None = None       # deg of the semi-major axis from north
    elevation_confidence: str | None = None  # ELEVATION_CONFIDENCE name of the reference point; None: not sent
    other: dict[str, Any] | None = None

    def _typed(self) -> dict[str, Any]:
        if not isinstance(self.source_id, (bytes, bytearray)) or len(self.source_id) != 4:
            raise J2735Error(f"source_id: 4 bytes required (TemporaryID), got {self.source_id!r}")
        if not isinstance(self.objects, (list, tuple)) or not 1 <= len(self.objects) <= MAX_OBJECTS:
            count = len(self.objects) if isinstance(self.objects, (list, tuple)) else repr(self.objects)
            raise J2735Error(f"objects: 1..{MAX_OBJECTS} detected objects, got {count}")
        if not isinstance(self.timestamp, DateTime):
            raise J2735Error(f"timestamp: a DateTime is required, got {self.timestamp!r}")
        ref: dict[str, Any] = {"lat": f.wire(scales.LATITUDE, self.latitude, "latitude"),
                               "long": f.wire(scales.LONGITUDE, self.longitude, "longitude")}
        if self.elevation is not None:
            ref["elevation"] = f.wire(scales.ELEVATION, self.elevation, "elevation")
        out: dict[str, Any] = {
            "msgCnt": f.integer(self.msg_count, 0, 127, "msg_count"),
            "sourceID": bytes(self.source_id),
            "equipmentType": f.name(self.equipment_type, EQUIPMENT_TYPES, "equipment_type"),
            "sDSMTimeStamp": self.timestamp.to_asn1(),
            "refPos": ref,
            "refPosXYConf": {"semiMajor": f.wire(scales.SEMI_AXIS, self.semi_major, "semi_major"),
                             "semiMinor": f.wire(scales.SEMI_AXIS, self.semi_minor, "semi_minor"),
                             "orientation": f.wire(scales.SEMI_AXIS_ORIENTATION, self.orientation, "orientation")},
        }
        if self.elevation_confidence is not None:
            out["refPosElConf"] = _conf(ELEVATION_CONFIDENCE, self.elevation_confidence, "elevation_confidence")
        out["objects"] = [_object(o, i).to_asn1(f"objects[{i}]") for i, o in enumerate(self.objects)]
        return out

    @classmethod
    def from_asn1(cls, m: dict[str, Any]) -> "Sdsm":
        _refuse_unknown_extensions(m, "SDSM")
        ref, accuracy = m["refPos"], m["refPosXYConf"]
        sdsm = cls(source_id=m["sourceID"], objects=[DetectedObject.from_asn1(o) for o in m["objects"]],
                   latitude=f.from_wire(scales.LATITUDE, ref["lat"]),
                   longitude=f.from_wire(scales.LONGITUDE, ref["long"]),
                   elevation=f.from_wire(scales.ELEVATION, ref.get("elevation")),
                   timestamp=DateTime.from_asn1(m["sDSMTimeStamp"]), msg_count=m["msgCnt"],
                   equipment_type=m["equipmentType"],
                   semi_major=f.from_wire(scales.SEMI_AXIS, accuracy["semiMajor"]),
                   semi_minor=f.from_wire(scales.SEMI_AXIS, accuracy["semiMinor"]),
                   orientation=f.from_wire(scales.SEMI_AXIS_ORIENTATION, accuracy["orientation"]),
                   elevation_confidence=m.get("refPosElConf"))
        return sdsm._keep(m)


def _refuse_unknown_extensions(value: Any, where: str) -> None:
    """An enumerated value or CHOICE alternative added by a later edition decodes as None (asn1tools cannot
    name it); the typed message cannot carry it on, so it is refused here with where it was."""
    if value is None:
        raise J2735Error(f"{where}: a value this edition does not define (an extension of a later one)")
    if isinstance(value, dict):
        for key, item in value.items():
            _refuse_unknown_extensions(item, f"{where}.{key}")
    elif isinstance(value, list):
        for index, item in enumerate(value):
            _refuse_unknown_extensions(item, f"{where}[{index}]")
    elif isinstance(value, tuple) and len(value) == 2 and (value[0] is None or isinstance(value[0], str)):
        if value[0] is None:
            raise J2735Error(f"{where}: a CHOICE alternative this edition does not define (an extension of a "
                             "later one)")
        _refuse_unknown_extensions(value[1], f"{where}.{value[0]}")


def _object(o: Any, index: int) -> DetectedObject:
    if not isinstance(o, DetectedObject):
        raise J2735Error(f"objects[{index}]: a DetectedObject is required, got {type(o).__name__}")
    return o
