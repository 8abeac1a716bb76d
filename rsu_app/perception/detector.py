"""One `Detector` interface, backends chosen by name.

    det = make_detector("torch", weights="weights.pt", threads=2)
    det = make_detector("torch")   # the shipped weights (weights/detector.pt)
    for d in det.detect(frame.rgb): ...

Like python-can's `Bus(interface=...)`: callers name a backend, the table
below maps the name to its class, imported only when asked for (so the
classical baseline works without torch installed).
"""
from __future__ import annotations

import difflib
import importlib
import inspect
import math
from pathlib import Path
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

LABELS = ("car", "emergency")
# CPU threads a learned backend uses unless told otherwise. One: on the 2-core machines this project runs
# on, the master, the renderer and the RSU app share the cores, and a detector spreading over both
# (torch's own default) stalls on the others' work: 1.5-3 FPS instead of ~40 (benchmarks/perception.py
# measures both beside a busy core). Ask for more with threads=N where cores are free.
DEFAULT_THREADS = 1

# the shipped weights (rsu_app/perception/weights/RECIPE.md says how they were made)
WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
DEFAULT_WEIGHTS = {"torch": WEIGHTS_DIR / "detector.pt", "onnx": WEIGHTS_DIR / "detector.onnx"}


def default_weights(backend: str) -> Path:
    """The shipped weights file for `backend` ("torch" or "onnx"); DetectorError if it is missing."""
    for path in (DEFAULT_WEIGHTS[backend], DEFAULT_WEIGHTS["torch"]):
        if path.is_file():
            return path
    raise DetectorError(f"no shipped weights at {DEFAULT_WEIGHTS[backend]}: pass weights=PATH "
                        f"(train one with `v2i train-detector`)")

BACKENDS: dict[str, str] = {
    "classical": "rsu_app.perception.classical:ClassicalDetector",
    "torch": "rsu_app.perception.torch_backend:TorchDetector",
    "onnx": "rsu_app.perception.onnx_backend:OnnxDetector",
}


class DetectorError(ValueError):
    """Bad input to a detector or a bad detector configuration."""


@dataclass(frozen=True)
class Detection:
    box: tuple[float, float, float, float]  # u0, v0, u1, v1 in continuous frame pixels
    label: str  # "car" | "emergency"
    score: float  # 0..1

    def __post_init__(self):
        if len(self.box) != 4 or not all(math.isfinite(b) for b in self.box):
            raise DetectorError(f"detection box must be 4 finite numbers, got {self.box!r}")
        if self.box[2] < self.box[0] or self.box[3] < self.box[1]:
            raise DetectorError(f"detection box must have u1 >= u0 and v1 >= v0, got {self.box!r}")
        if self.label not in LABELS:
            raise DetectorError(f"detection label must be one of {LABELS}, got {self.label!r}")


@runtime_checkable
class Detector(Protocol):
    name: str

    def detect(self, rgb: np.ndarray) -> list[Detection]:
        """Vehicles in one RGB frame, best score first; [] when there are none."""


def check_frame(rgb) -> np.ndarray:
    """The frame as a (H, W, 3) uint8 array, or a DetectorError saying what is wrong with it."""
    if not isinstance(rgb, np.ndarray):
        raise DetectorError(f"frame must be a numpy array, got {type(rgb).__name__}")
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise DetectorError(f"frame must have shape (H, W, 3), got {rgb.shape}")
    if rgb.shape[0] == 0 or rgb.shape[1] == 0:
        raise DetectorError(f"frame is empty: shape {rgb.shape}")
    if rgb.dtype != np.uint8:
        raise DetectorError(f"frame must be uint8 RGB, got dtype {rgb.dtype}")
    return rgb


def check_options(name: str, cls: type, options: dict) -> None:
    """DetectorError listing every option the backend `name` does not take, each with a "did you mean",
    and the options it does take.

    Why here and not left to Python: the backends take different options (only torch compiles, only the
    classical one has a background), and a bare TypeError from a constructor names neither the backend
    nor what it would take; every caller (CLI, RSU app, benchmarks) then had to re-check by hand."""
    params = inspect.signature(cls.__init__).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return
    known = [k for k, p in params.items() if k != "self"
             and p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)]
    problems = []
    for key in options:
        if key not in known:
            close = difflib.get_close_matches(key, known, n=2)
            hint = f" (did you mean {' or '.join(map(repr, close))}?)" if close else ""
            problems.append(f"{key!r}{hint}")
    if problems:
        raise DetectorError(f"detector {name!r} does not take option{'s' if len(problems) > 1 else ''} "
                            f"{', '.join(problems)}; it takes: {', '.join(known)}")


def make_detector(name: str, **options) -> Detector:
    """The detector backend called `name`, constructed with `options`; DetectorError for an unknown
    name, a missing package or an option that backend does not take."""
    try:
        target = BACKENDS[name]
    except KeyError:
        raise DetectorError(f"unknown detector {name!r}; known: {', '.join(sorted(BACKENDS))}") from None
    module, cls = target.split(":")
    try:
        mod = importlib.import_module(module)
    except ImportError as exc:
        raise DetectorError(f"detector {name!r} needs a missing package: {exc.name or exc} "
                            f"(install the 'perception' extra)") from exc
    backend = getattr(mod, cls)
    check_options(name, backend, options)
    return backend(**options)
