"""J2735 data elements in SI units and degrees, and back to wire integers.

Each `Scale` knows the element's resolution, its valid range and its
"unavailable" code: `to_wire(None)` sends the code, `from_wire(code)` gives
None, and a value outside the range is refused at encode time with the
element's name, the value and the range in SI units.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from bridges.j2735.codec import J2735Error

G = 9.80665  # m/s2, standard gravity (VerticalAcceleration is in units of 0.02 G)


@dataclass(frozen=True)
class Scale:
    name: str
    unit: str
    step: float             # SI value of one wire unit
    low: int                # smallest valid wire value
    high: int               # largest valid wire value (the unavailable code excluded)
    unavailable: int | None = None
    wraps: bool = False     # angles: values are taken modulo the full circle

    def to_wire(self, value: float | None) -> int:
        if value is None:
            if self.unavailable is None:
                raise J2735Error(f"{self.name}: a value is required (the element has no 'unavailable' code)")
            return self.unavailable
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise J2735Error(f"{self.name}: {value!r} is not a finite number")
        if self.wraps:
            value = math.fmod(value, 360.0) % 360.0
        raw = round(value / self.step)
        if self.wraps and raw == self.high + 1:
            raw = 0
        if not self.low <= raw <= self.high:
            raise J2735Error(f"{self.name}: {value:g} {self.unit} is outside "
                             f"{self.low * self.step:g}..{self.high * self.step:g} {self.unit}")
        return raw

    def from_wire(self, raw: int) -> float | None:
        if self.unavailable is not None and raw == self.unavailable:
            return None
        return raw * self.step


LATITUDE = Scale("latitude", "deg", 1e-7, -900000000, 900000000, unavailable=900000001)
LONGITUDE = Scale("longitude", "deg", 1e-7, -1799999999, 1800000000, unavailable=1800000001)
ELEVATION = Scale("elevation", "m", 0.1, -4095, 61439, unavailable=-4096)
SPEED = Scale("speed", "m/s", 0.02, 0, 8190, unavailable=8191)
HEADING = Scale("heading", "deg", 0.0125, 0, 28799, unavailable=28800, wraps=True)
STEERING_ANGLE = Scale("steering wheel angle", "deg", 1.5, -126, 126, unavailable=127)
ACCELERATION = Scale("acceleration", "m/s2", 0.01, -2000, 2000, unavailable=2001)
VERTICAL_ACCELERATION = Scale("vertical acceleration", "m/s2", 0.02 * G, -126, 127, unavailable=-127)
YAW_RATE = Scale("yaw rate", "deg/s", 0.01, -32767, 32767)
SEC_MARK = Scale("secMark", "ms", 1, 0, 60999, unavailable=65535)  # 60000..60999: leap second
# VehicleWidth/Length: 1 cm; deployed encoders send 0 when the size is not known.
VEHICLE_WIDTH = Scale("vehicle width", "m", 0.01, 1, 1023, unavailable=0)
VEHICLE_LENGTH = Scale("vehicle length", "m", 0.01, 1, 4095, unavailable=0)
SEMI_AXIS = Scale("position accuracy semi-axis", "m", 0.05, 0, 254, unavailable=255)  # 254: >= 12.7 m
SEMI_AXIS_ORIENTATION = Scale("position accuracy orientation", "deg", 360 / 65535, 0, 65534,
                              unavailable=65535)
TIME_MARK = Scale("time mark", "s", 0.1, 0, 36000, unavailable=36001)  # tenths of a second in the hour
