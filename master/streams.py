"""The world's sensors on the bus: camera frames, lidar scans and GNSS fixes at their own rates.

Keys (under the run prefix): `camera/<camera>` (bridges.camera_stream payload,
raw or JPEG), `lidar/<vehicle>` and `gnss/<vehicle>` (bridges.sensor_stream
payloads). Each message carries the simulation time of the sample; the
master publishes them after the step that produced them, so in lockstep an app
sees them before the tick of that time.
"""
from __future__ import annotations

from typing import Any

from bridges.camera_stream import CameraPublisher
from bridges.sensor_stream import GNSS_KEY, LIDAR_KEY, encode_fix, encode_scan


class SensorStreams:
    """A WorldParticipant listener that publishes what the world's sensors produce."""

    def __init__(self, bus, camera_encoding: str = "raw", labels: dict[int, tuple[str, str]] | None = None):
        self.bus = bus
        self.camera = CameraPublisher(bus, camera_encoding) if camera_encoding != "off" else None
        self.labels = labels or {}
        self.counts = {"camera": 0, "lidar": 0, "gnss": 0}

    def __call__(self, kind: str, name: str, t: float, data: Any) -> None:
        if kind == "camera":
            if self.camera is None:
                return
            self.camera(data)
        elif kind == "lidar":
            self.bus.publish(LIDAR_KEY.format(name), encode_scan(data, self.labels), t)
        elif kind == "gnss":
            self.bus.publish(GNSS_KEY.format(name), encode_fix(data), t)
        else:
            return
        self.counts[kind] += 1

    def report(self) -> dict[str, Any]:
        out: dict[str, Any] = {"published": dict(self.counts)}
        if self.camera is not None:
            out["camera_encoding"] = self.camera.encoding
            out["camera_bytes"] = self.camera.bytes
        return out
