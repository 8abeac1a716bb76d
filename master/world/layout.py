"""The `[world]` table of a scenario: what the pybullet world is made of.

Pure data and validation (no pybullet import), so `v2i validate` checks a
world without building it. Frame: x east, y north, z up, metres; the
intersection is centred at the origin, one road along x and one along y.

    origin = { lat = 42.2808, lon = -83.7430, alt = 260.0 }   # WGS-84 of the local (0, 0, 0);
                                    # default bridges.geo.DEFAULT_LAT/LON/ALT; apps get it when they join

    [world.intersection]            # all optional
    road_width = 7.0                # carriageway width of each road (m)
    lane_width = 3.5
    arm_length = 120.0              # road length from the centre outwards (m); the map is
                                    # the square |x|, |y| <= arm_length
    sidewalk_width = 2.0

    [[world.buildings]]             # axis-aligned boxes standing on the ground
    name = "sw_corner"; x = -30.0; y = -30.0   # centre (m)
    size_x = 48.0; size_y = 48.0; height = 15.0

    [[world.cameras]]
    name = "rsu_cam"; x = 8.0; y = -8.0; z = 6.0   # optical centre (m)
    yaw = 135.0      # heading of the optical axis, deg CCW from +x
    pitch = -20.0    # elevation of the optical axis, deg (negative looks down)
    roll = 0.0       # about the optical axis, deg
    width = 640; height = 480; fov_deg = 90.0  # horizontal field of view
    rate_hz = 10.0

    [world.vehicles.cav]            # key = a VehicleDynamics instance in [fmus]
    length = 4.5; width = 1.8; height = 1.5
    color = [0.1, 0.3, 0.8]         # RGB in 0..1
    kind = "car"                    # or "emergency"
    rear_overhang = 0.95            # rear bumper behind the rear axle (m); default
                                    # (length - wheelbase) / 2 with the instance's wheelbase
    [world.vehicles.cav.lidar]      # at most one vehicle carries a lidar
    channels = 16; horizontal_samples = 1024; range = 100.0; rate_hz = 10.0
    fov_up = 15.0; fov_down = -15.0  # deg; mount height = vehicle height + mount_above_roof
    [world.vehicles.cav.gnss]       # a GNSS receiver on the roof (any vehicle may carry one)
    rate_hz = 10.0                  # fixes per second
    sigma_h = 0.5; sigma_v = 1.0    # white noise std per horizontal axis / vertical (m)
    sigma_heading_deg = 1.0; sigma_speed = 0.05   # heading (deg) and speed (m/s) noise std
    bias_walk_h = 0.0; bias_walk_v = 0.0          # random-walk bias (m per sqrt(s)); 0 = none
    seed = 0                        # with the vehicle's name: the noise stream

    [world.radars.west]             # a roadside traffic radar (master/world/radar.py), keyed by name
    position = [6.5, 6.5, 6.0]      # antenna (m); required
    heading_deg = 180.0             # boresight, deg CCW from +x; required
    fov_deg = 16.0                  # full horizontal field of view, (0, 360]
    min_range_m = 5.0; max_range_m = 250.0   # slant range limits (m)
    rate_hz = 20.0                  # scans per second
    sigma_range_m = 0.25; sigma_azimuth_deg = 0.25; sigma_speed = 0.1   # 1-sigma noise
    p_detect = 0.98                 # chance an object in coverage with a clear view is reported, (0, 1]
    seed = 1                        # the radar's own noise stream

    [[world.signals]]               # a traffic-light head: pole, housing, red/yellow/green lamps
    name = "nb_head"; x = 5.5; y = 5.5      # pole foot (m)
    yaw = 270.0                     # direction the lamps face, deg CCW from +x (toward the drivers)
    signal_group = 2                # 1..8: shows the controller's state_2 output
    instance = "tlc"                # a TrafficLightController in [fmus]; default: the only one
    height = 4.5                    # lamp housing centre above ground (m)
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any, Callable

from bridges.geo import GeoError, GeoOrigin
from master.scenario.tables import Table, did_you_mean, is_number

DEFAULT_WHEELBASE = 2.3927  # VehicleDynamics default (CommonRoad vehicle 1)
VEHICLE_KINDS = ("car", "emergency")
TLC_MODEL = "TrafficLightController"
_TOP = ("origin", "intersection", "buildings", "cameras", "vehicles", "signals", "radars", "renderer",
        "sensor_processes")
RENDERERS = ("auto", "tiny", "egl")  # master/world/renderer.py
_INTERSECTION = ("road_width", "lane_width", "arm_length", "sidewalk_width")
_BUILDING = ("name", "x", "y", "size_x", "size_y", "height")
_CAMERA = ("name", "x", "y", "z", "yaw", "pitch", "roll", "width", "height", "fov_deg", "rate_hz")
_VEHICLE = ("length", "width", "height", "color", "kind", "rear_overhang", "lidar", "gnss")
_LIDAR = ("channels", "horizontal_samples", "range", "rate_hz", "fov_up", "fov_down", "mount_above_roof")
_GNSS = ("rate_hz", "sigma_h", "sigma_v", "sigma_heading_deg", "sigma_speed", "bias_walk_h", "bias_walk_v",
         "seed")
_RADAR = ("position", "heading_deg", "fov_deg", "min_range_m", "max_range_m", "rate_hz", "sigma_range_m",
          "sigma_azimuth_deg", "sigma_speed", "p_detect", "seed")
_RADAR_NAME = re.compile(r"^[A-Za-z0-9_-]+$")
_SIGNAL = ("name", "x", "y", "yaw", "signal_group", "instance", "height")
_VEHICLE_DEFAULTS = {"car": (4.5, 1.8, 1.5, (0.15, 0.3, 0.8)), "emergency": (6.5, 2.3, 2.6, (0.9, 0.1, 0.1))}


@dataclass
class Intersection:
    road_width: float = 7.0
    lane_width: float = 3.5
    arm_length: float = 120.0
    sidewalk_width: float = 2.0


@dataclass
class Building:
    name: str
    x: float
    y: float
    size_x: float
    size_y: float
    height: float

    @property
    def bounds(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """(min corner, max corner) of the box."""
        hx, hy = self.size_x / 2, self.size_y / 2
        return (self.x - hx, self.y - hy, 0.0), (self.x + hx, self.y + hy, self.height)


@dataclass
class CameraSpec:
    name: str
    x: float
    y: float
    z: float
    yaw: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0
    width: int = 640
    height: int = 480
    fov_deg: float = 90.0
    rate_hz: float = 10.0


@dataclass
class LidarSpec:
    channels: int = 16
    horizontal_samples: int = 1024
    range: float = 100.0
    rate_hz: float = 10.0
    fov_up: float = 15.0
    fov_down: float = -15.0
    mount_above_roof: float = 0.3


@dataclass
class GnssSpec:
    rate_hz: float = 10.0
    sigma_h: float = 0.5
    sigma_v: float = 1.0
    sigma_heading_deg: float = 1.0
    sigma_speed: float = 0.05
    bias_walk_h: float = 0.0
    bias_walk_v: float = 0.0
    seed: int = 0


@dataclass
class RadarSpec:
    """A mast-mounted traffic radar (master/world/radar.py); angles in degrees as the scenario writes them."""
    name: str
    position: tuple[float, float, float]  # antenna, world metres
    heading_deg: float                    # boresight, CCW from +x
    fov_deg: float = 16.0                 # full horizontal field of view
    min_range_m: float = 5.0              # slant range limits
    max_range_m: float = 250.0
    rate_hz: float = 20.0
    sigma_range_m: float = 0.25           # 1-sigma noise of each reported quantity
    sigma_azimuth_deg: float = 0.25
    sigma_speed: float = 0.1              # m/s
    p_detect: float = 0.98                # per object and scan, when covered and in clear view
    seed: int = 1


@dataclass
class SignalSpec:
    name: str
    x: float
    y: float
    yaw: float  # deg: the direction the lamps face
    signal_group: int
    instance: str  # the TrafficLightController instance whose state_<signal_group> it shows
    height: float = 4.5


@dataclass
class VehicleSpec:
    name: str  # the FMU instance it is posed from
    length: float = 4.5
    width: float = 1.8
    height: float = 1.5
    color: tuple[float, float, float] = (0.15, 0.3, 0.8)
    kind: str = "car"
    rear_overhang: float = 0.95
    lidar: LidarSpec | None = None
    gnss: GnssSpec | None = None

    @property
    def centre_offset(self) -> float:
        """Distance from the rear axle (the FMU's x, y) forward to the body centre."""
        return self.length / 2 - self.rear_overhang


@dataclass
class WorldLayout:
    intersection: Intersection = field(default_factory=Intersection)
    buildings: list[Building] = field(default_factory=list)
    cameras: list[CameraSpec] = field(default_factory=list)
    vehicles: dict[str, VehicleSpec] = field(default_factory=dict)
    signals: list[SignalSpec] = field(default_factory=list)
    origin: GeoOrigin = field(default_factory=GeoOrigin)
    radars: dict[str, RadarSpec] = field(default_factory=dict)
    renderer: str = "auto"  # "auto", "tiny" or "egl" (V2I_RENDERER overrides it)
    sensor_processes: bool = True  # cameras and lidars in worker processes beside the loop (sensor_worker.py)

    @property
    def half_extent(self) -> float:
        return self.intersection.arm_length

    def describe(self) -> dict[str, Any]:
        """What every app is told of the world when it joins (bridges.timesync Welcome.world): the geodetic
        origin, the intersection's geometry (centred at the origin, one road along x and one along y,
        driving on the right) and the signal heads with the signal group each shows."""
        from dataclasses import asdict

        return {"origin": self.origin.to_dict(), "intersection": asdict(self.intersection),
                "signals": [{"name": s.name, "x": s.x, "y": s.y, "yaw": s.yaw, "signal_group": s.signal_group}
                            for s in self.signals]}

    def resolved(self) -> dict[str, Any]:
        """The [world] table with defaults filled in, loadable again (vehicles keyed by name)."""
        from dataclasses import asdict

        out = asdict(self)
        out["origin"] = self.origin.to_dict()
        for v in out["vehicles"].values():
            v.pop("name")
            v["color"] = list(v["color"])
        if out["radars"]:
            for r in out["radars"].values():
                r.pop("name")
                r["position"] = list(r["position"])
        else:  # a world without radars resolves as it did before they existed
            del out["radars"]
        for key, default in (("renderer", "auto"), ("sensor_processes", True)):  # likewise for these keys
            if out[key] == default:
                del out[key]
        return out


_POSITIVE = {"low": 0, "low_open": True}  # Table.number bounds: > 0
_NONNEG = {"low": 0}  # >= 0


def _boxes_overlap(a: Building, b: Building) -> bool:
    (ax0, ay0, _), (ax1, ay1, _) = a.bounds
    (bx0, by0, _), (bx1, by1, _) = b.bounds
    return ax0 < bx1 and bx0 < ax1 and ay0 < by1 and by0 < ay1  # touching faces are allowed


def read_section(value: Any, context) -> WorldLayout | None:
    """The `[world]` section's reader (master.scenario.sections)."""
    return parse_world(value, context.instances, context.problem)


def parse_world(table: Any, instances: dict, problem: Callable[[str, str], None]) -> WorldLayout | None:
    """Validate the `[world]` table; every problem goes to `problem(key, message)`.

    `instances` maps FMU instance names to master.scenario.loader.Instance (its
    `parameters` give a vehicle's start position and wheelbase).
    """
    t = Table(table, "world", problem)
    if not t.ok:
        return None
    for key in t.raw:  # said as "world: unknown key 'x'" (tests/test_scenario.py expects the "world:" prefix)
        if key not in _TOP:
            hint = did_you_mean(key, _TOP)
            t.problem(None, f"unknown key {key!r} (expected one of: {', '.join(_TOP)})" + (f"; {hint}" if hint else ""))
    layout = WorldLayout()
    if "origin" in t:
        try:
            layout.origin = GeoOrigin.from_dict(t.get("origin"))
        except GeoError as exc:
            t.problem("origin", str(exc))

    inter = t.sub("intersection")
    inter.unknown_keys(_INTERSECTION)
    d = Intersection()
    ix = Intersection(road_width=inter.number("road_width", d.road_width, **_POSITIVE),
                      lane_width=inter.number("lane_width", d.lane_width, **_POSITIVE),
                      arm_length=inter.number("arm_length", d.arm_length, **_POSITIVE),
                      sidewalk_width=inter.number("sidewalk_width", d.sidewalk_width, **_NONNEG))
    if ix.lane_width > ix.road_width:
        inter.problem("lane_width", f"wider than the road ({ix.lane_width} > road_width {ix.road_width})")
    if ix.arm_length <= ix.road_width / 2 + ix.sidewalk_width:
        inter.problem("arm_length", "must reach beyond the sidewalks (> road_width/2 + sidewalk_width)")
    layout.intersection = ix
    half = ix.arm_length

    layout.buildings = _buildings(t, ix)
    layout.cameras = _cameras(t, layout.buildings, half)
    layout.vehicles = _vehicles(t, instances, half)
    layout.signals = _signals(t, instances, layout.buildings, half)
    layout.radars = _radars(t, layout.buildings, half)
    layout.renderer = t.choice("renderer", RENDERERS, "auto")
    layout.sensor_processes = t.boolean("sensor_processes", True)
    return layout if t.ok else None


def _named_list(world: Table, key: str) -> list[Table]:
    """The tables of the array of tables `[[world.KEY]]`, each named by a unique `name`."""
    where = world.key(key)
    items = world.get(key, [])
    if not isinstance(items, list):
        world.problem(key, f"expected an array of tables ([[{where}]]), got {type(items).__name__}")
        return []
    out = []
    names: dict[str, str] = {}
    for i, item in enumerate(items):
        t = Table(item, f"{where}[{i}]", parent=world)
        if not t.ok:
            continue
        name = t.string("name", required=True)
        if name is None:
            name = f"{key}{i}"
        elif name in names:
            t.problem("name", f"duplicate name {name!r} (also {names[name]})")
        names[name] = t.prefix
        out.append(t)
    return out


def _buildings(world: Table, ix: Intersection) -> list[Building]:
    out: list[tuple[str, Building]] = []
    for t in _named_list(world, "buildings"):
        t.unknown_keys(_BUILDING)
        b = Building(str(t.get("name", "")), t.number("x", 0.0), t.number("y", 0.0),
                     t.number("size_x", 1.0, **_POSITIVE), t.number("size_y", 1.0, **_POSITIVE),
                     t.number("height", 1.0, **_POSITIVE))
        (x0, y0, _), (x1, y1, _) = b.bounds
        if max(abs(x0), abs(x1), abs(y0), abs(y1)) > ix.arm_length:
            t.problem(None, f"outside the map (|x|, |y| <= arm_length {ix.arm_length})")
        hw = ix.road_width / 2
        if (x0 < hw and x1 > -hw) or (y0 < hw and y1 > -hw):
            t.problem(None, f"stands on the carriageway (|x| or |y| < road_width/2 = {hw})")
        for other_key, other in out:
            if _boxes_overlap(b, other):
                t.problem(None, f"overlaps {other_key} ({other.name})")
        out.append((t.prefix, b))
    return [b for _, b in out]


def _cameras(world: Table, buildings: list[Building], half: float) -> list[CameraSpec]:
    out = []
    d = CameraSpec("", 0, 0, 0)
    for t in _named_list(world, "cameras"):
        t.unknown_keys(_CAMERA)
        c = CameraSpec(str(t.get("name", "")), t.number("x", 0.0), t.number("y", 0.0),
                       t.number("z", 5.0, **_POSITIVE),
                       t.number("yaw", d.yaw), t.number("pitch", d.pitch), t.number("roll", d.roll),
                       t.number("width", d.width, integer=True, **_POSITIVE),
                       t.number("height", d.height, integer=True, **_POSITIVE),
                       t.number("fov_deg", d.fov_deg, **_POSITIVE),
                       t.number("rate_hz", d.rate_hz, **_POSITIVE))
        if c.fov_deg >= 170:
            t.problem("fov_deg", f"must be < 170 (a pinhole camera), got {c.fov_deg}")
        if not -90 < c.pitch < 90:
            t.problem("pitch", f"must be within (-90, 90) degrees, got {c.pitch}")
        if max(abs(c.x), abs(c.y)) > half:
            t.problem(None, f"outside the map (|x|, |y| <= arm_length {half})")
        for i, b in enumerate(buildings):
            (x0, y0, z0), (x1, y1, z1) = b.bounds
            if x0 <= c.x <= x1 and y0 <= c.y <= y1 and z0 <= c.z <= z1:
                t.problem(None, f"inside building world.buildings[{i}] ({b.name})")
        out.append(c)
    return out


def _vehicles(world: Table, instances: dict, half: float) -> dict[str, VehicleSpec]:
    vehicles = world.sub("vehicles", "a table of [world.vehicles.INSTANCE] tables")
    out: dict[str, VehicleSpec] = {}
    lidar_on: str | None = None
    for name in vehicles.raw:
        t = vehicles.sub(name)
        if not t.ok:
            continue
        t.unknown_keys(_VEHICLE)
        inst = instances.get(name)
        if inst is None:
            t.problem(None, f"no FMU instance {name!r} in [fmus] (instances: {', '.join(instances) or 'none'})")
        else:
            outputs = {v.name for v in inst.model_description.modelVariables if v.causality == "output"}
            missing = [v for v in ("x", "y", "yaw") if v not in outputs]
            if missing:
                t.problem(None, f"instance {name!r} has no output(s) {', '.join(missing)} to pose the body from")
        kind = t.choice("kind", VEHICLE_KINDS, "car")
        dl, dw, dh, dc = _VEHICLE_DEFAULTS[kind]
        length = t.number("length", dl, **_POSITIVE)
        width = t.number("width", dw, **_POSITIVE)
        height = t.number("height", dh, **_POSITIVE)
        color = t.get("color", dc)
        if (not isinstance(color, list | tuple) or len(color) != 3
                or not all(is_number(c) and 0 <= c <= 1 for c in color)):
            t.problem("color", f"expected [r, g, b] with each in 0..1, got {color!r}")
            color = dc
        params = inst.parameters if inst is not None else {}
        wheelbase = params.get("wheelbase", DEFAULT_WHEELBASE)
        overhang = t.number("rear_overhang", max((length - wheelbase) / 2, 0.0), **_NONNEG)
        if overhang >= length:
            t.problem("rear_overhang", f"must be shorter than the body ({overhang} >= length {length})")
        v = VehicleSpec(name, length, width, height, tuple(float(c) for c in color), kind, overhang)
        if inst is not None:
            x0, y0 = params.get("x0", 0.0), params.get("y0", 0.0)
            if max(abs(x0), abs(y0)) > half:
                t.problem(None, f"starts outside the map at ({x0}, {y0}) (|x|, |y| <= arm_length {half})")
        if "lidar" in t:
            v.lidar = _lidar(t.sub("lidar"))
            if lidar_on is not None:
                t.problem("lidar", f"only one vehicle carries a lidar (already on {lidar_on})")
            lidar_on = t.prefix
        if "gnss" in t:
            v.gnss = _gnss(t.sub("gnss"))
        out[name] = v
    return out


def _lidar(t: Table) -> LidarSpec | None:
    if not t.ok:  # not a table
        return None
    t.unknown_keys(_LIDAR)
    d = LidarSpec()
    spec = LidarSpec(t.number("channels", d.channels, integer=True, **_POSITIVE),
                     t.number("horizontal_samples", d.horizontal_samples, integer=True, **_POSITIVE),
                     t.number("range", d.range, **_POSITIVE),
                     t.number("rate_hz", d.rate_hz, **_POSITIVE),
                     t.number("fov_up", d.fov_up), t.number("fov_down", d.fov_down),
                     t.number("mount_above_roof", d.mount_above_roof, **_NONNEG))
    if not -90 <= spec.fov_down <= spec.fov_up <= 90:
        t.problem(None, f"need -90 <= fov_down <= fov_up <= 90, got fov_down {spec.fov_down}, fov_up {spec.fov_up}")
    return spec


def _gnss(t: Table) -> GnssSpec | None:
    if not t.ok:  # not a table
        return None
    t.unknown_keys(_GNSS)
    d = GnssSpec()
    noise = {k: t.number(k, getattr(d, k), **_NONNEG)
             for k in ("sigma_h", "sigma_v", "sigma_heading_deg", "sigma_speed", "bias_walk_h", "bias_walk_v")}
    return GnssSpec(rate_hz=t.number("rate_hz", d.rate_hz, **_POSITIVE),
                    seed=t.number("seed", d.seed, integer=True, **_NONNEG), **noise)


def _radars(world: Table, buildings: list[Building], half: float) -> dict[str, RadarSpec]:
    """`[world.radars.NAME]`: keyed by name (as vehicles are), each radar's table read and checked.

    Sigmas must be > 0 (the wire format, bridges.radar_stream, states them as
    accuracies an app divides by) and the ranges positive with max > min.
    """
    radars = world.sub("radars", "a table of [world.radars.NAME] tables")
    out: dict[str, RadarSpec] = {}
    d = RadarSpec("", (0.0, 0.0, 0.0), 0.0)
    for name in radars.raw:
        t = radars.sub(name)
        if not t.ok:
            continue
        t.unknown_keys(_RADAR)
        if not _RADAR_NAME.match(name):
            t.problem(None, f"name {name!r} must be letters, digits, '_' or '-' (it names the bus key radar/NAME)")
        position = t.get("position")
        if "position" not in t:
            t.problem("position", "required: [x, y, z] in metres")
            position = (0.0, 0.0, 0.0)
        elif (not isinstance(position, list | tuple) or len(position) != 3
              or not all(is_number(v) for v in position)):
            t.problem("position", f"expected [x, y, z] as three finite numbers (m), got {position!r}")
            position = (0.0, 0.0, 0.0)
        elif position[2] < 0:
            t.problem("position", f"z must be >= 0 (above the ground), got {position[2]!r}")
        position = tuple(float(v) for v in position)
        r = RadarSpec(
            name, position,
            t.number("heading_deg", 0.0, required=True, expected="a finite number (deg CCW from +x)"),
            t.number("fov_deg", d.fov_deg, low=0, high=360, low_open=True),
            t.number("min_range_m", d.min_range_m, **_POSITIVE),
            t.number("max_range_m", d.max_range_m, **_POSITIVE),
            t.number("rate_hz", d.rate_hz, **_POSITIVE),
            t.number("sigma_range_m", d.sigma_range_m, **_POSITIVE),
            t.number("sigma_azimuth_deg", d.sigma_azimuth_deg, **_POSITIVE),
            t.number("sigma_speed", d.sigma_speed, **_POSITIVE),
            t.number("p_detect", d.p_detect, low=0, high=1, low_open=True),
            t.number("seed", d.seed, integer=True, **_NONNEG))
        if r.max_range_m <= r.min_range_m:
            t.problem("max_range_m", f"must exceed min_range_m ({r.max_range_m} <= {r.min_range_m})")
        x, y, z = r.position
        if max(abs(x), abs(y)) > half:
            t.problem("position", f"outside the map at ({x}, {y}) (|x|, |y| <= arm_length {half})")
        for i, b in enumerate(buildings):
            (x0, y0, z0), (x1, y1, z1) = b.bounds
            if x0 <= x <= x1 and y0 <= y <= y1 and z0 <= z <= z1:
                t.problem("position", f"inside building world.buildings[{i}] ({b.name})")
        out[name] = r
    return out


def _tlc_instances(instances: dict) -> list[str]:
    out = []
    for name, inst in instances.items():
        cs = getattr(inst.model_description, "coSimulation", None)
        if cs is not None and cs.modelIdentifier == TLC_MODEL:
            out.append(name)
    return out


def _signals(world: Table, instances: dict, buildings: list[Building], half: float) -> list[SignalSpec]:
    out = []
    tlcs = _tlc_instances(instances)
    for t in _named_list(world, "signals"):
        t.unknown_keys(_SIGNAL)
        group = t.number("signal_group", 1, low=1, high=8, integer=True, required=True,
                         expected="an integer 1..8 (the controller's state_k output)")
        instance = t.get("instance")
        if instance is None:
            if len(tlcs) != 1:
                t.problem("instance", f"required when [fmus] has {len(tlcs)} {TLC_MODEL} instances "
                                      f"({', '.join(tlcs) or 'none'})")
            instance = tlcs[0] if tlcs else ""
        elif not isinstance(instance, str) or instance not in instances:
            t.problem("instance",
                      f"no FMU instance {instance!r} in [fmus] (instances: {', '.join(instances) or 'none'})")
        elif instance not in tlcs:
            t.problem("instance", f"instance {instance!r} is not a {TLC_MODEL} "
                                  f"({TLC_MODEL} instances: {', '.join(tlcs) or 'none'})")
        s = SignalSpec(str(t.get("name", "")), t.number("x", 0.0), t.number("y", 0.0), t.number("yaw", 0.0),
                       group, str(instance), t.number("height", SignalSpec.height, **_POSITIVE))
        if max(abs(s.x), abs(s.y)) > half:
            t.problem(None, f"outside the map at ({s.x}, {s.y}) (|x|, |y| <= arm_length {half})")
        for i, b in enumerate(buildings):
            (x0, y0, _), (x1, y1, _) = b.bounds
            if x0 <= s.x <= x1 and y0 <= s.y <= y1:
                t.problem(None, f"inside building world.buildings[{i}] ({b.name})")
        out.append(s)
    return out
