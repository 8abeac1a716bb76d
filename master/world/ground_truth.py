"""Ground truth for a camera frame: where each vehicle is in the image and in the world.

* `box`: the 2D box of the projected 3D bounding box (8 corners, the body's
  length x width x height at its pose), clipped to the image; None when the
  vehicle is wholly behind the camera or outside the image.
* `visible_box`: the box around the vehicle's pixels in the segmentation
  mask (None when no pixel is visible).
* `occlusion`: 1 - visible pixels / unoccluded pixels, where the unoccluded
  pixels come from a second render with every other body moved out of view
  (exact, costs one render per vehicle in view; `occlusion=False` skips it).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from master.world.quiet_pybullet import gl_to_stderr
from master.world.quiet_pybullet import pybullet as pb

from master.world.camera import Camera, Frame
from master.world.scene import Scene


@dataclass
class VehicleTruth:
    name: str
    body_id: int
    box: tuple[float, float, float, float] | None  # u0, v0, u1, v1 (continuous pixels)
    visible_box: tuple[int, int, int, int] | None  # u0, v0, u1, v1 (pixel edges, exclusive end)
    visible_pixels: int
    occlusion: float | None  # 0 fully visible .. 1 fully hidden; None if not in view
    position: tuple[float, float]  # rear axle (m)
    heading: float  # rad
    speed: float  # m/s


def mask_box(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if len(rows) == 0:
        return None
    return int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1


def projected_box(camera: Camera, corners) -> tuple[float, float, float, float] | None:
    uv, depth = camera.project(np.asarray(corners))
    if np.all(depth <= 0):
        return None
    if np.any(depth <= 0):  # straddles the camera plane: the box is unbounded on that side; clip wide
        uv = uv[depth > 0]
    W, H = camera.spec.width, camera.spec.height
    u0, v0 = np.clip(uv.min(axis=0), 0, [W, H])
    u1, v1 = np.clip(uv.max(axis=0), 0, [W, H])
    if u1 <= u0 or v1 <= v0:
        return None
    return float(u0), float(v0), float(u1), float(v1)


def _alone_pixels(scene: Scene, camera: Camera, body: int) -> int:
    """Pixels of `body` with every other body moved away (restored afterwards)."""
    c = scene.client
    others = [b for b in (*scene.static_ids, *scene.vehicle_ids.values()) if b != body]
    saved = [pb.getBasePositionAndOrientation(b, physicsClientId=c) for b in others]
    try:
        for b in others:
            pb.resetBasePositionAndOrientation(b, (0, 0, -1e4), (0, 0, 0, 1), physicsClientId=c)
        W, H = camera.spec.width, camera.spec.height
        with gl_to_stderr(camera.renderer):
            seg = pb.getCameraImage(W, H, camera._view, camera._proj, renderer=camera.renderer,
                                    physicsClientId=c)[4]
        seg = np.asarray(seg, dtype=np.int64).reshape(H, W)
        return int(np.count_nonzero(seg == body))
    finally:
        for b, (pos, orn) in zip(others, saved):
            pb.resetBasePositionAndOrientation(b, pos, orn, physicsClientId=c)


def frame_truth(scene: Scene, camera: Camera, frame: Frame, occlusion: bool = True) -> list[VehicleTruth]:
    out = []
    for name, body in scene.vehicle_ids.items():
        if name not in scene.poses:
            continue
        x, y, yaw, v = scene.poses[name]
        box = projected_box(camera, scene.vehicle_box_corners(name))
        mask = frame.seg == body
        n_vis = int(np.count_nonzero(mask))
        occ = None
        if occlusion and box is not None:
            full = _alone_pixels(scene, camera, body)
            occ = 1.0 - n_vis / full if full else None
        out.append(VehicleTruth(name, body, box, mask_box(mask), n_vis, occ, (x, y), math.remainder(yaw, math.tau), v))
    return out
