"""Which pybullet renderer draws the cameras: the CPU TinyRenderer, or OpenGL through EGL.

Chosen by `[world] renderer` (`auto`, the default, `tiny` or `egl`); the
environment variable `V2I_RENDERER` overrides the scenario. `auto` takes EGL
where a GPU device node exists and the CPU renderer elsewhere; when EGL cannot
be loaded there it falls back to the CPU renderer and says why in one line.
EGL also runs on Mesa's software rasteriser where no GPU exists (ask for `egl`).
There most of an EGL frame's CPU was its shadow map, a fixed-size depth pass
drawn before every frame whatever the picture's size (one thread: 60 ms of a
64x48 frame's 60, of a 640x480 frame's 83-92): EGL now draws it only where
the frame's lighting asks for shadows (`camera.Lighting.shadow`, as
TinyRenderer's shadow pass; not for the apps' live frames), and a 640x480
frame costs about 20 ms (TinyRenderer about 170, on one thread). `auto` stays on TinyRenderer without a GPU
because the shipped detector, trained on both renderers' images, meets its target
on TinyRenderer's and not yet on EGL's (docs/perception.md).
"""
from __future__ import annotations

import glob
import logging
import os
import pkgutil

from master.world.quiet_pybullet import pybullet as pb
from master.world.quiet_pybullet import stdout_to_stderr

RENDERERS = ("auto", "tiny", "egl")
ENV = "V2I_RENDERER"
# EGL's shadow map: drawn for a frame whose lighting asks for shadows (`camera.Lighting.shadow`, as
# TinyRenderer's shadow pass), or for every frame, as before it was switchable (to redraw the EGL data
# sets made then: rsu_app/perception/weights/RECIPE.md).
SHADOWS_ENV = "V2I_EGL_SHADOWS"
SHADOW_CHOICES = ("lighting", "always")
log = logging.getLogger(__name__)


def gpu_present() -> bool:
    return bool(glob.glob("/dev/nvidia[0-9]*") or glob.glob("/dev/dri/renderD*"))


def requested() -> str | None:
    """The environment's override, if set."""
    name = os.environ.get(ENV, "").strip().lower()
    if not name:
        return None
    if name not in RENDERERS:
        raise RuntimeError(f"{ENV}={name!r}: expected one of {', '.join(RENDERERS)}")
    return name


def egl_shadows_always() -> bool:
    """Does the environment ask EGL to draw its shadow map for every frame? ValueError naming the variable
    for a value that is neither choice (a typo would silently redraw a data set some other way)."""
    from master.scenario.tables import did_you_mean

    value = os.environ.get(SHADOWS_ENV, "").strip().lower() or "lighting"
    if value not in SHADOW_CHOICES:
        hint = did_you_mean(value, SHADOW_CHOICES)
        raise ValueError(f"{SHADOWS_ENV}={value!r}: expected one of {', '.join(SHADOW_CHOICES)}"
                         + (f"; {hint}" if hint else ""))
    return value == "always"


def choose(configured: str = "auto") -> str:
    """The renderer to ask for: the environment's override, else the scenario's `[world] renderer`."""
    return requested() or configured


def name_of(constant: int) -> str:
    """The name of a pybullet renderer constant `attach` returned."""
    return "egl" if constant == pb.ER_BULLET_HARDWARE_OPENGL else "tiny"


def attach(client: int, name: str | None = None) -> tuple[str, int]:
    """Set up the renderer on a DIRECT client: (name used, pybullet renderer constant)."""
    name = name or choose()
    fallback = name == "auto"
    if name == "auto":
        name = "egl" if gpu_present() else "tiny"
    if name == "tiny":
        return "tiny", pb.ER_TINY_RENDERER
    loader = pkgutil.get_loader("eglRenderer")
    with stdout_to_stderr():  # the plugin prints its GL strings while it loads
        plugin = pb.loadPlugin(loader.get_filename(), "_eglRendererPlugin", physicsClientId=client) if loader else -1
    if plugin < 0:
        if fallback:
            log.warning("renderer auto: pybullet's eglRenderer plugin could not be loaded; using TinyRenderer")
            return "tiny", pb.ER_TINY_RENDERER
        raise RuntimeError("renderer 'egl': pybullet's eglRenderer plugin could not be loaded "
                           f"(set [world] renderer = \"tiny\" or {ENV}=tiny for the CPU renderer)")
    return "egl", pb.ER_BULLET_HARDWARE_OPENGL
