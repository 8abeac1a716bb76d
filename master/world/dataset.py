"""Labelled camera frames for training and evaluating detectors (`v2i dataset`).

Each frame is its own random scene drawn from `numpy.random.default_rng((seed,
variant, index))`: the scenario's intersection and buildings, a camera at a
free corner of the junction (jittered around the scenario's camera), random
vehicles on the lanes (kind, size, colour, position, heading, speed) and a
random sun. The same seed gives the same images and labels, in any order and
with any number of jobs.

The `heldout` variant draws vehicle colours, sizes and camera heights/fields of
view from ranges the `train` variant never uses, so an evaluation on it says
whether a detector generalises beyond what it was trained on. The `wide`
variant is the training distribution of the shipped detector: the `train`
bands plus bands beyond the held-out ones on every side (smaller and larger
vehicles, higher and lower cameras, narrower and wider fields of view, more
hues, harsher and softer light), so that the held-out values lie inside the
spread the detector saw, yet no value it trained on is a held-out value
(`WIDE`'s bands never overlap `HELDOUT`'s; tests/test_world_dataset.py).

Output folder (COCO-style, documented in the README):

    DIR/images/000000.png    RGB frames
    DIR/annotations.json     {"info", "categories", "images", "annotations"}
    DIR/backgrounds/000000.png  with --backgrounds: the same view without vehicles
    DIR/frames.jsonl         one line per finished frame, written as it goes
                             (an interrupted run keeps what it rendered), with the renderer that drew it
    DIR/render.json          {"renderer": "tiny" | "egl", "frames": {name: count}}: what drew the images.
                             Not in annotations.json, so `Dataset.digest()` (annotations and images) of a
                             set is what it was before the file existed

An annotation's `bbox` is the visible box (pixels of the vehicle in the
renderer's segmentation mask), `full_bbox` the projected 3D box; `ignore`
marks vehicles too hidden to count (fewer than `MIN_VISIBLE_PIXELS` pixels or
occlusion above `MAX_OCCLUSION`).
"""
from __future__ import annotations

import colorsys
import json
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from master.world.camera import Lighting
from master.world.layout import CameraSpec, VehicleSpec, WorldLayout

CATEGORIES = [{"id": 1, "name": "car"}, {"id": 2, "name": "emergency"}]
CATEGORY_ID = {c["name"]: c["id"] for c in CATEGORIES}
VARIANTS = ("train", "heldout", "wide")
MIN_VISIBLE_PIXELS = 40
MAX_OCCLUSION = 0.9
GENERATOR = "v2i-cosim dataset 1"

Range = tuple[float, float]


@dataclass(frozen=True)
class VariantRanges:
    """What a variant draws from; each field is a list of (low, high) bands."""
    car_length: list[Range]
    car_width: list[Range]
    car_height: list[Range]
    ev_length: list[Range]
    ev_width: list[Range]
    ev_height: list[Range]
    car_hues: list[Range]
    ev_hues: list[Range]
    camera_dz: list[Range]  # camera height change from the scenario camera's (m)
    camera_dfov: list[Range]  # field-of-view change (deg)
    yaw_jitter: float  # deg, +-
    p_grey: float  # share of white/silver/black cars
    light: str = "standard"  # which lighting draw (`sample_lighting`): "standard" or "wide"


TRAIN = VariantRanges(
    car_length=[(3.8, 5.0)], car_width=[(1.65, 1.95)], car_height=[(1.35, 1.75)],
    ev_length=[(6.0, 7.0)], ev_width=[(2.2, 2.45)], ev_height=[(2.4, 2.8)],
    car_hues=[(0.0, 0.12), (0.2, 0.46), (0.54, 1.0)], ev_hues=[(0.97, 1.0), (0.0, 0.02)],
    camera_dz=[(-1.0, 1.5)], camera_dfov=[(-10.0, 8.0)], yaw_jitter=8.0, p_grey=0.3)
HELDOUT = VariantRanges(
    car_length=[(3.4, 3.8), (5.0, 5.6)], car_width=[(1.55, 1.65), (1.95, 2.05)], car_height=[(1.25, 1.35), (1.75, 2.0)],
    ev_length=[(5.4, 6.0), (7.0, 7.8)], ev_width=[(2.1, 2.2), (2.45, 2.55)], ev_height=[(2.8, 3.1)],
    car_hues=[(0.12, 0.2), (0.46, 0.54)], ev_hues=[(0.02, 0.06)],
    camera_dz=[(1.5, 3.0), (-1.6, -1.0)], camera_dfov=[(-20.0, -10.0), (8.0, 14.0)], yaw_jitter=12.0, p_grey=0.0)
WIDE = VariantRanges(
    car_length=[(3.0, 3.4), (3.8, 5.0), (5.6, 6.2)], car_width=[(1.45, 1.55), (1.65, 1.95), (2.05, 2.15)],
    car_height=[(1.15, 1.25), (1.35, 1.75), (2.0, 2.2)],
    ev_length=[(4.8, 5.4), (6.0, 7.0), (7.8, 8.6)], ev_width=[(2.0, 2.1), (2.2, 2.45), (2.55, 2.7)],
    ev_height=[(2.1, 2.4), (2.4, 2.8), (3.1, 3.4)],
    car_hues=[(0.0, 0.12), (0.2, 0.46), (0.54, 1.0)], ev_hues=[(0.94, 1.0), (0.0, 0.02), (0.06, 0.1)],
    camera_dz=[(-2.2, -1.6), (-1.0, 1.5), (3.0, 4.0)], camera_dfov=[(-26.0, -20.0), (-10.0, 8.0), (14.0, 20.0)],
    yaw_jitter=16.0, p_grey=0.3, light="wide")
RANGES = {"train": TRAIN, "heldout": HELDOUT, "wide": WIDE}


class DatasetError(Exception):
    """Bad arguments or output folder; the message says which."""


@dataclass
class PlacedVehicle:
    spec: VehicleSpec
    x: float  # rear axle (m)
    y: float
    yaw: float  # rad
    speed: float  # m/s


@dataclass
class Sample:
    """Everything one frame is rendered from (plain data, so a test can alter it)."""
    index: int
    camera: CameraSpec
    lighting: Lighting
    vehicles: list[PlacedVehicle] = field(default_factory=list)


def _band(rng: np.random.Generator, bands: list[Range]) -> float:
    widths = np.array([hi - lo for lo, hi in bands])
    i = rng.choice(len(bands), p=widths / widths.sum())
    return float(rng.uniform(*bands[i]))


def _colour(rng: np.random.Generator, hues: list[Range], p_grey: float, saturation: Range) -> tuple:
    if rng.random() < p_grey:
        v = float(rng.choice([rng.uniform(0.05, 0.15), rng.uniform(0.55, 0.75), rng.uniform(0.85, 0.97)]))
        return (v, v, v)
    h = _band(rng, hues) % 1.0
    r, g, b = colorsys.hsv_to_rgb(h, float(rng.uniform(*saturation)), float(rng.uniform(0.45, 0.95)))
    return (round(r, 4), round(g, 4), round(b, 4))


def free_corners(layout: WorldLayout) -> list[tuple[float, float]]:
    """Sidewalk corners of the junction (pole sites) not inside a building footprint."""
    ix = layout.intersection
    c = ix.road_width / 2 + 0.75 * max(ix.sidewalk_width, 0.5)
    out = []
    for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
        x, y = sx * c, sy * c
        if not any(b.bounds[0][0] <= x <= b.bounds[1][0] and b.bounds[0][1] <= y <= b.bounds[1][1]
                   for b in layout.buildings):
            out.append((x, y))
    return out


def sample_camera(rng: np.random.Generator, base: CameraSpec, layout: WorldLayout, r: VariantRanges) -> CameraSpec:
    """A pole camera at a free corner looking into the junction, jittered around `base`."""
    corners = free_corners(layout)
    if not corners:
        raise DatasetError("no free junction corner for the camera (every corner is inside a building)")
    base_corner = min(corners, key=lambda c: math.hypot(c[0] - base.x, c[1] - base.y))
    x, y = base_corner if rng.random() < 0.6 else corners[rng.integers(len(corners))]
    x, y = x + rng.uniform(-0.4, 0.4), y + rng.uniform(-0.4, 0.4)
    z = max(3.0, base.z + _band(rng, r.camera_dz))
    aim = rng.uniform(14.0, 30.0)  # ground distance the optical axis points at
    yaw = math.degrees(math.atan2(-y, -x)) + rng.uniform(-r.yaw_jitter, r.yaw_jitter)
    pitch = -math.degrees(math.atan2(z, aim)) + rng.uniform(-2.0, 2.0)
    fov = float(np.clip(base.fov_deg + _band(rng, r.camera_dfov), 50.0, 120.0))
    return replace(base, name=base.name, x=float(x), y=float(y), z=float(z), yaw=float(yaw), pitch=float(pitch),
                   roll=float(rng.uniform(-1.5, 1.5)), fov_deg=fov)


LIGHT = {  # elevation (deg), warmth, ambient, diffuse, specular, P(shadow)
    "standard": ((20, 80), (0.0, 0.15), (0.45, 0.8), (0.3, 0.65), (0.0, 0.3), 0.25),
    "wide": ((10, 85), (0.0, 0.25), (0.35, 0.9), (0.2, 0.75), (0.0, 0.4), 0.35),
}


def sample_lighting(rng: np.random.Generator, kind: str = "standard") -> Lighting:
    elevation, warmth, ambient, diffuse, specular, p_shadow = LIGHT[kind]
    az, el = rng.uniform(0, 2 * math.pi), math.radians(rng.uniform(*elevation))
    warm = rng.uniform(*warmth)
    return Lighting(direction=(math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)),
                    color=(1.0, 1.0 - warm / 2, 1.0 - warm), ambient=float(rng.uniform(*ambient)),
                    diffuse=float(rng.uniform(*diffuse)), specular=float(rng.uniform(*specular)),
                    shadow=bool(rng.random() < p_shadow))


def _footprint(v: PlacedVehicle) -> np.ndarray:
    """The vehicle's ground rectangle (4, 2)."""
    d = v.spec.centre_offset
    c, s = math.cos(v.yaw), math.sin(v.yaw)
    cx, cy = v.x + d * c, v.y + d * s
    hl, hw = v.spec.length / 2, v.spec.width / 2
    return np.array([(cx + c * lx - s * ly, cy + s * lx + c * ly) for lx, ly in
                     ((-hl, -hw), (hl, -hw), (hl, hw), (-hl, hw))])


def rectangles_overlap(a: np.ndarray, b: np.ndarray, margin: float = 0.0) -> bool:
    """Separating-axis test of two convex ground polygons, with `margin` metres of clearance."""
    for poly in (a, b):
        for i in range(len(poly)):
            edge = poly[(i + 1) % len(poly)] - poly[i]
            axis = np.array([-edge[1], edge[0]]) / (np.hypot(*edge) or 1.0)
            pa, pb = a @ axis, b @ axis
            if pa.max() + margin <= pb.min() or pb.max() + margin <= pa.min():
                return False
    return True


def _lanes(layout: WorldLayout) -> list[tuple[float, float, float]]:
    """(x, y, heading) of each lane's centre line at the junction centre, drive on the right."""
    o = layout.intersection.lane_width / 2
    return [(0.0, -o, 0.0), (0.0, o, math.pi), (o, 0.0, math.pi / 2), (-o, 0.0, -math.pi / 2)]


def sample_vehicles(rng: np.random.Generator, layout: WorldLayout, r: VariantRanges,
                    in_view) -> list[PlacedVehicle]:
    """Random traffic on the lanes; `in_view(vehicle)` says whether the camera would see it."""
    n = int(rng.choice(9, p=[0.04, 0.12, 0.14, 0.14, 0.14, 0.12, 0.11, 0.1, 0.09]))
    lanes = _lanes(layout)
    reach = min(layout.intersection.arm_length - 8.0, 75.0)
    placed: list[PlacedVehicle] = []
    for i in range(n):
        emergency = rng.random() < 0.2
        if emergency:
            L, W, H = _band(rng, r.ev_length), _band(rng, r.ev_width), _band(rng, r.ev_height)
            colour = _colour(rng, r.ev_hues, 0.0, (0.8, 1.0))
        else:
            L, W, H = _band(rng, r.car_length), _band(rng, r.car_width), _band(rng, r.car_height)
            colour = _colour(rng, r.car_hues, r.p_grey, (0.35, 0.95))
        spec = VehicleSpec(f"v{i}", L, W, H, colour, "emergency" if emergency else "car", rear_overhang=0.2 * L)
        for _ in range(25):
            lx, ly, heading = lanes[rng.integers(len(lanes))]
            s = rng.uniform(-reach, reach)
            lateral = rng.normal(0.0, 0.2)
            yaw = heading + rng.normal(0.0, math.radians(2.0))
            if abs(s) < layout.intersection.road_width / 2 + 2 and rng.random() < 0.5:
                yaw = rng.uniform(-math.pi, math.pi)  # turning in the junction
            cx = lx + s * math.cos(heading) - lateral * math.sin(heading)
            cy = ly + s * math.sin(heading) + lateral * math.cos(heading)
            d = spec.centre_offset
            v = PlacedVehicle(spec, cx - d * math.cos(yaw), cy - d * math.sin(yaw), float(yaw),
                              float(rng.uniform(0.0, 17.0)))
            box = _footprint(v)
            if any(rectangles_overlap(box, _footprint(o), margin=0.5) for o in placed):
                continue
            if in_view(v):
                placed.append(v)
                break
    return placed


def draw_sample(index: int, seed: int, variant: str, layout: WorldLayout, base_camera: CameraSpec) -> Sample:
    """The scene of frame `index` (pure function of its arguments)."""
    from master.world.camera import Camera  # projection only; no renderer is touched here

    rng = np.random.default_rng((seed, VARIANTS.index(variant), index))
    r = RANGES[variant]
    cam_spec = sample_camera(rng, base_camera, layout, r)
    lighting = sample_lighting(rng, r.light)
    cam = Camera(cam_spec, None)
    W, H = cam_spec.width, cam_spec.height

    def in_view(v: PlacedVehicle) -> bool:
        corners = np.array([(x, y, z) for x, y in _footprint(v) for z in (0.0, v.spec.height)])
        uv, depth = cam.project(corners)
        if np.any(depth <= 0.5):
            return False
        u0, v0 = uv.min(axis=0)
        u1, v1 = uv.max(axis=0)
        return u1 > 0 and v1 > 0 and u0 < W and v0 < H and (min(u1, W) - max(u0, 0)) * (min(v1, H) - max(v0, 0)) > 30

    return Sample(index, cam_spec, lighting, sample_vehicles(rng, layout, r, in_view))


def render_sample(sample: Sample, layout: WorldLayout, occlusion: bool = True):
    """Render a sample: (Frame, list of annotation dicts without ids)."""
    from master.world.camera import Camera
    from master.world.ground_truth import frame_truth
    from master.world.scene import Scene

    scene_layout = replace(layout, cameras=[sample.camera], vehicles={v.spec.name: v.spec for v in sample.vehicles})
    with Scene(scene_layout) as scene:
        for v in sample.vehicles:
            scene.pose_vehicle(v.spec.name, v.x, v.y, v.yaw, v.speed)
        cam = Camera(sample.camera, scene.client, scene.renderer)
        frame = cam.render(0.0, sample.lighting)
        truths = frame_truth(scene, cam, frame, occlusion=occlusion)
    by_name = {v.spec.name: v for v in sample.vehicles}
    labels = []
    for t in truths:
        if t.visible_box is None:
            continue
        v = by_name[t.name]
        u0, v0, u1, v1 = t.visible_box
        d = v.spec.centre_offset
        cx, cy = v.x + d * math.cos(v.yaw), v.y + d * math.sin(v.yaw)
        full = None if t.box is None else [round(t.box[0], 2), round(t.box[1], 2),
                                           round(t.box[2] - t.box[0], 2), round(t.box[3] - t.box[1], 2)]
        labels.append({
            "category_id": CATEGORY_ID[v.spec.kind], "bbox": [u0, v0, u1 - u0, v1 - v0], "area": (u1 - u0) * (v1 - v0),
            "iscrowd": 0,
            "ignore": bool(t.visible_pixels < MIN_VISIBLE_PIXELS or (t.occlusion or 0.0) > MAX_OCCLUSION),
            "occlusion": None if t.occlusion is None else round(float(t.occlusion), 4),
            "visible_pixels": t.visible_pixels, "full_bbox": full,
            "position": [round(cx, 3), round(cy, 3)], "heading": round(t.heading, 5), "speed": round(t.speed, 3),
            "size": [round(v.spec.length, 3), round(v.spec.width, 3), round(v.spec.height, 3)],
            "color": list(v.spec.color),
            "distance": round(math.hypot(cx - frame.position[0], cy - frame.position[1]), 3),
            "vehicle": v.spec.name,
        })
    return frame, labels


@dataclass
class DatasetJob:
    """Arguments of one dataset run, shared by the worker processes."""
    layout: WorldLayout
    base_camera: CameraSpec
    out: str
    seed: int
    variant: str
    occlusion: bool
    scenario: str = ""
    backgrounds: bool = False


def _frame_record(job: DatasetJob, index: int) -> dict[str, Any]:
    from PIL import Image

    sample = draw_sample(index, job.seed, job.variant, job.layout, job.base_camera)
    frame, labels = render_sample(sample, job.layout, occlusion=job.occlusion)
    name = f"images/{index:06d}.png"
    Image.fromarray(frame.rgb).save(Path(job.out) / name, compress_level=1)
    extra = {}
    if job.backgrounds:  # the same camera, sun and scene without vehicles (background-subtraction baselines)
        empty, _ = render_sample(replace(sample, vehicles=[]), job.layout, occlusion=False)
        extra["background"] = f"backgrounds/{index:06d}.png"
        Image.fromarray(empty.rgb).save(Path(job.out) / extra["background"], compress_level=1)
    c = sample.camera
    return {
        "image": {"id": index, "file_name": name, "width": c.width, "height": c.height, "t": 0.0, **extra,
                  "camera": {"name": c.name, "P": frame.P.round(6).tolist(), "K": frame.K.round(6).tolist(),
                             "R_wc": frame.R_wc.round(8).tolist(), "position": frame.position.round(4).tolist(),
                             "yaw": c.yaw, "pitch": c.pitch, "roll": c.roll, "fov_deg": c.fov_deg},
                  "lighting": {"direction": list(sample.lighting.direction), "ambient": sample.lighting.ambient,
                               "diffuse": sample.lighting.diffuse, "shadow": sample.lighting.shadow}},
        "annotations": labels,
        "renderer": frame.renderer,
    }


_JOB: DatasetJob | None = None


def _init_worker(job: DatasetJob) -> None:
    global _JOB
    _JOB = job


def _work(index: int) -> dict[str, Any]:
    assert _JOB is not None
    return _frame_record(_JOB, index)


def make_dataset(layout: WorldLayout, out: Path, frames: int, seed: int, variant: str = "train",
                 camera: str | None = None, jobs: int = 1, occlusion: bool = True, force: bool = False,
                 scenario: str = "", progress: bool = False, backgrounds: bool = False) -> dict[str, Any]:
    """Render `frames` labelled frames into `out`; returns the COCO dictionary it wrote."""
    if variant not in VARIANTS:
        raise DatasetError(f"variant: expected one of {', '.join(VARIANTS)}, got {variant!r}")
    if frames < 1:
        raise DatasetError(f"frames: must be >= 1, got {frames}")
    if jobs < 1:
        raise DatasetError(f"jobs: must be >= 1, got {jobs}")
    if not layout.cameras:
        raise DatasetError("the scenario's [world] has no camera to take the pose from ([[world.cameras]])")
    names = [c.name for c in layout.cameras]
    if camera is None:
        base = layout.cameras[0]
    elif camera in names:
        base = layout.cameras[names.index(camera)]
    else:
        raise DatasetError(f"camera: no camera {camera!r} in the scenario (cameras: {', '.join(names)})")
    out = Path(out)
    if out.exists() and any(out.iterdir()) and not force:
        raise DatasetError(f"out: {out} exists and is not empty (use --force to overwrite)")
    (out / "images").mkdir(parents=True, exist_ok=True)
    if backgrounds:
        (out / "backgrounds").mkdir(exist_ok=True)
    job = DatasetJob(layout, base, str(out), seed, variant, occlusion, scenario, backgrounds)
    records: list[dict[str, Any]] = []
    with open(out / "frames.jsonl", "w") as log:
        for record in _records(job, frames, jobs, progress):
            log.write(json.dumps(record) + "\n")
            log.flush()
            records.append(record)
    coco = _coco(records, job, frames)
    _write_json(out / "render.json", render_summary(r["renderer"] for r in records))
    _write_json(out / "annotations.json", coco)
    return coco


def render_summary(renderers: Iterable[str]) -> dict[str, Any]:
    """`render.json`'s content: the renderer of every frame ("mixed" where they differ, e.g. a worker whose
    EGL would not load fell back to TinyRenderer) and how many frames each drew."""
    from collections import Counter

    counts = Counter(renderers)
    return {"renderer": next(iter(counts)) if len(counts) == 1 else "mixed", "frames": dict(sorted(counts.items()))}


def _write_json(path: Path, doc: dict[str, Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(doc))
    os.replace(tmp, path)


def _records(job: DatasetJob, frames: int, jobs: int, progress: bool) -> Iterable[dict[str, Any]]:
    from tqdm import tqdm

    bar = tqdm(total=frames, unit="frame", disable=not progress)
    try:
        if jobs == 1:
            for i in range(frames):
                yield _frame_record(job, i)
                bar.update()
            return
        import multiprocessing as mp

        with mp.get_context("spawn").Pool(jobs, initializer=_init_worker, initargs=(job,)) as pool:
            for record in pool.imap(_work, range(frames), chunksize=4):
                yield record
                bar.update()
    finally:
        bar.close()


def _coco(records: list[dict[str, Any]], job: DatasetJob, frames: int) -> dict[str, Any]:
    images, annotations = [], []
    for record in records:
        images.append(record["image"])
        for label in record["annotations"]:
            annotations.append({"id": len(annotations) + 1, "image_id": record["image"]["id"], **label})
    return {
        "info": {"generator": GENERATOR, "seed": job.seed, "variant": job.variant, "frames": frames,
                 "scenario": job.scenario, "occlusion": job.occlusion, "backgrounds": job.backgrounds,
                 "min_visible_pixels": MIN_VISIBLE_PIXELS, "max_occlusion": MAX_OCCLUSION},
        "categories": CATEGORIES, "images": images, "annotations": annotations,
    }
