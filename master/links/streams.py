"""The world's sensors on the bus: camera frames, lidar scans, radar object lists and GNSS fixes at their rates.

Keys (under the run prefix): `camera/<camera>` (bridges.camera_stream payload,
raw or JPEG), `lidar/<vehicle>` and `gnss/<vehicle>` (bridges.sensor_stream
payloads), `radar/<radar>` (bridges.radar_stream payload). Each message carries
the simulation time of the sample; the master publishes them after the step
that produced them, so in lockstep an app sees them before the tick of that
time. In realtime a sample carries the run clock's time at which it was
taken (`RunContext.stamp_time` then), as a real sensor stamps its capture time
on the clock the apps share, and is published when it is ready: a camera
frame or lidar scan taken in a worker process arrives its render time later.
"""
from __future__ import annotations

import dataclasses

from typing import Any

from bridges import radar_stream
from bridges.camera_stream import CameraPublisher
from bridges.sensor_stream import GNSS_KEY, LIDAR_KEY, encode_fix, encode_scan
from master.hooks import Hook, Outcome, RunContext


class SensorStreams:
    """A WorldParticipant listener that publishes what the world's sensors produce."""

    def __init__(self, bus, camera_encoding: str = "raw", labels: dict[int, tuple[str, str]] | None = None):
        self.bus = bus
        self.camera = CameraPublisher(bus, camera_encoding) if camera_encoding != "off" else None
        self.labels = labels or {}
        self.counts = {"camera": 0, "lidar": 0, "gnss": 0, "radar": 0}

    def __call__(self, kind: str, name: str, t: float, data: Any) -> None:
        if kind == "camera":
            if self.camera is None:
                return
            self.camera(data)
        elif kind == "lidar":
            self.bus.publish(LIDAR_KEY.format(name), encode_scan(data, self.labels), t)
        elif kind == "gnss":
            self.bus.publish(GNSS_KEY.format(name), encode_fix(data), t)
        elif kind == "radar":
            self.bus.publish(radar_stream.KEY.format(name), radar_stream.encode_scan(data), t)
        else:
            return
        self.counts[kind] += 1

    def report(self) -> dict[str, Any]:
        out: dict[str, Any] = {"published": dict(self.counts)}
        if self.camera is not None:
            out["camera_encoding"] = self.camera.encoding
            out["camera_bytes"] = self.camera.bytes
        return out


class StreamsHook(Hook):
    """Opens before the world (whose first samples, at t0, come while it opens) and listens to it.

    The lidar payloads name the vehicle each ray hit by the scene's body labels, which exist
    once the world is open: the hook reads them then, so even the scans of t0 carry them.
    """

    name = "streams"

    def __init__(self, world_participant, camera_encoding: str = "raw"):
        self.part, self.encoding = world_participant, camera_encoding
        self.streams: SensorStreams | None = None
        self.ctx: RunContext | None = None

    def open(self, ctx: RunContext) -> None:
        self.ctx = ctx
        self.streams = SensorStreams(ctx.bus, self.encoding)
        self.part.listeners.append(self._publish)

    def _publish(self, kind: str, name: str, t: float, data: Any) -> None:
        streams = self.streams
        if not streams.labels and self.part.world is not None:
            streams.labels.update(self.part.world.scene.labels)
        # the run clock's time when the sample was taken (the world participant's; in realtime a frame a
        # worker drew arrives later than that, as a camera's frame arrives after its exposure)
        stamp = self.part.capture_stamp.get((kind, name))
        if stamp is None:
            stamp = self.ctx.stamp_time(t)
        if stamp != t:
            t = stamp
            if kind in ("camera", "radar"):  # their payloads carry the sample's time too
                data = dataclasses.replace(data, t=stamp)
        streams(kind, name, t, data)

    def close(self, outcome: Outcome | None = None) -> dict[str, Any] | None:
        if self._publish in self.part.listeners:
            self.part.listeners.remove(self._publish)
        return self.streams.report() if self.streams is not None else None
