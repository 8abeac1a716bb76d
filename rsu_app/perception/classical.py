"""The classical baseline: no learning, just a static camera and OpenCV.

Foreground = pixels that differ from the empty scene: either a background
image given at construction (exact for a static simulated camera), or a
MOG2 model learnt over the frames seen so far (for real footage). Then
morphology, connected contours -> boxes, and a colour heuristic for the
label: the emergency vehicle is mostly white with a red cab and stripe,
which a car (coloured body, glass cabin) is not.

What it cannot do, and why the learned detector must beat it: two vehicles
whose blobs touch come out as one box; a vehicle parked for long enough
melts into a MOG2 background; a white-and-red car is called an emergency
vehicle; the label ignores size (a box's pixel size says little without
its distance).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from rsu_app.perception.detector import Detection, DetectorError, check_frame


class ClassicalDetector:
    name = "classical"

    def __init__(self, background: np.ndarray | str | Path | None = None, threshold: int = 25,
                 min_area: int = 30, kernel: int = 3, history: int = 200, white_fraction: float = 0.25,
                 red_fraction: float = 0.05):
        if isinstance(background, (str, Path)):
            img = cv2.imread(str(background), cv2.IMREAD_COLOR)
            if img is None:
                raise DetectorError(f"classical detector: cannot read background image {str(background)!r}")
            background = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        self.background = None if background is None else check_frame(background).astype(np.int16)
        self.threshold, self.min_area = int(threshold), int(min_area)
        self.white_fraction, self.red_fraction = white_fraction, red_fraction
        self._kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (kernel, kernel))
        self._mog = None if self.background is not None else cv2.createBackgroundSubtractorMOG2(
            history=history, varThreshold=16, detectShadows=False)

    def set_background(self, background: np.ndarray) -> None:
        """Use this empty-scene image from now on (e.g. per frame, when the camera or the light moved)."""
        self.background = check_frame(background).astype(np.int16)
        self._mog = None

    def foreground(self, rgb: np.ndarray) -> np.ndarray:
        """uint8 mask (0/255) of the pixels that are not the empty scene, cleaned by morphology."""
        rgb = check_frame(rgb)
        if self.background is not None:
            if rgb.shape != self.background.shape:
                raise DetectorError(f"frame shape {rgb.shape} differs from the background's {self.background.shape}")
            diff = np.abs(rgb.astype(np.int16) - self.background).max(axis=2)
            mask = np.where(diff > self.threshold, 255, 0).astype(np.uint8)
        else:
            mask = self._mog.apply(rgb)
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, self._kernel)
        return cv2.morphologyEx(mask, cv2.MORPH_CLOSE, self._kernel, iterations=2)

    def detect(self, rgb: np.ndarray) -> list[Detection]:
        return self.boxes(rgb, self.foreground(rgb))

    def boxes(self, rgb: np.ndarray, mask: np.ndarray) -> list[Detection]:
        """Detections from a foreground mask of `rgb` (the second half of `detect`)."""
        n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        if n <= 1:
            return []
        hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
        # "white" is any unsaturated light surface: the renderer shades a white box to grey 130-230
        white = (hsv[..., 1] < 40) & (hsv[..., 2] > 110)
        red = ((hsv[..., 0] < 8) | (hsv[..., 0] > 170)) & (hsv[..., 1] > 150) & (hsv[..., 2] > 80)
        out = []
        for i in range(1, n):
            x, y, w, h, area = stats[i]
            if area < self.min_area:
                continue
            blob = labels[y:y + h, x:x + w] == i
            fw = float(np.count_nonzero(white[y:y + h, x:x + w] & blob)) / area
            fr = float(np.count_nonzero(red[y:y + h, x:x + w] & blob)) / area
            label = "emergency" if fw >= self.white_fraction and fr >= self.red_fraction else "car"
            score = min(1.0, 0.5 + 0.5 * area / float(w * h))  # solid blobs are more vehicle-like
            out.append(Detection((float(x), float(y), float(x + w), float(y + h)), label, float(score)))
        out.sort(key=lambda d: -d.score)
        return out
