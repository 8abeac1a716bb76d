"""SPaT as a typed object: each signal group's phase state and its time marks in seconds.

J2735 time marks count tenths of a second within the current UTC hour
(36001: unknown); `Movement` keeps them as seconds within the hour.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from bridges.j2735 import scales
from bridges.j2735.codec import J2735Codec, J2735Error, default_codec

PHASE_STATES = ("unavailable", "dark", "stop-Then-Proceed", "stop-And-Remain", "pre-Movement",
                "permissive-Movement-Allowed", "protected-Movement-Allowed", "permissive-clearance",
                "protected-clearance", "caution-Conflicting-Traffic")


@dataclass
class Movement:
    signal_group: int
    state: str                          # a MovementPhaseState name
    min_end_s: float | None = None      # seconds within the hour
    max_end_s: float | None = None
    likely_s: float | None = None


@dataclass
class IntersectionSignals:
    intersection_id: int
    revision: int = 0
    moy: int | None = None              # minute of the year
    time_stamp_ms: int | None = None    # ms within the minute
    status: tuple[bytes, int] = (b"\x00\x00", 16)  # IntersectionStatusObject bits
    movements: list[Movement] = field(default_factory=list)
    region: int | None = None


@dataclass
class Spat:
    intersections: list[IntersectionSignals]
    moy: int | None = None

    def to_asn1(self) -> dict[str, Any]:
        if not self.intersections:
            raise J2735Error("SPaT needs at least one intersection")
        message: dict[str, Any] = {"intersections": [_intersection(i) for i in self.intersections]}
        if self.moy is not None:
            message["timeStamp"] = self.moy
        return message

    def encode(self, codec: J2735Codec | None = None) -> bytes:
        return (codec or default_codec()).encode(19, self.to_asn1())

    @classmethod
    def from_asn1(cls, message: dict[str, Any]) -> "Spat":
        return cls([_intersection_from(i) for i in message["intersections"]], message.get("timeStamp"))

    @classmethod
    def decode(cls, data: bytes, codec: J2735Codec | None = None) -> "Spat":
        frame = (codec or default_codec()).decode(data)
        if frame.message_id != 19:
            raise J2735Error(f"messageId {frame.message_id} is not a SPaT (19)")
        return cls.from_asn1(frame.message)


def _intersection(signals: IntersectionSignals) -> dict[str, Any]:
    if not signals.movements:
        raise J2735Error(f"intersection {signals.intersection_id}: at least one movement is required")
    ref: dict[str, Any] = {"id": signals.intersection_id}
    if signals.region is not None:
        ref["region"] = signals.region
    state: dict[str, Any] = {"id": ref, "revision": signals.revision, "status": signals.status,
                             "states": [_movement(m) for m in signals.movements]}
    if signals.moy is not None:
        state["moy"] = signals.moy
    if signals.time_stamp_ms is not None:
        state["timeStamp"] = signals.time_stamp_ms
    return state


def _movement(movement: Movement) -> dict[str, Any]:
    if movement.state not in PHASE_STATES:
        raise J2735Error(f"signal group {movement.signal_group}: state {movement.state!r} is not one of {PHASE_STATES}")
    event: dict[str, Any] = {"eventState": movement.state}
    if movement.min_end_s is not None or movement.max_end_s is not None or movement.likely_s is not None:
        timing = {"minEndTime": scales.TIME_MARK.to_wire(movement.min_end_s)}
        if movement.max_end_s is not None:
            timing["maxEndTime"] = scales.TIME_MARK.to_wire(movement.max_end_s)
        if movement.likely_s is not None:
            timing["likelyTime"] = scales.TIME_MARK.to_wire(movement.likely_s)
        event["timing"] = timing
    return {"signalGroup": movement.signal_group, "state-time-speed": [event]}


def _intersection_from(state: dict[str, Any]) -> IntersectionSignals:
    movements = []
    for movement in state["states"]:
        event = movement["state-time-speed"][0]
        timing = event.get("timing", {})
        movements.append(Movement(
            signal_group=movement["signalGroup"], state=event["eventState"],
            min_end_s=scales.TIME_MARK.from_wire(timing["minEndTime"]) if "minEndTime" in timing else None,
            max_end_s=scales.TIME_MARK.from_wire(timing["maxEndTime"]) if "maxEndTime" in timing else None,
            likely_s=scales.TIME_MARK.from_wire(timing["likelyTime"]) if "likelyTime" in timing else None))
    return IntersectionSignals(intersection_id=state["id"]["id"], revision=state["revision"],
                               moy=state.get("moy"), time_stamp_ms=state.get("timeStamp"),
                               status=state["status"], movements=movements, region=state["id"].get("region"))
