"""`World`: the scene with its cameras and lidar; `WorldParticipant`: the world in the master's loop."""
from __future__ import annotations

import math
from typing import Any

from master.stats import percentiles
from master.world.camera import Camera
from master.world.layout import WorldLayout
from master.world.lidar import Lidar
from master.world.los import line_of_sight
from master.world.scene import Scene


class World:
    """Scene, cameras and lidar over one private pybullet DIRECT client. Close it (or use `with`)."""

    def __init__(self, layout: WorldLayout):
        self.layout = layout
        self.scene = Scene(layout)
        c = self.scene.client
        try:
            self.cameras = {s.name: Camera(s, c) for s in layout.cameras}
            self.lidars = {v.name: Lidar(v, v.lidar, c, self.scene.vehicle_ids[v.name])
                           for v in layout.vehicles.values() if v.lidar is not None}
        except Exception:
            self.scene.close()
            raise

    def pose_vehicle(self, name: str, x: float, y: float, yaw: float, v: float = 0.0) -> None:
        self.scene.pose_vehicle(name, x, y, yaw, v)

    def scan(self, name: str, t: float = 0.0):
        x, y, yaw, _ = self.scene.poses[name]
        return self.lidars[name].scan((x, y, yaw), t)

    def line_of_sight(self, p, q) -> tuple[bool, int, float]:
        return line_of_sight(p, q, self.layout.buildings)

    def close(self) -> None:
        self.scene.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class WorldParticipant:
    """Poses vehicle bodies from their FMU outputs after each master step and renders
    cameras at their rates. Stores no images yet: counts frames and render times."""

    def __init__(self, layout: WorldLayout, start: float):
        self.layout, self.start = layout, start
        self.world: World | None = None
        self._getters: list[tuple[str, Any]] = []
        self._next_frame: dict[str, int] = {}

    def open(self, fmus: dict[str, Any], t: float) -> dict[str, Any]:
        self.world = World(self.layout)
        for name in self.layout.vehicles:
            fmu = fmus[name]
            outs = [v for v in ("x", "y", "yaw", "v") if v in fmu.variables]
            get = fmu.accessor(fmu.access_key(outs[0]), [fmu.variables[n].valueReference for n in outs], setter=False)
            self._getters.append((name, get))
        self._next_frame = {n: 0 for n in self.world.cameras}
        self.after_step(-1, t)
        return self.metadata()

    def after_step(self, k: int, t_next: float) -> None:
        w = self.world
        for name, get in self._getters:
            vals = get()
            w.pose_vehicle(name, vals[0], vals[1], vals[2], vals[3] if len(vals) > 3 else 0.0)
        for name, cam in w.cameras.items():
            n = self._next_frame[name]
            due = self.start + n / cam.spec.rate_hz
            if t_next + 1e-9 >= due:
                cam.render(t_next)
                # next frame slot strictly after t_next (no backlog of missed frames)
                self._next_frame[name] = max(n + 1, math.floor((t_next - self.start) * cam.spec.rate_hz + 1e-9) + 1)

    def metadata(self) -> dict[str, Any]:
        w = self.world
        if w is None:
            return {}
        return {
            "vehicles": list(self.layout.vehicles),
            "buildings": [b.name for b in self.layout.buildings],
            "poses": {n: [x, y, yaw] for n, (x, y, yaw, _) in w.scene.poses.items()},  # last rear-axle poses
            "cameras": {n: {"frames": c.frame_id, "width": c.spec.width, "height": c.spec.height,
                            "rate_hz": c.spec.rate_hz, "render_s": percentiles(c.render_times)}
                        for n, c in w.cameras.items()},
        }

    def close(self) -> dict[str, Any]:
        meta = self.metadata()
        if self.world is not None:
            self.world.close()
            self.world = None
        return meta
