"""A GNSS receiver on a vehicle: noisy fixes of its true pose, in local metres.

Error model per fix: white Gaussian noise (std `sigma_h` on each of x and
y, `sigma_v` on z, `sigma_heading_deg` on the heading, `sigma_speed` on the
speed) plus an optional position bias that random-walks between fixes (std
`bias_walk_h`/`bias_walk_v` * sqrt(dt), starting at zero): the slowly
drifting error of a real receiver that averaging over fixes does not remove.

The noise stream is a numpy Generator seeded from (seed, crc32 of the
vehicle name): the same scenario gives the same fixes, and two vehicles with
the same seed still get independent noise. Every fix draws the same number
of variates, so changing a sigma never shifts the rest of the stream.

Fix frame: x east, y north, z up (the antenna, on the roof above the rear
axle), heading in rad counter-clockwise from +x (the FMU's yaw, wrapped to
[-pi, pi)), speed in m/s (noise clipped at 0: a receiver reports no
negative speed).
"""
from __future__ import annotations

import math
import zlib

import numpy as np

from bridges.sensor_stream import GnssFix
from master.world.layout import GnssSpec


Fix = GnssFix  # the fix an app receives over the bus is the one the world makes


class Gnss:
    def __init__(self, spec: GnssSpec, vehicle: str):
        self.spec, self.vehicle = spec, vehicle
        self.rng = np.random.default_rng([spec.seed, zlib.crc32(vehicle.encode())])
        self.bias = np.zeros(3)
        self._last_t: float | None = None
        self.count = 0

    def fix(self, t: float, x: float, y: float, z: float, heading: float, speed: float) -> Fix:
        """The fix at time t for the true antenna position (x, y, z), heading (rad) and speed (m/s)."""
        s = self.spec
        walk, white = self.rng.standard_normal(3), self.rng.standard_normal(5)
        if self._last_t is not None and t > self._last_t:
            dt = t - self._last_t
            self.bias += walk * np.array([s.bias_walk_h, s.bias_walk_h, s.bias_walk_v]) * math.sqrt(dt)
        self._last_t = t
        ex, ey, ez = self.bias + white[:3] * np.array([s.sigma_h, s.sigma_h, s.sigma_v])
        h = math.remainder(heading + white[3] * math.radians(s.sigma_heading_deg), math.tau)
        if h >= math.pi:
            h -= math.tau
        self.count += 1
        return Fix(t, x + ex, y + ey, z + ez, h, max(0.0, speed + white[4] * s.sigma_speed))
