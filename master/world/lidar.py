"""A spinning lidar mounted on a vehicle: ray casts against the scene with `rayTestBatch`.

Vehicle frame: origin at the rear axle on the ground (the FMU's x, y), x
forward along the heading, y left, z up. The lidar sits above the roof at
the body centre (`length/2 - rear_overhang` ahead of the rear axle), at
height `vehicle height + mount_above_roof`. Channels are spread evenly from
`fov_down` to `fov_up`; horizontal samples evenly over 360 degrees.
Hits on the carrying vehicle itself are dropped.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pybullet as pb

from master.world.layout import LidarSpec, VehicleSpec

BATCH = 16384  # pybullet's rays-per-call limit (MAX_RAY_INTERSECTION_BATCH_SIZE)


@dataclass
class Scan:
    t: float
    points: np.ndarray  # (N, 3) hit points in the vehicle frame (m)
    body_ids: np.ndarray  # (N,) pybullet body id hit by each point
    n_rays: int


class Lidar:
    def __init__(self, vehicle: VehicleSpec, spec: LidarSpec, client: int, self_id: int):
        self.vehicle, self.spec, self.client, self.self_id = vehicle, spec, client, self_id
        ch = np.linspace(math.radians(spec.fov_down), math.radians(spec.fov_up), spec.channels) \
            if spec.channels > 1 else np.array([math.radians((spec.fov_up + spec.fov_down) / 2)])
        az = np.arange(spec.horizontal_samples) * (2 * math.pi / spec.horizontal_samples)
        el, az = np.meshgrid(ch, az, indexing="ij")
        self.directions = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)
        self.mount = np.array([vehicle.centre_offset, 0.0, vehicle.height + spec.mount_above_roof])
        self.scan_times: list[float] = []

    def scan(self, pose: tuple[float, float, float], t: float = 0.0) -> Scan:
        """Cast every ray from the vehicle at rear-axle pose (x, y, yaw)."""
        import time

        t0 = time.perf_counter()
        x, y, yaw = pose
        c, s = math.cos(yaw), math.sin(yaw)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
        origin = np.array([x, y, 0.0]) + R @ self.mount
        ends = origin + (self.directions @ R.T) * self.spec.range
        starts = np.broadcast_to(origin, ends.shape)
        hits = []
        for i in range(0, len(ends), BATCH):
            hits.extend(pb.rayTestBatch(starts[i:i + BATCH].tolist(), ends[i:i + BATCH].tolist(),
                                        physicsClientId=self.client))
        ids = np.fromiter((h[0] for h in hits), dtype=np.int64, count=len(hits))
        keep = (ids >= 0) & (ids != self.self_id)
        pos = np.array([hits[i][3] for i in np.flatnonzero(keep)], dtype=float).reshape(-1, 3)
        local = (pos - np.array([x, y, 0.0])) @ R  # world -> vehicle frame
        self.scan_times.append(time.perf_counter() - t0)
        return Scan(t, local, ids[keep].astype(np.int32), len(ends))
