"""Oriented boxes on the ground: corners, the separating-axis overlap test, minimum-area rectangles.

Everything is vectorised over leading array dimensions, because the collision
estimator tests thousands of (ego pose, object pose) pairs per plan. Two convex
polygons are disjoint exactly when some edge normal of one separates their
projections (separating axis theorem); a rectangle has two distinct normals, so
four axes decide a pair.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.spatial import ConvexHull, QhullError


def wrap(angle):
    """Angle(s) wrapped to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def corners(cx, cy, yaw, length, width) -> np.ndarray:
    """Corners (..., 4, 2) of boxes centred at (cx, cy), heading yaw, counter-clockwise."""
    cx, cy, yaw, length, width = np.broadcast_arrays(*(np.asarray(v, float) for v in (cx, cy, yaw, length, width)))
    c, s = np.cos(yaw), np.sin(yaw)
    hl, hw = length / 2, width / 2
    local = np.array([[1, -1], [1, 1], [-1, 1], [-1, -1]], float)  # (4, 2) in units of half sizes
    lx = local[:, 0] * hl[..., None]
    ly = local[:, 1] * hw[..., None]
    x = cx[..., None] + lx * c[..., None] - ly * s[..., None]
    y = cy[..., None] + lx * s[..., None] + ly * c[..., None]
    return np.stack([x, y], -1)


def _axes(box: np.ndarray) -> np.ndarray:
    """The two edge directions (..., 2, 2) of rectangles given by their corners (..., 4, 2)."""
    e = np.stack([box[..., 1, :] - box[..., 0, :], box[..., 2, :] - box[..., 1, :]], -2)
    return e / np.maximum(np.linalg.norm(e, axis=-1, keepdims=True), 1e-12)


def overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Do rectangles a (..., 4, 2) and b (..., 4, 2) overlap (touching counts)? Broadcasts; bool (...)."""
    a, b = np.broadcast_arrays(np.asarray(a, float), np.asarray(b, float))
    axes = np.concatenate([_axes(a), _axes(b)], -2)  # (..., 4, 2)
    pa = np.einsum("...kd,...cd->...kc", axes, a)  # (..., 4 axes, 4 corners)
    pb = np.einsum("...kd,...cd->...kc", axes, b)
    separated = (pa.max(-1) < pb.min(-1)) | (pb.max(-1) < pa.min(-1))
    return ~separated.any(-1)


def overlap_boxes(ax, ay, ayaw, a_half_len, a_half_wid, bx, by, byaw, b_half_len, b_half_wid) -> np.ndarray:
    """The separating-axis test on boxes given by centre, heading and half sizes (arrays broadcast); bool.

    Same answer as `overlap` on their corners, with a few dot products per pair instead of projecting
    eight corners on four axes: along each box's two axes the boxes are apart when the distance of
    their centres exceeds the sum of their half extents on that axis.
    """
    dx, dy = np.subtract(bx, ax), np.subtract(by, ay)
    ca, sa, cb, sb = np.cos(ayaw), np.sin(ayaw), np.cos(byaw), np.sin(byaw)
    c = np.abs(ca * cb + sa * sb)  # |cos(b - a)|
    s = np.abs(sa * cb - ca * sb)  # |sin(b - a)|
    sep = np.abs(dx * ca + dy * sa) > a_half_len + b_half_len * c + b_half_wid * s
    sep |= np.abs(-dx * sa + dy * ca) > a_half_wid + b_half_len * s + b_half_wid * c
    sep |= np.abs(dx * cb + dy * sb) > b_half_len + a_half_len * c + a_half_wid * s
    sep |= np.abs(-dx * sb + dy * cb) > b_half_wid + a_half_len * s + a_half_wid * c
    return ~sep


def min_area_rect(points: np.ndarray) -> tuple[float, float, float, float, float]:
    """(cx, cy, yaw, length, width) of the smallest rectangle around 2-D points; length >= width.

    Rotating calipers: the optimal rectangle has a side on an edge of the convex hull, so each hull
    edge direction is tried. Degenerate sets (one point, a line) get a thin box along their extent.
    """
    pts = np.asarray(points, float)[:, :2]
    if len(pts) == 0:
        raise ValueError("min_area_rect of no points")
    try:
        hull = pts[ConvexHull(pts).vertices] if len(pts) >= 3 else pts
    except QhullError:  # collinear or coincident points
        hull = pts
    if len(hull) < 2:
        return float(hull[0, 0]), float(hull[0, 1]), 0.0, 0.0, 0.0
    edges = np.roll(hull, -1, 0) - hull
    angles = np.unique(np.mod(np.arctan2(edges[:, 1], edges[:, 0]), np.pi / 2))
    c, s = np.cos(angles), np.sin(angles)
    # hull points in each candidate frame: u along the angle, v across
    u = hull[:, 0][None] * c[:, None] + hull[:, 1][None] * s[:, None]
    v = -hull[:, 0][None] * s[:, None] + hull[:, 1][None] * c[:, None]
    du, dv = u.max(1) - u.min(1), v.max(1) - v.min(1)
    i = int(np.argmin(du * dv + 1e-9 * (du + dv)))
    uc, vc = (u[i].max() + u[i].min()) / 2, (v[i].max() + v[i].min()) / 2
    cx, cy = uc * c[i] - vc * s[i], uc * s[i] + vc * c[i]
    yaw, length, width = float(angles[i]), float(du[i]), float(dv[i])
    if width > length:
        yaw, length, width = yaw + math.pi / 2, width, length
    return float(cx), float(cy), float(wrap(yaw)), length, width


def to_frame(x, y, pose) -> tuple[np.ndarray, np.ndarray]:
    """World points into the frame of `pose` = (x0, y0, yaw0): (forward, left)."""
    x0, y0, yaw0 = pose
    dx, dy = np.asarray(x) - x0, np.asarray(y) - y0
    c, s = math.cos(yaw0), math.sin(yaw0)
    return dx * c + dy * s, -dx * s + dy * c


def from_frame(u, v, pose) -> tuple[np.ndarray, np.ndarray]:
    """Points (forward, left) in the frame of `pose` into the world."""
    x0, y0, yaw0 = pose
    c, s = math.cos(yaw0), math.sin(yaw0)
    u, v = np.asarray(u), np.asarray(v)
    return x0 + u * c - v * s, y0 + u * s + v * c
