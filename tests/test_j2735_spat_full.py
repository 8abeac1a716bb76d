"""The typed SPaT keeps everything (bridges/j2735/spat.py).

Every real SPaT in tests/fixtures/interop/j2735_vectors.json decodes into the
typed form and encodes back to the same bytes; so do generated SPaTs that use
every element of the message (several events per signal group, all time
marks, advisory speeds, maneuver assists, enabled lanes, names, regional
extensions, 'unavailable' codes). Typed SPaTs survive the wire unchanged;
times are seconds within the UTC hour, checked against a deployed message by
hand; values the wire cannot carry are refused naming the field.
"""
from __future__ import annotations

import json

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bridges.j2735 import EDITIONS, J2735Codec, J2735Error, default_codec
from bridges.j2735.scales import Reserved
from bridges.j2735.spat import (ADVISORY_SPEED_TYPES, PHASE_STATES, SPEED_CONFIDENCES, AdvisorySpeed,
                                IntersectionSignals, ManeuverAssist, Movement, MovementEvent, Spat, seconds_until,
                                status_bits)

from conftest import fixture_path

VECTORS = json.loads(fixture_path("interop/j2735_vectors.json").read_text())
SPATS = [v for v in VECTORS if v["message"] == "SPaT"]


def test_the_fixture_holds_real_spats():
    assert len(SPATS) >= 10


@pytest.mark.parametrize("edition", sorted(EDITIONS))
@pytest.mark.parametrize("index", range(len(SPATS)))
def test_real_spat_reencodes_to_the_same_bytes_with_every_event_typed(index, edition):
    data = bytes.fromhex(SPATS[index]["hex"])
    codec = J2735Codec(edition=edition)
    frame = codec.decode(data)
    spat = Spat.decode(data, codec)
    assert spat.encode(codec) == data[:frame.length], SPATS[index]["source"]
    # everything in these messages is typed: nothing had to be kept verbatim
    assert spat.other is None
    for raw, ix in zip(frame.message["intersections"], spat.intersections):
        assert ix.other is None and ix.name == raw.get("name")
        assert [m.signal_group for m in ix.movements] == [s["signalGroup"] for s in raw["states"]]
        for raw_state, m in zip(raw["states"], ix.movements):
            assert len(m.events) == len(raw_state["state-time-speed"]) and m.other is None
            for raw_event, e in zip(raw_state["state-time-speed"], m.events):
                assert e.state == raw_event["eventState"] and e.other is None
                timing = raw_event.get("timing", {})
                for key, attr in (("startTime", "start_s"), ("minEndTime", "min_end_s"),
                                  ("maxEndTime", "max_end_s"), ("likelyTime", "likely_s"), ("nextTime", "next_s")):
                    assert getattr(e, attr) == (timing[key] / 10 if key in timing else None), key
                assert e.confidence == timing.get("confidence")


def test_seconds_of_a_deployed_spat_by_hand():
    """V2X-Hub's encodeSpat test message: first movement is signal group 8, stop-And-Remain, startTime 32486,
    min/maxEndTime 32558 tenths of a second in the hour (published beside the bytes), likely/next 0."""
    vector = next(v for v in SPATS if (v["expected"] or {}).get("intersections", [{}])[0].get("id") == 9001)
    published = vector["expected"]["intersections"][0]
    spat = Spat.decode(bytes.fromhex(vector["hex"]))
    ix = spat.intersections[0]
    assert (ix.intersection_id, ix.revision, ix.moy, ix.time_stamp_ms) == (9001, 120, 316554, 8609)
    assert ix.name == "WestIntersection" and spat.moy == published["moy"]
    m = ix.movements[0]
    assert m.signal_group == 8 and m.state == "stop-And-Remain"
    e = m.events[0]
    assert e.start_s == 3248.6 and e.min_end_s == 3255.8 and e.max_end_s == 3255.8  # 54 min 8.6 s, 55 min 15.8 s
    assert (e.likely_s, e.confidence, e.next_s) == (0.0, 0, 0.0)
    assert m.min_end_s == 3255.8 and m.max_end_s == 3255.8  # the current event's, as before


def test_seconds_until_crosses_the_hour():
    hour = 1_700_000_000 - 1_700_000_000 % 3600
    assert seconds_until(5.0, hour + 3598.0) == pytest.approx(7.0)      # 5 s into the next hour
    assert seconds_until(3590.0, hour + 3.0) == pytest.approx(-13.0)    # 10 s before the top of this hour
    assert seconds_until(100.0, hour + 40.0) == pytest.approx(60.0)


def test_several_events_speeds_and_assists_survive_the_wire():
    spat = Spat([IntersectionSignals(
        1201, revision=3, moy=400000, time_stamp_ms=1500, status=status_bits("fixedTimeOperation"),
        name="Main & 1st", enabled_lanes=[3, 7], region=26,
        maneuver_assists=[ManeuverAssist(4, queue_length=35.0, wait_on_stop=True)],
        movements=[
            Movement(2, events=[
                MovementEvent("protected-Movement-Allowed", start_s=1200.0, min_end_s=1234.5, max_end_s=1240.0,
                              likely_s=1236.2, confidence=12, next_s=1300.0,
                              speeds=[AdvisorySpeed("greenwave", speed=13.9, confidence="prec1ms", distance=250.0,
                                                    restriction_class=2)]),
                MovementEvent("protected-clearance", start_s=1236.2, min_end_s=1240.2),
                MovementEvent("stop-And-Remain", min_end_s=1270.0)],
                name="northbound through",
                maneuver_assists=[ManeuverAssist(1, available_storage_length=80.0, ped_bicycle_detect=False)]),
            Movement(4, "stop-And-Remain", max_end_s=1250.2),
            Movement(6, "dark")])], moy=400000, name="corridor 7")
    data = spat.encode()
    back = Spat.decode(data)
    assert back == spat
    assert back.encode() == data
    m = back.intersections[0].movements[0]
    assert [e.state for e in m.events] == ["protected-Movement-Allowed", "protected-clearance", "stop-And-Remain"]
    assert m.events[0].speeds[0].speed == pytest.approx(13.9)
    assert back.intersections[0].status_flags == frozenset({"fixedTimeOperation"})
    raw = default_codec().decode(data).message["intersections"][0]
    assert raw["states"][0]["state-time-speed"][0]["timing"] == {
        "startTime": 12000, "minEndTime": 12345, "maxEndTime": 12400, "likelyTime": 12362, "confidence": 12,
        "nextTime": 13000}
    assert raw["states"][0]["state-time-speed"][0]["speeds"] == [
        {"type": "greenwave", "speed": 139, "confidence": "prec1ms", "distance": 250, "class": 2}]
    # a max end alone still sends TimeChangeDetails, with the mandatory minEndTime 'unknown'
    unknown = default_codec().edition.time_mark_unknown
    assert raw["states"][1]["state-time-speed"][0]["timing"] == {"minEndTime": unknown, "maxEndTime": 12502}
    assert "timing" not in raw["states"][2]["state-time-speed"][0]


@pytest.mark.parametrize("edition", sorted(EDITIONS))
def test_unavailable_codes_read_as_none_and_are_sent_again(edition):
    codec = J2735Codec(edition=edition)
    unknown = codec.edition.time_mark_unknown  # 2016: 36001, 2020: 36111
    raw = {"intersections": [{"id": {"id": 5}, "revision": 0, "status": (b"\0\0", 16), "states": [
        {"signalGroup": 1, "state-time-speed": [
            {"eventState": "dark", "timing": {"minEndTime": unknown}},
            {"eventState": "dark", "timing": {"minEndTime": 100, "nextTime": unknown},
             "speeds": [{"type": "ecoDrive", "speed": 500}]}]}]}]}
    data = codec.encode(19, raw)
    spat = Spat.decode(data, codec)
    first, second = spat.intersections[0].movements[0].events
    assert first.min_end_s is None and not first.timed and first.other == {"timing": {"minEndTime": unknown}}
    assert second.next_s is None and second.other == {"timing": {"nextTime": unknown}}
    assert second.speeds[0].speed is None and second.speeds[0].other == {"speed": 500}
    assert spat.encode(codec) == data
    second.speeds[0].speed = 8.0  # a typed value set by the user wins over the kept code
    assert codec.decode(spat.encode(codec)).message["intersections"][0]["states"][0]["state-time-speed"][1][
        "speeds"] == [{"type": "ecoDrive", "speed": 80}]


def test_editions_differ_in_the_codes_beyond_the_hour():
    """2016: 36001 is unknown; 2020: 36001 is 3600.1 s (a leap second's tenth), 36050 reserved, 36111 unknown."""
    raw = {"intersections": [{"id": {"id": 5}, "revision": 0, "status": (b"\0\0", 16), "states": [
        {"signalGroup": 1, "state-time-speed": [{"eventState": "dark", "timing": {
            "startTime": 36050, "minEndTime": 36001, "maxEndTime": 36009}}]}]}]}
    new = J2735Codec(edition="2020")
    data = new.encode(19, raw)
    event = Spat.decode(data, new).intersections[0].movements[0].events[0]
    assert event.min_end_s == 3600.1 and event.max_end_s == 3600.9
    assert event.start_s == Reserved(36050) and isinstance(event.start_s, Reserved)
    assert Spat.decode(data, new).encode(new) == data
    with pytest.raises(J2735Error, match="reserves"):
        seconds_until(event.start_s, 0.0)
    old = J2735Codec(edition="2016")
    del raw["intersections"][0]["states"][0]["state-time-speed"][0]["timing"]["startTime"]
    raw["intersections"][0]["states"][0]["state-time-speed"][0]["timing"]["maxEndTime"] = 36000
    data = old.encode(19, raw)
    event = Spat.decode(data, old).intersections[0].movements[0].events[0]
    assert event.min_end_s is None and event.max_end_s == 3600.0
    assert Spat.decode(data, old).encode(old) == data
    # the same typed event in each edition: 'unknown' is each edition's own code
    typed = Spat([IntersectionSignals(5, movements=[Movement(1, "dark", max_end_s=12.0)])])
    for codec in (old, new):
        timing = codec.decode(typed.encode(codec)).message["intersections"][0]["states"][0]["state-time-speed"][0][
            "timing"]
        assert timing == {"minEndTime": codec.edition.time_mark_unknown, "maxEndTime": 120}


def test_the_existing_api_still_reads_the_current_event():
    m = Movement(2, "protected-Movement-Allowed", min_end_s=10.0, likely_s=12.0)
    assert (m.state, m.min_end_s, m.max_end_s, m.likely_s) == ("protected-Movement-Allowed", 10.0, None, 12.0)
    m.state = "protected-clearance"
    assert m.events[0].state == "protected-clearance" and len(m.events) == 1
    with pytest.raises(J2735Error, match="either state"):
        Movement(2, "dark", events=[MovementEvent("dark")])
    with pytest.raises(J2735Error, match="give its state or its events"):
        Movement(2)


def _spat_with(**changes) -> Spat:
    event = MovementEvent("stop-And-Remain", min_end_s=10.0, speeds=[AdvisorySpeed("greenwave", speed=10.0)])
    movement = Movement(3, events=[event], maneuver_assists=[ManeuverAssist(1, queue_length=5.0)])
    ix = IntersectionSignals(77, movements=[movement])
    for path, value in changes.items():
        target, attr = {"event": event, "movement": movement, "ix": ix, "speed": event.speeds[0],
                        "assist": movement.maneuver_assists[0]}[path.split(".")[0]], path.split(".")[1]
        setattr(target, attr, value)
    return Spat([ix])


@pytest.mark.parametrize("change,match", [
    ({"event.min_end_s": 3601.0},
     r"intersection 77: signal group 3: event 0: min_end_s: time mark: 3601 s is outside"),
    ({"event.likely_s": -1.0}, r"event 0: likely_s: time mark: -1 s is outside"),
    ({"event.confidence": 16}, r"event 0: confidence: 16 is outside 0\.\.15"),
    ({"event.state": "green"}, r"event 0: state 'green' is not a known value"),
    ({"speed.speed": 50.0}, r"speeds\[0\]: speed: advisory speed: 50 m/s is outside 0\.\.49\.9 m/s"),
    ({"speed.kind": "greenWave"}, r"speeds\[0\]: kind 'greenWave' is not a known value; did you mean 'greenwave'"),
    ({"assist.queue_length": 10001.0}, r"connection 1: queue_length: zone length: 10001 m is outside 0\.\.10000 m"),
    ({"movement.signal_group": 256}, r"intersection 77: signal_group: 256 is outside 0\.\.255"),
    ({"movement.events": []}, r"signal group 3: events: 1\.\.16 movement events, got 0"),
    ({"ix.revision": 128}, r"intersection 77: revision: 128 is outside 0\.\.127"),
    ({"ix.intersection_id": 70000}, r"intersection 70000: intersection_id: 70000 is outside 0\.\.65535"),
    ({"ix.enabled_lanes": list(range(17))}, r"enabled_lanes: 1\.\.16 lane ids, got 17"),
    ({"ix.status": (b"\0", 8)}, r"intersection 77: status: 16 bits"),
    ({"ix.name": "é"}, r"intersection 77: name: 'é' is not ASCII text"),
    ({"ix.movements": []}, r"intersection 77: at least one movement is required"),
])
def test_values_the_wire_cannot_carry_are_refused_naming_the_field(change, match):
    with pytest.raises(J2735Error, match=match):
        _spat_with(**change).encode()


def test_a_map_is_not_a_spat():
    vector = next(v for v in VECTORS if v["message"] == "MAP")
    with pytest.raises(J2735Error, match="messageId 18 is not a SPaT"):
        Spat.decode(bytes.fromhex(vector["hex"]))


# -- generated messages -----------------------------------------------------------------------------------
optional = lambda strategy: st.one_of(st.none(), strategy)  # noqa: E731
ia5 = st.text(st.characters(min_codepoint=32, max_codepoint=126), min_size=1, max_size=12)
regional = st.lists(st.fixed_dictionaries({"regionId": st.integers(0, 255),
                                           "regExtValue": st.binary(min_size=1, max_size=4)}), min_size=1, max_size=2)


def raw_spats(time_mark_max: int):
    """asn1tools SPAT values using every element, time marks 0..time_mark_max (the edition's TimeMark)."""
    codes_beyond_the_hour = [c for c in (36000, 36001, 36009, 36010, 36050, 36110, 36111) if c <= time_mark_max]
    time_mark = st.one_of(st.integers(0, time_mark_max), st.sampled_from(codes_beyond_the_hour))
    raw_timing = st.fixed_dictionaries({"minEndTime": time_mark}, optional={
        "startTime": time_mark, "maxEndTime": time_mark, "likelyTime": time_mark, "confidence": st.integers(0, 15),
        "nextTime": time_mark})
    raw_event = st.fixed_dictionaries({"eventState": st.sampled_from(PHASE_STATES)}, optional={
        "timing": raw_timing, "speeds": st.lists(raw_speed, min_size=1, max_size=3), "regional": regional})
    raw_movement = st.fixed_dictionaries(
        {"signalGroup": st.integers(0, 255), "state-time-speed": st.lists(raw_event, min_size=1, max_size=4)},
        optional={"movementName": ia5, "maneuverAssistList": st.lists(raw_assist, min_size=1, max_size=2),
                  "regional": regional})
    raw_intersection = st.fixed_dictionaries(
        {"id": st.fixed_dictionaries({"id": st.integers(0, 65535)}, optional={"region": st.integers(0, 65535)}),
         "revision": st.integers(0, 127), "status": st.binary(min_size=2, max_size=2).map(lambda b: (b, 16)),
         "states": st.lists(raw_movement, min_size=1, max_size=4)},
        optional={"name": ia5, "moy": st.integers(0, 527040), "timeStamp": st.integers(0, 65535),
                  "enabledLanes": st.lists(st.integers(0, 255), min_size=1, max_size=16),
                  "maneuverAssistList": st.lists(raw_assist, min_size=1, max_size=2), "regional": regional})
    return st.fixed_dictionaries({"intersections": st.lists(raw_intersection, min_size=1, max_size=2)},
                                 optional={"timeStamp": st.integers(0, 527040), "name": ia5, "regional": regional})


raw_speed = st.fixed_dictionaries({"type": st.sampled_from(ADVISORY_SPEED_TYPES)}, optional={
    "speed": st.integers(0, 500), "confidence": st.sampled_from(SPEED_CONFIDENCES), "distance": st.integers(0, 10000),
    "class": st.integers(0, 255), "regional": regional})
raw_assist = st.fixed_dictionaries({"connectionID": st.integers(0, 255)}, optional={
    "queueLength": st.integers(0, 10000), "availableStorageLength": st.integers(0, 10000),
    "waitOnStop": st.booleans(), "pedBicycleDetect": st.booleans(), "regional": regional})
def _check_generated(raw, codec):
    data = codec.encode(19, raw)
    spat = Spat.decode(data, codec)
    assert spat.encode(codec) == data
    unknown, reserved = codec.edition.time_mark_unknown, codec.edition.time_mark_reserved or (1, 0)
    for raw_ix, ix in zip(raw["intersections"], spat.intersections):
        assert ix.enabled_lanes == raw_ix.get("enabledLanes")
        for raw_state, m in zip(raw_ix["states"], ix.movements):
            assert m.signal_group == raw_state["signalGroup"] and m.name == raw_state.get("movementName")
            assert [e.state for e in m.events] == [e["eventState"] for e in raw_state["state-time-speed"]]
            for raw_event, e in zip(raw_state["state-time-speed"], m.events):
                wire = raw_event.get("timing", {}).get("minEndTime")
                if wire is not None and reserved[0] <= wire <= reserved[1]:
                    assert e.min_end_s == Reserved(wire)
                else:
                    assert e.min_end_s == (None if wire in (None, unknown) else wire / 10)
                assert [s.kind for s in e.speeds] == [s["type"] for s in raw_event.get("speeds", ())]


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(raw_spats(EDITIONS["2020"].time_mark_max))
def test_generated_2020_spats_using_every_element_reencode_to_the_same_bytes(raw):
    _check_generated(raw, J2735Codec(edition="2020"))


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(raw_spats(EDITIONS["2016"].time_mark_max))
def test_generated_2016_spats_using_every_element_reencode_to_the_same_bytes(raw):
    _check_generated(raw, J2735Codec(edition="2016"))


tenths = st.integers(0, 36000).map(lambda t: t / 10)
typed_speed = st.builds(AdvisorySpeed, kind=st.sampled_from(ADVISORY_SPEED_TYPES),
                        speed=optional(st.integers(0, 499).map(lambda v: v / 10)),
                        confidence=optional(st.sampled_from(SPEED_CONFIDENCES)),
                        distance=optional(st.integers(0, 10000).map(float)),
                        restriction_class=optional(st.integers(0, 255)))
typed_event = st.builds(MovementEvent, state=st.sampled_from(PHASE_STATES), min_end_s=optional(tenths),
                        max_end_s=optional(tenths), likely_s=optional(tenths), start_s=optional(tenths),
                        next_s=optional(tenths), confidence=optional(st.integers(0, 15)),
                        speeds=st.lists(typed_speed, max_size=2))
typed_movement = st.builds(lambda group, events, name: Movement(group, events=events, name=name),
                           st.integers(0, 255), st.lists(typed_event, min_size=1, max_size=3), optional(ia5))
typed_spats = st.builds(
    lambda movements, ix_id, moy, lanes: Spat([IntersectionSignals(ix_id, moy=moy, movements=movements,
                                                                   enabled_lanes=lanes)]),
    st.lists(typed_movement, min_size=1, max_size=4), st.integers(0, 65535), optional(st.integers(0, 527040)),
    optional(st.lists(st.integers(0, 255), min_size=1, max_size=16)))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(typed_spats)
def test_generated_typed_spats_come_back_equal(spat):
    data = spat.encode()
    back = Spat.decode(data)
    assert back == spat
    assert back.encode() == data
