"""Camera frames on the bus: the image (raw RGB or JPEG) with the camera model needed to use it.

Payload: a 4-byte big-endian header length, a UTF-8 JSON header, then the
image bytes. The header carries the simulation time, frame id and the camera
model (3x4 projection P = K[R|t], K, camera axes R_wc, optical centre), so a
subscriber on another machine can map pixels to the ground without the
scenario file. Subscribers take frames with `latest_only=True`: a slow
detector gets the newest frame, never a growing queue.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bridges.headed_payload import pack, unpack

ENCODINGS = ("raw", "jpeg")
KEY = "camera/{}"
_REQUIRED = ("camera", "frame_id", "t", "width", "height", "encoding", "P", "K", "R_wc", "position")
MAX_SIDE = 8192


class CameraStreamError(ValueError):
    """A camera payload that cannot be used; the message says why."""


@dataclass
class CameraFrame:
    camera: str
    frame_id: int
    t: float
    rgb: np.ndarray  # (H, W, 3) uint8
    P: np.ndarray
    K: np.ndarray
    R_wc: np.ndarray
    position: np.ndarray

    @property
    def sensor(self) -> str:
        """The name an app's ingest files it under (a radar scan has one too)."""
        return self.camera

    @property
    def seq(self) -> int:
        return self.frame_id


def encode_frame(frame, encoding: str = "raw", quality: int = 90) -> bytes:
    """`frame`: anything with camera, frame_id, t, rgb, P, K, R_wc, position (master.world.camera.Frame)."""
    if encoding not in ENCODINGS:
        raise CameraStreamError(f"encoding: expected one of {', '.join(ENCODINGS)}, got {encoding!r}")
    rgb = np.ascontiguousarray(frame.rgb)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise CameraStreamError(f"rgb: expected an (H, W, 3) uint8 image, got {rgb.dtype} {rgb.shape}")
    if encoding == "raw":
        body = rgb.tobytes()
    else:
        import cv2

        ok, buf = cv2.imencode(".jpg", rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
        if not ok:
            raise CameraStreamError("jpeg: OpenCV could not encode the frame")
        body = buf.tobytes()
    header = {"camera": frame.camera, "frame_id": int(frame.frame_id), "t": float(frame.t),
              "width": int(rgb.shape[1]), "height": int(rgb.shape[0]), "encoding": encoding,
              "P": np.asarray(frame.P, float).tolist(), "K": np.asarray(frame.K, float).tolist(),
              "R_wc": np.asarray(frame.R_wc, float).tolist(), "position": np.asarray(frame.position, float).tolist()}
    return pack(header, body)


def _matrix(header: dict, key: str, shape: tuple[int, ...]) -> np.ndarray:
    try:
        m = np.asarray(header[key], dtype=float)
    except (TypeError, ValueError) as exc:
        raise CameraStreamError(f"header.{key}: not a numeric matrix ({exc})") from None
    if m.shape != shape:
        raise CameraStreamError(f"header.{key}: expected shape {shape}, got {m.shape}")
    if not np.all(np.isfinite(m)):
        raise CameraStreamError(f"header.{key}: contains NaN or infinity")
    return m


def decode_frame(payload: bytes) -> CameraFrame:
    """Inverse of encode_frame; raises CameraStreamError naming what is wrong."""
    header, body = unpack(payload, CameraStreamError, "camera")
    missing = [k for k in _REQUIRED if k not in header]
    if missing:
        raise CameraStreamError(f"header: missing {', '.join(missing)}")
    W, H, enc = header["width"], header["height"], header["encoding"]
    if not all(isinstance(v, int) and not isinstance(v, bool) and 0 < v <= MAX_SIDE for v in (W, H)):
        raise CameraStreamError(f"header.width/height: expected integers in 1..{MAX_SIDE}, got {W!r} x {H!r}")
    if enc not in ENCODINGS:
        raise CameraStreamError(f"header.encoding: expected one of {', '.join(ENCODINGS)}, got {enc!r}")
    if enc == "raw":
        if len(body) != W * H * 3:
            raise CameraStreamError(f"raw image: expected {W * H * 3} bytes for {W}x{H} RGB, got {len(body)}")
        rgb = np.frombuffer(body, np.uint8).reshape(H, W, 3)
    else:
        import cv2

        bgr = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_COLOR) if body else None
        if bgr is None:
            raise CameraStreamError("jpeg: OpenCV could not decode the image")
        if bgr.shape[:2] != (H, W):
            raise CameraStreamError(f"jpeg: image is {bgr.shape[1]}x{bgr.shape[0]}, header says {W}x{H}")
        rgb = np.ascontiguousarray(bgr[:, :, ::-1])
    try:
        frame_id, t = int(header["frame_id"]), float(header["t"])
    except (TypeError, ValueError):
        raise CameraStreamError("header.frame_id/t: not numbers") from None
    return CameraFrame(str(header["camera"]), frame_id, t, rgb, _matrix(header, "P", (3, 4)),
                       _matrix(header, "K", (3, 3)), _matrix(header, "R_wc", (3, 3)),
                       _matrix(header, "position", (3,)))


class CameraPublisher:
    """Publishes a world camera's frames on `camera/<name>` (master side)."""

    def __init__(self, bus, encoding: str = "raw", quality: int = 90):
        if encoding not in ENCODINGS:
            raise CameraStreamError(f"encoding: expected one of {', '.join(ENCODINGS)}, got {encoding!r}")
        self.bus, self.encoding, self.quality = bus, encoding, quality
        self.published = 0
        self.bytes = 0

    def __call__(self, frame) -> None:
        payload = encode_frame(frame, self.encoding, self.quality)
        self.bus.publish(KEY.format(frame.camera), payload, frame.t)
        self.published += 1
        self.bytes += len(payload)


class CameraSubscriber:
    """The newest frame of one camera (app side); undecodable payloads are counted, not raised."""

    def __init__(self, bus, camera: str):
        self.sub = bus.subscribe(KEY.format(camera), latest_only=True)
        self.errors: dict[str, int] = {}
        self.received = 0

    def get(self, timeout: float | None = None) -> CameraFrame | None:
        msg = self.sub.recv(timeout)
        if msg is None:
            return None
        try:
            frame = decode_frame(msg.payload)
        except CameraStreamError as exc:
            reason = str(exc).split(":", 1)[0]
            self.errors[reason] = self.errors.get(reason, 0) + 1
            return None
        self.received += 1
        return frame

    def close(self) -> None:
        self.sub.close()
