"""Fusion: V2X objects and lidar obstacles into one object list with source tags.

Both kinds are predicted to the planning time first (a BSM's measurement is
up to `obu.max_age_s` old, a lidar track is as old as its scan). Then gated
Hungarian association on centre distance (scipy.optimize.linear_sum_assignment;
the gate grows by what a partly seen vehicle's box may be off) pairs a V2X object with the lidar track of the same vehicle: one object,
source "both", position weighted by the two sources' standard deviations,
size and the emergency flag from the BSM (a partially seen vehicle's lidar box
is too small, and its centre counts for less the more of the vehicle it
misses), velocity from the BSM when it is fresh. Unpaired objects keep
their source ("v2x" or "lidar"); static structure from the lidar passes
through untouched. Every object keeps its age: the planning time minus its
newest measurement.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from av_app.config import FusionSection
from av_app.obu import V2xObject
from av_app.perception import LidarObject


@dataclass(frozen=True)
class FusedObject:
    id: str
    source: str  # v2x | lidar | both
    t: float  # the time the state below refers to (the planning time)
    x: float
    y: float
    yaw: float
    speed: float
    yaw_rate: float
    length: float
    width: float
    emergency: bool = False
    static: bool = False
    age: float = 0.0  # t - newest measurement
    station: str = ""  # the V2X sender, if any
    lidar_id: str = ""


def predict_pose(x: float, y: float, yaw: float, speed: float, yaw_rate: float, dt: float):
    """Constant turn rate and velocity (straight line when the turn rate is ~0)."""
    if abs(yaw_rate) < 1e-3:
        return x + speed * dt * math.cos(yaw), y + speed * dt * math.sin(yaw), yaw
    nyaw = yaw + yaw_rate * dt
    r = speed / yaw_rate
    return x + r * (math.sin(nyaw) - math.sin(yaw)), y - r * (math.cos(nyaw) - math.cos(yaw)), nyaw


def _from_v2x(o: V2xObject, t: float) -> FusedObject:
    x, y, yaw = predict_pose(o.x, o.y, o.yaw, o.speed, o.yaw_rate, max(0.0, t - o.t))
    return FusedObject(o.id, "v2x", t, x, y, yaw, o.speed, o.yaw_rate, o.length, o.width, o.emergency, False,
                       max(0.0, t - o.t), o.station)


def _from_lidar(o: LidarObject, t: float) -> FusedObject:
    dt = max(0.0, t - o.t)
    return FusedObject(o.id, "lidar", t, o.x + o.vx * dt, o.y + o.vy * dt, o.yaw, o.speed, 0.0, o.length,
                       o.width, False, o.static, dt, "", o.id)


def _missing(v: FusedObject, l_: FusedObject) -> tuple[float, float]:
    """How far a lidar box's centre may be from the centre of the vehicle a BSM describes, along and across:
    a box smaller than the vehicle sees only part of it (the rest hidden or facing away), and its centre is
    off by up to half the missing size. So such a box counts for less in the fused position, and the gate
    that pairs the two grows by as much (measured: the ev's front coming out past the corner building, a
    2 m box 3.1 m ahead of its BSM, was a second object for one plan, and the cav braked at 4.3 m/s^2)."""
    return max(0.0, v.length - l_.length) / 2, max(0.0, v.width - l_.width) / 2


def fuse(v2x: list[V2xObject], lidar: list[LidarObject], t: float, cfg: FusionSection) -> list[FusedObject]:
    """One object list at time t from both sources (deterministic order: by id)."""
    vs = [_from_v2x(o, t) for o in v2x]
    sigmas = {o.id: o.pos_std for o in v2x}
    moving = [_from_lidar(o, t) for o in lidar if not o.static]
    static = [_from_lidar(o, t) for o in lidar if o.static]
    pairs: list[tuple[int, int]] = []
    if vs and moving:
        a = np.array([[o.x, o.y] for o in vs])
        b = np.array([[o.x, o.y] for o in moving])
        cost = np.linalg.norm(a[:, None] - b[None], axis=-1)
        gate = cfg.gate_m + np.array([[math.hypot(*_missing(v, l_)) for l_ in moving] for v in vs])
        rows, cols = linear_sum_assignment(np.where(cost <= gate, cost, 1e6))
        pairs = [(r, c) for r, c in zip(rows, cols) if cost[r, c] <= gate[r, c]]
    out: list[FusedObject] = []
    paired_v, paired_l = {r for r, _ in pairs}, {c for _, c in pairs}
    for r, c in pairs:
        v, l_ = vs[r], moving[c]
        missing = _missing(v, l_)
        wv = 1.0 / sigmas[v.id] ** 2
        wl = 1.0 / (cfg.lidar_sigma ** 2 + missing[0] ** 2 + missing[1] ** 2)
        x = (v.x * wv + l_.x * wl) / (wv + wl)
        y = (v.y * wv + l_.y * wl) / (wv + wl)
        use_v = v.age <= l_.age + 0.2  # the BSM's speed and heading are measured, the track's estimated
        out.append(FusedObject(v.id, "both", t, x, y, v.yaw if use_v else l_.yaw, v.speed if use_v else l_.speed,
                               v.yaw_rate if use_v else 0.0, max(v.length, l_.length), max(v.width, l_.width),
                               v.emergency, False, min(v.age, l_.age), v.station, l_.id))
    out += [o for i, o in enumerate(vs) if i not in paired_v]
    out += [o for i, o in enumerate(moving) if i not in paired_l]
    out.sort(key=lambda o: o.id)
    return out + static
