"""Line of sight between two points against the buildings (axis-aligned boxes).

Exact segment/box intersection by the slab method. For each building the
segment crosses, `walls` counts the boundary crossings (entering and leaving;
an end point inside a building is not a crossing) and `inside_m` the length
of the segment inside it. These are the V2XChannel FMU's obstruction inputs.
"""
from __future__ import annotations

import math
from typing import Iterable, Sequence

from master.world.layout import Building

EPS = 1e-9


def segment_box(p: Sequence[float], q: Sequence[float], lo: Sequence[float], hi: Sequence[float]
                ) -> tuple[float, float] | None:
    """Parameter interval [t0, t1] within [0, 1] of segment p->q inside box [lo, hi], or None."""
    t0, t1 = 0.0, 1.0
    for a in range(3):
        d = q[a] - p[a]
        if abs(d) < EPS:
            if p[a] < lo[a] or p[a] > hi[a]:
                return None
            continue
        ta, tb = (lo[a] - p[a]) / d, (hi[a] - p[a]) / d
        if ta > tb:
            ta, tb = tb, ta
        t0, t1 = max(t0, ta), min(t1, tb)
        if t0 >= t1:
            return None
    return t0, t1


def line_of_sight(p: Sequence[float], q: Sequence[float], buildings: Iterable[Building]
                  ) -> tuple[bool, int, float]:
    """(blocked, walls, inside_m) for the segment p->q (3D points, m)."""
    length = math.dist(p, q)
    walls, inside = 0, 0.0
    for b in buildings:
        lo, hi = b.bounds
        span = segment_box(p, q, lo, hi)
        if span is None:
            continue
        t0, t1 = span
        inside += (t1 - t0) * length
        walls += (t0 > EPS) + (t1 < 1 - EPS)
    return inside > 0.0, walls, inside
