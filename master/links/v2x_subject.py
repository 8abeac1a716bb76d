"""Which world vehicle a frame on the V2X air describes (the `subject` of the air's events).

The RSU app's frames are signed surrogate BSMs of vehicles its camera tracked;
the frame itself does not say which simulated vehicle that was. The air (the
master, i.e. the simulator, not a receiver) ties each frame to one:

1. unwrap the 1609.2 envelope without verifying it (signed or unsecured data,
   as `v2i j2735 decode` does) and decode the J2735 MessageFrame;
2. for a BSM, convert its latitude/longitude to local metres with the world's
   geodetic origin (bridges.geo.GeoOrigin);
3. compare with the body centre of every world vehicle at the frame's time and
   take the nearest one within `gate_m`.

Reference points: a vehicle FMU's x, y is its rear axle; the BSM's position is
the RSU's estimate of the body centre (rsu_app.perception.geo), so the
vehicle's centre is `centre_offset = length/2 - rear_overhang` ahead of the
rear axle along its yaw (master.world.layout.VehicleSpec). Without a world
layout the offset is unknown: the rear axle is used and the gate is widened by
`UNKNOWN_BODY_EXTRA_M`.

Time: the FMUs are read when the frame goes on the air (their state is at the
end of the step, `fmu.time`), and each vehicle is moved back along its heading
at its current speed to the time the frame describes (its send time: the RSU
predicts each track to the BSM slot, a few ms before the send).

Anything that is not a BSM in an envelope (SPaT, MAP, unsigned bytes,
garbage) has no subject; nothing here raises on a frame's bytes.
"""
from __future__ import annotations

import math
from collections import Counter, deque
from time import perf_counter
from dataclasses import dataclass
from typing import Any, Callable, Iterable

from bridges.geo import GeoOrigin

GATE_M = 5.0  # BSM position to the body centre: the RSU's centre estimate is within ~0.3-3 m
UNKNOWN_BODY_EXTRA_M = 3.0  # added to the gate when a vehicle's centre offset is unknown (rear axle used)
BSM_ID = 20  # J2735 DSRCmsgID of the BasicSafetyMessage

# why a frame got no subject
NOT_A_BSM = "not_a_bsm"          # not an envelope, not J2735, or a J2735 message other than a BSM
NO_POSITION = "no_position"      # a BSM whose latitude/longitude are "unavailable"
BEYOND_GATE = "beyond_gate"      # no vehicle within the gate


@dataclass
class Body:
    """A world vehicle as the tie sees it.

    `pose()` gives (x, y, yaw, v, t_state): the rear axle (m), heading (rad,
    counter-clockwise from x; None if unknown), speed (m/s; None if unknown)
    and the simulation time of that state (None if unknown: taken as the frame's).
    """

    name: str
    pose: Callable[[], tuple[float, float, float | None, float | None, float | None]]
    centre_offset: float | None = 0.0  # rear axle -> body centre along the heading (m); None: unknown

    def centre(self, t: float) -> tuple[float, float, bool]:
        """(x, y, exact) of the body centre at time t; exact is False when the reference point is the rear axle."""
        x, y, yaw, v, t_state = self.pose()
        if yaw is None:
            return float(x), float(y), False
        ahead = (self.centre_offset or 0.0) + (v or 0.0) * (0.0 if t_state is None else t - t_state)
        return (float(x) + ahead * math.cos(yaw), float(y) + ahead * math.sin(yaw),
                self.centre_offset is not None)


def unwrap(data: bytes) -> bytes | None:
    """The payload inside a version-3 Ieee1609Dot2Data (unsecuredData, or signedData with an inline
    payload), without any verification; None for anything else."""
    from bridges.security.envelope import unverified_payload
    from bridges.security.oer import PROTOCOL_VERSION, SecurityFormatError, decode

    if not isinstance(data, (bytes, bytearray, memoryview)) or bytes(data[:1]) != bytes([PROTOCOL_VERSION]):
        return None
    try:
        return unverified_payload(decode("Ieee1609Dot2Data", data))
    except (SecurityFormatError, KeyError, TypeError, ValueError, IndexError):
        return None


def bsm_lat_lon(data: bytes, codec) -> tuple[float, float] | str:
    """(latitude, longitude) of the BSM in an envelope; NOT_A_BSM or NO_POSITION when there is none."""
    from bridges.j2735.codec import J2735Error
    from bridges.j2735.scales import LATITUDE, LONGITUDE

    inner = unwrap(data)
    if inner is None:
        return NOT_A_BSM
    try:
        frame = codec.decode(inner)
        if frame.message_id != BSM_ID or frame.message is None:
            return NOT_A_BSM
        core = frame.message["coreData"]
        lat, lon = LATITUDE.from_wire(core["lat"]), LONGITUDE.from_wire(core["long"])
    except (J2735Error, KeyError, TypeError, ValueError):
        return NOT_A_BSM
    if lat is None or lon is None:
        return NO_POSITION
    return float(lat), float(lon)


def nearest(point: tuple[float, float], centres: Iterable[tuple[str, float, float, float]]) -> tuple[str | None, float]:
    """The name of the nearest centre (name, x, y, gate) whose distance is within its own gate, and the
    distance to it (inf when none is)."""
    best, best_d = None, math.inf
    for name, x, y, gate in centres:
        d = math.hypot(point[0] - x, point[1] - y)
        if d <= gate and d < best_d:
            best, best_d = name, d
    return best, best_d


class SubjectFinder:
    """Ties a frame's bytes to the world vehicle it describes; keeps counts and the cost per frame."""

    def __init__(self, origin: GeoOrigin, bodies: Iterable[Body], gate_m: float = GATE_M, codec=None):
        import pymap3d

        if codec is None:
            from bridges.j2735.codec import default_codec

            codec = default_codec()
        from bridges.security.oer import spec

        spec()  # compile the envelope's ASN.1 now, not on the first frame
        self.origin, self.bodies, self.gate_m, self.codec = origin, list(bodies), float(gate_m), codec
        self._geodetic2enu = pymap3d.geodetic2enu
        self.tied: Counter[str] = Counter()
        self.untied: Counter[str] = Counter()
        self.cost_s: deque[float] = deque(maxlen=20000)

    def local(self, lat: float, lon: float) -> tuple[float, float]:
        o = self.origin
        x, y, _ = self._geodetic2enu(lat, lon, o.h0, o.lat0, o.lon0, o.h0)
        return float(x), float(y)

    def find(self, payload: bytes, t: float) -> tuple[str | None, str | None, float | None]:
        """(subject, why none, distance m) for a frame describing time t; never raises on the bytes."""
        found = bsm_lat_lon(payload, self.codec)
        if isinstance(found, str):
            return None, found, None
        point = self.local(*found)
        centres = []
        for b in self.bodies:
            x, y, exact = b.centre(t)
            centres.append((b.name, x, y, self.gate_m if exact else self.gate_m + UNKNOWN_BODY_EXTRA_M))
        name, d = nearest(point, centres)
        return (name, None, d) if name is not None else (None, BEYOND_GATE, None)

    def about(self, payload: bytes, t: float, frame_t: float | None) -> dict[str, Any]:
        """The air's extra event fields for one frame: subject and frame_t (both may be None); counted."""
        c0 = perf_counter()
        try:
            subject, why, _ = self.find(payload, t)
        except Exception as exc:  # a bug here must not stop the air: the frame just has no subject
            subject, why = None, f"error: {type(exc).__name__}"
        self.cost_s.append(perf_counter() - c0)
        if subject is not None:
            self.tied[subject] += 1
        else:
            self.untied[why] += 1
        return {"subject": subject, "frame_t": frame_t}

    def section(self) -> dict[str, Any]:
        """For the hook's metadata: frames tied per vehicle, untied per reason, cost per frame (µs)."""
        from master.stats import percentiles

        cost = percentiles([c * 1e6 for c in self.cost_s], (50, 99))
        return {"subjects": dict(sorted(self.tied.items())), "untied": dict(sorted(self.untied.items())),
                "subject_gate_m": self.gate_m,
                "subject_cost_us": {k: (round(v, 1) if isinstance(v, float) else v) for k, v in cost.items()}}


def world_bodies(fmus: dict[str, Any], layout=None) -> list[Body]:
    """The vehicles to tie frames to: the world layout's vehicles (with their centre offsets), or, without a
    layout, every FMU instance with x and y outputs (reference point: the rear axle)."""
    if layout is not None:
        names = {n: v.centre_offset for n, v in layout.vehicles.items() if n in fmus}
    else:
        names = {}
        for n, fmu in fmus.items():
            variables = getattr(fmu, "variables", {})
            if all(k in variables and getattr(variables[k], "causality", None) == "output" for k in ("x", "y")):
                names[n] = None
    out = []
    for name, offset in names.items():
        pose = _pose_reader(fmus[name])
        if pose is not None:
            out.append(Body(name, pose, offset))
    return out


def _pose_reader(fmu) -> Callable | None:
    variables = fmu.variables
    if "x" not in variables or "y" not in variables:
        return None
    key = fmu.access_key("x")
    names = ["x", "y"] + [n for n in ("yaw", "v") if n in variables and fmu.access_key(n) == key]
    get = fmu.accessor(key, [variables[n].valueReference for n in names], setter=False)
    has_yaw, has_v = "yaw" in names, "v" in names

    def pose():
        vals = get()
        yaw = float(vals[2]) if has_yaw else None
        v = float(vals[names.index("v")]) if has_v else None
        t_state = getattr(fmu, "time", None)
        return float(vals[0]), float(vals[1]), yaw, v, None if t_state is None else float(t_state)

    return pose
