"""Did the vehicles touch, and how close did they come? Oriented footprints, every step.

A vehicle's footprint is its body's rectangle on the ground (length x width
from the world's `[world.vehicles.NAME]`, placed from the vehicle FMU's
rear-axle pose x, y, yaw with the body's rear overhang). shapely does the
geometry (overlap, distance, unions), so this module only says what is
measured, when:

* **contact**: the footprints of a pair overlap (touching edges count). The
  first contact of each pair is recorded with its time and the relative speed
  of the two bodies (|v_a - v_b| as vectors, m/s).
* **min gap**: the smallest distance between the two footprints over the run
  (0 once they touch).
* **TTC**: time to collision if both kept their current speed and heading:
  the first future time within `ttc_horizon_s` at which the straight-line
  projections of the footprints overlap (sampled every `ttc_resolution_s`;
  evaluated every `ttc_every_s` of simulated time). Straight-line projection
  is the usual definition; for a turning vehicle it is an approximation.
* **PET** (post-encroachment time): the conflict zone of a pair is where the
  areas the two footprints swept during the run overlap. PET is defined at a
  point: the time from the first vehicle leaving it to the second reaching it;
  the pair's PET is the smallest over the zone's points (a grid of
  `pet_grid_m`, and the zone's corners). Negative: both covered one point at
  once (-how long). None: the paths never crossed, or the second vehicle
  never reached the zone. For two paths that cross this is the zone-level PET
  (first out of the zone to second into it) up to the grid; for a vehicle that
  merges behind another into its lane, where the zone is the whole shared
  stretch of lane, it is the follower's time gap at the point it is smallest,
  not the time from the leader's leaving the far end of the stretch (which
  read as both in the zone at once for a car 8 m behind a leader pulling away).

`CollisionCheck` is the pure core (feed it poses, read its metrics); the
master's observer hook feeds it every step.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import combinations
from typing import Any

import numpy as np
import shapely
from shapely.geometry import Polygon

from master.hooks import Hook, Outcome, RunContext


@dataclass(frozen=True)
class Body:
    """A vehicle's rectangle: `rear_overhang` is how far the body reaches behind the rear axle."""

    name: str
    length: float
    width: float
    rear_overhang: float

    def corners(self, x: float, y: float, yaw: float) -> np.ndarray:
        """The four ground corners (4 x 2) for the rear-axle pose (x, y, yaw)."""
        c, s = math.cos(yaw), math.sin(yaw)
        back, front, half = -self.rear_overhang, self.length - self.rear_overhang, self.width / 2
        local = np.array([[back, -half], [front, -half], [front, half], [back, half]])
        return local @ np.array([[c, s], [-s, c]]) + (x, y)

    def footprint(self, x: float, y: float, yaw: float) -> Polygon:
        return Polygon(self.corners(x, y, yaw))


@dataclass
class Contact:
    """The first contact of a pair."""

    t: float
    a: str
    b: str
    relative_speed_mps: float

    def to_dict(self) -> dict[str, Any]:
        return {"t": self.t, "pair": [self.a, self.b], "relative_speed_mps": self.relative_speed_mps}


@dataclass
class _Pair:
    a: str
    b: str
    min_gap: float = math.inf
    min_gap_t: float | None = None
    min_ttc: float = math.inf
    min_ttc_t: float | None = None
    contact: Contact | None = None


@dataclass
class CollisionCheck:
    bodies: dict[str, Body]
    ttc_horizon_s: float = 10.0
    ttc_resolution_s: float = 0.05
    ttc_every_s: float = 0.1
    pet_grid_m: float = 0.2
    _pairs: list[_Pair] = field(default_factory=list, init=False)
    _track: dict[str, list[tuple[float, float, float, float]]] = field(default_factory=dict, init=False)
    _next_ttc: float = field(default=-math.inf, init=False)

    def __post_init__(self):
        for name, body in self.bodies.items():
            if not (body.length > 0 and body.width > 0 and 0 <= body.rear_overhang < body.length):
                raise ValueError(f"vehicle {name!r}: a body needs length > 0, width > 0 and "
                                 f"0 <= rear_overhang < length, got {body}")
        self._pairs = [_Pair(a, b) for a, b in combinations(sorted(self.bodies), 2)]
        self._track = {n: [] for n in self.bodies}
        self._taus = np.arange(0.0, self.ttc_horizon_s + 1e-9, self.ttc_resolution_s)

    # -- feeding ---------------------------------------------------------------------------------------
    def update(self, t: float, poses: dict[str, tuple[float, float, float, float]]) -> list[Contact]:
        """Poses (x, y, yaw, v) of every body at time t; returns the pairs that touched for the first time."""
        shapes = {}
        for name, body in self.bodies.items():
            x, y, yaw, v = (float(q) for q in poses[name])
            self._track[name].append((t, x, y, yaw))
            shapes[name] = body.footprint(x, y, yaw)
        new = []
        for pair in self._pairs:
            fa, fb = shapes[pair.a], shapes[pair.b]
            gap = 0.0 if fa.intersects(fb) else fa.distance(fb)
            if gap < pair.min_gap:
                pair.min_gap, pair.min_gap_t = gap, t
            if gap == 0.0 and pair.contact is None:
                pair.contact = Contact(t, pair.a, pair.b, _relative_speed(poses[pair.a], poses[pair.b]))
                new.append(pair.contact)
        if t >= self._next_ttc - 1e-9:
            self._next_ttc = t + self.ttc_every_s
            for pair in self._pairs:
                ttc = self.ttc(poses[pair.a], poses[pair.b], pair.a, pair.b)
                if ttc is not None and ttc < pair.min_ttc:
                    pair.min_ttc, pair.min_ttc_t = ttc, t
        return new

    def ttc(self, pose_a, pose_b, a: str, b: str) -> float | None:
        """Time to collision of bodies a and b from their poses (x, y, yaw, v), straight-line projection."""
        taus = self._taus
        polys = []
        for (x, y, yaw, v), name in ((pose_a, a), (pose_b, b)):
            corners = self.bodies[name].corners(x, y, yaw)
            shift = np.outer(taus, (v * math.cos(yaw), v * math.sin(yaw)))  # (n, 2)
            polys.append(shapely.polygons(corners[None, :, :] + shift[:, None, :]))
        hit = np.flatnonzero(shapely.intersects(polys[0], polys[1]))
        return float(taus[hit[0]]) if hit.size else None

    # -- results ---------------------------------------------------------------------------------------
    @property
    def contacts(self) -> list[Contact]:
        return sorted((p.contact for p in self._pairs if p.contact is not None), key=lambda c: c.t)

    def pet(self, a: str, b: str) -> float | None:
        """Post-encroachment time of the pair over what was fed so far (see the module docstring). A pair that
        touched covered its contact point at once: at most 0, even where the footprints only met edge to edge or
        corner to side (a zone of no area, or one no grid point lies in)."""
        touched = any(p.contact is not None for p in self._pairs if {p.a, p.b} == {a, b})
        pet = self._pet(a, b)
        if not touched:
            return pet
        return 0.0 if pet is None else min(pet, 0.0)

    def _pet(self, a: str, b: str) -> float | None:
        zone = self._swept(a).intersection(self._swept(b))
        if zone.is_empty or zone.area < 1e-6:
            return None
        points = _zone_points(zone, self.pet_grid_m)
        (a_in, a_out), (b_in, b_out) = (self._cover_times(n, points) for n in (a, b))
        both = np.isfinite(a_in) & np.isfinite(b_in)  # a point a footprint only grazed between samples drops out
        if not both.any():
            return None
        a_in, a_out, b_in, b_out = a_in[both], a_out[both], b_in[both], b_out[both]
        gap = np.where(a_in <= b_in, b_in - a_out, a_in - b_out)
        return float(gap.min())

    def _cover_times(self, name: str, points: np.ndarray, chunk: int = 4096) -> tuple[np.ndarray, np.ndarray]:
        """When the body's footprint first and last covered each point (inf / -inf: never)."""
        body = self.bodies[name]
        track = np.asarray(self._track[name], dtype=float)  # (n, 4): t, x, y, yaw
        t, x, y, yaw = track.T
        c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
        centre = (body.length / 2 - body.rear_overhang)
        first = np.full(len(points), np.inf)
        last = np.full(len(points), -np.inf)
        for k in range(0, len(points), chunk):
            px, py = points[k:k + chunk, 0][None, :], points[k:k + chunk, 1][None, :]
            dx, dy = px - x[:, None], py - y[:, None]
            u = dx * c + dy * s - centre  # along the body from its centre
            v = -dx * s + dy * c
            inside = (np.abs(u) <= body.length / 2 + 1e-9) & (np.abs(v) <= body.width / 2 + 1e-9)  # (n, m)
            hit = inside.any(axis=0)
            first[k:k + chunk][hit] = t[inside.argmax(axis=0)[hit]]
            last[k:k + chunk][hit] = t[len(t) - 1 - inside[::-1].argmax(axis=0)[hit]]
        return first, last

    def _swept(self, name: str):
        body = self.bodies[name]
        return shapely.union_all([body.footprint(x, y, yaw) for _, x, y, yaw in self._track[name]])

    def metrics(self) -> dict[str, Any]:
        """The collision part of metrics.json (field names are a contract: README 'metrics.json')."""
        contacts = self.contacts
        pairs = {}
        for p in self._pairs:
            pairs[f"{p.a}-{p.b}"] = {
                "collision": p.contact is not None,
                "first_collision_s": p.contact.t if p.contact else None,
                "relative_speed_mps": p.contact.relative_speed_mps if p.contact else None,
                "min_gap_m": _finite(p.min_gap), "min_gap_t_s": p.min_gap_t,
                "min_ttc_s": _finite(p.min_ttc), "min_ttc_t_s": p.min_ttc_t,
                "pet_s": self.pet(p.a, p.b),
            }
        gaps = [v["min_gap_m"] for v in pairs.values() if v["min_gap_m"] is not None]
        ttcs = [v["min_ttc_s"] for v in pairs.values() if v["min_ttc_s"] is not None]
        pets = [v["pet_s"] for v in pairs.values() if v["pet_s"] is not None]
        return {
            "collision": bool(contacts),
            "first_collision_s": contacts[0].t if contacts else None,
            "first_collision": contacts[0].to_dict() if contacts else None,
            "min_gap_m": min(gaps) if gaps else None,
            "min_ttc_s": min(ttcs) if ttcs else None,
            "pet_s": min(pets) if pets else None,  # the most critical pair (negative: shared the zone)
            "pairs": pairs,
        }


def _zone_points(zone, spacing: float) -> np.ndarray:
    """Points of the zone to judge PET at: a grid of `spacing` inside it, and the corners of its outline
    (a zone thinner than the grid still has its corners)."""
    x0, y0, x1, y1 = zone.bounds
    gx, gy = np.meshgrid(np.arange(x0, x1 + spacing / 2, spacing), np.arange(y0, y1 + spacing / 2, spacing))
    gx, gy = gx.ravel(), gy.ravel()
    keep = shapely.intersects_xy(zone, gx, gy)
    corners = shapely.get_coordinates(shapely.get_exterior_ring(shapely.get_parts(zone)))
    return np.concatenate([np.column_stack([gx[keep], gy[keep]]), corners])


def _relative_speed(pa, pb) -> float:
    (_, _, ya, va), (_, _, yb, vb) = pa[:4], pb[:4]
    return math.hypot(va * math.cos(ya) - vb * math.cos(yb), va * math.sin(ya) - vb * math.sin(yb))


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


class CollisionHook(Hook):
    """The collision check as an observer of the master's loop (master.hooks protocol).

    Bodies come from the world's `[world.vehicles.NAME]` (length, width, rear
    overhang), poses from each vehicle FMU's x, y, yaw (and v when it has one)
    after every step. A first contact is written to the run's event log and, when
    the scenario stops on collisions, ends the run after that step.
    """

    name = "collision"

    def __init__(self, bodies: dict[str, Body], stop_on_collision: bool = False):
        self.check = CollisionCheck(bodies)
        self.stop_on_collision = stop_on_collision
        self._getters: list[tuple[str, Any]] = []
        self._ctx = None

    @classmethod
    def for_scenario(cls, scenario, stop_on_collision: bool = False) -> "CollisionHook | None":
        """The check of a scenario's world vehicles (None without a world of at least two vehicles)."""
        world = scenario.world
        if world is None:
            return None
        bodies = {n: Body(n, v.length, v.width, v.rear_overhang) for n, v in world.vehicles.items()
                  if n in scenario.instances}
        return cls(bodies, stop_on_collision) if len(bodies) >= 2 else None

    def open(self, ctx: RunContext) -> dict[str, Any]:
        self._ctx = ctx
        for name in self.check.bodies:
            fmu = ctx.members[name].fmu
            outs = [v for v in ("x", "y", "yaw", "v") if v in fmu.variables]
            if outs[:3] != ["x", "y", "yaw"]:
                raise ValueError(f"collision check: vehicle {name!r} needs x, y and yaw outputs, has {outs}")
            get = fmu.accessor(fmu.access_key("x"), [fmu.variables[n].valueReference for n in outs], setter=False)
            self._getters.append((name, get))
        self.after_step(-1, ctx.t0)
        return {"bodies": {n: [b.length, b.width, b.rear_overhang] for n, b in self.check.bodies.items()},
                "stop_on_collision": self.stop_on_collision}

    def after_step(self, k: int, t_next: float) -> None:
        poses = {}
        for name, get in self._getters:
            vals = get()
            poses[name] = (vals[0], vals[1], vals[2], vals[3] if len(vals) > 3 else 0.0)
        for contact in self.check.update(t_next, poses):
            self._ctx.events({"t": t_next, "event": "collision", **contact.to_dict()})
            if self.stop_on_collision:
                self._ctx.request_stop(f"collision: {contact.a} and {contact.b} touch at t = {t_next:.2f} s")

    def close(self, outcome: Outcome | None = None) -> dict[str, Any]:
        return self.check.metrics()
