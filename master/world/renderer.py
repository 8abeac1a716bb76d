"""Which pybullet renderer draws the cameras: the CPU TinyRenderer, or OpenGL through EGL.

`V2I_RENDERER` = `auto` (default: EGL when a GPU device node exists, else the
CPU renderer), `tiny` or `egl`. EGL also runs on Mesa's software rasteriser
where no GPU exists (set `egl` explicitly); pybullet ships the plugin.
"""
from __future__ import annotations

import glob
import os
import pkgutil

from master.world.quiet_pybullet import pybullet as pb

RENDERERS = ("auto", "tiny", "egl")
ENV = "V2I_RENDERER"


def gpu_present() -> bool:
    return bool(glob.glob("/dev/nvidia[0-9]*") or glob.glob("/dev/dri/renderD*"))


def requested() -> str:
    name = os.environ.get(ENV, "auto").strip().lower() or "auto"
    if name not in RENDERERS:
        raise RuntimeError(f"{ENV}={name!r}: expected one of {', '.join(RENDERERS)}")
    return name


def attach(client: int, name: str | None = None) -> tuple[str, int]:
    """Set up the renderer on a DIRECT client: (name used, pybullet renderer constant)."""
    name = name or requested()
    if name == "auto":
        name = "egl" if gpu_present() else "tiny"
    if name == "tiny":
        return "tiny", pb.ER_TINY_RENDERER
    loader = pkgutil.get_loader("eglRenderer")
    plugin = pb.loadPlugin(loader.get_filename(), "_eglRendererPlugin", physicsClientId=client) if loader else -1
    if plugin < 0:
        raise RuntimeError("renderer 'egl': pybullet's eglRenderer plugin could not be loaded "
                           f"(set {ENV}=tiny for the CPU renderer)")
    return "egl", pb.ER_BULLET_HARDWARE_OPENGL
