"""The Basic Safety Message as a typed object in SI units and degrees.

`Bsm.encode()` gives the UPER MessageFrame; `Bsm.decode(bytes)` reads one.
Part II content the typed fields do not cover (path history, trailers, unknown
ids) is kept verbatim in `other_part_ii`, regional extensions in `regional`,
so decode → encode is lossless; a secMark the standard reserves (61000..65534)
is kept as `scales.Reserved` and sent back as received.

Editions: the emergency alerts' SSP index is `sspRights` in J2735 2016 and
`notUsed` in 2020; `EmergencyInfo.ssp_rights` is either, by the codec's
edition (`encode(codec)`, `to_asn1(edition)`), and either is read.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any

from bridges.j2735 import scales
from bridges.j2735.codec import J2735Codec, J2735Error, default_codec
from bridges.j2735.editions import SSP_MEMBERS, Edition, edition as edition_named
from bridges.j2735.typed import Framed

TRANSMISSION_STATES = ("neutral", "park", "forwardGears", "reverseGears",
                       "reserved1", "reserved2", "reserved3", "unavailable")
SIREN_STATES = ("unavailable", "notInUse", "inUse", "reserved")
LIGHTBAR_STATES = ("unavailable", "notInUse", "inUse", "yellowCautionLights", "schooldBusLights",
                   "arrowSignsActive", "slowMovingVehicle", "freqStops")
RESPONSE_TYPES = ("notInUseOrNotEquipped", "emergency", "nonEmergency", "pursuit", "stationary",
                  "slowMoving", "stopAndGoMovement")


@dataclass
class EmergencyInfo:
    """SpecialVehicleExtensions.vehicleAlerts: what an emergency vehicle announces."""

    siren: str = "unavailable"
    lightbar: str = "unavailable"
    response_type: str | None = None
    ssp_rights: int = 0                 # 2016 sspRights, 2020 notUsed (send 0 in 2020)
    multi: str = "unavailable"


@dataclass
class Bsm(Framed):
    """BSM core data (part I) in SI units; None where J2735 says 'unavailable'."""

    MESSAGE_ID, WHAT = 20, "a BSM"

    temporary_id: bytes
    msg_count: int = 0
    sec_mark_ms: int | None = None
    latitude: float | None = None      # deg
    longitude: float | None = None     # deg
    elevation: float | None = None     # m
    speed: float | None = None         # m/s
    heading: float | None = None       # deg clockwise from north
    steering_angle: float | None = None  # deg
    accel_long: float | None = None    # m/s2
    accel_lat: float | None = None     # m/s2
    accel_vert: float | None = None    # m/s2
    yaw_rate: float = 0.0              # deg/s
    transmission: str = "unavailable"
    width: float | None = None         # m
    length: float | None = None        # m
    semi_major: float | None = None    # m (1 sigma)
    semi_minor: float | None = None    # m
    orientation: float | None = None  # deg
    emergency: EmergencyInfo | None = None
    other_part_ii: list[dict[str, Any]] = field(default_factory=list)
    brakes: dict[str, Any] | None = None  # BrakeSystemStatus as asn1 values; None: all unavailable
    emergency_position: int | None = field(default=None, repr=False)  # where in part II it was received
    regional: list[dict[str, Any]] | None = None  # regional extensions, kept verbatim

    # -- to and from asn1 values ----------------------------------------------------
    def to_asn1(self, edition: str | Edition | None = None) -> dict[str, Any]:
        """asn1tools values in `edition`'s names (None: the default codec's edition)."""
        if not isinstance(self.temporary_id, (bytes, bytearray)) or len(self.temporary_id) != 4:
            raise J2735Error(f"temporary_id: 4 bytes required, got {self.temporary_id!r}")
        if not isinstance(self.msg_count, int) or not 0 <= self.msg_count <= 127:
            raise J2735Error(f"msg_count: {self.msg_count!r} is outside 0..127")
        if self.transmission not in TRANSMISSION_STATES:
            raise J2735Error(f"transmission: {self.transmission!r} is not one of {TRANSMISSION_STATES}")
        core = {
            "msgCnt": self.msg_count,
            "id": bytes(self.temporary_id),
            "secMark": scales.SEC_MARK.to_wire(self.sec_mark_ms),
            "lat": scales.LATITUDE.to_wire(self.latitude),
            "long": scales.LONGITUDE.to_wire(self.longitude),
            "elev": scales.ELEVATION.to_wire(self.elevation),
            "accuracy": {"semiMajor": scales.SEMI_AXIS.to_wire(self.semi_major),
                         "semiMinor": scales.SEMI_AXIS.to_wire(self.semi_minor),
                         "orientation": scales.SEMI_AXIS_ORIENTATION.to_wire(self.orientation)},
            "transmission": self.transmission,
            "speed": scales.SPEED.to_wire(self.speed),
            "heading": scales.HEADING.to_wire(self.heading),
            "angle": scales.STEERING_ANGLE.to_wire(self.steering_angle),
            "accelSet": {"long": scales.ACCELERATION.to_wire(self.accel_long),
                         "lat": scales.ACCELERATION.to_wire(self.accel_lat),
                         "vert": scales.VERTICAL_ACCELERATION.to_wire(self.accel_vert),
                         "yaw": scales.YAW_RATE.to_wire(self.yaw_rate)},
            "brakes": self.brakes or _UNAVAILABLE_BRAKES,
            "size": {"width": scales.VEHICLE_WIDTH.to_wire(self.width),
                     "length": scales.VEHICLE_LENGTH.to_wire(self.length)},
        }
        message: dict[str, Any] = {"coreData": core}
        part_ii = list(self.other_part_ii)
        if self.emergency is not None:
            position = len(part_ii) if self.emergency_position is None else self.emergency_position
            ssp_member = (edition_named(edition) if edition is not None else default_codec().edition).ssp_member
            part_ii.insert(position, {"partII-Id": 1, "partII-Value": {
                "vehicleAlerts": _emergency_to_asn1(self.emergency, ssp_member)}})
        if part_ii:
            message["partII"] = part_ii
        if self.regional:
            message["regional"] = self.regional
        return message

    @classmethod
    def from_asn1(cls, message: dict[str, Any]) -> "Bsm":
        core = message["coreData"]
        emergency, position, others = None, None, []
        for index, content in enumerate(message.get("partII", ())):
            value = content["partII-Value"]
            if content["partII-Id"] == 1 and isinstance(value, dict) and set(value) == {"vehicleAlerts"} \
                    and set(value["vehicleAlerts"]) <= _TYPED_EMERGENCY_FIELDS and emergency is None:
                emergency, position = _emergency_from_asn1(value["vehicleAlerts"]), index
            else:
                others.append(content)
        accel, accuracy, size = core["accelSet"], core["accuracy"], core["size"]
        brakes = core["brakes"]
        return cls(
            temporary_id=core["id"], msg_count=core["msgCnt"],
            sec_mark_ms=_ms(scales.SEC_MARK.from_wire(core["secMark"])),
            latitude=scales.LATITUDE.from_wire(core["lat"]),
            longitude=scales.LONGITUDE.from_wire(core["long"]),
            elevation=scales.ELEVATION.from_wire(core["elev"]),
            speed=scales.SPEED.from_wire(core["speed"]),
            heading=scales.HEADING.from_wire(core["heading"]),
            steering_angle=scales.STEERING_ANGLE.from_wire(core["angle"]),
            accel_long=scales.ACCELERATION.from_wire(accel["long"]),
            accel_lat=scales.ACCELERATION.from_wire(accel["lat"]),
            accel_vert=scales.VERTICAL_ACCELERATION.from_wire(accel["vert"]),
            yaw_rate=scales.YAW_RATE.from_wire(accel["yaw"]),
            transmission=core["transmission"],
            width=scales.VEHICLE_WIDTH.from_wire(size["width"]),
            length=scales.VEHICLE_LENGTH.from_wire(size["length"]),
            semi_major=scales.SEMI_AXIS.from_wire(accuracy["semiMajor"]),
            semi_minor=scales.SEMI_AXIS.from_wire(accuracy["semiMinor"]),
            orientation=scales.SEMI_AXIS_ORIENTATION.from_wire(accuracy["orientation"]),
            emergency=emergency, emergency_position=position, other_part_ii=others,
            brakes=None if brakes == _UNAVAILABLE_BRAKES else brakes,
            regional=message.get("regional"),
        )

    def _to_wire(self, codec: J2735Codec) -> dict[str, Any]:
        return self.to_asn1(codec.edition)


_TYPED_EMERGENCY_FIELDS = {"sirenUse", "lightsUse", "multi", "responseType", *SSP_MEMBERS}
_UNAVAILABLE_BRAKES = {"wheelBrakes": (b"\x80", 5), "traction": "unavailable", "abs": "unavailable",
                       "scs": "unavailable", "brakeBoost": "unavailable", "auxBrakes": "unavailable"}


def _ms(value: float | None) -> int | None:
    """Milliseconds as an int; None and a Reserved code as they are."""
    return value if value is None or isinstance(value, scales.Reserved) else int(value)


def _emergency_to_asn1(info: EmergencyInfo, ssp_member: str) -> dict[str, Any]:
    for name, value, allowed in (("siren", info.siren, SIREN_STATES), ("lightbar", info.lightbar, LIGHTBAR_STATES),
                                 ("multi", info.multi, ("unavailable", "singleVehicle", "multiVehicle", "reserved"))):
        if value not in allowed:
            raise J2735Error(f"emergency.{name}: {value!r} is not one of {allowed}")
    if info.response_type is not None and info.response_type not in RESPONSE_TYPES:
        raise J2735Error(f"emergency.response_type: {info.response_type!r} is not one of {RESPONSE_TYPES}")
    if not isinstance(info.ssp_rights, int) or not 0 <= info.ssp_rights <= 31:
        raise J2735Error(f"emergency.ssp_rights: {info.ssp_rights!r} is outside 0..31")
    details: dict[str, Any] = {ssp_member: info.ssp_rights, "sirenUse": info.siren,
                               "lightsUse": info.lightbar, "multi": info.multi}
    if info.response_type is not None:
        details["responseType"] = info.response_type
    return details


def _emergency_from_asn1(details: dict[str, Any]) -> EmergencyInfo:
    return EmergencyInfo(siren=details["sirenUse"], lightbar=details["lightsUse"],
                         response_type=details.get("responseType"),
                         ssp_rights=next(details[m] for m in SSP_MEMBERS if m in details),
                         multi=details["multi"])


def surrogate_temporary_id(track_id: int, session_salt: bytes) -> bytes:
    """A 4-byte TemporaryID for a tracked vehicle that has no radio.

    Stable for the life of the track (receivers can follow it) and unlinkable
    across RSU sessions: the first 4 bytes of SHA-256(salt || track id). The
    salt is per RSU session (random in the field, from the seed in a run).
    """
    return hashlib.sha256(session_salt + int(track_id).to_bytes(8, "big", signed=True)).digest()[:4]


def surrogate_bsm(track_id: int, session_salt: bytes, **fields: Any) -> Bsm:
    """A BSM the RSU sends on behalf of a detected vehicle (SAE J2945/8 surrogate BSM).

    Sign it under `bridges.security.PSID_SURROGATE_BSM` (0x7F, the test PSID
    J2945/8 uses), never the BSM's 0x20: receivers must be able to tell a
    vehicle's own BSM from an RSU's estimate of a vehicle.
    """
    return Bsm(temporary_id=surrogate_temporary_id(track_id, session_salt), **fields)
