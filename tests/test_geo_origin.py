"""The scenario's geodetic origin: `[world] origin`, carried to every app in the join reply, and its errors."""
from __future__ import annotations

import itertools
import threading
import time

import pytest

from bridges.geo import DEFAULT_ALT, DEFAULT_LAT, DEFAULT_LON, GeoError, GeoOrigin
from bridges.timesync.coordinator import Coordinator, Expected
from bridges.timesync.participant import Participant
from bridges.transport.memory import MemoryBus
from master.errors import ScenarioError
from master.scenario.loader import load_scenario

_ids = itertools.count()
BASE = """
[time]
stop = 1.0
step = 0.1
[fmus.car]
fmu = "{vehicle}"
[world.intersection]
arm_length = 60.0
"""


def test_world_origin_is_read_and_written_back(write_scenario, tmp_path):
    sc = load_scenario(write_scenario('[world]\norigin = { lat = 48.1, lon = 11.5, alt = 520.0 }\n' + BASE))
    assert sc.world.origin == GeoOrigin(48.1, 11.5, 520.0)
    assert sc.world.resolved()["origin"] == {"lat": 48.1, "lon": 11.5, "alt": 520.0}
    assert sc.world.describe()["origin"] == {"lat": 48.1, "lon": 11.5, "alt": 520.0}
    assert sc.world.describe()["intersection"]["arm_length"] == 60.0


def test_world_without_origin_gets_the_default(write_scenario):
    sc = load_scenario(write_scenario(BASE))
    assert sc.world.origin == GeoOrigin(DEFAULT_LAT, DEFAULT_LON, DEFAULT_ALT)


@pytest.mark.parametrize("origin,words", [
    ('{ lat = 91.0, lon = 0.0 }', "out of range"),
    ('{ lat = 10.0 }', "missing lon"),
    ('{ lat = 10.0, lon = 5.0, altitude = 3.0 }', "unknown key(s) altitude"),
    ('{ lat = "north", lon = 5.0 }', "lat must be a number"),
    ('"somewhere"', "expected a table"),
])
def test_bad_origin_is_refused_naming_the_key(write_scenario, origin, words):
    with pytest.raises(ScenarioError) as err:
        load_scenario(write_scenario(f"[world]\norigin = {origin}\n" + BASE))
    assert "world.origin" in str(err.value) and words in str(err.value)


def test_geo_origin_from_dict_round_trip_and_bad_values():
    o = GeoOrigin.from_dict({"lat": 42.0, "lon": -83.0})
    assert o.h0 == DEFAULT_ALT and GeoOrigin.from_dict(o.to_dict()) == o
    with pytest.raises(GeoError, match="finite"):
        GeoOrigin(float("nan"), 0.0)
    with pytest.raises(GeoError, match="height"):
        GeoOrigin(0.0, 0.0, 1e6)
    with pytest.raises(GeoError, match="must be numbers"):
        GeoOrigin(True, 0.0)


def test_join_reply_carries_the_world_to_the_app():
    prefix = f"test/geo-{next(_ids)}-{time.monotonic_ns()}"
    world = {"origin": {"lat": 48.1, "lon": 11.5, "alt": 520.0}, "intersection": {"road_width": 7.0}}
    master_bus, app_bus = MemoryBus(prefix=prefix, sender="master"), MemoryBus(prefix=prefix, sender="app")
    c = Coordinator(master_bus, [Expected("app")], heartbeat_s=0.05, heartbeat_timeout_s=0.5, world=world)
    c.start()
    p = Participant(app_bus, "app", "echo")
    joined = threading.Thread(target=p.join, args=(5,), daemon=True)
    joined.start()
    try:
        c.wait_for_participants(5)
        joined.join(5)
        assert p.origin == GeoOrigin(48.1, 11.5, 520.0)
        assert p.world["intersection"] == {"road_width": 7.0}
        lat, lon, _ = p.origin.to_geodetic(0.0, 0.0)
        assert lat == pytest.approx(48.1) and lon == pytest.approx(11.5)
    finally:
        c.end("completed")
        p.close()
        c.close()
        master_bus.close()
        app_bus.close()


def test_participant_before_joining_has_no_origin():
    bus = MemoryBus(prefix=f"test/geo-{next(_ids)}", sender="app")
    try:
        p = Participant(bus, "app", "echo")
        assert p.origin is None and p.world == {}
        p.close()
    finally:
        bus.close()
