"""`v2i snapshot`: pictures of the case study at one time; bad requests exit 2 naming the problem."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pybullet")

from master.cli import main  # noqa: E402
from master.world.layout import CameraSpec, WorldLayout  # noqa: E402
from master.report.snapshot import camera_footprint  # noqa: E402
from master.world.world import World  # noqa: E402

SCENARIO = Path(__file__).resolve().parent.parent / "scenarios" / "ima_world.toml"


def magenta_pixels(png: Path) -> int:
    """Pixels of the top-down map's vehicle-hit colour (pure magenta)."""
    from PIL import Image

    rgb = np.asarray(Image.open(png).convert("RGB")).astype(int)
    return int(np.sum((rgb[..., 0] > 230) & (rgb[..., 1] < 40) & (rgb[..., 2] > 230)))


def test_snapshot_of_the_case_study(fmu_dir, tmp_path, capsys):
    """At 4.8 s the cav's lidar sees the ev (hits drawn in magenta); at 2.0 s the building hides it
    and only the lidar's own marker is magenta. Camera frames have the camera's size."""
    from PIL import Image

    counts = {}
    for t in (2.0, 4.8):
        out = tmp_path / f"t{t}"
        assert main(["snapshot", str(SCENARIO), "--t", str(t), "--out", str(out)]) == 0
        printed = capsys.readouterr().out.split()
        assert [Path(p).name for p in printed] == ["rsu_cam.png", "top_down.png", "snapshot.json"]
        assert Image.open(out / "rsu_cam.png").size == (640, 480)
        record = json.loads((out / "snapshot.json").read_text())
        assert record["t"] == pytest.approx(t)
        assert record["poses"]["cav"][1] == pytest.approx(-50.0 + 8.333 * t, abs=0.05)
        assert record["poses"]["ev"][0] == pytest.approx(-100.0 + 16.667 * t, abs=0.05)
        counts[t] = (record["lidars"]["cav"]["vehicles"].get("ev", 0), magenta_pixels(out / "top_down.png"))
    assert counts[2.0][0] == 0 and counts[4.8][0] > 20
    assert counts[4.8][1] > counts[2.0][1] + 50  # the highlighted hits show in the picture


def test_snapshot_bad_requests_exit_2(fmu_dir, tmp_path, capsys, write_scenario):
    cases = [
        (["--t", "2.0", "--camera", "nope"], "unknown camera 'nope' (cameras: rsu_cam)"),
        (["--t", "-1.0"], "--t: must be >= time.start"),
        (["--t", "2.005"], "not on the 0.01 s step grid"),
    ]
    for extra, message in cases:
        assert main(["snapshot", str(SCENARIO), "--out", str(tmp_path / "x"), *extra]) == 2
        assert message in capsys.readouterr().err
    no_world = write_scenario('[time]\nstop = 1.0\nstep = 0.1\n[fmus.car]\nfmu = "{vehicle}"\n')
    assert main(["snapshot", str(no_world), "--out", str(tmp_path / "y")]) == 2
    assert "no [world] table" in capsys.readouterr().err
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()  # nothing written


def test_camera_footprint_maps_the_image_border():
    """Footprint points the camera sees on the ground project back onto the image border;
    rays above the horizon end at the clip range."""
    spec = CameraSpec("c", 0.0, 0.0, 6.0, yaw=30.0, pitch=-10.0, width=160, height=120, fov_deg=90.0)
    with World(WorldLayout(cameras=[spec])) as w:
        cam = w.cameras["c"]
        pts = np.array(camera_footprint(cam, max_range=50.0))
        r = np.hypot(pts[:, 0], pts[:, 1])
        assert np.all(r <= 50.0 + 1e-6)
        near = pts[r < 49.0]
        clipped = pts[r >= 49.0]
        assert len(near) > 10 and len(clipped) > 10  # pitch -10 with a 67 deg vertical fov: horizon in view
        uv, depth = cam.project(np.column_stack([near, np.zeros(len(near))]))
        assert np.all(depth > 0)
        on_border = (np.isclose(uv[:, 0], 0, atol=1e-6) | np.isclose(uv[:, 0], 160, atol=1e-6)
                     | np.isclose(uv[:, 1], 0, atol=1e-6) | np.isclose(uv[:, 1], 120, atol=1e-6))
        assert on_border.all()
        assert np.allclose(r[r >= 49.0], 50.0)
