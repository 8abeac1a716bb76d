"""A toy dataset drawn with OpenCV, in the `v2i dataset` format.

For smoke tests of training, export and evaluation without rendering the
3D world: a fixed textured road scene and rectangles for vehicles (a car
is a coloured body with a glass cabin; the emergency vehicle a white box
with a red cab). Not training data for the real detector.
"""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

CAR_COLOURS = [(40, 75, 215), (200, 30, 30), (30, 150, 60), (20, 20, 20), (180, 180, 40)]


def background(width: int = 640, height: int = 480, seed: int = 0) -> np.ndarray:
    """The empty scene: grass, two roads, lane marks, mild noise."""
    rng = np.random.default_rng(seed)
    img = np.empty((height, width, 3), np.uint8)
    img[:] = (90, 140, 76)
    cv2.rectangle(img, (0, height // 3), (width, height // 3 + height // 6), (64, 64, 69), -1)
    cv2.fillPoly(img, [np.array([[width // 2 - 40, 0], [width // 2 + 40, 0], [width, height], [width // 4, height]])],
                 (64, 64, 69))
    cv2.line(img, (0, height // 3 + height // 12), (width, height // 3 + height // 12), (240, 240, 240), 1)
    noise = rng.integers(-6, 7, img.shape, dtype=np.int16)
    return np.clip(img.astype(np.int16) + noise, 0, 255).astype(np.uint8)


def draw_vehicle(img: np.ndarray, box: tuple[int, int, int, int], label: str, colour=(40, 75, 215)) -> None:
    u0, v0, u1, v1 = box
    h = v1 - v0
    if label == "emergency":
        cab = u0 + int(0.7 * (u1 - u0))
        cv2.rectangle(img, (u0, v0), (cab, v1 - 1), (245, 245, 245), -1)
        cv2.rectangle(img, (u0, v0 + int(0.55 * h)), (cab, v0 + int(0.7 * h)), (230, 15, 15), -1)
        cv2.rectangle(img, (cab, v0 + h // 4), (u1 - 1, v1 - 1), (230, 20, 20), -1)
    else:
        cv2.rectangle(img, (u0, v0 + h // 2), (u1 - 1, v1 - 1), colour, -1)
        w = u1 - u0
        cv2.rectangle(img, (u0 + w // 5, v0), (u1 - 1 - w // 5, v0 + h // 2), (140, 178, 216), -1)


def write_dataset(root: str | Path, n_images: int = 8, seed: int = 0, width: int = 640, height: int = 480,
                  max_vehicles: int = 3) -> Path:
    """Write n_images frames with 0..max_vehicles non-overlapping vehicles each; returns root."""
    root = Path(root)
    (root / "images").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    bg = background(width, height, seed)
    images, anns = [], []
    for i in range(n_images):
        img = bg.copy()
        boxes: list[tuple[int, int, int, int]] = []
        for _ in range(int(rng.integers(0, max_vehicles + 1))):
            label = "emergency" if rng.random() < 0.35 else "car"
            bh = int(rng.integers(16, 60)) * (3 if label == "emergency" else 2) // 2
            bw = int(bh * rng.uniform(1.6, 2.6))
            for _ in range(20):  # place without overlap
                u0, v0 = int(rng.integers(0, width - bw)), int(rng.integers(height // 5, height - bh))
                cand = (u0, v0, u0 + bw, v0 + bh)
                if all(cand[2] <= b[0] or b[2] <= cand[0] or cand[3] <= b[1] or b[3] <= cand[1] for b in boxes):
                    boxes.append(cand)
                    draw_vehicle(img, cand, label, CAR_COLOURS[int(rng.integers(len(CAR_COLOURS)))])
                    anns.append({"id": len(anns) + 1, "image_id": i, "category_id": 2 if label == "emergency" else 1,
                                 "bbox": [u0, v0, bw, bh], "area": bw * bh, "iscrowd": 0, "ignore": False,
                                 "occlusion": 0.0, "visible_pixels": bw * bh, "full_bbox": [u0, v0, bw, bh],
                                 "position": None, "heading": None, "speed": None, "size": None,
                                 "distance": float(10 + (height - v0 - bh) / 4)})
                    break
        name = f"images/{i:06d}.png"
        cv2.imwrite(str(root / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        images.append({"id": i, "file_name": name, "width": width, "height": height, "camera": None, "t": i * 0.1})
    doc = {"info": {"seed": seed, "scenario": "synthetic", "variant": 0, "frames": n_images,
                    "generator": "rsu_app.perception.synthetic"},
           "categories": [{"id": 1, "name": "car"}, {"id": 2, "name": "emergency"}],
           "images": images, "annotations": anns}
    (root / "annotations.json").write_text(json.dumps(doc, indent=1))
    return root
