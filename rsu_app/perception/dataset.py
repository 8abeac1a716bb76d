"""Reading a detection dataset folder (COCO-style, written by `v2i dataset`).

    DIR/annotations.json   images (with the camera model), annotations with
                           visible box, ignore flag, occlusion, distance, ...
    DIR/images/*.png       RGB frames

Only the fields the detector, its training and its evaluation need are
turned into typed records; the rest stays available in `Sample.raw`.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np


class DatasetError(ValueError):
    """A dataset folder that cannot be read, with the file and what is wrong."""


@dataclass
class Truth:
    box: tuple[float, float, float, float]  # u0, v0, u1, v1 (visible box, frame pixels)
    label: str
    ignore: bool = False
    occlusion: float | None = None
    distance: float | None = None  # m, camera to vehicle centre, horizontal
    position: tuple[float, float] | None = None  # vehicle centre on the ground (world m)
    heading: float | None = None
    size: tuple[float, float, float] | None = None
    visible_pixels: int | None = None  # the renderer's count of the vehicle's unhidden pixels in the frame


@dataclass
class Sample:
    image_id: int
    path: Path
    width: int
    height: int
    truths: list[Truth]
    camera: dict | None = None
    t: float | None = None
    raw: dict = field(default_factory=dict, repr=False)
    root: Path = Path(".")

    def load(self) -> np.ndarray:
        """The frame as (H, W, 3) uint8 RGB."""
        return _read_rgb(self.path)

    def background(self) -> np.ndarray | None:
        """The empty-scene image of this frame (image field "background"), if the dataset has one."""
        name = self.raw.get("background")
        return None if not name else _read_rgb(self.root / name)


def _read_rgb(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise DatasetError(f"{path}: cannot read image")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


@dataclass
class Dataset:
    root: Path
    samples: list[Sample]
    categories: dict[int, str]
    info: dict
    parts: list["Dataset"] = field(default_factory=list)  # the folders a joined set was made of (join_datasets)
    renderer: str | None = None  # what drew the images (render.json: "tiny", "egl", "mixed"); None: not recorded
    # digest() reads every image; a training run asks for it twice (the joined set's and each folder's)
    _digest: str | None = field(default=None, init=False, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.samples)

    def part_digests(self) -> list[str]:
        """The digest of each folder this set was made of (one for a plain folder)."""
        return [d.digest() for d in self.parts] if self.parts else [self.digest()]

    def digest(self) -> str:
        """sha256 over annotations.json and every image's bytes: names the exact data a model saw. A joined
        set's digest is the sha256 of its parts' digests, in order, joined by '+'."""
        if self._digest is None:
            if self.parts:
                self._digest = hashlib.sha256("+".join(self.part_digests()).encode()).hexdigest()
            else:
                h = hashlib.sha256((self.root / "annotations.json").read_bytes())
                for s in self.samples:
                    h.update(s.path.name.encode())
                    h.update(s.path.read_bytes())
                self._digest = h.hexdigest()
        return self._digest


def join_datasets(parts: list[Dataset]) -> Dataset:
    """Several dataset folders as one training set, in the order given (e.g. the same scenes drawn by each
    renderer). Their categories must agree (a label means one class); the joined set keeps the first
    one's `root` and `info` and records every part, so `part_digests` still names the exact data."""
    if not parts:
        raise DatasetError("no dataset folders given")
    first = parts[0]
    for other in parts[1:]:
        if other.categories != first.categories:
            raise DatasetError(f"{other.root}: categories {other.categories} differ from {first.root}'s "
                               f"{first.categories}; a label must mean one class in every folder")
    if len(parts) == 1:
        return first
    names = {d.renderer for d in parts}
    renderer = names.pop() if len(names) == 1 else (None if None in names else "mixed")
    return Dataset(first.root, [s for d in parts for s in d.samples], first.categories, first.info, parts,
                   renderer)


def load_dataset(root: str | Path) -> Dataset:
    root = Path(root)
    ann_path = root / "annotations.json"
    if not ann_path.is_file():
        raise DatasetError(f"{root}: no annotations.json (is this a dataset folder written by `v2i dataset`?)")
    try:
        doc = json.loads(ann_path.read_text())
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{ann_path}: not JSON: {exc}") from exc
    for key in ("images", "annotations", "categories"):
        if not isinstance(doc.get(key), list):
            raise DatasetError(f"{ann_path}: missing list {key!r}")
    categories = {int(c["id"]): str(c["name"]) for c in doc["categories"]}
    by_image: dict[int, list[Truth]] = {int(im["id"]): [] for im in doc["images"]}
    for i, a in enumerate(doc["annotations"]):
        where = f"{ann_path}: annotations[{i}]"
        try:
            x, y, w, h = (float(v) for v in a["bbox"])
            label = categories[int(a["category_id"])]
            image_id = int(a["image_id"])
        except (KeyError, TypeError, ValueError) as exc:
            raise DatasetError(f"{where}: bad or missing bbox/category_id/image_id ({exc})") from exc
        if image_id not in by_image:
            raise DatasetError(f"{where}: image_id {image_id} is not in images")
        if w < 0 or h < 0 or not np.isfinite([x, y, w, h]).all():
            raise DatasetError(f"{where}: bbox must be finite with w, h >= 0, got {a['bbox']}")
        visible = a.get("visible_pixels")
        if visible is not None and (isinstance(visible, bool) or not isinstance(visible, (int, float))
                                    or not np.isfinite(visible) or visible < 0):
            raise DatasetError(f"{where}: visible_pixels must be a number >= 0 (the renderer's pixel count), "
                               f"got {visible!r}")
        pos, size = a.get("position"), a.get("size")
        by_image[image_id].append(Truth(
            (x, y, x + w, y + h), label, bool(a.get("ignore", False) or a.get("iscrowd", 0)),
            a.get("occlusion"), a.get("distance"), tuple(pos) if pos else None, a.get("heading"),
            tuple(size) if size else None, visible))
    samples = []
    for im in doc["images"]:
        path = root / im["file_name"]
        if not path.is_file():
            raise DatasetError(f"{ann_path}: image {im['file_name']!r} not found under {root}")
        samples.append(Sample(int(im["id"]), path, int(im["width"]), int(im["height"]), by_image[int(im["id"])],
                              im.get("camera"), im.get("t"), im, root))
    return Dataset(root, samples, categories, doc.get("info", {}), renderer=_renderer(root))


def _renderer(root: Path) -> str | None:
    """render.json's renderer (`v2i dataset` writes it; sets made before it existed have none)."""
    path = root / "render.json"
    if not path.is_file():
        return None
    try:
        name = json.loads(path.read_text()).get("renderer")
    except (json.JSONDecodeError, AttributeError) as exc:
        raise DatasetError(f"{path}: not a JSON object ({exc})") from exc
    if not isinstance(name, str) or not name:
        raise DatasetError(f"{path}: 'renderer' must be a name such as \"tiny\" or \"egl\", got {name!r}")
    return name
