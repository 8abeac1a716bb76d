"""Renderer choice: the CPU TinyRenderer by default without a GPU, OpenGL through EGL on request."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from master.scenario.loader import load_scenario
from master.world import renderer
from master.world.world import World

ROOT = Path(__file__).resolve().parent.parent


def _render(monkeypatch, name):
    monkeypatch.setenv(renderer.ENV, name)
    layout = load_scenario(ROOT / "scenarios" / "ima_world.toml").world
    with World(layout) as w:
        w.pose_vehicle("cav", 1.75, -20.0, np.pi / 2)
        w.pose_vehicle("ev", -25.0, -1.75, 0.0)
        frame = w.cameras["rsu_cam"].render(0.0)
        return w.scene.renderer_name, frame, {n: w.scene.vehicle_ids[n] for n in ("cav", "ev")}


def test_auto_is_the_cpu_renderer_without_a_gpu(monkeypatch):
    if renderer.gpu_present():
        pytest.skip("a GPU device node exists here: auto picks EGL")
    name, frame, _ = _render(monkeypatch, "auto")
    assert name == "tiny" and frame.rgb.shape == (480, 640, 3)


_EGL_CHILD = """
import sys, numpy as np
sys.path.insert(0, {root!r})
from tests.test_world_renderer import _render_env
try:
    name, egl, ids = _render_env("egl")
except RuntimeError as exc:
    print("SKIP", exc); sys.exit(0)
"""


def _egl_child(body: str):
    """Run `body` in a child process after it drew the scene with EGL (`name`, `egl`, `ids` bound); skip where
    EGL will not load. A child: Mesa's EGL can corrupt the heap at interpreter exit after the plugin ran, and
    the plugin writes to the real descriptor 1, which pytest's capture would hide."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", _EGL_CHILD.format(root=str(ROOT)) + body], capture_output=True,
                          text=True, timeout=120, cwd=ROOT)
    if proc.stdout.startswith("SKIP"):
        pytest.skip(f"EGL not available here: {proc.stdout.split('SKIP', 1)[1].strip()}")
    return proc


_COMPARE = """
_, tiny, _ = _render_env("tiny")
for vehicle, body in ids.items():
    a, b = egl.seg == body, tiny.seg == body
    print(name, vehicle, np.count_nonzero(a & b) / max(np.count_nonzero(a | b), 1))
"""


def _render_env(name):
    import os

    os.environ[renderer.ENV] = name
    layout = load_scenario(ROOT / "scenarios" / "ima_world.toml").world
    with World(layout) as w:
        w.pose_vehicle("cav", 1.75, -20.0, np.pi / 2)
        w.pose_vehicle("ev", -25.0, -1.75, 0.0)
        return w.scene.renderer_name, w.cameras["rsu_cam"].render(0.0), dict(w.scene.vehicle_ids)


def test_egl_draws_the_same_vehicles_as_the_cpu_renderer():
    out = _egl_child(_COMPARE).stdout
    rows = [line.split() for line in out.splitlines() if line.startswith("egl ")]
    assert {r[1] for r in rows} == {"cav", "ev"}, out
    for _, vehicle, iou in rows:
        assert float(iou) > 0.9, f"{vehicle}: EGL and CPU masks differ (IoU {iou})"


def test_unknown_renderer_is_refused_by_name(monkeypatch):
    monkeypatch.setenv(renderer.ENV, "vulkan")
    with pytest.raises(RuntimeError, match="V2I_RENDERER='vulkan'.*auto, tiny, egl"):
        renderer.requested()


_STDOUT = """
print("frame", name, egl.rgb.shape)
"""


def test_egl_plugin_chatter_goes_to_stderr_not_into_stdout():
    """pybullet's EGL plugin printf's its GL strings on load, first frames and close: on stdout they broke
    `v2i eval-tracker --json` (the JSON began with 'Loaded EGL 1.5')."""
    proc = _egl_child(_STDOUT)
    assert proc.stdout == "frame egl (480, 640, 3)\n", proc.stdout[:400]
    assert "GL_VENDOR" in proc.stderr and "Destroy EGL OpenGL window" in proc.stderr  # kept, where logs go


def _pixel_offset(name: str) -> np.ndarray:
    """Median (du, dv) of where `name` draws 30 small spheres at known points, less where the camera model
    (Camera.project, principal point at the picture's centre, pixel k spanning [k, k+1)) puts them."""
    import pybullet as pb

    from master.world.layout import CameraSpec, WorldLayout

    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-6, 6, 30), rng.uniform(10, 25, 30), rng.uniform(0.5, 6, 30)])
    spec = CameraSpec("c", 0.0, 0.0, 5.0, yaw=90.0, pitch=-10.0, width=640, height=480, fov_deg=60.0)
    with World(WorldLayout(cameras=[spec]), renderer=name) as w:  # not through the environment: the test
        assert w.scene.renderer_name == name                        # process's other tests keep theirs
        client = w.scene.client
        shape = pb.createVisualShape(pb.GEOM_SPHERE, radius=0.2, physicsClientId=client)
        ids = [pb.createMultiBody(0, -1, shape, p.tolist(), physicsClientId=client) for p in points]
        frame = w.cameras["c"].render()
        uv, _ = w.cameras["c"].project(points)
    offsets = []
    for body, at in zip(ids, uv):
        v, u = np.nonzero(frame.seg == body)
        assert len(u) > 30, (body, len(u))  # every sphere is whole in the picture: 30-250 pixels
        offsets.append([u.mean() + 0.5 - at[0], v.mean() + 0.5 - at[1]])
    return np.median(offsets, axis=0)


_OFFSET = """
from tests.test_world_renderer import _pixel_offset
print("offset", *_pixel_offset("egl"))
"""


def test_where_each_renderer_draws_a_point():
    """EGL draws a point where the pinhole model projects it (to 0.1 px); TinyRenderer draws the whole picture
    half a pixel right and half a pixel up (measured +0.52 / -0.51 px). The frames keep the one camera model
    (principal point at the centre), so TinyRenderer's boxes sit half a pixel off the geometry: about 0.3 m
    along the ray for a vehicle 30 m from a 6 m pole, as much as a box edge's own rounding to whole pixels
    there. Not corrected (a frame's K would then depend on its renderer); this test says when pybullet
    moves either renderer."""
    du, dv = _pixel_offset("tiny")
    assert abs(du - 0.5) < 0.1 and abs(dv + 0.5) < 0.1, (du, dv)
    out = _egl_child(_OFFSET).stdout
    rows = [line.split()[1:] for line in out.splitlines() if line.startswith("offset ")]
    assert len(rows) == 1, out
    du, dv = (float(x) for x in rows[0])
    assert abs(du) < 0.1 and abs(dv) < 0.1, (du, dv)


_SHADOWS = """
import os
from master.world.camera import Camera, Lighting
layout = load_scenario(ROOT / "scenarios" / "ima_world.toml").world
with World(layout, renderer="egl") as w:
    w.pose_vehicle("cav", 1.75, -20.0, np.pi / 2)
    w.pose_vehicle("ev", -25.0, -1.75, 0.0)
    cam = w.cameras["rsu_cam"]
    flat, shadowed = cam.render(0.0), cam.render(0.0, Lighting(shadow=True))
    os.environ["V2I_EGL_SHADOWS"] = "always"  # read when a camera is made
    always = Camera(cam.spec, cam.client, cam.renderer).render(0.0)
lift = flat.rgb.astype(int) - shadowed.rgb.astype(int)
print("lift", lift.min(), np.mean(lift.max(axis=2) > 10), np.array_equal(flat.seg, shadowed.seg),
      np.array_equal(always.rgb, shadowed.rgb))
"""


def test_egl_draws_its_shadow_map_only_where_the_lighting_asks_for_shadows():
    """Without shadows (the apps' live frames) EGL skips its shadow map, most of a frame's CPU on llvmpipe
    (benchmarks/world.py): the same picture less its shadows, so no pixel darker and every body where it was;
    shadowed pixels brighter (the corner building's shadow falls across the road). V2I_EGL_SHADOWS=always
    draws the map for every frame, as before it was switchable."""
    out = _egl_child("from tests.test_world_renderer import ROOT, World, load_scenario\n" + _SHADOWS).stdout
    rows = [line.split()[1:] for line in out.splitlines() if line.startswith("lift ")]
    assert len(rows) == 1, out
    darkest, lifted, same_bodies, always_shadowed = rows[0]
    assert int(darkest) >= 0  # nothing darker without the shadow map
    assert float(lifted) > 0.01  # and the shadows are gone: it did skip the map
    assert same_bodies == "True" and always_shadowed == "True"


def test_a_mistyped_egl_shadows_choice_is_refused_naming_the_variable(monkeypatch):
    monkeypatch.setenv(renderer.SHADOWS_ENV, "allways")
    with pytest.raises(ValueError, match=r"V2I_EGL_SHADOWS='allways': expected one of lighting, always; "
                                         r"did you mean 'always'"):
        renderer.egl_shadows_always()
    monkeypatch.setenv(renderer.SHADOWS_ENV, "always")
    assert renderer.egl_shadows_always()
    monkeypatch.delenv(renderer.SHADOWS_ENV)
    assert not renderer.egl_shadows_always()
