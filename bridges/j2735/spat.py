"""SPaT as a typed object: every movement event of every signal group, times in seconds, nothing dropped.

    spat = Spat.decode(frame_bytes)
    for ix in spat.intersections:
        for m in ix.movements:                  # one per signal group (MovementState)
            m.signal_group, m.state             # the current phase (m.events[0])
            for e in m.events:                  # the phases to come, in order (MovementEvent)
                e.state, e.min_end_s, e.likely_s, e.speeds

Time marks (TimeChangeDetails: start, minEnd, maxEnd, likely, next) are kept
as **seconds within the current UTC hour**, 0.1 s steps: the wire counts tenths
of a second from the top of the hour. Its codes beyond the hour depend on the
J2735 edition of the codec (bridges.j2735.editions): in 2020, 3600.0..3600.9 s
are the tenths of a leap second, 36010..36110 are reserved (kept as
`scales.Reserved`, sent back as received) and 36111 is "unknown"; in 2016,
3600.0 s means "more than an hour away" and 36001 is "unknown". "Unknown" reads
as None in both. `encode(codec)`/`decode(data, codec)` use the codec's edition,
`to_asn1(edition)`/`from_asn1(message, edition)` the one named (None: the
default codec's). `seconds_until(mark_s, unix_s)` turns a mark into seconds
from a moment, across the hour boundary. `MovementEvent.confidence` is the
TimeIntervalConfidence index (0..15) as sent.

Other units: advisory speeds in m/s (0.1 m/s steps; the wire's 500,
'unavailable', reads as None), zone lengths (advisory distances, queue and
storage lengths) in metres as sent. Enumerations are their J2735 names.

Decoding then encoding gives the received bytes back (every real SPaT in
tests/fixtures/interop/j2735_vectors.json, and generated ones): what the typed
fields do not model (extension additions, 'unavailable' codes of optional
elements) is kept verbatim in each object's `other` (see bridges.j2735.fields),
regional extensions in `regional`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from bridges.j2735 import fields as f
from bridges.j2735 import scales
from bridges.j2735.codec import J2735Codec, J2735Error, default_codec
from bridges.j2735.editions import Edition, edition as edition_named
from bridges.j2735.scales import Scale
from bridges.j2735.typed import Framed, Kept

MESSAGE_ID = 19
PHASE_STATES = ("unavailable", "dark", "stop-Then-Proceed", "stop-And-Remain", "pre-Movement",
                "permissive-Movement-Allowed", "protected-Movement-Allowed", "permissive-clearance",
                "protected-clearance", "caution-Conflicting-Traffic")
# IntersectionStatusObject bits 0..13 (16 bits on the wire)
STATUS_FLAGS = ("manualControlIsEnabled", "stopTimeIsActivated", "failureFlash", "preemptIsActive",
                "signalPriorityIsActive", "fixedTimeOperation", "trafficDependentOperation", "standbyOperation",
                "failureMode", "off", "recentMAPmessageUpdate", "recentChangeInMAPassignedLanesIDsUsed",
                "noValidMAPisAvailableAtThisTime", "noValidSPATisAvailableAtThisTime")
ADVISORY_SPEED_TYPES = ("none", "greenwave", "ecoDrive", "transit")
SPEED_CONFIDENCES = ("unavailable", "prec100ms", "prec10ms", "prec5ms", "prec1ms", "prec0-1ms", "prec0-05ms",
                     "prec0-01ms")
SPEED_ADVICE = Scale("advisory speed", "m/s", 0.1, 0, 499, unavailable=500)
ZONE_LENGTH = Scale("zone length", "m", 1.0, 0, 10000)
# TimeChangeDetails members, in wire order, and the typed field of each
TIME_MARKS = (("startTime", "start_s"), ("minEndTime", "min_end_s"), ("maxEndTime", "max_end_s"),
              ("likelyTime", "likely_s"), ("nextTime", "next_s"))


def _edition(edition: str | Edition | None) -> Edition:
    return edition_named(edition) if edition is not None else default_codec().edition


def seconds_until(mark_s: float, unix_s: float) -> float:
    """Seconds from the moment `unix_s` (POSIX time) to the time mark `mark_s` (seconds within a UTC hour),
    taking the occurrence of the mark nearest to that moment (-1800..+1800 s): a mark of 5.0 s read at
    hh:59:58 is 7 s away, in the next hour."""
    if isinstance(mark_s, scales.Reserved):
        raise J2735Error(f"time mark {mark_s!r} is a code the standard reserves, not a time")
    delta = (mark_s - unix_s % 3600.0) % 3600.0
    return delta - 3600.0 if delta >= 1800.0 else delta


def status_bits(*flags: str) -> tuple[bytes, int]:
    """An IntersectionStatusObject with the named flags set (names from STATUS_FLAGS)."""
    return f.names_to_bits(flags, STATUS_FLAGS, "status", 16)


# -- the typed message ----------------------------------------------------------------------------------
@dataclass
class AdvisorySpeed(Kept):
    """A speed advice for a movement event (e.g. a green wave)."""

    kind: str = "none"                     # AdvisorySpeedType name
    speed: float | None = None             # m/s; None: not sent (or sent as 'unavailable')
    confidence: str | None = None          # SpeedConfidence name
    distance: float | None = None          # m (ZoneLength) over which the advice applies
    restriction_class: int | None = None   # RestrictionClassID the advice is for
    regional: list[dict[str, Any]] | None = None
    other: dict[str, Any] | None = None    # kept verbatim (see bridges.j2735.fields)

    def _typed(self, where: str = "advisory speed") -> dict[str, Any]:
        out: dict[str, Any] = {"type": f.name(self.kind, ADVISORY_SPEED_TYPES, f"{where}: kind")}
        if self.speed is not None:
            out["speed"] = f.wire(SPEED_ADVICE, self.speed, f"{where}: speed")
        if self.confidence is not None:
            out["confidence"] = f.name(self.confidence, SPEED_CONFIDENCES, f"{where}: confidence")
        if self.distance is not None:
            out["distance"] = f.wire(ZONE_LENGTH, self.distance, f"{where}: distance")
        if self.restriction_class is not None:
            out["class"] = f.integer(self.restriction_class, 0, 255, f"{where}: restriction_class")
        if self.regional:
            out["regional"] = self.regional
        return out

    @classmethod
    def from_asn1(cls, v: dict[str, Any]) -> "AdvisorySpeed":
        speed = cls(kind=v["type"], speed=f.from_wire(SPEED_ADVICE, v.get("speed")), confidence=v.get("confidence"),
                    distance=f.from_wire(ZONE_LENGTH, v.get("distance")), restriction_class=v.get("class"),
                    regional=v.get("regional"))
        return speed._keep(v)


@dataclass
class MovementEvent:
    """One phase of a signal group and when it changes (times: seconds within the UTC hour, see the module)."""

    state: str                              # MovementPhaseState name
    min_end_s: float | None = None          # earliest end; None: unknown (the edition's code, if timing is sent)
    max_end_s: float | None = None          # latest end
    likely_s: float | None = None           # most likely end
    start_s: float | None = None            # when the phase started (or starts, for a future event)
    next_s: float | None = None             # when this phase is next expected to start again
    confidence: int | None = None           # TimeIntervalConfidence 0..15 of likely_s
    speeds: list[AdvisorySpeed] = field(default_factory=list)
    regional: list[dict[str, Any]] | None = None
    other: dict[str, Any] | None = None

    @property
    def timed(self) -> bool:
        """Whether a TimeChangeDetails is sent: any time mark or the confidence is known."""
        return self.confidence is not None or any(getattr(self, name) is not None for _, name in TIME_MARKS)

    def _typed(self, where: str, edition: Edition, received: dict[str, Any] | None = None) -> dict[str, Any]:
        out: dict[str, Any] = {"eventState": f.name(self.state, PHASE_STATES, f"{where}: state")}
        if self.timed:
            timing: dict[str, Any] = {}
            mark = scales.time_mark(edition)
            for key, attr in TIME_MARKS:
                value = getattr(self, attr)
                if value is not None or key == "minEndTime":  # minEndTime is mandatory: None sends 'unknown'
                    timing[key] = f.wire(mark, value, f"{where}: {attr}")
            if self.confidence is not None:
                timing["confidence"] = f.integer(self.confidence, 0, 15, f"{where}: confidence")
            out["timing"] = {k: timing[k] for k in ("startTime", "minEndTime", "maxEndTime", "likelyTime",
                                                     "confidence", "nextTime") if k in timing}
        if self.speeds:
            if len(self.speeds) > 16:
                raise J2735Error(f"{where}: speeds: at most 16 advisory speeds, got {len(self.speeds)}")
            out["speeds"] = _children(received, "speeds") or [s.to_asn1(f"{where}: speeds[{i}]")
                                                              for i, s in enumerate(self.speeds)]
        if self.regional:
            out["regional"] = self.regional
        return out

    def to_asn1(self, where: str = "movement event", edition: str | Edition | None = None) -> dict[str, Any]:
        return f.fill(self._typed(where, _edition(edition)), self.other)

    @classmethod
    def from_asn1(cls, v: dict[str, Any], edition: str | Edition | None = None) -> "MovementEvent":
        edition = _edition(edition)
        timing, mark = v.get("timing", {}), scales.time_mark(edition)
        marks = {attr: f.from_wire(mark, timing.get(key)) for key, attr in TIME_MARKS}
        event = cls(state=v["eventState"], confidence=timing.get("confidence"),
                    speeds=[AdvisorySpeed.from_asn1(s) for s in v.get("speeds", ())], regional=v.get("regional"),
                    **marks)
        event.other = f.residue(v, event._typed("movement event", edition, v))
        return event


@dataclass
class ManeuverAssist(Kept):
    """ConnectionManeuverAssist: queue and storage on one MAP connection (`connection_id`)."""

    connection_id: int
    queue_length: float | None = None             # m
    available_storage_length: float | None = None  # m
    wait_on_stop: bool | None = None
    ped_bicycle_detect: bool | None = None
    regional: list[dict[str, Any]] | None = None
    other: dict[str, Any] | None = None

    def _typed(self, where: str = "maneuver assist") -> dict[str, Any]:
        where = f"{where}: connection {self.connection_id}"
        out: dict[str, Any] = {"connectionID": f.integer(self.connection_id, 0, 255, f"{where}: connection_id")}
        if self.queue_length is not None:
            out["queueLength"] = f.wire(ZONE_LENGTH, self.queue_length, f"{where}: queue_length")
        if self.available_storage_length is not None:
            out["availableStorageLength"] = f.wire(ZONE_LENGTH, self.available_storage_length,
                                                   f"{where}: available_storage_length")
        for key, value in (("waitOnStop", self.wait_on_stop), ("pedBicycleDetect", self.ped_bicycle_detect)):
            if value is not None:
                if not isinstance(value, bool):
                    raise J2735Error(f"{where}: {key}: {value!r} is not True or False")
                out[key] = value
        if self.regional:
            out["regional"] = self.regional
        return out

    @classmethod
    def from_asn1(cls, v: dict[str, Any]) -> "ManeuverAssist":
        assist = cls(connection_id=v["connectionID"], queue_length=f.from_wire(ZONE_LENGTH, v.get("queueLength")),
                     available_storage_length=f.from_wire(ZONE_LENGTH, v.get("availableStorageLength")),
                     wait_on_stop=v.get("waitOnStop"), ped_bicycle_detect=v.get("pedBicycleDetect"),
                     regional=v.get("regional"))
        return assist._keep(v)


def _children(received: dict[str, Any] | None, key: str) -> list[dict[str, Any]] | None:
    """On decoding, the received values of a list of typed children: each child keeps its own residue, so its
    parent's residue need not build them again (that would rebuild every event once per level above it)."""
    return None if received is None else received.get(key)


def _assists(assists: list[ManeuverAssist] | None, where: str) -> list[dict[str, Any]]:
    if not 1 <= len(assists) <= 16:
        raise J2735Error(f"{where}: maneuver_assists: 1..16 entries, got {len(assists)}")
    return [a.to_asn1(where) for a in assists]


@dataclass(init=False)
class Movement:
    """One signal group's movement (MovementState): its events, the current one first.

    `Movement(2, "protected-Movement-Allowed", min_end_s=..., max_end_s=...)` is a signal group with one
    event; `Movement(2, events=[...])` gives several. `state`, `min_end_s`, `max_end_s` and `likely_s`
    read (and set) the current event, `events[0]`."""

    signal_group: int
    events: list[MovementEvent]
    name: str | None
    maneuver_assists: list[ManeuverAssist] | None
    regional: list[dict[str, Any]] | None
    other: dict[str, Any] | None

    def __init__(self, signal_group: int, state: str | None = None, min_end_s: float | None = None,
                 max_end_s: float | None = None, likely_s: float | None = None, *,
                 events: list[MovementEvent] | None = None, name: str | None = None,
                 maneuver_assists: list[ManeuverAssist] | None = None,
                 regional: list[dict[str, Any]] | None = None, other: dict[str, Any] | None = None):
        if events is None:
            if state is None:
                raise J2735Error(f"signal group {signal_group}: give its state or its events")
            events = [MovementEvent(state, min_end_s=min_end_s, max_end_s=max_end_s, likely_s=likely_s)]
        elif state is not None or min_end_s is not None or max_end_s is not None or likely_s is not None:
            raise J2735Error(f"signal group {signal_group}: give either state/min_end_s/max_end_s/likely_s "
                             "or events, not both")
        self.signal_group, self.events, self.name = signal_group, events, name
        self.maneuver_assists, self.regional, self.other = maneuver_assists, regional, other

    state = property(lambda self: self.events[0].state if self.events else None,
                     lambda self, value: setattr(self.events[0], "state", value),
                     doc="The current phase (events[0].state).")
    min_end_s = property(lambda self: self.events[0].min_end_s if self.events else None,
                         lambda self, value: setattr(self.events[0], "min_end_s", value))
    max_end_s = property(lambda self: self.events[0].max_end_s if self.events else None,
                         lambda self, value: setattr(self.events[0], "max_end_s", value))
    likely_s = property(lambda self: self.events[0].likely_s if self.events else None,
                        lambda self, value: setattr(self.events[0], "likely_s", value))

    def _typed(self, where: str, edition: Edition, received: dict[str, Any] | None = None) -> dict[str, Any]:
        group = f.integer(self.signal_group, 0, 255, f"{where}: signal_group")
        where = f"{where}: signal group {group}"
        if not 1 <= len(self.events) <= 16:
            raise J2735Error(f"{where}: events: 1..16 movement events, got {len(self.events)}")
        out: dict[str, Any] = {}
        if self.name is not None:
            out["movementName"] = f.text(self.name, f"{where}: name")
        out["signalGroup"] = group
        out["state-time-speed"] = _children(received, "state-time-speed") or [
            e.to_asn1(f"{where}: event {i}", edition) for i, e in enumerate(self.events)]
        if self.maneuver_assists is not None:
            out["maneuverAssistList"] = _children(received, "maneuverAssistList") or _assists(self.maneuver_assists,
                                                                                              where)
        if self.regional:
            out["regional"] = self.regional
        return out

    def to_asn1(self, where: str = "movement", edition: str | Edition | None = None) -> dict[str, Any]:
        return f.fill(self._typed(where, _edition(edition)), self.other)

    @classmethod
    def from_asn1(cls, v: dict[str, Any], edition: str | Edition | None = None) -> "Movement":
        edition = _edition(edition)
        assists = v.get("maneuverAssistList")
        movement = cls(v["signalGroup"], events=[MovementEvent.from_asn1(e, edition) for e in v["state-time-speed"]],
                       name=v.get("movementName"), regional=v.get("regional"),
                       maneuver_assists=None if assists is None else [ManeuverAssist.from_asn1(a) for a in assists])
        movement.other = f.residue(v, movement._typed("movement", edition, v))
        return movement


@dataclass
class IntersectionSignals:
    """One intersection's signal state (IntersectionState)."""

    intersection_id: int
    revision: int = 0
    moy: int | None = None              # minute of the year
    time_stamp_ms: int | None = None    # ms within the minute (DSecond)
    status: tuple[bytes, int] = (b"\x00\x00", 16)  # IntersectionStatusObject bits (see status_flags)
    movements: list[Movement] = field(default_factory=list)
    region: int | None = None           # road regulator id of the intersection id
    name: str | None = None
    enabled_lanes: list[int] | None = None   # MAP lane ids of revocable lanes now enabled
    maneuver_assists: list[ManeuverAssist] | None = None
    regional: list[dict[str, Any]] | None = None
    other: dict[str, Any] | None = None

    @property
    def status_flags(self) -> frozenset[str]:
        """The names (STATUS_FLAGS) of the status bits set."""
        return f.bits_to_names(self.status, STATUS_FLAGS)

    def movement(self, signal_group: int) -> Movement:
        for m in self.movements:
            if m.signal_group == signal_group:
                return m
        raise KeyError(f"intersection {self.intersection_id} has no signal group {signal_group} "
                       f"(groups: {sorted(m.signal_group for m in self.movements)})")

    def _typed(self, edition: Edition, received: dict[str, Any] | None = None) -> dict[str, Any]:
        where = f"intersection {self.intersection_id}"
        if not self.movements:
            raise J2735Error(f"{where}: at least one movement is required")
        if len(self.movements) > 255:
            raise J2735Error(f"{where}: movements: at most 255, got {len(self.movements)}")
        ref: dict[str, Any] = {}
        if self.region is not None:
            ref["region"] = f.integer(self.region, 0, 65535, f"{where}: region")
        ref["id"] = f.integer(self.intersection_id, 0, 65535, f"{where}: intersection_id")
        data, bits = self.status if isinstance(self.status, tuple) and len(self.status) == 2 else (None, None)
        if not isinstance(data, bytes) or bits != 16 or len(data) != 2:
            raise J2735Error(f"{where}: status: 16 bits as (2 bytes, 16) required, got {self.status!r} "
                             "(status_bits() makes one from flag names)")
        out: dict[str, Any] = {}
        if self.name is not None:
            out["name"] = f.text(self.name, f"{where}: name")
        out["id"] = ref
        out["revision"] = f.integer(self.revision, 0, 127, f"{where}: revision")
        out["status"] = self.status
        if self.moy is not None:
            out["moy"] = f.integer(self.moy, 0, 527040, f"{where}: moy")
        if self.time_stamp_ms is not None:
            out["timeStamp"] = f.integer(self.time_stamp_ms, 0, 65535, f"{where}: time_stamp_ms")
        if self.enabled_lanes is not None:
            if not 1 <= len(self.enabled_lanes) <= 16:
                raise J2735Error(f"{where}: enabled_lanes: 1..16 lane ids, got {len(self.enabled_lanes)}")
            out["enabledLanes"] = [f.integer(l, 0, 255, f"{where}: enabled_lanes") for l in self.enabled_lanes]
        out["states"] = _children(received, "states") or [m.to_asn1(where, edition) for m in self.movements]
        if self.maneuver_assists is not None:
            out["maneuverAssistList"] = _children(received, "maneuverAssistList") or _assists(self.maneuver_assists,
                                                                                              where)
        if self.regional:
            out["regional"] = self.regional
        return out

    def to_asn1(self, edition: str | Edition | None = None) -> dict[str, Any]:
        return f.fill(self._typed(_edition(edition)), self.other)

    @classmethod
    def from_asn1(cls, v: dict[str, Any], edition: str | Edition | None = None) -> "IntersectionSignals":
        edition = _edition(edition)
        assists = v.get("maneuverAssistList")
        signals = cls(intersection_id=v["id"]["id"], region=v["id"].get("region"), revision=v["revision"],
                      moy=v.get("moy"), time_stamp_ms=v.get("timeStamp"), status=v["status"],
                      movements=[Movement.from_asn1(m, edition) for m in v["states"]], name=v.get("name"),
                      enabled_lanes=list(v["enabledLanes"]) if "enabledLanes" in v else None,
                      maneuver_assists=None if assists is None else [ManeuverAssist.from_asn1(a) for a in assists],
                      regional=v.get("regional"))
        signals.other = f.residue(v, signals._typed(edition, v))
        return signals


@dataclass
class Spat(Framed):
    """SPAT: the signal state of one or more intersections; time marks in the codec's edition."""

    MESSAGE_ID, WHAT = MESSAGE_ID, "a SPaT"

    intersections: list[IntersectionSignals]
    moy: int | None = None               # SPAT.timeStamp: minute of the year
    name: str | None = None
    regional: list[dict[str, Any]] | None = None
    other: dict[str, Any] | None = None

    def _typed(self, edition: Edition, received: dict[str, Any] | None = None) -> dict[str, Any]:
        if not 1 <= len(self.intersections) <= 32:
            raise J2735Error(f"SPaT needs 1..32 intersections, got {len(self.intersections)}")
        message: dict[str, Any] = {}
        if self.moy is not None:
            message["timeStamp"] = f.integer(self.moy, 0, 527040, "moy")
        if self.name is not None:
            message["name"] = f.text(self.name, "name")
        message["intersections"] = _children(received, "intersections") or [i.to_asn1(edition)
                                                                               for i in self.intersections]
        if self.regional:
            message["regional"] = self.regional
        return message

    def to_asn1(self, edition: str | Edition | None = None) -> dict[str, Any]:
        """asn1tools values, time marks in `edition`'s codes (None: the default codec's edition)."""
        return f.fill(self._typed(_edition(edition)), self.other)

    def _to_wire(self, codec: J2735Codec) -> dict[str, Any]:
        return self.to_asn1(codec.edition)

    @classmethod
    def from_asn1(cls, message: dict[str, Any], edition: str | Edition | None = None) -> "Spat":
        """The typed SPaT of asn1tools values decoded in `edition` (None: the default codec's edition)."""
        edition = _edition(edition)
        spat = cls([IntersectionSignals.from_asn1(i, edition) for i in message["intersections"]],
                   moy=message.get("timeStamp"), name=message.get("name"), regional=message.get("regional"))
        spat.other = f.residue(message, spat._typed(edition, message))
        return spat

    @classmethod
    def _from_wire(cls, message: dict[str, Any], codec: J2735Codec) -> "Spat":
        return cls.from_asn1(message, codec.edition)
