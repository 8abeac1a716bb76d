"""A ghost vehicle: where it is on its path at a time, and the surrogate BSM that says so.

The ghost drives a polyline of local metres (x east, y north) at a constant
speed from the attack's start and stands at the last point once it gets
there. Its BSM is what an RSU would send for a vehicle it tracks (a surrogate
BSM): the centre of the body in WGS-84 through the scenario's origin, heading
clockwise from north, the emergency-vehicle extension when it plays an
ambulance (siren and lightbar in use: the strongest claim a receiver acts on).
Pure functions: the attacks (attacker.attacks) wrap the bytes in an envelope.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

from bridges.geo import GeoOrigin
from bridges.j2735.bsm import Bsm, EmergencyInfo


@dataclass(frozen=True)
class GhostPose:
    x: float
    y: float
    yaw: float  # rad, counter-clockwise from east
    speed: float  # m/s (0 once it has reached the end of its path)


class GhostPath:
    """A polyline driven at `speed_mps` from time `start_s`; before it the ghost waits at the first point."""

    def __init__(self, points: list[tuple[float, float]], speed_mps: float, start_s: float):
        if len(points) < 2:
            raise ValueError("a ghost path needs at least two points")
        self.points = [(float(x), float(y)) for x, y in points]
        self.speed, self.start = float(speed_mps), float(start_s)
        self.legs = [math.dist(a, b) for a, b in zip(self.points, self.points[1:])]
        if not all(leg > 0 for leg in self.legs):
            raise ValueError("consecutive points of a ghost path must differ")

    def pose(self, t: float) -> GhostPose:
        s = max(0.0, t - self.start) * self.speed
        for (a, b), leg in zip(zip(self.points, self.points[1:]), self.legs):
            yaw = math.atan2(b[1] - a[1], b[0] - a[0])
            if s <= leg:
                f = s / leg
                return GhostPose(a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), yaw, self.speed)
            s -= leg
        a, b = self.points[-2], self.points[-1]
        return GhostPose(b[0], b[1], math.atan2(b[1] - a[1], b[0] - a[0]), 0.0)


def temporary_id(label: str, seed: int) -> bytes:
    """The ghost's 4-byte TemporaryID: stable for the run, different per attack and seed."""
    return hashlib.sha256(f"v2i-attacker:{label}:{seed}".encode()).digest()[:4]


def sec_mark_ms(t_sim: float, epoch_unix_s: float) -> int:
    """Milliseconds within the UTC minute of simulation time t_sim, on the run's millisecond grid (as the
    RSU counts them: the epoch's millisecond plus t_sim's, so a lockstep run repeats)."""
    return (round(epoch_unix_s * 1000.0) + math.floor(t_sim * 1000.0 + 1e-6)) % 60000


def ghost_bsm(pose: GhostPose, t_sim: float, epoch_unix_s: float, origin: GeoOrigin, tid: bytes, msg_count: int,
              length: float, width: float, emergency: bool) -> bytes:
    """The UPER MessageFrame of the ghost's BSM at t_sim."""
    lat, lon, h = origin.to_geodetic(pose.x, pose.y, 0.0)
    bsm = Bsm(temporary_id=tid, msg_count=msg_count % 128, sec_mark_ms=sec_mark_ms(t_sim, epoch_unix_s),
              latitude=float(lat), longitude=float(lon), elevation=float(h), speed=pose.speed,
              heading=(90.0 - math.degrees(pose.yaw)) % 360.0, transmission="forwardGears", width=width,
              length=length, semi_major=0.3, semi_minor=0.3, orientation=0.0,
              emergency=EmergencyInfo(siren="inUse", lightbar="inUse", response_type="emergency")
              if emergency else None)
    return bsm.encode()
