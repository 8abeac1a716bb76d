"""Local metres <-> WGS-84 around the scenario's geodetic origin (pymap3d does the geodesy).

The world is flat local ENU metres (x east, y north, z up) around the
intersection centre; J2735 speaks latitude, longitude and elevation. The
scenario's `[world] origin = { lat = ..., lon = ..., alt = ... }` ties the
two together; the master hands it to every participant in the join reply
(`Participant.origin`), and the RSU uses it as its MAP's reference point, so
the RSU app, the AV app and a box on the network all convert with the same
origin.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

# Where a scenario without `[world] origin` sits: a signalised junction in Ann Arbor, Michigan
# (the region of the US connected-vehicle test deployments), 260 m above the WGS-84 ellipsoid.
DEFAULT_LAT, DEFAULT_LON, DEFAULT_ALT = 42.2808, -83.7430, 260.0


class GeoError(ValueError):
    """A geodetic origin (or a camera model, a pixel) that cannot be used, with the reason."""


@dataclass(frozen=True)
class GeoOrigin:
    """The scenario's local origin: world (0, 0, 0) is (lat0, lon0, h0) on WGS-84, x east, y north, z up."""

    lat0: float = DEFAULT_LAT
    lon0: float = DEFAULT_LON
    h0: float = DEFAULT_ALT

    def __post_init__(self):
        values = (self.lat0, self.lon0, self.h0)
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
            raise GeoError(f"geo origin must be numbers, got {self}")
        if not all(math.isfinite(v) for v in values):
            raise GeoError(f"geo origin must be finite, got {self}")
        if not -90 <= self.lat0 <= 90 or not -180 <= self.lon0 <= 180:
            raise GeoError(f"geo origin out of range: lat0 {self.lat0}, lon0 {self.lon0}")
        if not -1000 <= self.h0 <= 10000:
            raise GeoError(f"geo origin height {self.h0} m is not on the earth's surface (-1000..10000 m)")

    def to_geodetic(self, x, y, z=0.0) -> tuple:
        """Local ENU metres -> (lat deg, lon deg, ellipsoidal height m)."""
        import pymap3d

        return pymap3d.enu2geodetic(x, y, z, self.lat0, self.lon0, self.h0)

    def to_local(self, lat, lon, h=None) -> tuple:
        """(lat deg, lon deg, height m) -> local ENU metres (x east, y north, z up)."""
        import pymap3d

        return pymap3d.geodetic2enu(lat, lon, self.h0 if h is None else h, self.lat0, self.lon0, self.h0)

    def to_dict(self) -> dict[str, float]:
        """As the scenario writes it and the join reply carries it: {"lat", "lon", "alt"}."""
        return {"lat": self.lat0, "lon": self.lon0, "alt": self.h0}

    @classmethod
    def from_dict(cls, d: Any) -> "GeoOrigin":
        """From {"lat", "lon"[, "alt"]}; GeoError naming the key for anything else."""
        if not isinstance(d, dict):
            raise GeoError(f"geo origin: expected a table {{lat, lon, alt}}, got {type(d).__name__}")
        unknown = sorted(set(d) - {"lat", "lon", "alt"})
        if unknown:
            raise GeoError(f"geo origin: unknown key(s) {', '.join(unknown)} (expected lat, lon, alt)")
        missing = [k for k in ("lat", "lon") if k not in d]
        if missing:
            raise GeoError(f"geo origin: missing {', '.join(missing)}")
        for k in ("lat", "lon", "alt"):
            v = d.get(k, 0.0)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise GeoError(f"geo origin: {k} must be a number, got {v!r}")
        return cls(float(d["lat"]), float(d["lon"]), float(d.get("alt", DEFAULT_ALT)))
