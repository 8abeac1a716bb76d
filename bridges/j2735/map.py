"""MAP (MapData) as a typed object: each intersection's lanes in local metres from its reference point.

    geometry = MapData.decode(frame_bytes).intersections[0]
    lane, to_stop = geometry.ingress_lane_at(x, y, heading_deg=0.0)   # which approach lane am I in?
    group = lane.signal_group()                                       # the SPaT signal group it obeys
    sx, sy = lane.stop_line                                           # where to stop on red

Why a typed layer over the UPER values: on the wire a lane is a list of node
*offsets* in centimetres, each from the previous node (the first from the
reference point), chosen among six integer widths, with lane width changes and
stop lines hidden in per-node attribute sets. A vehicle that must stop at a red
light needs absolute positions in metres, the stop line and the signal group of
its lane; that is what this module gives, both ways:

* `Node.x`, `Node.y`: metres east and north of the intersection's reference
  point (`IntersectionGeometry.ref_latitude/ref_longitude/ref_elevation`, the
  scenario's origin for the RSU app's MAP, so these are the world's x and y).
  Absolute, not deltas: encoding rounds each node to the centimetre and sends
  the differences, so no rounding error accumulates along a lane.
* A lane's nodes run from the intersection outward (J2735): an ingress lane's
  first node is at its stop line, traffic on it moves toward node 0; an egress
  lane's first node is where traffic leaves the intersection.
* Widths: `IntersectionGeometry.lane_width` (m) is the default; a node's
  `d_width` changes the width from that node on (`Lane.widths`).
* `Connection`: where an ingress lane leads (an egress lane id), by which
  manoeuvre, under which SPaT signal group.
* Computed lanes (a lane described as an offset copy of another) are resolved:
  their `nodes` are filled in on decoding (and ignored on encoding, where the
  `ComputedLane` description is sent).
* Nodes sent as latitude/longitude (node-LatLon) are placed in the same local
  metres with pymap3d (east/north on the WGS-84 ellipsoid at the reference
  point) and keep their `latlon`; the node after one continues from it.
  A regional node offset is kept verbatim (`Node.regional_offset`) and placed
  on the previous node. `Lane.polyline` lists a lane's (x, y);
  `IntersectionGeometry.geodetic(x, y)` gives a point's latitude/longitude.

Decoding then encoding reproduces the bytes of the deployed MAPs in
`tests/fixtures/interop/j2735_vectors.json`: every element the typed fields do
not model (node attribute data, segment attributes, regional extensions,
restriction lists, road segments...) is kept verbatim in an `other` dict, and
the node offset width of each received node in `Node.delta_choice` (and the
small/large choice of a computed lane's offsets in `ComputedLane.offset_choices`).
Generated MAPs using every element re-encode to their bytes too
(tests/test_j2735_map_typed.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Iterable

from bridges.j2735 import scales
from bridges.j2735.codec import J2735Error
from bridges.j2735.fields import finite as _finite, from_wire as _from_wire, wire as _scaled
from bridges.j2735.typed import Framed

MESSAGE_ID = 18

# AllowedManeuvers bits 0..11
MANEUVERS = ("straight", "left", "right", "uTurn", "leftTurnOnRed", "rightTurnOnRed", "laneChange",
             "noStopping", "yieldAlways", "goWithHalt", "caution", "reserved1")
# LaneSharing bits 0..9
SHARED_WITH = ("overlappingLaneDescriptionProvided", "multipleLanesTreatedAsOneLane",
               "otherNonMotorizedTrafficTypes", "individualMotorizedVehicleTraffic", "busVehicleTraffic",
               "taxiVehicleTraffic", "pedestriansTraffic", "cyclistVehicleTraffic", "trackedVehicleTraffic",
               "pedestrianTraffic")
LANE_TYPES = ("vehicle", "crosswalk", "bikeLane", "sidewalk", "median", "striping", "trackedVehicle", "parking")
_TYPE_BITS = {"vehicle": 8}  # the other lane types carry 16 attribute bits
# node offset choices: (name, bits of each of x and y); an offset is in centimetres
NODE_CHOICES = (("node-XY1", 10), ("node-XY2", 11), ("node-XY3", 12), ("node-XY4", 13), ("node-XY5", 14),
                ("node-XY6", 16))
_NODE_BITS = dict(NODE_CHOICES)
_LANE_WIDTH_MAX_M = 327.67  # LaneWidth 0..32767 cm
_D_ELEVATION_STEP = 0.1  # m: NodeAttributeSetXY.dElevation counts 10 cm
_D_WIDTH_STEP = 0.01  # m: dWidth counts 1 cm
_ROTATION_STEP = 0.0125  # deg: ComputedLane.rotateXY (Angle)
_SCALE_STEP = 0.0005  # ComputedLane.scaleX/Yaxis (Scale-B12): 0.05 % per unit, 0 = 1:1
_NODE_ATTR_TYPED = ("localNode", "dWidth", "dElevation")


# -- bit strings (asn1tools: (bytes, number of bits), bit 0 the most significant of the first byte) -------
def _bits_to_names(value: tuple[bytes, int], names: tuple[str, ...]) -> frozenset[str]:
    data, n = value
    out = set()
    for i in range(min(n, len(names))):
        if data[i // 8] >> (7 - i % 8) & 1:
            out.add(names[i])
    return frozenset(out)


def _names_to_bits(selected: Iterable[str], names: tuple[str, ...], what: str) -> tuple[bytes, int]:
    selected = set(selected)
    unknown = sorted(selected - set(names))
    if unknown:
        raise J2735Error(f"{what}: unknown name(s) {', '.join(unknown)} (known: {', '.join(names)})")
    buf = bytearray((len(names) + 7) // 8)
    for i, name in enumerate(names):
        if name in selected:
            buf[i // 8] |= 0x80 >> (i % 8)
    return bytes(buf), len(names)


def _cm(value: float, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise J2735Error(f"{what}: {value!r} is not a finite number of metres")
    return round(value * 100.0)


def _in_range(raw: int, low: int, high: int, what: str, unit_m: float = 0.01) -> int:
    if not low <= raw <= high:
        raise J2735Error(f"{what}: {raw * unit_m:g} m is outside {low * unit_m:g}..{high * unit_m:g} m")
    return raw


# -- the typed message -----------------------------------------------------------------------------------
@dataclass
class Node:
    """One point of a lane's centreline, in metres east (x) and north (y) of the reference point."""

    x: float
    y: float
    local: tuple[str, ...] = ()            # NodeAttributeXY names here, e.g. ("stopLine",)
    d_width: float | None = None           # m: lane width change from this node on (None: none sent)
    d_elevation: float | None = None       # m: elevation change at this node (10 cm steps)
    other: dict[str, Any] | None = None    # the node's other attributes (segment attributes, data, regional);
                                           # {}: an empty attribute set was received (and is sent again)
    delta_choice: str | None = None        # "node-XY1".."node-XY6" as received; None: the smallest that fits
    latlon: tuple[float | None, float | None] | None = None  # (lat, lon) deg when sent as node-LatLon (None: the
                                                             # wire's 'unavailable'; x, y then repeat the previous)
    regional_offset: dict[str, Any] | None = None  # a regional NodeOffsetPointXY, verbatim: x, y repeat the previous
                                                   # node's, as this module cannot place it

    @property
    def stop_line(self) -> bool:
        return "stopLine" in self.local


@dataclass
class Connection:
    """Where an ingress lane leads: `lane` is the connecting (egress) lane's id."""

    lane: int
    maneuvers: frozenset[str] | None = None   # names from MANEUVERS; None: not sent
    signal_group: int | None = None           # the SPaT signal group that controls this movement
    connection_id: int | None = None
    remote_intersection: int | None = None    # the connecting lane belongs to another intersection
    remote_region: int | None = None
    user_class: int | None = None


@dataclass
class ComputedLane:
    """A lane described as a copy of `reference_lane` moved by (offset_x, offset_y) m, then rotated clockwise
    by `rotation_deg` and scaled by (scale_x, scale_y) about its first node."""

    reference_lane: int
    offset_x: float
    offset_y: float
    rotation_deg: float | None = None
    scale_x: float | None = None   # factor, 1.0 = unchanged
    scale_y: float | None = None
    other: dict[str, Any] | None = None  # regional extensions, verbatim
    offset_choices: tuple[str, str] | None = None  # ("small"|"large",) * 2 as received; None: the smallest that fits


@dataclass
class Lane:
    lane_id: int
    nodes: list[Node] = field(default_factory=list)
    ingress: bool = False                 # directionalUse: traffic enters the intersection on it
    egress: bool = False                  # ... leaves the intersection on it
    ingress_approach: int | None = None
    egress_approach: int | None = None
    lane_type: str = "vehicle"            # one of LANE_TYPES
    type_attributes: tuple[bytes, int] | None = None  # the lane type's attribute bits, verbatim (None: all clear)
    shared_with: frozenset[str] = frozenset()  # names from SHARED_WITH
    maneuvers: frozenset[str] | None = None    # names from MANEUVERS allowed from this lane; None: not sent
    connections: list[Connection] = field(default_factory=list)
    name: str | None = None
    overlays: list[int] | None = None
    computed: ComputedLane | None = None  # set: `nodes` were derived from another lane (see ComputedLane)
    other: dict[str, Any] | None = None   # regional extensions of the lane and of its attributes, verbatim

    @property
    def polyline(self) -> list[tuple[float, float]]:
        """The lane's centreline: (east, north) metres from the reference point of each node, node 0 first."""
        return [(n.x, n.y) for n in self.nodes]

    @property
    def stop_line(self) -> tuple[float, float] | None:
        """Where traffic on this lane stops: the node marked stopLine, else an ingress lane's first node."""
        for node in self.nodes:
            if node.stop_line:
                return node.x, node.y
        if self.ingress and self.nodes:
            return self.nodes[0].x, self.nodes[0].y
        return None

    def widths(self, lane_width: float | None) -> list[float | None]:
        """The lane's width at each node (m): the intersection's lane width plus every d_width so far."""
        out, width = [], lane_width
        for node in self.nodes:
            if node.d_width is not None and width is not None:
                width += node.d_width
            out.append(width)
        return out

    def signal_group(self, to_lane: int | None = None) -> int | None:
        """The signal group of the connection to `to_lane` (default: the first connection that has one)."""
        for c in self.connections:
            if c.signal_group is not None and (to_lane is None or c.lane == to_lane):
                return c.signal_group
        return None

    def locate(self, x: float, y: float) -> tuple[float, float, float]:
        """(distance from the centreline (m), distance along it from node 0 (m), direction of the
        node-0-outward segment there, deg clockwise from north) of the point nearest to (x, y)."""
        if len(self.nodes) < 2:
            raise J2735Error(f"lane {self.lane_id}: needs at least two nodes to locate a point on it")
        best = None
        along = 0.0
        for a, b in zip(self.nodes, self.nodes[1:]):
            dx, dy = b.x - a.x, b.y - a.y
            seg = math.hypot(dx, dy)
            if seg == 0:
                continue
            s = max(0.0, min(seg, ((x - a.x) * dx + (y - a.y) * dy) / seg))
            px, py = a.x + dx * s / seg, a.y + dy * s / seg
            d = math.hypot(x - px, y - py)
            if best is None or d < best[0]:
                best = (d, along + s, math.degrees(math.atan2(dx, dy)) % 360.0)
            along += seg
        if best is None:
            raise J2735Error(f"lane {self.lane_id}: all its nodes coincide")
        return best


@dataclass
class IntersectionGeometry:
    intersection_id: int
    ref_latitude: float                   # deg: the reference point every node is measured from
    ref_longitude: float
    ref_elevation: float | None = None    # m; None: not sent
    lanes: list[Lane] = field(default_factory=list)
    lane_width: float | None = None       # m: default width of every lane
    revision: int = 0
    name: str | None = None
    region: int | None = None
    speed_limits: list[tuple[str, float]] = field(default_factory=list)  # (SpeedLimitType name, m/s)
    other: dict[str, Any] | None = None   # preemptPriorityData, regional extensions, verbatim

    def geodetic(self, x: float, y: float) -> tuple[float, float]:
        """(lat, lon) deg of the point x m east, y m north of the reference point (pymap3d, WGS-84)."""
        from bridges.geo import GeoOrigin

        lat, lon, _ = GeoOrigin(self.ref_latitude, self.ref_longitude, self.ref_elevation or 0.0).to_geodetic(x, y)
        return float(lat), float(lon)

    def lane(self, lane_id: int) -> Lane:
        for lane in self.lanes:
            if lane.lane_id == lane_id:
                return lane
        raise KeyError(f"intersection {self.intersection_id} has no lane {lane_id} "
                       f"(lanes: {sorted(l.lane_id for l in self.lanes)})")

    def ingress_lanes(self, approach: int | None = None) -> list[Lane]:
        return [l for l in self.lanes if l.ingress and (approach is None or l.ingress_approach == approach)]

    def ingress_lane_at(self, x: float, y: float, heading_deg: float | None = None,
                        max_heading_error_deg: float = 45.0) -> tuple[Lane, float] | None:
        """The vehicle ingress lane a vehicle at (x, y) (m from the reference point) drives on, and its distance
        to the lane's stop line along the lane (m, negative once past it); None when it is on none.

        On a lane: within half the lane's width of its centreline, between its stop line and its far end.
        With `heading_deg` (clockwise from north), the vehicle must also move toward the stop line (within
        `max_heading_error_deg`), which tells the two directions of a road apart."""
        best = None
        for lane in self.ingress_lanes():
            if lane.lane_type != "vehicle" or len(lane.nodes) < 2:
                continue
            d, along, direction = lane.locate(x, y)
            width = next((w for w in lane.widths(self.lane_width) if w), None) or 3.5
            if d > width / 2:
                continue
            if heading_deg is not None:
                travel = (direction + 180.0) % 360.0  # traffic on an ingress lane moves toward node 0
                if abs((heading_deg - travel + 180.0) % 360.0 - 180.0) > max_heading_error_deg:
                    continue
            stop = lane.stop_line
            stop_along = lane.locate(*stop)[1] if stop is not None else 0.0
            if best is None or d < best[0]:
                best = (d, lane, along - stop_along)
        return None if best is None else (best[1], best[2])

    def resolve_computed(self, strict: bool = True) -> None:
        """Fill the nodes of computed lanes from their reference lanes (J2735 ComputedLane).

        A reference lane the intersection lacks, or one itself computed, is an error naming both lanes; with
        `strict=False` (decoding: the message is what it is) such a lane keeps no nodes and its ComputedLane."""
        for lane in self.lanes:
            c = lane.computed
            if c is None:
                continue
            try:
                ref = self.lane(c.reference_lane)
            except KeyError:
                if not strict:
                    continue
                raise J2735Error(f"lane {lane.lane_id}: computed from lane {c.reference_lane}, which the "
                                 f"intersection does not have") from None
            if ref.computed is not None:
                if not strict:
                    continue
                raise J2735Error(f"lane {lane.lane_id}: computed from lane {c.reference_lane}, itself computed")
            pts = [(n.x + c.offset_x, n.y + c.offset_y) for n in ref.nodes]
            if pts:
                x0, y0 = pts[0]
                a = math.radians(c.rotation_deg or 0.0)
                ca, sa = math.cos(a), math.sin(a)
                sx, sy = c.scale_x or 1.0, c.scale_y or 1.0
                out = []
                for px, py in pts:
                    dx, dy = (px - x0) * sx, (py - y0) * sy
                    out.append((x0 + dx * ca + dy * sa, y0 - dx * sa + dy * ca))  # clockwise rotation
                pts = out
            lane.nodes = [Node(px, py) for px, py in pts]


@dataclass
class MapData(Framed):
    """MapData: the geometry of one or more intersections (lanes, nodes, connections)."""

    MESSAGE_ID, WHAT = MESSAGE_ID, "a MAP"

    intersections: list[IntersectionGeometry]
    revision: int = 0                  # msgIssueRevision (MsgCount 0..127): bump when the map changes
    moy: int | None = None             # minute of the year of the message
    layer_type: str | None = None      # e.g. "intersectionData"
    layer_id: int | None = None
    other: dict[str, Any] | None = None  # roadSegments, dataParameters, restrictionList, regional, verbatim

    # -- wire -------------------------------------------------------------------------------------------
    def to_asn1(self) -> dict[str, Any]:
        if not isinstance(self.revision, int) or not 0 <= self.revision <= 127:
            raise J2735Error(f"revision: {self.revision!r} is outside 0..127 (MsgCount)")
        message: dict[str, Any] = {}
        if self.moy is not None:
            message["timeStamp"] = self.moy
        message["msgIssueRevision"] = self.revision
        if self.layer_type is not None:
            message["layerType"] = self.layer_type
        if self.layer_id is not None:
            message["layerID"] = self.layer_id
        if self.intersections:
            message["intersections"] = [_intersection_to_asn1(i) for i in self.intersections]
        message.update(self.other or {})
        return message

    @classmethod
    def from_asn1(cls, message: dict[str, Any]) -> "MapData":
        known = ("timeStamp", "msgIssueRevision", "layerType", "layerID", "intersections")
        other = {k: v for k, v in message.items() if k not in known}
        return cls([_intersection_from_asn1(i) for i in message.get("intersections", ())],
                   revision=message["msgIssueRevision"], moy=message.get("timeStamp"),
                   layer_type=message.get("layerType"), layer_id=message.get("layerID"), other=other or None)


# -- to asn1 -------------------------------------------------------------------------------------------
def _position(lat: float, lon: float, elevation: float | None, regional, where: str,
              elevation_code: int | None = None) -> dict[str, Any]:
    p: dict[str, Any] = {"lat": _scaled(scales.LATITUDE, lat, f"{where}: ref_latitude"),
                         "long": _scaled(scales.LONGITUDE, lon, f"{where}: ref_longitude")}
    if elevation is not None:
        p["elevation"] = _scaled(scales.ELEVATION, elevation, f"{where}: ref_elevation")
    elif elevation_code is not None:  # the wire's 'unavailable' (-4096), received and sent again
        p["elevation"] = elevation_code
    if regional is not None:
        p["regional"] = regional
    return p


def _intersection_to_asn1(g: IntersectionGeometry) -> dict[str, Any]:
    where = f"intersection {g.intersection_id}"
    if not g.lanes:
        raise J2735Error(f"{where}: at least one lane is required")
    other = dict(g.other or {})
    ref: dict[str, Any] = {"id": g.intersection_id}
    if g.region is not None:
        ref = {"region": g.region, "id": g.intersection_id}
    out: dict[str, Any] = {}
    if g.name is not None:
        out["name"] = g.name
    out["id"] = ref
    out["revision"] = g.revision
    out["refPoint"] = _position(g.ref_latitude, g.ref_longitude, g.ref_elevation, other.pop("refPointRegional", None),
                                where, other.pop("refPointElevation", None))
    if g.lane_width is not None:
        out["laneWidth"] = _in_range(_cm(g.lane_width, f"{where}: lane_width"), 0, 32767, f"{where}: lane_width")
    if g.speed_limits:
        out["speedLimits"] = [_speed_limit(t, v, where) for t, v in g.speed_limits]
    ids = [l.lane_id for l in g.lanes]
    if len(set(ids)) != len(ids):
        raise J2735Error(f"{where}: lane ids repeat: {sorted(i for i in set(ids) if ids.count(i) > 1)}")
    out["laneSet"] = [_lane_to_asn1(l, where) for l in g.lanes]
    out.update(other)
    return out


def _speed_limit(kind: str, speed: float, where: str) -> dict[str, Any]:
    return {"type": kind, "speed": scales.SPEED.to_wire(speed) if speed is not None else 8191}


def _lane_to_asn1(lane: Lane, where: str) -> dict[str, Any]:
    where = f"{where}: lane {lane.lane_id}"
    if lane.lane_type not in LANE_TYPES:
        raise J2735Error(f"{where}: lane_type {lane.lane_type!r} is not one of {', '.join(LANE_TYPES)}")
    other = dict(lane.other or {})
    type_bits = lane.type_attributes
    if type_bits is None:
        n = _TYPE_BITS.get(lane.lane_type, 16)
        type_bits = (bytes(n // 8), n)
    attrs: dict[str, Any] = {
        "directionalUse": (bytes(((0x80 if lane.ingress else 0) | (0x40 if lane.egress else 0),)), 2),
        "sharedWith": _names_to_bits(lane.shared_with, SHARED_WITH, f"{where}: shared_with"),
        "laneType": (lane.lane_type, type_bits),
    }
    if "attributesRegional" in other:
        attrs["regional"] = other.pop("attributesRegional")
    out: dict[str, Any] = {"laneID": lane.lane_id}
    if lane.name is not None:
        out["name"] = lane.name
    if lane.ingress_approach is not None:
        out["ingressApproach"] = lane.ingress_approach
    if lane.egress_approach is not None:
        out["egressApproach"] = lane.egress_approach
    out["laneAttributes"] = attrs
    if lane.maneuvers is not None:
        out["maneuvers"] = _names_to_bits(lane.maneuvers, MANEUVERS, f"{where}: maneuvers")
    if lane.computed is not None:
        out["nodeList"] = _computed_to_asn1(lane.computed, where)
    elif "nodeList" not in other:  # else an extension of NodeListXY kept verbatim
        out["nodeList"] = ("nodes", _nodes_to_asn1(lane.nodes, where))
    if lane.connections:
        out["connectsTo"] = [_connection_to_asn1(c, where) for c in lane.connections]
    if lane.overlays:
        out["overlays"] = list(lane.overlays)
    out.update(other)
    return out


def _nodes_to_asn1(nodes: list[Node], where: str) -> list[dict[str, Any]]:
    if not 2 <= len(nodes) <= 63:
        raise J2735Error(f"{where}: a lane needs 2..63 nodes, got {len(nodes)}")
    out, px, py = [], 0, 0
    for i, node in enumerate(nodes):
        what = f"{where}: node {i}"
        if node.regional_offset is not None:
            delta = ("regional", node.regional_offset)
            cx, cy = px, py
        elif node.latlon is not None:
            lat, lon = node.latlon
            delta = ("node-LatLon", {"lon": _scaled(scales.LONGITUDE, lon, f"{what}: longitude"),
                                     "lat": _scaled(scales.LATITUDE, lat, f"{what}: latitude")})
            cx, cy = _cm(node.x, f"{what}.x"), _cm(node.y, f"{what}.y")
        else:
            cx, cy = _cm(node.x, f"{what}.x"), _cm(node.y, f"{what}.y")
            dx, dy = cx - px, cy - py
            choice = node.delta_choice or _smallest_choice(dx, dy, what)
            if choice not in _NODE_BITS:
                raise J2735Error(f"{what}: delta_choice {choice!r} is not one of {', '.join(_NODE_BITS)}")
            half = 1 << (_NODE_BITS[choice] - 1)
            if not (-half <= dx < half and -half <= dy < half):
                raise J2735Error(f"{what}: offset ({dx / 100:g}, {dy / 100:g}) m from the previous node does not "
                                 f"fit {choice} (+-{half / 100:g} m)")
            delta = (choice, {"x": dx, "y": dy})
        px, py = cx, cy
        entry: dict[str, Any] = {"delta": delta}
        attributes = _node_attributes(node, what)
        if attributes or node.other is not None:  # other == {}: an empty attribute set was received
            entry["attributes"] = attributes
        out.append(entry)
    return out


def _smallest_choice(dx: int, dy: int, what: str) -> str:
    for name, bits in NODE_CHOICES:
        half = 1 << (bits - 1)
        if -half <= dx < half and -half <= dy < half:
            return name
    raise J2735Error(f"{what}: {max(abs(dx), abs(dy)) / 100:g} m from the previous node, more than the "
                     f"327.67 m an offset can carry (add intermediate nodes)")


def _node_attributes(node: Node, what: str) -> dict[str, Any]:
    other = dict(node.other or {})
    bad = sorted(set(other) & set(_NODE_ATTR_TYPED))
    if bad:
        raise J2735Error(f"{what}: other: {', '.join(bad)} belong in the typed fields (local, d_width, d_elevation)")
    out: dict[str, Any] = {}
    if node.local:
        if not 1 <= len(node.local) <= 8:
            raise J2735Error(f"{what}: local: 1..8 node attributes, got {len(node.local)}")
        out["localNode"] = list(node.local)
    for key in ("disabled", "enabled", "data"):
        if key in other:
            out[key] = other.pop(key)
    if node.d_width is not None:
        out["dWidth"] = _in_range(round(node.d_width / _D_WIDTH_STEP), -512, 511, f"{what}: d_width")
    if node.d_elevation is not None:
        out["dElevation"] = _in_range(round(node.d_elevation / _D_ELEVATION_STEP), -512, 511,
                                      f"{what}: d_elevation", _D_ELEVATION_STEP)
    out.update(other)
    return out


def _computed_to_asn1(c: ComputedLane, where: str) -> tuple[str, dict[str, Any]]:
    def offset(value: float, choice: str | None, what: str):
        cm = _cm(value, what)
        if choice is None:
            choice = "small" if -2047 <= cm <= 2047 else "large"
        if choice == "small" and -2047 <= cm <= 2047:
            return ("small", cm)
        if choice not in ("small", "large"):
            raise J2735Error(f"{what}: offset choice {choice!r} is not 'small' or 'large'")
        return ("large", _in_range(cm, -32767, 32767, what))

    x_choice, y_choice = c.offset_choices or (None, None)
    out: dict[str, Any] = {"referenceLaneId": c.reference_lane,
                           "offsetXaxis": offset(c.offset_x, x_choice, f"{where}: computed.offset_x"),
                           "offsetYaxis": offset(c.offset_y, y_choice, f"{where}: computed.offset_y")}
    if c.rotation_deg is not None:
        rotation = _finite(c.rotation_deg, f"{where}: computed.rotation_deg")
        raw = round(rotation / _ROTATION_STEP)
        # 0..359.9875 deg as given, other angles wrapped; 360 deg is the wire's 28800 ('unavailable'), as received
        out["rotateXY"] = raw if 0 <= raw <= 28800 else round((rotation % 360.0) / _ROTATION_STEP) % 28800
    for key, value in (("scaleXaxis", c.scale_x), ("scaleYaxis", c.scale_y)):
        if value is not None:
            out[key] = _in_range(round((value - 1.0) / _SCALE_STEP), -2048, 2047, f"{where}: computed.{key}",
                                 _SCALE_STEP)
    if c.other:
        out.update(c.other)
    return ("computed", out)


def _connection_to_asn1(c: Connection, where: str) -> dict[str, Any]:
    lane: dict[str, Any] = {"lane": c.lane}
    if c.maneuvers is not None:
        lane["maneuver"] = _names_to_bits(c.maneuvers, MANEUVERS, f"{where}: connection to {c.lane}: maneuvers")
    out: dict[str, Any] = {"connectingLane": lane}
    if c.remote_intersection is not None:
        ref: dict[str, Any] = {"id": c.remote_intersection}
        if c.remote_region is not None:
            ref = {"region": c.remote_region, "id": c.remote_intersection}
        out["remoteIntersection"] = ref
    if c.signal_group is not None:
        out["signalGroup"] = c.signal_group
    if c.user_class is not None:
        out["userClass"] = c.user_class
    if c.connection_id is not None:
        out["connectionID"] = c.connection_id
    return out


# -- from asn1 -----------------------------------------------------------------------------------------
def _intersection_from_asn1(g: dict[str, Any]) -> IntersectionGeometry:
    known = ("name", "id", "revision", "refPoint", "laneWidth", "speedLimits", "laneSet")
    other = {k: v for k, v in g.items() if k not in known}
    ref = g["refPoint"]
    if "regional" in ref:
        other["refPointRegional"] = ref["regional"]
    if ref.get("elevation") == scales.ELEVATION.unavailable:
        other["refPointElevation"] = ref["elevation"]
    lat, lon = _from_wire(scales.LATITUDE, ref["lat"]), _from_wire(scales.LONGITUDE, ref["long"])
    elevation = _from_wire(scales.ELEVATION, ref["elevation"]) if "elevation" in ref else None
    geometry = IntersectionGeometry(
        intersection_id=g["id"]["id"], region=g["id"].get("region"), revision=g["revision"], name=g.get("name"),
        ref_latitude=lat, ref_longitude=lon, ref_elevation=elevation,
        lane_width=g["laneWidth"] / 100.0 if "laneWidth" in g else None,
        speed_limits=[(s["type"], _from_wire(scales.SPEED, s["speed"])) for s in g.get("speedLimits", ())],
        other=other or None)
    geometry.lanes = [_lane_from_asn1(l, geometry) for l in g["laneSet"]]
    geometry.resolve_computed(strict=False)
    return geometry


def _lane_from_asn1(l: dict[str, Any], g: IntersectionGeometry) -> Lane:
    known = ("laneID", "name", "ingressApproach", "egressApproach", "laneAttributes", "maneuvers", "nodeList",
             "connectsTo", "overlays")
    other = {k: v for k, v in l.items() if k not in known}
    attrs = l["laneAttributes"]
    if "regional" in attrs:
        other["attributesRegional"] = attrs["regional"]
    direction = attrs["directionalUse"][0][0] if attrs["directionalUse"][1] else 0
    lane_type, type_bits = attrs["laneType"]
    n_default = _TYPE_BITS.get(lane_type, 16)
    lane = Lane(
        lane_id=l["laneID"], name=l.get("name"), ingress_approach=l.get("ingressApproach"),
        egress_approach=l.get("egressApproach"), ingress=bool(direction & 0x80), egress=bool(direction & 0x40),
        lane_type=lane_type,
        type_attributes=None if type_bits == (bytes(n_default // 8), n_default) else type_bits,
        shared_with=_bits_to_names(attrs["sharedWith"], SHARED_WITH),
        maneuvers=_bits_to_names(l["maneuvers"], MANEUVERS) if "maneuvers" in l else None,
        connections=[_connection_from_asn1(c) for c in l.get("connectsTo", ())],
        overlays=list(l["overlays"]) if "overlays" in l else None, other=other or None)
    kind, value = l["nodeList"]
    if kind == "nodes":
        lane.nodes = _nodes_from_asn1(value, g)
    elif kind == "computed":
        lane.computed = _computed_from_asn1(value)
    else:  # an extension of NodeListXY this module does not know: keep it to send it back
        lane.other = {**(lane.other or {}), "nodeList": l["nodeList"]}
    return lane


def _nodes_from_asn1(nodes: list[dict[str, Any]], g: IntersectionGeometry) -> list[Node]:
    out, px, py = [], 0, 0  # the previous node in whole centimetres
    x_m = y_m = 0.0
    for entry in nodes:
        choice, value = entry["delta"]
        latlon = regional = None
        if choice == "node-LatLon":
            lat, lon = _from_wire(scales.LATITUDE, value["lat"]), _from_wire(scales.LONGITUDE, value["lon"])
            if None not in (lat, lon, g.ref_latitude, g.ref_longitude):
                x_m, y_m = _local_metres(g, lat, lon)
                px, py = round(x_m * 100), round(y_m * 100)
            latlon, choice = (lat, lon), None
        elif choice in _NODE_BITS:
            px, py = px + value["x"], py + value["y"]
            x_m, y_m = px / 100.0, py / 100.0
        else:  # a regional offset: kept verbatim, the node placed on the previous one
            regional, choice = value, None
        attrs = dict(entry.get("attributes") or {})
        empty_set = "attributes" in entry and not entry["attributes"]
        local = tuple(attrs.pop("localNode", ()))
        d_width = attrs.pop("dWidth", None)
        d_elev = attrs.pop("dElevation", None)
        out.append(Node(x_m, y_m, local=local,
                        d_width=None if d_width is None else d_width * _D_WIDTH_STEP,
                        d_elevation=None if d_elev is None else d_elev * _D_ELEVATION_STEP,
                        other=attrs or ({} if empty_set else None), delta_choice=choice, latlon=latlon,
                        regional_offset=regional))
    return out


def _computed_from_asn1(c: dict[str, Any]) -> ComputedLane:
    other = {k: v for k, v in c.items()
             if k not in ("referenceLaneId", "offsetXaxis", "offsetYaxis", "rotateXY", "scaleXaxis", "scaleYaxis")}
    choices = (c["offsetXaxis"][0], c["offsetYaxis"][0])
    return ComputedLane(
        offset_choices=None if choices == _smallest_offsets(c) else choices,
        reference_lane=c["referenceLaneId"], offset_x=c["offsetXaxis"][1] / 100.0, offset_y=c["offsetYaxis"][1] / 100.0,
        rotation_deg=c["rotateXY"] * _ROTATION_STEP if "rotateXY" in c else None,
        scale_x=1.0 + c["scaleXaxis"] * _SCALE_STEP if "scaleXaxis" in c else None,
        scale_y=1.0 + c["scaleYaxis"] * _SCALE_STEP if "scaleYaxis" in c else None, other=other or None)


def _connection_from_asn1(c: dict[str, Any]) -> Connection:
    lane = c["connectingLane"]
    remote = c.get("remoteIntersection")
    return Connection(
        lane=lane["lane"], maneuvers=_bits_to_names(lane["maneuver"], MANEUVERS) if "maneuver" in lane else None,
        signal_group=c.get("signalGroup"), connection_id=c.get("connectionID"),
        remote_intersection=remote["id"] if remote else None, remote_region=remote.get("region") if remote else None,
        user_class=c.get("userClass"))


def _smallest_offsets(c: dict[str, Any]) -> tuple[str, str]:
    return tuple("small" if -2047 <= c[k][1] <= 2047 else "large" for k in ("offsetXaxis", "offsetYaxis"))


def _local_metres(g: IntersectionGeometry, lat: float, lon: float) -> tuple[float, float]:
    """East and north metres of (lat, lon) from the intersection's reference point (pymap3d, on the WGS-84
    ellipsoid at the reference point's height)."""
    from bridges.geo import GeoOrigin

    origin = GeoOrigin(g.ref_latitude, g.ref_longitude, g.ref_elevation or 0.0)
    x, y, _ = origin.to_local(lat, lon)
    return float(x), float(y)
