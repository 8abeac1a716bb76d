"""`v2i dataset`: reproducible labelled frames whose labels match the renderer's pixels."""
from __future__ import annotations

import colorsys
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from master.cli import main
from master.scenario.loader import load_scenario
from master.world.camera import Lighting
from master.world.dataset import (CATEGORY_ID, DatasetError, HELDOUT, TRAIN, PlacedVehicle, Sample, draw_sample,
                                  make_dataset, rectangles_overlap, render_sample, render_summary)
from master.world.layout import VehicleSpec

ROOT = Path(__file__).resolve().parent.parent
CASE = ROOT / "scenarios" / "ima_world.toml"


@pytest.fixture(scope="module")
def layout():
    return load_scenario(CASE).world


@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory, layout):
    out = tmp_path_factory.mktemp("ds") / "train"
    coco = make_dataset(layout, out, frames=6, seed=11)
    return out, coco


def _no_shadow(sample: Sample) -> Sample:
    return replace(sample, lighting=replace(sample.lighting, shadow=False))


def test_labels_match_the_pixels_each_vehicle_changes(layout):
    """Removing one vehicle changes exactly the pixels inside its label's box, tight on all four sides."""
    checked = 0
    for index in range(4):
        sample = _no_shadow(draw_sample(index, 5, "train", layout, layout.cameras[0]))
        frame, labels = render_sample(sample, layout, occlusion=False)
        for label in labels:
            others = [v for v in sample.vehicles if v.spec.name != label["vehicle"]]
            without, _ = render_sample(replace(sample, vehicles=others), layout, occlusion=False)
            changed = np.any(frame.rgb != without.rgb, axis=2)
            rows, cols = np.flatnonzero(changed.any(axis=1)), np.flatnonzero(changed.any(axis=0))
            assert len(rows), f"vehicle {label['vehicle']} of frame {index} changes no pixel"
            x, y, w, h = label["bbox"]
            assert (cols[0], rows[0], cols[-1] + 1, rows[-1] + 1) == (x, y, x + w, y + h), label["vehicle"]
            kind = next(v.spec.kind for v in sample.vehicles if v.spec.name == label["vehicle"])
            assert label["category_id"] == CATEGORY_ID[kind]
            checked += 1
    assert checked >= 6


def test_same_seed_same_dataset_any_jobs_other_seed_differs(small_dataset, layout, tmp_path):
    """--jobs 2 runs in a child `v2i dataset`: a spawn pool inside the long-lived test process
    was seen to leave its heap corrupted at exit (glibc abort after all tests passed)."""
    import subprocess
    import sys

    out, coco = small_dataset
    subprocess.run([sys.executable, "-m", "master.cli", "dataset", "--scenario", str(CASE), "--out",
                    str(tmp_path / "again"), "--frames", "6", "--seed", "11", "--jobs", "2", "--quiet"],
                   check=True, cwd=ROOT, capture_output=True, timeout=300)
    again = json.loads((tmp_path / "again" / "annotations.json").read_text())
    again["info"]["scenario"] = coco["info"]["scenario"]
    assert again == coco
    for image in coco["images"]:
        assert (out / image["file_name"]).read_bytes() == (tmp_path / "again" / image["file_name"]).read_bytes()
    other = make_dataset(layout, tmp_path / "other", frames=6, seed=12)
    assert other["annotations"] != coco["annotations"]


def test_coco_structure_and_files(small_dataset):
    out, coco = small_dataset
    on_disk = json.loads((out / "annotations.json").read_text())
    assert on_disk == coco
    assert [c["name"] for c in coco["categories"]] == ["car", "emergency"]
    assert coco["info"]["seed"] == 11 and coco["info"]["frames"] == 6
    lines = (out / "frames.jsonl").read_text().splitlines()
    assert len(lines) == 6  # written as it went, one line per frame
    images = {im["id"]: im for im in coco["images"]}
    assert len(images) == 6
    ids = [a["id"] for a in coco["annotations"]]
    assert len(set(ids)) == len(ids) and len(ids) > 6
    for im in coco["images"]:
        with Image.open(out / im["file_name"]) as png:
            assert png.size == (im["width"], im["height"]) and png.mode == "RGB"
        P = np.array(im["camera"]["P"])
        assert P.shape == (3, 4) and np.all(np.isfinite(P))
    for a in coco["annotations"]:
        im = images[a["image_id"]]
        x, y, w, h = a["bbox"]
        assert 0 <= x and 0 <= y and w > 0 and h > 0 and x + w <= im["width"] and y + h <= im["height"]
        assert a["area"] == w * h and a["visible_pixels"] <= w * h
        assert a["occlusion"] is None or 0.0 <= a["occlusion"] <= 1.0
        # the vehicle's ground centre projects into (or near) its projected 3D box
        P = np.array(im["camera"]["P"])
        hx = P @ np.array([*a["position"], a["size"][2] / 2, 1.0])
        if hx[2] > 0 and a["full_bbox"] is not None:
            u, v = hx[:2] / hx[2]
            fx, fy, fw, fh = a["full_bbox"]
            if 0 <= u < im["width"] and 0 <= v < im["height"]:
                assert fx - 1 <= u <= fx + fw + 1 and fy - 1 <= v <= fy + fh + 1


def test_backgrounds_are_the_same_view_without_vehicles(layout, tmp_path):
    coco = make_dataset(layout, tmp_path / "bg", frames=2, seed=3, backgrounds=True, occlusion=False)
    for im in coco["images"]:
        frame = np.asarray(Image.open(tmp_path / "bg" / im["file_name"]))
        empty = np.asarray(Image.open(tmp_path / "bg" / im["background"]))
        changed = np.any(frame != empty, axis=2)
        inside = np.zeros_like(changed)
        for a in coco["annotations"]:
            if a["image_id"] == im["id"]:
                x, y, w, h = a["bbox"]
                inside[y:y + h, x:x + w] = True
        assert changed.any() == bool(inside.any())
        assert not (changed & ~inside).any(), "the background differs outside the vehicles' boxes"


def test_frame_without_vehicles_has_no_labels(layout):
    sample = replace(draw_sample(0, 1, "train", layout, layout.cameras[0]), vehicles=[])
    frame, labels = render_sample(sample, layout)
    assert labels == [] and frame.rgb.shape == (480, 640, 3)


def test_vehicle_behind_another_is_partly_occluded(layout):
    cam = layout.cameras[0]
    base = _no_shadow(draw_sample(0, 1, "train", layout, cam))
    sample = replace(base, camera=cam, lighting=Lighting())
    # both in the westbound lane south-west of the camera's view centre, one behind the other along the sight line
    near = PlacedVehicle(VehicleSpec("near", 6.5, 2.4, 2.8, (0.9, 0.1, 0.1), "emergency", 1.3), -2.0, 1.75, math.pi, 0)
    far = PlacedVehicle(VehicleSpec("far", 4.5, 1.8, 1.5, (0.2, 0.6, 0.2), "car", 0.9), -14.0, 1.75, math.pi, 0)
    _, labels = render_sample(replace(sample, vehicles=[near, far]), layout)
    by = {a["vehicle"]: a for a in labels}
    assert by["near"]["occlusion"] == pytest.approx(0.0, abs=0.01)
    assert 0.05 < by["far"]["occlusion"] < 1.0
    alone, labels_alone = render_sample(replace(sample, vehicles=[far]), layout)
    full = labels_alone[0]["visible_pixels"]
    assert by["far"]["occlusion"] == pytest.approx(1 - by["far"]["visible_pixels"] / full, abs=1e-3)


def test_heldout_draws_from_ranges_train_never_uses(layout):
    def drawn(variant, n=60):
        samples = [draw_sample(i, 2, variant, layout, layout.cameras[0]) for i in range(n)]
        cars = [v.spec for s in samples for v in s.vehicles if v.spec.kind == "car"]
        hues = [colorsys.rgb_to_hsv(*c.color)[0] for c in cars if len(set(c.color)) > 1]
        return samples, cars, hues

    _, train_cars, train_hues = drawn("train")
    held_samples, held_cars, held_hues = drawn("heldout")

    def inside(value, bands):
        return any(lo <= value <= hi for lo, hi in bands)

    assert all(inside(c.length, TRAIN.car_length) for c in train_cars)
    assert not any(inside(c.length, TRAIN.car_length[:1]) and c.length not in (3.8, 5.0) for c in held_cars)
    assert all(inside(h, HELDOUT.car_hues) for h in held_hues)
    assert not any(0.125 < h < 0.195 or 0.465 < h < 0.535 for h in train_hues)
    base_z, base_fov = layout.cameras[0].z, layout.cameras[0].fov_deg
    for s in held_samples:
        dz, dfov = s.camera.z - base_z, s.camera.fov_deg - base_fov
        assert not (-1.0 < dz < 1.5 and -10.0 < dfov < 8.0), "a heldout camera inside the training ranges"


def test_vehicles_do_not_overlap(layout):
    from master.world.dataset import _footprint

    for i in range(40):
        vs = draw_sample(i, 9, "train", layout, layout.cameras[0]).vehicles
        for a in range(len(vs)):
            for b in range(a + 1, len(vs)):
                assert not rectangles_overlap(_footprint(vs[a]), _footprint(vs[b]))


def test_rectangles_overlap_basic():
    sq = np.array([(0, 0), (1, 0), (1, 1), (0, 1)], dtype=float)
    assert rectangles_overlap(sq, sq + 0.5)
    assert not rectangles_overlap(sq, sq + [1.2, 0])
    assert rectangles_overlap(sq, sq + [1.2, 0], margin=0.5)
    diamond = np.array([(1.6, 0.5), (2.1, 1.0), (1.6, 1.5), (1.1, 1.0)])
    assert not rectangles_overlap(sq, diamond)


def test_bad_arguments_name_the_problem(layout, tmp_path):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("keep me")
    with pytest.raises(DatasetError, match="not empty.*--force"):
        make_dataset(layout, tmp_path / "full", frames=1, seed=0)
    assert (tmp_path / "full" / "x").read_text() == "keep me"
    with pytest.raises(DatasetError, match="camera: no camera 'nope'.*rsu_cam"):
        make_dataset(layout, tmp_path / "a", frames=1, seed=0, camera="nope")
    with pytest.raises(DatasetError, match="frames: must be >= 1"):
        make_dataset(layout, tmp_path / "b", frames=0, seed=0)
    with pytest.raises(DatasetError, match="variant"):
        make_dataset(layout, tmp_path / "c", frames=1, seed=0, variant="test")


def test_cli(tmp_path, capsys, write_scenario):
    assert main(["dataset", "--scenario", str(CASE), "--out", str(tmp_path / "d"), "--frames", "2", "--seed", "4",
                 "--quiet", "--no-occlusion"]) == 0
    assert "2 frames" in capsys.readouterr().out
    coco = json.loads((tmp_path / "d" / "annotations.json").read_text())
    assert all(a["occlusion"] is None for a in coco["annotations"])
    no_world = write_scenario("""
        [time]
        stop = 1.0
        step = 0.1
        [fmus.car]
        fmu = "{vehicle}"
    """)
    assert main(["dataset", "--scenario", str(no_world), "--out", str(tmp_path / "e"), "--quiet"]) == 2
    assert "no [world]" in capsys.readouterr().err


def test_wide_brackets_heldout_on_every_side_and_never_touches_it(layout):
    """The shipped detector's training variant: every held-out band lies inside the spread `wide`
    draws from, and no `wide` band overlaps a held-out one (the held-out set stays novel)."""
    from master.world.dataset import WIDE

    for key in ("car_length", "car_width", "car_height", "ev_length", "ev_width", "ev_height", "car_hues",
                "camera_dz", "camera_dfov"):
        wide, held = getattr(WIDE, key), getattr(HELDOUT, key)
        assert min(lo for lo, _ in wide) < min(lo for lo, _ in held), key
        assert max(hi for _, hi in wide) > max(hi for _, hi in held), key
        for lo, hi in wide:
            assert not any(lo < h_hi and h_lo < hi for h_lo, h_hi in held), (key, (lo, hi))
    assert not any(lo < 0.06 and 0.02 < hi for lo, hi in WIDE.ev_hues)  # held-out ev hues 0.02..0.06
    assert any(lo >= 0.06 for lo, _ in WIDE.ev_hues) and any(hi <= 0.02 for _, hi in WIDE.ev_hues)
    samples = [draw_sample(i, 3, "wide", layout, layout.cameras[0]) for i in range(40)]
    evs = [v.spec for s in samples for v in s.vehicles if v.spec.kind == "emergency"]
    assert evs and all(any(lo <= e.length <= hi for lo, hi in WIDE.ev_length) for e in evs)
    ambient = [s.lighting.ambient for s in samples]
    assert min(ambient) < 0.45 or max(ambient) > 0.8  # the wider light draw, not the standard one


def test_render_json_names_what_drew_the_images_and_stays_out_of_the_digest(small_dataset, tmp_path):
    """The two renderers' pictures differ (a detector trained on one lost 0.05 AP on the other), so a set says
    which drew it; render.json is not part of `Dataset.digest()`, so the sets recorded before it keep theirs."""
    import shutil

    from rsu_app.perception.dataset import DatasetError, join_datasets, load_dataset

    out, coco = small_dataset
    drawn = {json.loads(line)["renderer"] for line in (out / "frames.jsonl").read_text().splitlines()}
    assert len(drawn) == 1 and drawn <= {"tiny", "egl"}, drawn
    (name,) = drawn
    assert json.loads((out / "render.json").read_text()) == {"renderer": name, "frames": {name: 6}}
    assert "renderer" not in (out / "annotations.json").read_text()
    ds = load_dataset(out)
    assert ds.renderer == name
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    (copy / "render.json").unlink()
    bare = load_dataset(copy)
    assert bare.renderer is None and bare.digest() == ds.digest()  # the file is provenance, not content
    assert join_datasets([ds, bare]).renderer is None  # one folder does not say: the whole does not
    (copy / "render.json").write_text(json.dumps({"renderer": "egl" if name == "tiny" else "tiny"}))
    assert join_datasets([ds, load_dataset(copy)]).renderer == "mixed"
    assert render_summary(["egl", "tiny", "egl"]) == {"renderer": "mixed", "frames": {"egl": 2, "tiny": 1}}
    for bad, why in (("{not json", "not a JSON object"), ('{"renderer": 3}', "'renderer' must be a name"),
                     ("[1, 2]", "not a JSON object")):
        (copy / "render.json").write_text(bad)
        with pytest.raises(DatasetError, match=f"{copy / 'render.json'}: {why}"):
            load_dataset(copy)
