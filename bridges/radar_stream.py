"""Radar object lists on the bus (`radar/<name>`), as a roadside radar reports them.

A traffic radar of the kind mounted on a signal mast for advance detection on
an approach (long range, narrow beam) reports, per scan, the objects it
resolved: each one's range, its azimuth from the radar's boresight and its
radial (Doppler) speed. It says nothing of what kind of vehicle an object is.
A scan also states where the radar is, where it points and what it covers
(field of view, range limits) and its 1-sigma accuracies, so an app needs no
configuration of its own to place the objects, weigh them against a camera's,
and know where a silence means "nothing there" (coverage) and where it means
nothing at all.

The payload is one JSON object (small: a few objects per scan). Angles are
radians; the boresight `heading` counter-clockwise from east; an object's
`azimuth` counter-clockwise from the boresight; `radial_speed` positive away
from the radar.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

from bridges.headed_payload import json_object

KEY = "radar/{}"
_HEADER = ("radar", "scan_id", "t", "position", "heading", "fov", "min_range_m", "max_range_m",
           "sigma_range_m", "sigma_azimuth", "sigma_speed", "objects")


class RadarStreamError(ValueError):
    """A radar payload that cannot be used; the message says every reason."""


@dataclass(frozen=True)
class RadarObject:
    range_m: float
    azimuth: float        # rad, CCW from the boresight
    radial_speed: float   # m/s, positive away from the radar


@dataclass
class RadarScan:
    radar: str
    scan_id: int
    t: float                                  # the scan's simulation time
    position: tuple[float, float, float]      # world metres
    heading: float                            # boresight, rad CCW from east
    fov: float                                # full horizontal field of view, rad
    min_range_m: float
    max_range_m: float
    sigma_range_m: float
    sigma_azimuth: float                      # rad
    sigma_speed: float                        # m/s
    objects: list[RadarObject] = field(default_factory=list)

    @property
    def sensor(self) -> str:
        """The name an app's ingest files it under (as a camera frame's camera)."""
        return self.radar

    @property
    def seq(self) -> int:
        return self.scan_id

    def covers(self, x: float, y: float) -> bool:
        """Whether world point (x, y) is inside the radar's field of view and range limits."""
        dx, dy = x - self.position[0], y - self.position[1]
        r = math.hypot(dx, dy)
        if not self.min_range_m <= r <= self.max_range_m:
            return False
        off = (math.atan2(dy, dx) - self.heading + math.pi) % (2 * math.pi) - math.pi
        return abs(off) <= self.fov / 2

    def ground_point(self, obj: RadarObject) -> tuple[float, float]:
        """An object's world (x, y) on the ground from its range and azimuth (the radar's height removed)."""
        h = self.position[2]
        g = math.sqrt(max(obj.range_m ** 2 - h ** 2, 0.0))
        a = self.heading + obj.azimuth
        return self.position[0] + g * math.cos(a), self.position[1] + g * math.sin(a)

    def ground_covariance(self, obj: RadarObject) -> tuple[float, float, float]:
        """(var_x, cov_xy, var_y) of `ground_point` from the stated range and azimuth accuracies."""
        h = self.position[2]
        g = math.sqrt(max(obj.range_m ** 2 - h ** 2, 1e-6))
        sr = self.sigma_range_m * obj.range_m / g  # ground range error from slant range error
        st = g * self.sigma_azimuth
        a = self.heading + obj.azimuth
        c, s = math.cos(a), math.sin(a)
        var_x = (c * sr) ** 2 + (s * st) ** 2
        var_y = (s * sr) ** 2 + (c * st) ** 2
        cov = c * s * (sr ** 2 - st ** 2)
        return var_x, cov, var_y


def encode_scan(scan: RadarScan) -> bytes:
    d = {"radar": scan.radar, "scan_id": int(scan.scan_id), "t": float(scan.t),
         "position": [float(v) for v in scan.position], "heading": float(scan.heading), "fov": float(scan.fov),
         "min_range_m": float(scan.min_range_m), "max_range_m": float(scan.max_range_m),
         "sigma_range_m": float(scan.sigma_range_m), "sigma_azimuth": float(scan.sigma_azimuth),
         "sigma_speed": float(scan.sigma_speed),
         "objects": [[float(o.range_m), float(o.azimuth), float(o.radial_speed)] for o in scan.objects]}
    return json.dumps(d, separators=(",", ":")).encode()


def _number(d: dict, key: str, problems: list[str], low: float | None = None, positive: bool = False) -> float:
    v = d.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        problems.append(f"{key}: not a finite number ({v!r})")
        return 0.0
    if positive and v <= 0:
        problems.append(f"{key}: must be > 0, got {v}")
    elif low is not None and v < low:
        problems.append(f"{key}: must be >= {low}, got {v}")
    return float(v)


def decode_scan(payload: bytes) -> RadarScan:
    """The scan in `payload`; raises RadarStreamError naming every bad or missing key."""
    d = json_object(payload, _HEADER, RadarStreamError, "radar")
    problems: list[str] = []
    if not isinstance(d["radar"], str) or not d["radar"]:
        problems.append(f"radar: not a name ({d['radar']!r})")
    scan_id = d["scan_id"]
    if isinstance(scan_id, bool) or not isinstance(scan_id, int) or scan_id < 0:
        problems.append(f"scan_id: not a count ({scan_id!r})")
    t = _number(d, "t", problems)
    pos = d["position"]
    if not (isinstance(pos, list) and len(pos) == 3 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in pos)):
        problems.append(f"position: not three finite numbers ({pos!r})")
        pos = [0.0, 0.0, 0.0]
    heading = _number(d, "heading", problems)
    fov = _number(d, "fov", problems, positive=True)
    if fov > 2 * math.pi:
        problems.append(f"fov: more than a full turn ({fov} rad)")
    rmin = _number(d, "min_range_m", problems, low=0.0)
    rmax = _number(d, "max_range_m", problems, positive=True)
    if rmax <= rmin:
        problems.append(f"max_range_m: must exceed min_range_m ({rmax} <= {rmin})")
    sr = _number(d, "sigma_range_m", problems, positive=True)
    sa = _number(d, "sigma_azimuth", problems, positive=True)
    sv = _number(d, "sigma_speed", problems, positive=True)
    objects = []
    raw = d["objects"]
    if not isinstance(raw, list):
        problems.append("objects: not a list")
        raw = []
    for i, o in enumerate(raw):
        if not (isinstance(o, list) and len(o) == 3 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in o)):
            problems.append(f"objects[{i}]: not [range_m, azimuth, radial_speed] as finite numbers ({o!r})")
            continue
        if o[0] <= 0:
            problems.append(f"objects[{i}]: range_m must be > 0, got {o[0]}")
            continue
        objects.append(RadarObject(float(o[0]), float(o[1]), float(o[2])))
    if problems:
        raise RadarStreamError("radar: " + "; ".join(problems))
    return RadarScan(d["radar"], scan_id, t, (float(pos[0]), float(pos[1]), float(pos[2])), heading, fov, rmin, rmax,
                     sr, sa, sv, objects)
