"""The typed MAP keeps everything (bridges/j2735/map.py), beyond the deployed MAPs of test_j2735_map.py.

Generated MAPs that use every element (node offsets of all six widths,
latitude/longitude and regional nodes, every node attribute, computed lanes
with either offset size and any rotation, connections, speed limits,
'unavailable' codes, regional extensions) re-encode to the same bytes; typed
MAPs built in metres survive the wire to the centimetre. Lanes come out as
polylines in metres checked by hand against real MAPs, and latitude/longitude
nodes land where an independent ellipsoid computation puts them.
"""
from __future__ import annotations

import json
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bridges.j2735 import J2735Error, default_codec
from bridges.j2735.map import (LANE_TYPES, MANEUVERS, ComputedLane, Connection, IntersectionGeometry, Lane, MapData,
                               Node)

from conftest import fixture_path

VECTORS = json.loads(fixture_path("interop/j2735_vectors.json").read_text())
MAPS = [v for v in VECTORS if v["message"] == "MAP"]


def _flat(polyline) -> list[float]:
    return [v for point in polyline for v in point]


def _real(source_end: str) -> MapData:
    (vector,) = [v for v in MAPS if v["source"].endswith(source_end)]
    return MapData.decode(bytes.fromhex(vector["hex"]))


# -- real MAPs in metres, by hand -------------------------------------------------------------------------
def test_carma_map_first_lane_in_metres():
    """carma-messenger's MAP: lane 1 starts with node-XY3 (-523, -1294) cm, then node-XY2 (-360, -724) cm."""
    m = _real("test_MapMessage.cpp")
    g = m.intersections[0]
    assert (g.intersection_id, g.ref_latitude, g.ref_longitude, g.ref_elevation) == (9709, 38.9549844, -77.1493239,
                                                                                     39.0)
    assert g.lane_width == 2.74
    lane = g.lanes[0]
    assert lane.lane_id == 1 and lane.ingress and not lane.egress and lane.lane_type == "vehicle"
    assert lane.polyline[:2] == [(-5.23, -12.94), (-8.83, -20.18)]   # -523 cm; -523 - 360 = -883 cm ...
    assert lane.nodes[0].d_elevation == 1.0                          # dElevation 10 x 10 cm
    assert [(c.lane, c.signal_group) for c in lane.connections] == [(6, 2), (7, 2), (8, 2)]
    assert lane.type_attributes == (b"", 0)  # the zero-length vehicle attribute string it sends, kept


def test_ode_map_first_lane_in_metres():
    """JPO ODE's decoder-output MAP: lane 2 starts node-XY6 (2225, 808) cm, then (10517, -161) cm."""
    g = _real("decoder-output-map.xml").intersections[0]
    lane = g.lanes[0]
    assert lane.lane_id == 2 and lane.polyline[:2] == [(22.25, 8.08), (127.42, 6.47)]
    assert [n.d_elevation for n in lane.nodes[:2]] == [-1.0, -6.0]
    (first, *_) = lane.connections
    assert (first.lane, first.signal_group, first.connection_id, first.maneuvers) == (19, 4, 1,
                                                                                       frozenset({"straight"}))


def test_utah_map_uses_every_offset_width_and_reads_in_metres():
    """A Utah deployment's MAP (JPO ODE asn1_codec batch): lane 1 starts node-XY4 (2205, 2195) cm, then
    node-XY5 (6861, -101) cm; its connection to lane 31 carries maneuver bit 10 (caution)."""
    g = _real("batch-json.http (line 6)").intersections[0]
    lane = g.lanes[0]
    assert lane.polyline[:2] == [(22.05, 21.95), (90.66, 20.94)]
    assert lane.connections[0].lane == 31 and lane.connections[0].maneuvers == frozenset({"caution"})
    widths = {n.delta_choice for m in MAPS for l in MapData.decode(bytes.fromhex(m["hex"])).intersections[0].lanes
              for n in l.nodes}
    assert widths == {"node-XY1", "node-XY2", "node-XY3", "node-XY4", "node-XY5", "node-XY6"}


# -- latitude/longitude nodes, regional nodes, computed lanes ---------------------------------------------
A, F = 6378137.0, 1 / 298.257223563  # WGS-84
E2 = F * (2 - F)


def _metres_per_degree(lat_deg: float) -> tuple[float, float]:
    """(east per degree of longitude, north per degree of latitude) at lat_deg on WGS-84: N cos(lat), M."""
    s = math.sin(math.radians(lat_deg))
    n = A / math.sqrt(1 - E2 * s * s)
    m = A * (1 - E2) / (1 - E2 * s * s) ** 1.5
    return n * math.cos(math.radians(lat_deg)) * math.pi / 180, m * math.pi / 180


def _raw_map(nodes, ref=None):
    ref = ref or {"lat": 420000000, "long": -830000000}
    lane = {"laneID": 1, "laneAttributes": {"directionalUse": (b"\x80", 2), "sharedWith": (b"\0\0", 10),
                                            "laneType": ("vehicle", (b"\0", 8))}, "nodeList": ("nodes", nodes)}
    return {"msgIssueRevision": 1, "intersections": [{"id": {"id": 3}, "revision": 0, "refPoint": ref,
                                                      "laneSet": [lane]}]}


def test_latlon_nodes_are_placed_in_metres_and_the_next_offset_continues_from_them():
    codec = default_codec()
    nodes = [{"delta": ("node-LatLon", {"lat": 420010000, "lon": -829990000})},  # +0.001 deg north and east
             {"delta": ("node-XY1", {"x": 100, "y": -50})}]
    data = codec.encode(18, _raw_map(nodes))
    m = MapData.decode(data)
    first, second = m.intersections[0].lanes[0].nodes
    east, north = _metres_per_degree(42.0005)  # mid-latitude of the step
    assert first.latlon == (42.001, -82.999)
    assert first.x == pytest.approx(0.001 * east, abs=0.02) and first.y == pytest.approx(0.001 * north, abs=0.02)
    assert (second.x, second.y) == pytest.approx((round(first.x, 2) + 1.0, round(first.y, 2) - 0.5))
    assert m.intersections[0].geodetic(first.x, first.y) == pytest.approx((42.001, -82.999), abs=1e-9)
    assert m.encode() == data


def test_regional_offsets_and_unavailable_codes_are_kept():
    codec = default_codec()
    nodes = [{"delta": ("node-XY2", {"x": 300, "y": 400})},
             {"delta": ("regional", {"regionId": 9, "regExtValue": b"\x01\x02"})},
             {"delta": ("node-LatLon", {"lat": 900000001, "lon": 1800000001})},
             {"delta": ("node-XY1", {"x": -10, "y": 0}), "attributes": {}}]
    raw = _raw_map(nodes, ref={"lat": 420000000, "long": -830000000, "elevation": -4096})
    data = codec.encode(18, raw)
    g = MapData.decode(data).intersections[0]
    lane = g.lanes[0]
    assert lane.nodes[1].regional_offset == {"regionId": 9, "regExtValue": b"\x01\x02"}
    assert lane.polyline == [(3.0, 4.0), (3.0, 4.0), (3.0, 4.0), (2.9, 4.0)]  # unplaceable nodes repeat the last
    assert lane.nodes[2].latlon == (None, None) and g.ref_elevation is None
    assert MapData.decode(data).encode() == data


def test_computed_lanes_keep_their_offset_size_and_rotation_code():
    g = IntersectionGeometry(5, 42.0, -83.0, None, [
        Lane(1, [Node(0.0, -5.0), Node(0.0, -50.0)], ingress=True),
        Lane(2, computed=ComputedLane(1, offset_x=3.5, offset_y=0.0, rotation_deg=360.0,
                                      offset_choices=("large", "small"))),
        Lane(3, computed=ComputedLane(9, offset_x=-3.5, offset_y=0.0))])  # no lane 9: kept, not resolved
    with pytest.raises(J2735Error, match="lane 3: computed from lane 9, which the intersection does not have"):
        g.resolve_computed()
    data = MapData([g]).encode()
    raw = default_codec().decode(data).message["intersections"][0]["laneSet"]
    assert raw[1]["nodeList"][1]["offsetXaxis"] == ("large", 350) and raw[1]["nodeList"][1]["rotateXY"] == 28800
    back = MapData.decode(data)
    assert back.encode() == data
    assert _flat(back.intersections[0].lane(2).polyline) == pytest.approx([3.5, -5.0, 3.5, -50.0])  # 360 deg: no turn
    assert back.intersections[0].lane(3).nodes == []


@pytest.mark.parametrize("change,match", [
    (lambda g: setattr(g, "ref_latitude", 91.0), r"intersection 5: ref_latitude: latitude: 91 deg is outside"),
    (lambda g: setattr(g, "ref_elevation", 7000.0), r"intersection 5: ref_elevation: elevation: 7000 m is outside"),
    (lambda g: setattr(g.lanes[1].computed, "rotation_deg", math.nan), r"lane 2: computed.rotation_deg: nan"),
    (lambda g: setattr(g.lanes[1].computed, "offset_choices", ("huge", "small")), r"offset choice 'huge'"),
    (lambda g: setattr(g.lanes[1].computed, "offset_x", 400.0), r"lane 2: computed.offset_x: 400 m is outside"),
    (lambda g: setattr(g.lanes[0].nodes[0], "latlon", (42.0, 181.0)), r"lane 1: node 0: longitude: longitude"),
])
def test_values_the_wire_cannot_carry_are_refused_naming_the_field(change, match):
    g = IntersectionGeometry(5, 42.0, -83.0, 250.0, [
        Lane(1, [Node(0.0, -5.0), Node(0.0, -50.0)], ingress=True),
        Lane(2, computed=ComputedLane(1, offset_x=3.5, offset_y=0.0))])
    change(g)
    with pytest.raises(J2735Error, match=match):
        MapData([g]).encode()


# -- generated messages -----------------------------------------------------------------------------------
ia5 = st.text(st.characters(min_codepoint=32, max_codepoint=126), min_size=1, max_size=12)
region_ext = st.fixed_dictionaries({"regionId": st.integers(0, 255), "regExtValue": st.binary(min_size=1, max_size=4)})
regional = st.lists(region_ext, min_size=1, max_size=2)


def bits(n):
    return st.integers(0, (1 << n) - 1).map(lambda v: ((v << ((8 - n % 8) % 8)).to_bytes((n + 7) // 8, "big"), n))


def xy(width):
    half = 1 << (width - 1)
    return st.fixed_dictionaries({"x": st.integers(-half, half - 1), "y": st.integers(-half, half - 1)})


lat, lon = st.integers(-900000000, 900000001), st.integers(-1799999999, 1800000001)
# near the reference point too, so that most latitude/longitude nodes are placeable
near_lat, near_lon = st.integers(419990000, 420010000), st.integers(-830010000, -829990000)
position = st.fixed_dictionaries({"lat": st.one_of(near_lat, lat), "long": st.one_of(near_lon, lon)},
                                 optional={"elevation": st.integers(-4096, 61439), "regional": regional})
delta = st.one_of(*[st.tuples(st.just(f"node-XY{i}"), xy(w)) for i, w in enumerate((10, 11, 12, 13, 14, 16), 1)],
                  st.tuples(st.just("node-LatLon"), st.fixed_dictionaries({"lon": st.one_of(near_lon, lon),
                                                                           "lat": st.one_of(near_lat, lat)})),
                  st.tuples(st.just("regional"), region_ext))
speed_limit = st.fixed_dictionaries({"type": st.sampled_from(["unknown", "vehicleMaxSpeed", "truckMinSpeed"]),
                                     "speed": st.integers(0, 8191)})
data_attribute = st.one_of(st.tuples(st.just("pathEndPointAngle"), st.integers(-150, 150)),
                           st.tuples(st.just("laneAngle"), st.integers(-180, 180)),
                           st.tuples(st.just("speedLimits"), st.lists(speed_limit, min_size=1, max_size=2)),
                           st.tuples(st.just("regional"), regional))
segments = st.lists(st.sampled_from(["reserved", "doNotBlock", "whiteLine", "curbOnLeft", "unEvenPavementPresent"]),
                    min_size=1, max_size=2)
attributes = st.fixed_dictionaries({}, optional={
    "localNode": st.lists(st.sampled_from(["reserved", "stopLine", "mergePoint", "safeIsland", "hydrantPresent"]),
                          min_size=1, max_size=3),
    "disabled": segments, "enabled": segments, "data": st.lists(data_attribute, min_size=1, max_size=2),
    "dWidth": st.integers(-512, 511), "dElevation": st.integers(-512, 511), "regional": regional})
node = st.fixed_dictionaries({"delta": delta}, optional={"attributes": attributes})
axis_offset = st.one_of(st.tuples(st.just("small"), st.integers(-2047, 2047)),
                        st.tuples(st.just("large"), st.integers(-32767, 32767)))
lane_type = st.one_of(st.tuples(st.just("vehicle"), bits(8)),
                      *[st.tuples(st.just(kind), bits(16)) for kind in LANE_TYPES[1:]])
id_ref = st.fixed_dictionaries({"id": st.integers(0, 65535)}, optional={"region": st.integers(0, 65535)})
connection = st.fixed_dictionaries(
    {"connectingLane": st.fixed_dictionaries({"lane": st.integers(0, 255)}, optional={"maneuver": bits(12)})},
    optional={"remoteIntersection": id_ref, "signalGroup": st.integers(0, 255), "userClass": st.integers(0, 255),
              "connectionID": st.integers(0, 255)})


def computed(reference_ids):
    return st.fixed_dictionaries(
        {"referenceLaneId": st.sampled_from(reference_ids), "offsetXaxis": axis_offset, "offsetYaxis": axis_offset},
        optional={"rotateXY": st.integers(0, 28800), "scaleXaxis": st.integers(-2048, 2047),
                  "scaleYaxis": st.integers(-2048, 2047), "regional": regional})


def lane(lane_id, ids):
    node_list = st.one_of(st.tuples(st.just("nodes"), st.lists(node, min_size=2, max_size=5)),
                          st.tuples(st.just("computed"), computed(ids + [255])))
    return st.fixed_dictionaries(
        {"laneID": st.just(lane_id), "nodeList": node_list,
         "laneAttributes": st.fixed_dictionaries({"directionalUse": bits(2), "sharedWith": bits(10),
                                                  "laneType": lane_type}, optional={"regional": region_ext})},
        optional={"name": ia5, "ingressApproach": st.integers(0, 15), "egressApproach": st.integers(0, 15),
                  "maneuvers": bits(12), "connectsTo": st.lists(connection, min_size=1, max_size=2),
                  "overlays": st.lists(st.integers(0, 255), min_size=1, max_size=2), "regional": regional})


@st.composite
def lane_sets(draw):
    ids = draw(st.lists(st.integers(0, 254), min_size=1, max_size=4, unique=True))
    return [draw(lane(i, ids)) for i in ids]


intersection = st.fixed_dictionaries(
    {"id": id_ref, "revision": st.integers(0, 127), "refPoint": position, "laneSet": lane_sets()},
    optional={"name": ia5, "laneWidth": st.integers(0, 32767), "speedLimits": st.lists(speed_limit, min_size=1,
                                                                                         max_size=2),
              "preemptPriorityData": st.lists(st.fixed_dictionaries({"zone": region_ext}), min_size=1, max_size=2),
              "regional": regional})
raw_maps = st.fixed_dictionaries({"msgIssueRevision": st.integers(0, 127)}, optional={
    "timeStamp": st.integers(0, 527040), "layerType": st.sampled_from(["none", "intersectionData", "curveData"]),
    "layerID": st.integers(0, 100), "intersections": st.lists(intersection, min_size=1, max_size=2),
    "dataParameters": st.fixed_dictionaries({}, optional={"processMethod": ia5, "geoidUsed": ia5}),
    "regional": regional})


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(raw_maps)
def test_generated_maps_using_every_element_reencode_to_the_same_bytes(raw):
    data = default_codec().encode(18, raw)
    m = MapData.decode(data)
    assert m.encode() == data
    for raw_ix, g in zip(raw.get("intersections", ()), m.intersections):
        for raw_lane, typed in zip(raw_ix["laneSet"], g.lanes):
            kind, value = raw_lane["nodeList"]
            if kind != "nodes":
                continue
            x = y = 0  # the XY offsets add up to the node positions, in metres
            for raw_node, n in zip(value, typed.nodes):
                choice, offset = raw_node["delta"]
                if choice.startswith("node-XY"):
                    x, y = x + offset["x"], y + offset["y"]
                    assert (n.x, n.y) == (x / 100, y / 100)
                else:  # a latitude/longitude node (or an unplaceable one): the next offset starts from it
                    x, y = round(n.x * 100), round(n.y * 100)


centimetres = st.integers(-15000, 15000).map(lambda cm: cm / 100)  # consecutive nodes within one offset's reach
typed_node = st.builds(Node, x=centimetres, y=centimetres,
                       local=st.lists(st.sampled_from(["stopLine", "mergePoint"]), max_size=2).map(tuple),
                       d_width=st.one_of(st.none(), st.integers(-512, 511).map(lambda v: v / 100)),
                       d_elevation=st.one_of(st.none(), st.integers(-512, 511).map(lambda v: v / 10)))
typed_connection = st.builds(Connection, lane=st.integers(0, 255),
                             maneuvers=st.one_of(st.none(), st.frozensets(st.sampled_from(MANEUVERS))),
                             signal_group=st.one_of(st.none(), st.integers(0, 255)),
                             connection_id=st.one_of(st.none(), st.integers(0, 255)))


@st.composite
def typed_geometries(draw):
    ids = draw(st.lists(st.integers(0, 255), min_size=1, max_size=4, unique=True))
    lanes = [Lane(i, draw(st.lists(typed_node, min_size=2, max_size=6)), ingress=draw(st.booleans()),
                  egress=draw(st.booleans()), lane_type=draw(st.sampled_from(LANE_TYPES)),
                  ingress_approach=draw(st.one_of(st.none(), st.integers(0, 15))),
                  maneuvers=draw(st.one_of(st.none(), st.frozensets(st.sampled_from(MANEUVERS)))),
                  connections=draw(st.lists(typed_connection, max_size=3)), name=draw(st.one_of(st.none(), ia5)))
             for i in ids]
    return IntersectionGeometry(draw(st.integers(0, 65535)), draw(st.integers(-900000000, 900000000)) / 1e7,
                                draw(st.integers(-1799999999, 1800000000)) / 1e7,
                                draw(st.one_of(st.none(), st.integers(-4095, 61439).map(lambda v: v / 10))), lanes,
                                lane_width=draw(st.one_of(st.none(), st.integers(0, 32767).map(lambda v: v / 100))),
                                speed_limits=draw(st.lists(st.tuples(st.sampled_from(["vehicleMaxSpeed", "unknown"]),
                                                                     st.integers(0, 8190).map(lambda v: v / 50)),
                                                           max_size=3)))


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(typed_geometries())
def test_generated_typed_maps_survive_the_wire(g):
    data = MapData([g], revision=3).encode()
    back = MapData.decode(data)
    b = back.intersections[0]
    assert back.encode() == data
    assert (b.ref_latitude, b.ref_longitude) == pytest.approx((g.ref_latitude, g.ref_longitude), abs=1e-9)
    assert b.lane_width == g.lane_width and _flat(b.speed_limits) == _flat(g.speed_limits)  # m/s in 0.02 m/s steps
    for mine, theirs in zip(g.lanes, b.lanes):
        assert _flat(theirs.polyline) == pytest.approx(_flat(mine.polyline), abs=1e-9)  # centimetres come back exact
        assert [n.local for n in theirs.nodes] == [n.local for n in mine.nodes]
        assert (theirs.lane_type, theirs.ingress, theirs.egress, theirs.maneuvers, theirs.name) == (
            mine.lane_type, mine.ingress, mine.egress, mine.maneuvers, mine.name)
        assert theirs.connections == mine.connections
