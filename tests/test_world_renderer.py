"""Renderer choice: the CPU TinyRenderer by default without a GPU, OpenGL through EGL on request."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from master.scenario import load_scenario
from master.world import renderer
from master.world.world import World

ROOT = Path(__file__).resolve().parent.parent


def _render(monkeypatch, name):
    monkeypatch.setenv(renderer.ENV, name)
    layout = load_scenario(ROOT / "scenarios" / "ima_case_study.toml").world
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


def test_egl_draws_the_same_vehicles_as_the_cpu_renderer(monkeypatch):
    try:
        name, egl, ids = _render(monkeypatch, "egl")
    except RuntimeError as exc:
        pytest.skip(f"EGL not available here: {exc}")
    assert name == "egl"
    _, tiny, _ = _render(monkeypatch, "tiny")
    for vehicle, body in ids.items():
        a, b = egl.seg == body, tiny.seg == body
        iou = np.count_nonzero(a & b) / max(np.count_nonzero(a | b), 1)
        assert iou > 0.9, f"{vehicle}: EGL and CPU masks differ (IoU {iou:.2f})"


def test_unknown_renderer_is_refused_by_name(monkeypatch):
    monkeypatch.setenv(renderer.ENV, "vulkan")
    with pytest.raises(RuntimeError, match="V2I_RENDERER='vulkan'.*auto, tiny, egl"):
        renderer.requested()
