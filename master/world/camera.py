"""Pinhole cameras placed in the world, rendered by pybullet (its CPU TinyRenderer or OpenGL: renderer.py).

Conventions (OpenCV): camera axes x right, y down, z forward (optical axis).
Image coordinates are continuous pixels: pixel (row i, column j) covers
u in [j, j+1), v in [i, i+1); the principal point is the image centre
(W/2, H/2). `fov_deg` is the horizontal field of view; pixels are square.
A world point X (metres, x east, y north, z up) maps to the image through
the 3x4 matrix P = K [R | t]: (u*w, v*w, w) = P (X, 1).

Camera pose: `yaw` is the heading of the optical axis (deg CCW from +x),
`pitch` its elevation (deg, negative looks down), `roll` a rotation about
the optical axis (deg; positive turns the image's right side down).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from bridges.allocator import keep_freed_memory
from master.world.quiet_pybullet import gl_to_stderr
from master.world.quiet_pybullet import pybullet as pb

from master.world.layout import CameraSpec
from master.world.renderer import name_of as renderer_name

NEAR, FAR = 0.1, 500.0


@dataclass(frozen=True)
class Lighting:
    """The TinyRenderer's single directional light (pybullet getCameraImage's light* arguments).

    `direction` points from the scene towards the light (x east, y north, z up);
    the default (None everywhere) is pybullet's own light.
    """
    direction: tuple[float, float, float] | None = None
    color: tuple[float, float, float] | None = None
    ambient: float | None = None
    diffuse: float | None = None
    specular: float | None = None
    shadow: bool = False  # cast shadows: TinyRenderer's shadow pass, EGL's shadow map (Camera._draw_arguments)

    def arguments(self) -> dict:
        args = {"shadow": int(self.shadow)}
        for key, name in (("direction", "lightDirection"), ("color", "lightColor"), ("ambient", "lightAmbientCoeff"),
                          ("diffuse", "lightDiffuseCoeff"), ("specular", "lightSpecularCoeff")):
            value = getattr(self, key)
            if value is not None:
                args[name] = list(value) if isinstance(value, tuple) else float(value)
        return args


@dataclass
class Frame:
    camera: str
    frame_id: int
    t: float  # simulation time of the frame (s)
    rgb: np.ndarray  # (H, W, 3) uint8
    seg: np.ndarray | None  # (H, W) int32: pybullet body id under each pixel, -1 for none; None when not asked for
    P: np.ndarray  # 3x4 projection matrix K [R | t]
    K: np.ndarray  # 3x3 intrinsics
    R_wc: np.ndarray  # camera axes in world coordinates (columns x right, y down, z forward)
    position: np.ndarray  # optical centre in the world (m)
    renderer: str = ""  # which renderer drew it ("tiny" or "egl"; their pictures differ: docs/perception.md)


class Camera:
    """A pinhole camera; with `client=None` it only projects (no renderer is touched)."""

    def __init__(self, spec: CameraSpec, client: int | None, renderer: int = pb.ER_TINY_RENDERER):
        self.spec, self.client, self.renderer = spec, client, renderer
        self._shadow_map_always = False  # EGL: draw its shadow map for every frame (V2I_EGL_SHADOWS=always)
        if client is not None and renderer == pb.ER_BULLET_HARDWARE_OPENGL:
            from master.world.renderer import egl_shadows_always

            self._shadow_map_always = egl_shadows_always()  # read once: a typo is refused before any frame
        keep_freed_memory()  # process-wide: each frame's buffers reused, not faulted in afresh (its docstring)
        self.frame_id = 0
        self.render_times: list[float] = []
        yaw, pitch, roll = (math.radians(a) for a in (spec.yaw, spec.pitch, spec.roll))
        f = np.array([math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), math.sin(pitch)])
        r = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
        d = np.cross(f, r)
        r, d = math.cos(roll) * r + math.sin(roll) * d, -math.sin(roll) * r + math.cos(roll) * d
        self.R_wc = np.column_stack([r, d, f])
        self.position = np.array([spec.x, spec.y, spec.z], dtype=float)
        W, H = spec.width, spec.height
        fx = W / (2 * math.tan(math.radians(spec.fov_deg) / 2))
        self.K = np.array([[fx, 0, W / 2], [0, fx, H / 2], [0, 0, 1.0]])
        self._vfov_deg = math.degrees(2 * math.atan(H / (2 * fx)))
        if client is not None:
            eye = self.position
            self._view = pb.computeViewMatrix(eye.tolist(), (eye + f).tolist(), (-d).tolist(), physicsClientId=client)
            self._proj = pb.computeProjectionMatrixFOV(self._vfov_deg, W / H, NEAR, FAR, physicsClientId=client)

    @property
    def name(self) -> str:
        return self.spec.name

    def projection_matrix(self) -> np.ndarray:
        """3x4 P = K [R | t] with R = R_wc^T and t = -R position."""
        R = self.R_wc.T
        return self.K @ np.hstack([R, (-R @ self.position)[:, None]])

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (N, 3) -> pixel coordinates (N, 2) and depth along the optical axis (N,)."""
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        h = self.projection_matrix() @ np.hstack([pts, np.ones((len(pts), 1))]).T
        depth = h[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (h[:2] / depth).T
        return uv, depth

    def pixel_to_ground(self, u: float, v: float, z: float = 0.0) -> np.ndarray | None:
        """The world point on the plane at height z seen at pixel (u, v); None above the horizon."""
        ray = self.R_wc @ np.linalg.solve(self.K, np.array([u, v, 1.0]))
        if ray[2] >= 0 and self.position[2] > z or ray[2] <= 0 and self.position[2] < z:
            return None
        s = (z - self.position[2]) / ray[2]
        return self.position + s * ray

    def warm_up(self, frames: int) -> None:
        """Draw `frames` frames and keep nothing (not counted, not timed)."""
        flags, args = self._draw_arguments(Lighting(), segmentation=False)
        W, H = self.spec.width, self.spec.height
        with gl_to_stderr(self.renderer):
            for _ in range(frames):
                pb.getCameraImage(W, H, self._view, self._proj, renderer=self.renderer, flags=flags,
                                  physicsClientId=self.client, **args)

    def _draw_arguments(self, lighting: Lighting, segmentation: bool) -> tuple[int, dict]:
        """getCameraImage's flags and keyword arguments for a frame under `lighting`.

        EGL draws its shadow map (a depth pass of fixed size, before the picture: most of an EGL frame's CPU
        on Mesa's llvmpipe) only where the lighting asks for shadows, as TinyRenderer its shadow pass: else
        it draws through its projective-texture path, which skips the shadow map. The scene's bodies carry
        colours and no textures, so that path, projecting from the camera itself, draws the same picture less
        its shadows (no pixel darker: tests/test_world_renderer.py). `V2I_EGL_SHADOWS=always` draws the shadow
        map for every frame, as before (renderer.SHADOWS_ENV, read when the camera is made)."""
        flags = 0 if segmentation else pb.ER_NO_SEGMENTATION_MASK
        args = lighting.arguments()
        if self.renderer == pb.ER_BULLET_HARDWARE_OPENGL and not lighting.shadow and not self._shadow_map_always:
            flags |= pb.ER_USE_PROJECTIVE_TEXTURE
            args.update(projectiveTextureView=self._view, projectiveTextureProj=self._proj)
        return flags, args

    def render(self, t: float = 0.0, lighting: Lighting | None = None, segmentation: bool = True) -> Frame:
        """Render one frame at simulation time t; raises RuntimeError naming the camera on failure.

        `segmentation=False` skips the body-id pass (`Frame.seg` is None): only ground truth needs it
        (datasets, evaluation), not an app's live frames; on EGL it is a second render of the scene.
        """
        import time

        if self.client is None:
            raise RuntimeError(f"camera {self.name!r}: made for projection only (no pybullet client to render with)")
        W, H = self.spec.width, self.spec.height
        flags, args = self._draw_arguments(lighting or Lighting(), segmentation)
        t0 = time.perf_counter()
        try:
            with gl_to_stderr(self.renderer):
                _, _, rgba, _, seg = pb.getCameraImage(W, H, self._view, self._proj, renderer=self.renderer,
                                                       flags=flags, physicsClientId=self.client, **args)
        except pb.error as exc:
            raise RuntimeError(f"camera {self.name!r}: render failed: {exc}") from exc
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(H, W, 4)[:, :, :3].copy()
        if segmentation:
            seg = np.asarray(seg, dtype=np.int64).reshape(H, W)
            # without the link-index flag pybullet stores the body id; -1 where nothing was hit
            seg = np.where(seg < 0, -1, seg & ((1 << 24) - 1)).astype(np.int32)
        else:
            seg = None
        self.render_times.append(time.perf_counter() - t0)
        frame = Frame(self.name, self.frame_id, t, rgb, seg, self.projection_matrix(), self.K.copy(),
                      self.R_wc.copy(), self.position.copy(), renderer_name(self.renderer))
        self.frame_id += 1
        return frame
