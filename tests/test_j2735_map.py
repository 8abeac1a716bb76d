"""The typed MAP (bridges/j2735/map.py): lanes in metres from the reference point, both ways on the wire.

Real deployments' MAPs (tests/fixtures/interop/j2735_vectors.json) decode into
the typed form, reproduce the values published beside them and re-encode to
the same bytes; a MAP built in SI units survives the wire to the centimetre;
values the wire cannot carry are refused naming the lane, node and field.
"""
from __future__ import annotations

import json
import math

import pytest

from bridges.j2735 import J2735Error, default_codec
from bridges.j2735.map import (ComputedLane, Connection, IntersectionGeometry, Lane, MapData, Node)

from conftest import fixture_path

VECTORS = json.loads(fixture_path("interop/j2735_vectors.json").read_text())
MAPS = [v for v in VECTORS if v["message"] == "MAP"]


def test_the_fixture_holds_real_maps():
    assert len(MAPS) >= 4


@pytest.mark.parametrize("index", range(len(MAPS)))
def test_real_map_decodes_to_metres_and_reencodes_to_the_same_bytes(index):
    vector = MAPS[index]
    data = bytes.fromhex(vector["hex"])
    length = default_codec().decode(data).length
    m = MapData.decode(data)
    assert m.encode() == data[:length], vector["source"]
    g = m.intersections[0]
    assert g.lanes and all(len(l.nodes) >= 2 for l in g.lanes)
    # nodes are absolute positions: the first node of a lane is its first offset from the reference point
    raw = default_codec().decode(data).message["intersections"][0]["laneSet"][0]["nodeList"][1]
    first = raw[0]["delta"][1]
    assert (g.lanes[0].nodes[0].x, g.lanes[0].nodes[0].y) == pytest.approx((first["x"] / 100, first["y"] / 100))
    second = raw[1]["delta"][1]
    assert g.lanes[0].nodes[1].x == pytest.approx((first["x"] + second["x"]) / 100)
    # every lane is within a few hundred metres of the reference point
    assert max(math.hypot(n.x, n.y) for l in g.lanes for n in l.nodes) < 500


def test_published_values_of_the_ode_map():
    vector = next(v for v in MAPS if v["expected"] and v["expected"].get("intersection", {}).get("id") == 12110)
    exp = vector["expected"]["intersection"]
    g = MapData.decode(bytes.fromhex(vector["hex"])).intersections[0]
    assert g.intersection_id == 12110 and g.revision == 0
    assert g.ref_latitude == pytest.approx(exp["refPoint"]["lat"] * 1e-7)
    assert g.ref_longitude == pytest.approx(exp["refPoint"]["long"] * 1e-7)
    assert g.ref_elevation == pytest.approx(exp["refPoint"]["elevation"] * 0.1)
    assert g.lane_width == pytest.approx(3.66) and len(g.lanes) == exp["laneSet.count"]


def test_published_values_of_the_v2x_hub_map():
    vector = next(v for v in MAPS if v["expected"] and v["expected"].get("intersection", {}).get("id") == 36243)
    m = MapData.decode(bytes.fromhex(vector["hex"]))
    g = m.intersections[0]
    assert m.revision == 113 and m.layer_type == "intersectionData" and m.layer_id == 1
    assert len(g.lanes) == 16 and g.lane_width == pytest.approx(3.66)
    lane = g.lanes[0]
    assert lane.lane_id == 6 and lane.ingress_approach == 6 and lane.ingress and not lane.egress
    assert (lane.nodes[0].x, lane.nodes[0].y) == pytest.approx((13.81, 1.75))
    assert lane.nodes[0].d_elevation == pytest.approx(-6.0)
    assert [c.signal_group for c in lane.connections] == [6, 6]
    assert lane.connections[0].maneuvers == frozenset({"straight"})
    assert lane.connections[1].maneuvers == frozenset({"left"})
    assert g.speed_limits[0][0] == "vehicleMaxSpeed" and g.speed_limits[0][1] == pytest.approx(22.36)


def _xy(nodes) -> list[float]:
    return [v for n in nodes for v in (n.x, n.y)]


def _geometry() -> IntersectionGeometry:
    ingress = Lane(11, [Node(1.75, -4.5, local=("stopLine",)), Node(1.75, -60.0), Node(1.9, -120.0, d_width=0.25)],
                   ingress=True, ingress_approach=1, maneuvers=frozenset({"straight", "right"}),
                   connections=[Connection(35, frozenset({"straight"}), signal_group=2, connection_id=1),
                                Connection(45, frozenset({"right"}), signal_group=2, connection_id=2)])
    egress = Lane(35, [Node(1.75, 3.5), Node(1.75, 120.0)], egress=True, egress_approach=3, name="north out")
    crosswalk = Lane(90, [Node(-3.5, -6.0), Node(3.5, -6.0)], ingress=True, egress=True, lane_type="crosswalk",
                     shared_with=frozenset({"pedestriansTraffic"}))
    computed = Lane(12, ingress=True, ingress_approach=1, computed=ComputedLane(11, offset_x=3.5, offset_y=0.0))
    return IntersectionGeometry(7, 42.2808, -83.743, 260.0, [ingress, egress, crosswalk, computed], lane_width=3.5,
                                revision=3, name="test junction")


def test_typed_map_round_trip_keeps_centimetres():
    m = MapData([_geometry()], revision=5, moy=123456, layer_type="intersectionData")
    back = MapData.decode(m.encode())
    g, b = m.intersections[0], back.intersections[0]
    assert back.revision == 5 and back.moy == 123456 and b.name == "test junction" and b.revision == 3
    assert (b.ref_latitude, b.ref_longitude, b.ref_elevation) == pytest.approx((42.2808, -83.743, 260.0))
    for mine, theirs in zip(g.lanes, b.lanes):
        assert theirs.lane_id == mine.lane_id and theirs.lane_type == mine.lane_type
        assert (theirs.ingress, theirs.egress) == (mine.ingress, mine.egress)
        if mine.computed is None:
            assert _xy(theirs.nodes) == pytest.approx(_xy(mine.nodes), abs=0.005)
    lane = b.lane(11)
    assert lane.stop_line == pytest.approx((1.75, -4.5))
    assert lane.widths(b.lane_width) == pytest.approx([3.5, 3.5, 3.75])
    assert lane.signal_group() == 2 and lane.signal_group(to_lane=45) == 2
    assert lane.maneuvers == frozenset({"straight", "right"})
    assert b.lane(90).shared_with == frozenset({"pedestriansTraffic"})
    # the computed lane is resolved: the reference lane moved 3.5 m east
    assert _xy(b.lane(12).nodes) == pytest.approx([5.25, -4.5, 5.25, -60.0, 5.4, -120.0])
    # and encoding what was decoded gives the same bytes again
    assert back.encode() == m.encode()


def test_long_lanes_use_wider_offsets_and_no_error_accumulates():
    nodes = [Node(0.0, -3.0)] + [Node(0.0, -3.0 - 0.333 * k) for k in range(1, 40)] + [Node(0.0, -300.0)]
    g = IntersectionGeometry(1, 42.0, -83.0, None, [Lane(1, nodes, ingress=True)])
    raw = MapData([g]).to_asn1()["intersections"][0]["laneSet"][0]["nodeList"][1]
    assert raw[1]["delta"][0] == "node-XY1" and raw[-1]["delta"][0] == "node-XY6"
    back = MapData.decode(MapData([g]).encode()).intersections[0].lanes[0]
    assert back.nodes[-2].y == pytest.approx(-3.0 - 0.333 * 39, abs=0.005)
    assert back.nodes[-1].y == pytest.approx(-300.0)


def test_ingress_lane_at_tells_directions_and_distance_to_the_stop_line():
    g = MapData.decode(MapData([_geometry()]).encode()).intersections[0]
    lane, to_stop = g.ingress_lane_at(1.8, -30.0, heading_deg=0.0)  # northbound, 25.5 m before the stop line
    assert lane.lane_id == 11 and to_stop == pytest.approx(25.5, abs=0.01)
    assert g.ingress_lane_at(1.8, -30.0, heading_deg=180.0) is None  # driving the other way
    assert g.ingress_lane_at(20.0, -30.0) is None                      # not on any ingress lane


@pytest.mark.parametrize("change,match", [
    (lambda g: setattr(g.lanes[0], "nodes", g.lanes[0].nodes[:1]), r"lane 11: a lane needs 2\.\.63 nodes"),
    (lambda g: setattr(g.lanes[0].nodes[1], "y", -400.0), r"lane 11: node 1: .*more than the 327\.67 m"),
    (lambda g: setattr(g.lanes[0].nodes[1], "delta_choice", "node-XY1"), r"node 1: offset .* does not fit node-XY1"),
    (lambda g: setattr(g.lanes[0], "maneuvers", frozenset({"sideways"})), r"lane 11: maneuvers: unknown name"),
    (lambda g: setattr(g.lanes[0], "lane_type", "runway"), r"lane 11: lane_type 'runway'"),
    (lambda g: setattr(g.lanes[1], "lane_id", 11), r"lane ids repeat: \[11\]"),
    (lambda g: setattr(g, "lane_width", 400.0), r"lane_width: 400 m is outside"),
    (lambda g: setattr(g.lanes[0].nodes[2], "d_width", 9.0), r"node 2: d_width: 9 m is outside"),
])
def test_values_the_wire_cannot_carry_are_refused_naming_the_field(change, match):
    g = _geometry()
    change(g)
    with pytest.raises(J2735Error, match=match):
        MapData([g]).encode()


def test_a_bsm_is_not_a_map():
    from bridges.j2735.bsm import Bsm

    with pytest.raises(J2735Error, match="messageId 20 is not a MAP"):
        MapData.decode(Bsm(temporary_id=b"\0\0\0\1").encode())
