"""J2735 data elements in SI units and degrees, and back to wire integers.

Each `Scale` knows the element's resolution, its valid range and its
"unavailable" code: `to_wire(None)` sends the code, `from_wire(code)` gives
None, and a value outside the range is refused at encode time with the
element's name, the value and the range in SI units.

Codes the standard reserves (secMark 61000..65534, a 2020 TimeMark's
36010..36110) have no value in SI units. A decoder that accepts them must not
make the message impossible to send on: `from_wire` gives them as
`Reserved(code)`, an int that remembers it is a wire code, and `to_wire`
sends a `Reserved` back unchanged. A plain number in that range (a value
computed by user code) is still refused.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from bridges.j2735.editions import DEFAULT_EDITION, EDITIONS, Edition, edition as edition_named
from bridges.j2735.errors import J2735Error

G = 9.80665  # m/s2, standard gravity (VerticalAcceleration is in units of 0.02 G)


class Reserved(int):
    """A code the standard reserves, kept as received so that decode -> encode gives the same bytes."""

    def __repr__(self) -> str:
        return f"Reserved({int(self)})"


@dataclass(frozen=True)
class Scale:
    name: str
    unit: str
    step: float             # SI value of one wire unit
    low: int                # smallest valid wire value
    high: int               # largest valid wire value (the unavailable code excluded)
    unavailable: int | None = None
    wraps: bool = False     # angles: values are taken modulo the full circle
    reserved: tuple[int, int] | None = None  # wire codes the standard reserves: Reserved both ways

    def to_wire(self, value: float | None) -> int:
        if value is None:
            if self.unavailable is None:
                raise J2735Error(f"{self.name}: a value is required (the element has no 'unavailable' code)")
            return self.unavailable
        if isinstance(value, Reserved):
            if self.reserved is None or not self.reserved[0] <= value <= self.reserved[1]:
                raise J2735Error(f"{self.name}: {value!r} is not a reserved code of this element"
                                 + (f" ({self.reserved[0]}..{self.reserved[1]})" if self.reserved else ""))
            return int(value)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise J2735Error(f"{self.name}: {value!r} is not a finite number")
        if self.wraps:
            value = math.fmod(value, 360.0) % 360.0
        raw = round(value / self.step)
        if self.wraps and raw == self.high + 1:
            raw = 0
        if not self.low <= raw <= self.high:
            reserved = f"; codes {self.reserved[0]}..{self.reserved[1]} are reserved" if self.reserved else ""
            raise J2735Error(f"{self.name}: {value:g} {self.unit} is outside "
                             f"{self.low * self.step:g}..{self.high * self.step:g} {self.unit}{reserved}")
        return raw

    def from_wire(self, raw: int) -> float | None:
        if self.unavailable is not None and raw == self.unavailable:
            return None
        if self.reserved is not None and self.reserved[0] <= raw <= self.reserved[1]:
            return Reserved(raw)
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
SEC_MARK = Scale("secMark", "ms", 1, 0, 60999, unavailable=65535,  # 60000..60999: leap second
                 reserved=(61000, 65534))
# VehicleWidth/Length: 1 cm; deployed encoders send 0 when the size is not known.
VEHICLE_WIDTH = Scale("vehicle width", "m", 0.01, 1, 1023, unavailable=0)
VEHICLE_LENGTH = Scale("vehicle length", "m", 0.01, 1, 4095, unavailable=0)
SEMI_AXIS = Scale("position accuracy semi-axis", "m", 0.05, 0, 254, unavailable=255)  # 254: >= 12.7 m
SEMI_AXIS_ORIENTATION = Scale("position accuracy orientation", "deg", 360 / 65535, 0, 65534,
                              unavailable=65535)


def _time_mark(e: Edition) -> Scale:
    """Tenths of a second in the hour. 2016: 36000 is 'more than an hour away', 36001 unknown; 2020:
    36000..36009 are the tenths of a leap second (3600.0..3600.9 s), 36010..36110 reserved, 36111 unknown."""
    return Scale("time mark", "s", 0.1, 0, e.time_mark_last, unavailable=e.time_mark_unknown,
                 reserved=e.time_mark_reserved)


TIME_MARKS: dict[str, Scale] = {name: _time_mark(e) for name, e in EDITIONS.items()}


def time_mark(edition: "str | Edition | None" = None) -> Scale:
    """The TimeMark scale of an edition (a name, or an Edition such as `codec.edition`; None:
    $V2I_J2735_EDITION, else the default), the one to use with a codec: `time_mark(codec.edition)`."""
    return TIME_MARKS[edition_named(edition).name]


TIME_MARK = TIME_MARKS[DEFAULT_EDITION]  # the default edition's; a codec's own: time_mark(codec.edition)
