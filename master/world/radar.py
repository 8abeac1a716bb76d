"""A roadside traffic radar: per scan, the vehicles it resolves as (range, azimuth, radial speed).

The model is geometric, not a ray tracer, because an advance-detection radar
on a signal mast is specified by its coverage and accuracies, not by what its
beam bounces off: a vehicle is reported when its body centre is

* inside the horizontal field of view about the boresight,
* within [min_range_m, max_range_m] of slant (3D) range from the antenna,
* in clear line of sight from the antenna (buildings only: other vehicles do
  not occlude, as a mast-high radar looks over cars and resolves vehicles
  queued behind one another by range and Doppler), and
* drawn as detected (a uniform draw < p_detect).

What it reports carries Gaussian noise: slant range + N(0, sigma_range_m),
azimuth from the boresight + N(0, sigma_azimuth), radial speed (the
vehicle's velocity along the unit line of sight, positive away from the
radar, so an approaching vehicle is negative) + N(0, sigma_speed). No vehicle
name or class goes out (a radar does not know them); objects are sorted by
range. `reported` keeps the names behind the last scan's objects, for the
master's own bookkeeping only.

Repeatability: the radar owns a numpy Generator seeded from its spec, and
every scan draws the same number of variates per vehicle (one uniform, three
normals) in sorted-name order whether or not the vehicle is covered, so a
lockstep run repeats bit for bit and one vehicle entering the beam does not
shift another's noise.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np

from bridges.radar_stream import RadarObject, RadarScan
from master.world.layout import RadarSpec, VehicleSpec

Point = Sequence[float]
MIN_REPORTED_RANGE_M = 1e-3  # the wire format refuses a range <= 0; noise never takes one below this


@dataclass(frozen=True)
class Target:
    """A vehicle as the radar sees it: body centre (m), speed (m/s) along heading (rad CCW from +x)."""
    x: float
    y: float
    z: float
    speed: float
    heading: float


def targets(poses: Mapping[str, tuple[float, float, float, float]], vehicles: Mapping[str, VehicleSpec]
            ) -> dict[str, Target]:
    """Targets from the scene's rear-axle poses (x, y, yaw, v): the body centre `centre_offset` ahead of the
    rear axle (as master/world/lidar.py places its mount), at half the body's height."""
    out = {}
    for name, (x, y, yaw, v) in poses.items():
        spec = vehicles[name]
        c = spec.centre_offset
        out[name] = Target(x + c * math.cos(yaw), y + c * math.sin(yaw), spec.height / 2, v, yaw)
    return out


def _always_clear(p: Point, q: Point) -> bool:
    return True


class Radar:
    """One radar of `spec`; `clear(p, q)` says whether the segment p->q is free of buildings."""

    def __init__(self, spec: RadarSpec, clear: Callable[[Point, Point], bool] = _always_clear):
        self.spec, self.clear = spec, clear
        self.position = tuple(float(v) for v in spec.position)
        self.heading = math.radians(spec.heading_deg)
        self.fov = math.radians(spec.fov_deg)
        self.sigma_azimuth = math.radians(spec.sigma_azimuth_deg)
        self.rng = np.random.default_rng(spec.seed)
        self.scan_id = 0
        self.scan_times: list[float] = []   # perf_counter seconds per scan
        self.reported: list[str] = []       # names behind the last scan's objects, in their order

    def scan(self, t: float, vehicles: Mapping[str, Target]) -> RadarScan:
        """The scan at time `t` of `vehicles` (name -> Target)."""
        t0 = time.perf_counter()
        s = self.spec
        px, py, pz = self.position
        found: list[tuple[RadarObject, str]] = []
        for name in sorted(vehicles):
            u = self.rng.random()
            noise = self.rng.standard_normal(3)
            v = vehicles[name]
            dx, dy, dz = v.x - px, v.y - py, v.z - pz
            r = math.sqrt(dx * dx + dy * dy + dz * dz)
            if not s.min_range_m <= r <= s.max_range_m:
                continue
            az = (math.atan2(dy, dx) - self.heading + math.pi) % (2 * math.pi) - math.pi
            if abs(az) > self.fov / 2 or u >= s.p_detect or not self.clear(self.position, (v.x, v.y, v.z)):
                continue
            radial = v.speed * (math.cos(v.heading) * dx + math.sin(v.heading) * dy) / r
            obj = RadarObject(max(r + s.sigma_range_m * noise[0], MIN_REPORTED_RANGE_M),
                              az + self.sigma_azimuth * noise[1],
                              radial + s.sigma_speed * noise[2])
            found.append((obj, name))
        found.sort(key=lambda f: f[0].range_m)
        self.reported = [n for _, n in found]
        out = RadarScan(s.name, self.scan_id, t, self.position, self.heading, self.fov, s.min_range_m,
                        s.max_range_m, s.sigma_range_m, self.sigma_azimuth, s.sigma_speed, [o for o, _ in found])
        self.scan_id += 1
        self.scan_times.append(time.perf_counter() - t0)
        return out
