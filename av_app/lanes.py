"""The road map the app knows: where the roads are, and which way traffic goes on them.

The world the master describes in its join reply (`Welcome.world["intersection"]`)
is two straight roads crossing at the origin, one along x and one along y, with
traffic on the right. Outside the junction box, a point on the x road south of
its centre line is in an eastbound lane, north of it westbound; on the y road
east of the centre line northbound, west of it southbound. An object moving
on a road arm is predicted along its lane's direction when its own heading is
within `max_deviation` of it (Autoware's map-based prediction does the same
with its lanelet map): a lidar box of a vehicle that is only partly visible has
a skewed velocity; the lane has not. Lidar clusters off the roads (a building's
wall seen at a grazing angle breaks into small pieces) are static structure.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

from av_app.geometry import wrap


@dataclass(frozen=True)
class LaneMap:
    road_width: float = 7.0
    arm_length: float = 120.0
    tolerance: float = 1.0  # m beyond the road's edge still counted on it (a box's centre is biased)
    max_deviation: float = math.radians(45.0)

    @classmethod
    def from_world(cls, world: dict | None) -> "LaneMap | None":
        ix = (world or {}).get("intersection")
        if not isinstance(ix, dict):
            return None
        try:
            return cls(float(ix.get("road_width", 7.0)), float(ix.get("arm_length", 120.0)))
        except (TypeError, ValueError):
            return None

    def on_road(self, x: float, y: float, margin: float) -> bool:
        """Is (x, y) on a road arm or in the junction, counting `margin` metres beyond the kerb?"""
        edge = self.road_width / 2 + margin
        return (abs(y) <= edge and abs(x) <= self.arm_length + margin) or \
            (abs(x) <= edge and abs(y) <= self.arm_length + margin)

    def direction(self, x: float, y: float) -> float | None:
        """The travel direction (rad) of the lane at (x, y); None in the junction box or off the roads."""
        half = self.road_width / 2
        edge = half + self.tolerance
        on_x_road = abs(y) <= edge and half < abs(x) <= self.arm_length
        on_y_road = abs(x) <= edge and half < abs(y) <= self.arm_length
        if on_x_road and not on_y_road:
            return 0.0 if y < 0 else math.pi
        if on_y_road and not on_x_road:
            return math.pi / 2 if x > 0 else -math.pi / 2
        return None

    def centre_shift(self, obj) -> float:
        """How far (m, to the object's left) the centre line of the lane it drives in is from its centre:
        the lane of the road it is on that goes its way (in the junction box too, where its heading says
        which road it follows); 0 off the roads or when its heading follows neither road."""
        edge = self.road_width / 2 + self.tolerance
        quarter = self.road_width / 4
        for d in (0.0, math.pi, math.pi / 2, -math.pi / 2):
            if abs(float(wrap(obj.yaw - d))) > self.max_deviation:
                continue
            if d in (0.0, math.pi) and abs(obj.y) <= edge and abs(obj.x) <= self.arm_length:
                cx, cy = obj.x, (-quarter if d == 0.0 else quarter)  # eastbound south of the centre line
            elif d not in (0.0, math.pi) and abs(obj.x) <= edge and abs(obj.y) <= self.arm_length:
                cx, cy = (quarter if d > 0 else -quarter), obj.y  # northbound east of it
            else:
                continue
            return -(cx - obj.x) * math.sin(obj.yaw) + (cy - obj.y) * math.cos(obj.yaw)
        return 0.0

    def snap(self, obj):
        """The object with its heading along its lane (speed kept), or unchanged."""
        if obj.static or obj.speed < 1.0:
            return obj
        d = self.direction(obj.x, obj.y)
        if d is None or abs(float(wrap(obj.yaw - d))) > self.max_deviation:
            return obj
        return replace(obj, yaw=d, yaw_rate=0.0)
