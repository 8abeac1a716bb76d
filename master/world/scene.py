"""The pybullet scene: static intersection and buildings, and vehicle bodies posed from FMUs.

Each `Scene` owns its own pybullet client in DIRECT mode (headless, no GUI,
never the process-global default client) and disconnects on `close()`.
Nothing is simulated here: bodies have zero mass and are only re-posed.

Vehicle frame: the FMU's (x, y) is the rear axle on the ground; the body
centre lies `length/2 - rear_overhang` ahead of it along the heading.

Every body with a collision shape has a label (kind, name) in `labels`, so
a lidar return or a segmentation pixel can be told apart: ("vehicle", "ev"),
("building", "sw_corner"), ("signal", "nb_head"), ("road", ...), ...
"""
from __future__ import annotations

import math

from master.world.quiet_pybullet import gl_to_stderr
from master.world.quiet_pybullet import pybullet as pb

from master.world import signals
from master.world.layout import SignalSpec, VehicleSpec, WorldLayout

ROAD_Z = 0.02  # thickness of the road slab above the ground (m)
MARK_Z = 0.005  # lane/stop-line markings stand this far above the road
SIDEWALK_Z = 0.15  # kerb height (m)
GROUND_RGB = (0.35, 0.55, 0.3)
ROAD_RGB = (0.25, 0.25, 0.27)
SIDEWALK_RGB = (0.7, 0.7, 0.68)
MARK_RGB = (0.95, 0.95, 0.95)
BUILDING_RGB = (0.72, 0.6, 0.48)
WHEEL_RGB = (0.05, 0.05, 0.05)
CABIN_GLASS_RGB = (0.55, 0.7, 0.85)
# traffic-light head (m): a 12-inch-lamp, three-section vertical head on a pole
POLE_R = 0.1
HOUSING_W, HOUSING_H, HOUSING_D = 0.45, 1.15, 0.25
LAMP_R, LAMP_T, LAMP_PITCH = 0.16, 0.04, 0.36


class Scene:
    """Static geometry plus one multibody per vehicle; `client` is the pybullet client id."""

    def __init__(self, layout: WorldLayout, renderer_choice: str | None = None):
        """`renderer_choice`: "auto", "tiny" or "egl" (master/world/renderer.py); None: the layout's."""
        self.layout = layout
        self.client = pb.connect(pb.DIRECT)
        if self.client < 0:
            raise RuntimeError("pybullet: cannot open a DIRECT client")
        self.static_ids: list[int] = []
        self.building_ids: dict[str, int] = {}
        self.vehicle_ids: dict[str, int] = {}
        self.signal_ids: dict[str, int] = {}
        self.signal_states: dict[str, int] = {}  # name -> the MovementPhaseState its lamps show
        self.labels: dict[int, tuple[str, str]] = {}
        self.poses: dict[str, tuple[float, float, float, float]] = {}  # name -> x, y, yaw, v (rear axle)
        try:
            from master.world import renderer

            self.renderer_name, self.renderer = renderer.attach(self.client,
                                                                renderer_choice or renderer.choose(layout.renderer))
            self._build_ground()
            for b in layout.buildings:
                self.building_ids[b.name] = self._box((b.x, b.y, b.height / 2),
                                                      (b.size_x / 2, b.size_y / 2, b.height / 2), BUILDING_RGB,
                                                      label=("building", b.name))
            for v in layout.vehicles.values():
                self.vehicle_ids[v.name] = self._vehicle(v)
                self.labels[self.vehicle_ids[v.name]] = ("vehicle", v.name)
            for sig in layout.signals:
                self.signal_ids[sig.name] = self._signal_head(sig)
                self.labels[self.signal_ids[sig.name]] = ("signal", sig.name)
                self.signal_states[sig.name] = 1
        except Exception:
            self.close()
            raise

    # -- static ---------------------------------------------------------------
    def _box(self, centre, half, rgb, collide: bool = True, label: tuple[str, str] | None = None) -> int:
        c = self.client
        vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=(*rgb, 1.0), physicsClientId=c)
        col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=c) if collide else -1
        uid = pb.createMultiBody(0.0, col, vis, basePosition=centre, physicsClientId=c)
        self.static_ids.append(uid)
        if label is not None:
            self.labels[uid] = label
        return uid

    def _build_ground(self) -> None:
        ix = self.layout.intersection
        L, hw = ix.arm_length, ix.road_width / 2
        self._box((0, 0, -0.05), (L, L, 0.05), GROUND_RGB, label=("ground", "ground"))
        # the two roads as thin slabs
        self._box((0, 0, ROAD_Z / 2), (L, hw, ROAD_Z / 2), ROAD_RGB, label=("road", "east-west"))
        self._box((0, 0, ROAD_Z / 2 + 1e-3), (hw, L, ROAD_Z / 2), ROAD_RGB, label=("road", "north-south"))
        # sidewalks: four L-shaped corners as two strips per arm side
        sw = ix.sidewalk_width
        if sw > 0:
            arm = (L - hw) / 2
            mid = hw + arm
            for sx in (-1, 1):
                for sy in (-1, 1):
                    # along x (beside the east-west road)
                    self._box((sx * mid, sy * (hw + sw / 2), SIDEWALK_Z / 2), (arm, sw / 2, SIDEWALK_Z / 2),
                              SIDEWALK_RGB, label=("sidewalk", "sidewalk"))
                    # along y (beside the north-south road), excluding the corner square
                    self._box((sx * (hw + sw / 2), sy * (mid + sw / 2), SIDEWALK_Z / 2),
                              (sw / 2, arm - sw / 2, SIDEWALK_Z / 2), SIDEWALK_RGB, label=("sidewalk", "sidewalk"))
        # centre lines (dashed is not needed for the sensors: a solid line) and stop lines
        z = ROAD_Z + MARK_Z
        arm = (L - hw) / 2
        for s in (-1, 1):
            self._box((s * (hw + arm), 0, z), (arm, 0.075, MARK_Z), MARK_RGB, collide=False)
            self._box((0, s * (hw + arm), z), (0.075, arm, MARK_Z), MARK_RGB, collide=False)
        stop = hw + 1.0  # 1 m before the crossing road's edge, across each approach lane (drive on the right)
        self._box((hw / 2, -stop, z), (hw / 2, 0.2, MARK_Z), MARK_RGB, collide=False)   # northbound
        self._box((-hw / 2, stop, z), (hw / 2, 0.2, MARK_Z), MARK_RGB, collide=False)   # southbound
        self._box((-stop, -hw / 2, z), (0.2, hw / 2, MARK_Z), MARK_RGB, collide=False)  # eastbound
        self._box((stop, hw / 2, z), (0.2, hw / 2, MARK_Z), MARK_RGB, collide=False)    # westbound

    # -- vehicles -------------------------------------------------------------
    def _vehicle(self, v: VehicleSpec) -> int:
        """Body box + cabin box + four wheel cylinders as one multibody.

        Base frame: ground point under the body centre, x forward, y left.
        """
        c = self.client
        L, W, H = v.length, v.width, v.height
        wheel_r = min(0.45, 0.18 * H + 0.06)
        clearance = 0.6 * wheel_r
        body_h = (H - clearance) * (0.7 if v.kind == "emergency" else 0.5)
        cabin_h = H - clearance - body_h
        cabin_len = L * (0.35 if v.kind == "emergency" else 0.5)
        cabin_x = (L / 2 - cabin_len / 2) if v.kind == "emergency" else -0.05 * L
        body_rgb = tuple(v.color)
        cabin_rgb = (0.95, 0.95, 0.95) if v.kind == "emergency" else CABIN_GLASS_RGB
        if v.kind == "emergency":  # white box body, coloured cab: red/white
            body_rgb, cabin_rgb = (0.95, 0.95, 0.95), tuple(v.color)
            cabin_x = L / 2 - cabin_len / 2
        body_half = (L / 2, W / 2, body_h / 2)
        body_z = clearance + body_h / 2
        vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=body_half, rgbaColor=(*body_rgb, 1),
                                   visualFramePosition=(0, 0, body_z), physicsClientId=c)
        col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=body_half, collisionFramePosition=(0, 0, body_z),
                                      physicsClientId=c)
        links = []
        cabin_half = (cabin_len / 2, W / 2 * 0.92, cabin_h / 2)
        links.append((cabin_half, (cabin_x, 0, clearance + body_h + cabin_h / 2), cabin_rgb, pb.GEOM_BOX))
        if v.kind == "emergency":
            # tall white box behind the cab, full height
            box_len = L - cabin_len
            links.append(((box_len / 2, W / 2, (H - clearance - body_h) / 2),
                          (-L / 2 + box_len / 2, 0, clearance + body_h + (H - clearance - body_h) / 2),
                          (0.97, 0.97, 0.97), pb.GEOM_BOX))
            # a red stripe along the box
            links.append(((box_len / 2 + 0.01, W / 2 + 0.01, 0.15),
                          (-L / 2 + box_len / 2, 0, clearance + body_h * 0.6), (0.9, 0.05, 0.05), pb.GEOM_BOX))
        axle_rear = -L / 2 + v.rear_overhang
        axle_front = min(L / 2 - 0.6 * wheel_r - 0.2, axle_rear + max(L - 2 * v.rear_overhang, 0.5))
        for ax in (axle_rear, axle_front):
            for side in (-1, 1):
                links.append(((wheel_r, 0.12), (ax, side * (W / 2 - 0.12), wheel_r), WHEEL_RGB, pb.GEOM_CYLINDER))
        shapes_v, shapes_c, pos, orn = [], [], [], []
        wheel_orn = pb.getQuaternionFromEuler((math.pi / 2, 0, 0))
        for dims, p, rgb, geom in links:
            if geom == pb.GEOM_BOX:
                shapes_v.append(pb.createVisualShape(geom, halfExtents=dims, rgbaColor=(*rgb, 1), physicsClientId=c))
                shapes_c.append(pb.createCollisionShape(geom, halfExtents=dims, physicsClientId=c))
                orn.append((0, 0, 0, 1))
            else:
                r, half_len = dims
                shapes_v.append(pb.createVisualShape(geom, radius=r, length=2 * half_len, rgbaColor=(*rgb, 1),
                                                     physicsClientId=c))
                shapes_c.append(pb.createCollisionShape(geom, radius=r, height=2 * half_len, physicsClientId=c))
                orn.append(wheel_orn)
            pos.append(p)
        n = len(links)
        uid = pb.createMultiBody(
            0.0, col, vis, basePosition=(0, 0, -1000),
            linkMasses=[0.0] * n, linkCollisionShapeIndices=shapes_c, linkVisualShapeIndices=shapes_v,
            linkPositions=pos, linkOrientations=orn, linkInertialFramePositions=[(0, 0, 0)] * n,
            linkInertialFrameOrientations=[(0, 0, 0, 1)] * n, linkParentIndices=[0] * n,
            linkJointTypes=[pb.JOINT_FIXED] * n, linkJointAxis=[(0, 0, 1)] * n, physicsClientId=c)
        return uid

    # -- traffic-light heads -------------------------------------------------------
    def _signal_head(self, sig: SignalSpec) -> int:
        """Pole (base) + housing + three lamp discs (links 1, 2, 3: red, yellow, green).

        Base frame: the pole's foot, x along the facing direction (toward the
        drivers the lamps face). The housing hangs in front of the pole so the
        lamps are not hidden behind it; all lamps start dim (dark).
        """
        c = self.client
        pole_h = sig.height + HOUSING_H / 2 + 0.1
        vis = pb.createVisualShape(pb.GEOM_CYLINDER, radius=POLE_R, length=pole_h, rgbaColor=(*signals.POLE_RGB, 1),
                                   visualFramePosition=(0, 0, pole_h / 2), physicsClientId=c)
        col = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=POLE_R, height=pole_h,
                                      collisionFramePosition=(0, 0, pole_h / 2), physicsClientId=c)
        hx = POLE_R + HOUSING_D / 2
        housing_v = pb.createVisualShape(pb.GEOM_BOX, halfExtents=(HOUSING_D / 2, HOUSING_W / 2, HOUSING_H / 2),
                                         rgbaColor=(*signals.HOUSING_RGB, 1), physicsClientId=c)
        housing_c = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=(HOUSING_D / 2, HOUSING_W / 2, HOUSING_H / 2),
                                            physicsClientId=c)
        vis_ids, col_ids, pos = [housing_v], [housing_c], [(hx, 0, sig.height)]
        lamp_x = POLE_R + HOUSING_D + LAMP_T / 2
        disc = pb.getQuaternionFromEuler((0, math.pi / 2, 0))  # cylinder axis along the facing x
        orn = [(0, 0, 0, 1)]
        for i, lamp in enumerate(signals.LAMPS):
            vis_ids.append(pb.createVisualShape(pb.GEOM_CYLINDER, radius=LAMP_R, length=LAMP_T,
                                                rgbaColor=(*signals.DIM_RGB[lamp], 1), physicsClientId=c))
            col_ids.append(-1)
            pos.append((lamp_x, 0, sig.height + (1 - i) * LAMP_PITCH))
            orn.append(disc)
        n = len(vis_ids)
        yaw = math.radians(sig.yaw)
        return pb.createMultiBody(
            0.0, col, vis, basePosition=(sig.x, sig.y, 0.0),
            baseOrientation=(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)),
            linkMasses=[0.0] * n, linkCollisionShapeIndices=col_ids, linkVisualShapeIndices=vis_ids,
            linkPositions=pos, linkOrientations=orn, linkInertialFramePositions=[(0, 0, 0)] * n,
            linkInertialFrameOrientations=[(0, 0, 0, 1)] * n, linkParentIndices=[0] * n,
            linkJointTypes=[pb.JOINT_FIXED] * n, linkJointAxis=[(0, 0, 1)] * n, physicsClientId=c)

    def lamp_centre(self, name: str, lamp: str) -> tuple[float, float, float]:
        """World position of the centre of lamp `lamp` ("red", "yellow", "green") of head `name`."""
        link = 1 + signals.LAMPS.index(lamp)
        return tuple(pb.getLinkState(self.signal_ids[name], link, physicsClientId=self.client)[4])

    def set_signal(self, name: str, state: int) -> bool:
        """Show MovementPhaseState `state` on head `name`; recolours only on a change (returns whether it did)."""
        if self.signal_states.get(name) == state:
            return False
        old = signals.lamp_colours(self.signal_states.get(name, 1))
        body = self.signal_ids[name]
        for i, (lamp, rgb) in enumerate(signals.lamp_colours(state).items()):
            if rgb != old[lamp]:
                pb.changeVisualShape(body, 1 + i, rgbaColor=(*rgb, 1.0), physicsClientId=self.client)
        self.signal_states[name] = state
        return True

    def pose_vehicle(self, name: str, x: float, y: float, yaw: float, v: float = 0.0) -> None:
        """Place vehicle `name` from its FMU outputs: rear axle (x, y), heading yaw (rad), speed v."""
        spec = self.layout.vehicles[name]
        d = spec.centre_offset
        pb.resetBasePositionAndOrientation(
            self.vehicle_ids[name], (x + d * math.cos(yaw), y + d * math.sin(yaw), 0.0),
            (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)), physicsClientId=self.client)
        self.poses[name] = (x, y, yaw, v)

    def vehicle_box_corners(self, name: str) -> list[tuple[float, float, float]]:
        """The 8 world corners of vehicle `name`'s bounding box (length x width x height) at its pose."""
        spec = self.layout.vehicles[name]
        x, y, yaw, _ = self.poses[name]
        d = spec.centre_offset
        cx, cy = x + d * math.cos(yaw), y + d * math.sin(yaw)
        c, s = math.cos(yaw), math.sin(yaw)
        out = []
        for lx in (-spec.length / 2, spec.length / 2):
            for ly in (-spec.width / 2, spec.width / 2):
                for z in (0.0, spec.height):
                    out.append((cx + c * lx - s * ly, cy + s * lx + c * ly, z))
        return out

    def close(self) -> None:
        if self.client is not None and self.client >= 0:
            try:
                with gl_to_stderr(getattr(self, "renderer", None)):  # EGL's plugin says goodbye on stdout
                    pb.disconnect(physicsClientId=self.client)
            except pb.error:
                pass
        self.client = -1

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
