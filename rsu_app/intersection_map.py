"""The intersection's MAP, generated from what the master says of the world.

The join reply describes the intersection (`world.intersection`: road_width,
lane_width, arm_length, sidewalk_width; centred at the origin, one road along
x, one along y, driving on the right) and the signal heads (`world.signals`:
position, the direction the lamps face, signal group). From that:

* reference point: the scenario's origin (so the MAP's x, y are the world's);
* four approaches, numbered 1 south arm, 2 west arm, 3 north arm, 4 east arm
  (an arm's traffic enters from that side: approach 1 is the northbound one);
* per arm `n = round(road_width / 2 / lane_width)` ingress lanes (ids 10k+1..)
  on the right of the traffic entering, from the stop line (`stop_line_offset_m`
  before the crossing road's edge, the node marked stopLine) to the arm's end,
  and n egress lanes (ids 10k+5..) from the crossing road's edge outward;
* connections of each ingress lane: straight on to the opposite arm, left and
  right (the innermost lane turns left, the outermost right, one lane does all),
  under the signal group of the head whose lamps face the approaching drivers
  (within 45 deg); without such a head, no signal group.
"""
from __future__ import annotations

import math

from bridges.geo import GeoOrigin
from bridges.j2735.map import Connection, IntersectionGeometry, Lane, MapData, Node

# approach id -> unit vector from the centre out along the arm
ARMS = {1: (0.0, -1.0), 2: (-1.0, 0.0), 3: (0.0, 1.0), 4: (1.0, 0.0)}
ARM_NAMES = {1: "south", 2: "west", 3: "north", 4: "east"}


def _signal_group_facing(signals: list[dict], u: tuple[float, float]) -> int | None:
    """The signal group of the head whose lamps face along u (toward drivers coming in along -u)."""
    best = None
    for s in signals or ():
        try:
            yaw = math.radians(float(s["yaw"]))
            group = int(s["signal_group"])
        except (KeyError, TypeError, ValueError):
            continue
        err = abs(math.remainder(yaw - math.atan2(u[1], u[0]), math.tau))
        if err <= math.radians(45.0) and (best is None or err < best[0]):
            best = (err, group)
    return None if best is None else best[1]


def intersection_geometry(world: dict, origin: GeoOrigin, intersection_id: int, revision: int,
                          stop_line_offset_m: float) -> IntersectionGeometry:
    """The typed MAP geometry of the world the master described; ValueError naming what is missing."""
    ix = world.get("intersection")
    if not isinstance(ix, dict):
        raise ValueError("the master's join reply describes no intersection (the scenario has no [world])")
    try:
        road, lane_w, arm = float(ix["road_width"]), float(ix["lane_width"]), float(ix["arm_length"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"the master's intersection description lacks {exc}: {ix!r}") from None
    n = max(1, round(road / 2 / lane_w))
    stop = road / 2 + stop_line_offset_m
    signals = world.get("signals") or []
    lanes: list[Lane] = []
    for k, u in ARMS.items():
        right_in = (-u[1], u[0])  # entering traffic moves along d = -u; the right of d is (d.y, -d.x)
        right_out = (u[1], -u[0])  # leaving traffic moves along u; its right is (u.y, -u.x)
        group = _signal_group_facing(signals, u)
        for i in range(n):
            lateral = (i + 0.5) * lane_w
            ingress_nodes = [Node(u[0] * d + right_in[0] * lateral, u[1] * d + right_in[1] * lateral,
                                  local=("stopLine",) if d == stop else ())
                             for d in (stop, arm)]
            egress_nodes = [Node(u[0] * d + right_out[0] * lateral, u[1] * d + right_out[1] * lateral)
                            for d in (road / 2, arm)]
            lanes.append(Lane(10 * k + 1 + i, ingress_nodes, ingress=True, ingress_approach=k,
                              name=f"{ARM_NAMES[k]} in {i + 1}"))
            lanes.append(Lane(10 * k + 5 + i, egress_nodes, egress=True, egress_approach=k,
                              name=f"{ARM_NAMES[k]} out {i + 1}"))
        for i in range(n):
            lane = next(l for l in lanes if l.lane_id == 10 * k + 1 + i)
            opposite = (k + 1) % 4 + 1          # 1<->3, 2<->4
            left = k % 4 + 1                    # entering from the south (1), left leads west (2)
            right = (k + 2) % 4 + 1             # ... right leads east (4)
            moves = [("straight", opposite, i)]
            if i == 0:
                moves.append(("left", left, 0))
            if i == n - 1:
                moves.append(("right", right, n - 1))
            for c_id, (move, to_arm, j) in enumerate(moves, start=1):
                lane.connections.append(Connection(10 * to_arm + 5 + j, frozenset({move}), group, c_id))
            lane.maneuvers = frozenset(m for m, _, _ in moves)
    return IntersectionGeometry(intersection_id, origin.lat0, origin.lon0, origin.h0, lanes, lane_width=lane_w,
                                revision=revision, name="v2i-cosim intersection")


def map_message(geometry: IntersectionGeometry, revision: int, moy: int | None) -> MapData:
    return MapData([geometry], revision=revision, moy=moy, layer_type="intersectionData")
