"""What the apps and the cameras leave in the run folder for metrics and the report.

* `TraceRecorder`: the apps' trace records (`trace/<app>` on the bus, one JSON
  object per finished frame with its stamps, names in bridges.v2x) appended to
  `trace.jsonl` as they arrive, so a run that dies keeps what came before.
* `CameraArchive`: every camera frame the world renders, as JPEG under
  `camera/<camera>/` with `frames.csv` (frame id, simulation time, file) and
  `camera.json` (the camera model), for the report's annotated clip.

Both open before the apps and the world and close after them: the records the
apps publish while they shut down and the world's frame of t0 are kept.
"""
from __future__ import annotations

import csv
import json
import threading
from pathlib import Path
from typing import Any

from bridges.v2x import TRACE_KEY
from master.hooks import Hook, Outcome, RunContext
from master.run.metrics import TRACE

CAMERA_DIR = "camera"
FRAMES_CSV = "frames.csv"
JPEG_QUALITY = 85


class TraceRecorder(Hook):
    """Subscribes to every app's trace records and writes them, one line each, to trace.jsonl."""

    name = "trace"

    def __init__(self):
        self._lock = threading.Lock()
        self._file = None
        self._sub = None
        self.records = 0
        self.garbage = 0

    def open(self, ctx: RunContext) -> None:
        self._file = open(Path(ctx.run_dir) / TRACE, "w", buffering=1)
        self._sub = ctx.bus.subscribe(TRACE_KEY.format("*"), callback=self._on_record)

    def _on_record(self, msg) -> None:
        try:
            record = json.loads(msg.payload)
            if not isinstance(record, dict):
                raise ValueError("not a JSON object")
        except ValueError:
            with self._lock:
                self.garbage += 1
            return
        record.setdefault("app", msg.sender)
        line = json.dumps(record, separators=(",", ":"), default=str)
        with self._lock:
            if self._file is not None and not self._file.closed:
                self._file.write(line + "\n")
                self.records += 1

    def close(self, outcome: Outcome | None = None) -> dict[str, Any]:
        if self._sub is not None:
            self._sub.close()
            self._sub = None
        with self._lock:
            if self._file is not None:
                self._file.close()
            return {"file": TRACE, "records": self.records, "garbage": self.garbage}


class CameraArchive(Hook):
    """Listens to the world's cameras and keeps each frame as a JPEG (OpenCV) for the report's clip.

    The JPEG encoding and the file writes run on a thread of their own, in the order the frames came
    (OpenCV releases the GIL while it encodes): on the loop's thread they cost a realtime step 3-8 ms
    at 10 Hz. Closing waits for every frame handed over.
    """

    name = "camera_archive"

    def __init__(self, world_participant, quality: int = JPEG_QUALITY):
        self.part, self.quality = world_participant, quality
        self.root: Path | None = None
        self._writers: dict[str, tuple[Any, Any]] = {}
        self._pool = None
        self._pending: list[Any] = []  # the thread's futures: a failure is raised at close, not lost
        self.frames = 0
        self.bytes = 0

    def open(self, ctx: RunContext) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self.root = Path(ctx.run_dir) / CAMERA_DIR
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="camera-archive")
        self.part.listeners.append(self._on_sample)

    def _on_sample(self, kind: str, name: str, t: float, data: Any) -> None:
        if kind == "camera":
            self._pending = [f for f in self._pending if not f.done() or f.exception() is not None]
            self._pending.append(self._pool.submit(self._keep, name, data))

    def _keep(self, name: str, data: Any) -> None:
        import cv2

        folder = self.root / name
        if name not in self._writers:
            folder.mkdir(parents=True, exist_ok=True)
            (folder / "camera.json").write_text(json.dumps({
                "camera": name, "width": int(data.rgb.shape[1]), "height": int(data.rgb.shape[0]),
                "P": data.P.tolist(), "K": data.K.tolist(), "R_wc": data.R_wc.tolist(),
                "position": data.position.tolist()}, indent=1) + "\n")
            f = open(folder / FRAMES_CSV, "w", newline="", buffering=1)
            writer = csv.writer(f)
            writer.writerow(["frame_id", "t", "file"])
            self._writers[name] = (f, writer)
        ok, jpeg = cv2.imencode(".jpg", data.rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, self.quality])
        if not ok:
            return
        file = f"{data.frame_id:06d}.jpg"
        (folder / file).write_bytes(jpeg.tobytes())
        self._writers[name][1].writerow([data.frame_id, repr(float(data.t)), file])
        self.frames += 1
        self.bytes += len(jpeg)

    def close(self, outcome: Outcome | None = None) -> dict[str, Any]:
        if self._on_sample in self.part.listeners:
            self.part.listeners.remove(self._on_sample)
        if self._pool is not None:
            self._pool.shutdown(wait=True)  # every frame handed over is written before the files close
            self._pool = None
        for f, _ in self._writers.values():
            f.close()
        for future in self._pending:
            if future.exception() is not None:
                raise RuntimeError(f"camera archive: {future.exception()}") from future.exception()
        return {"folder": CAMERA_DIR, "cameras": sorted(self._writers), "frames": self.frames, "bytes": self.bytes}
