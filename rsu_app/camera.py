"""Sensor samples in (camera frames, radar scans): the bus subscription (thin) and the busy-detector rule (pure).

`SensorIngest` takes each sensor's samples off its key (`CameraIngest`:
`camera/<name>`, `RadarIngest`: `radar/<name>`). In lockstep the
master publishes a frame of time t before the tick of t, but on another key:
a 1 MB frame may still be on its way when the tiny tick arrives, so for a tick
at which a camera's next frame is due, `collect` waits (bounded by
`camera.wait_s`) for that frame; a camera that stays silent for three due
frames is no longer waited for until it sends again. Frames that do not decode
(garbage, truncated, a broken JPEG) are counted by reason and logged once per
reason, never raised.

`BusyGate` is hardware's rule for a detector that is still working: a frame
that arrives before the previous one's detections are ready is skipped and
counted, in simulated time, so a slow hardware profile loses frames exactly as
the slow computer would.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from collections import Counter

from bridges import camera_stream, radar_stream

log = logging.getLogger(__name__)
EPS = 1e-6  # s: simulation times closer than this are the same instant
MISSES_BEFORE_ABSENT = 3


class BusyGate:
    """One detector: accepts a frame only when the previous one's detections are ready (in simulated time)."""

    def __init__(self):
        self.busy_until = float("-inf")
        self.accepted = 0
        self.dropped = 0

    def offer(self, t: float) -> bool:
        if t < self.busy_until - EPS:
            self.dropped += 1
            return False
        self.accepted += 1
        return True

    def occupy(self, t_start: float, duration: float) -> None:
        self.busy_until = t_start + duration


class _SensorState:
    def __init__(self, rate_hz: float):
        self.period = 1.0 / rate_hz
        self.last_t: float | None = None
        self.next_due: float | None = None  # None: due at the first tick
        self.misses = 0
        self.absent = False
        self.last_id: int | None = None


class SensorIngest:
    """Samples of the configured sensors of one kind, per tick; decoding errors counted in `errors`.
    A sample has `.sensor` (its sensor's name), `.seq` (its number) and `.t`."""

    kind = "sensor"

    def __init__(self, bus, names: list[str], key: str, decode, error: type[Exception], rate_hz: float = 10.0,
                 wait_s: float = 2.0):
        self.names = list(names)
        self.wait_s = wait_s
        self._decode, self._error = decode, error
        self._q: queue.Queue = queue.Queue(maxsize=64)
        self._state = {c: _SensorState(rate_hz) for c in self.names}
        self._held: list = []
        self.errors: Counter = Counter()
        self.received = 0
        self.late = 0          # due frames that did not come within wait_s
        self.skipped = 0       # frame ids never seen (the bus kept only the newest: realtime)
        self.overflow = 0
        self._lock = threading.Lock()
        self._subs = [bus.subscribe(key.format(c), self._on_message) for c in self.names]

    # bus thread: decode here so a garbage payload is counted where it arrives
    def _on_message(self, msg) -> None:
        try:
            frame = self._decode(msg.payload)
        except self._error as exc:
            reason = str(exc).split(":", 1)[0]
            with self._lock:
                self.errors[reason] += 1
                first = self.errors[reason] == 1
            (log.warning if first else log.debug)("%s sample on %s from %s rejected: %s", self.kind, msg.key,
                                                  msg.sender, exc)
            return
        if frame.sensor not in self._state:
            with self._lock:
                self.errors[f"{self.kind} name differs from its key"] += 1
            log.debug("%s sample on %s names %r", self.kind, msg.key, frame.sensor)
            return
        try:
            self._q.put_nowait(frame)
        except queue.Full:  # the app fell far behind (realtime): drop the oldest
            try:
                self._q.get_nowait()
            except queue.Empty:
                pass
            self._q.put_nowait(frame)
            with self._lock:
                self.overflow += 1

    def _take(self, frame) -> None:
        st = self._state[frame.sensor]
        if st.last_id is not None and frame.seq > st.last_id + 1:
            self.skipped += frame.seq - st.last_id - 1
        st.last_id = frame.seq
        if st.last_t is not None and frame.t > st.last_t + EPS:
            st.period = frame.t - st.last_t
        st.last_t = frame.t
        st.next_due = frame.t + st.period
        st.misses, st.absent = 0, False
        self.received += 1
        self._held.append(frame)

    def _drain(self, timeout: float | None = None) -> bool:
        try:
            frame = self._q.get(timeout=timeout) if timeout else self._q.get_nowait()
        except queue.Empty:
            return False
        self._take(frame)
        while True:
            try:
                self._take(self._q.get_nowait())
            except queue.Empty:
                return True

    def _due(self, t: float) -> list[str]:
        return [c for c, st in self._state.items()
                if not st.absent and (st.next_due is None or t >= st.next_due - EPS)
                and not any(f.sensor == c and f.t >= (st.next_due if st.next_due is not None else t) - EPS
                            for f in self._held)]

    def collect(self, t: float, wait: bool = True) -> list:
        """Frames of time <= t not handed out yet, oldest first. `wait`: lockstep, wait for frames due at t."""
        self._drain()
        if wait:
            deadline = time.monotonic() + self.wait_s
            while (due := self._due(t)):
                left = deadline - time.monotonic()
                if left <= 0:
                    for c in due:
                        st = self._state[c]
                        st.misses += 1
                        self.late += 1
                        if st.next_due is None:
                            st.next_due = t
                        st.next_due += st.period
                        if st.misses >= MISSES_BEFORE_ABSENT and not st.absent:
                            st.absent = True
                            log.warning("%s %r: no sample for %d due times; not waiting for it until it sends",
                                        self.kind, c, st.misses)
                    break
                self._drain(timeout=min(left, 0.05))
        ready = sorted((f for f in self._held if f.t <= t + EPS), key=lambda f: (f.t, f.sensor))
        self._held = [f for f in self._held if f.t > t + EPS]
        return ready

    def newest_only(self, frames: list) -> list:
        """Realtime: of several samples per sensor keep the newest (the older ones count as skipped)."""
        newest: dict[str, object] = {}
        for f in frames:
            if f.sensor in newest:
                self.skipped += 1
            newest[f.sensor] = f
        return sorted(newest.values(), key=lambda f: (f.t, f.sensor))

    def stats(self) -> dict:
        with self._lock:
            errors = dict(self.errors)
        return {"received": self.received, "bad": sum(errors.values()), "bad_by_reason": errors,
                "late": self.late, "skipped": self.skipped, "overflow": self.overflow}

    def close(self) -> None:
        for s in self._subs:
            try:
                s.close()
            except Exception as exc:  # the bus may be gone already
                log.debug("closing a %s subscription: %s", self.kind, exc)
        self._subs = []


class CameraIngest(SensorIngest):
    """Frames of the configured cameras (`camera/<name>`)."""

    kind = "camera"

    def __init__(self, bus, cameras: list[str], rate_hz: float = 10.0, wait_s: float = 2.0):
        super().__init__(bus, cameras, camera_stream.KEY, camera_stream.decode_frame,
                         camera_stream.CameraStreamError, rate_hz, wait_s)


class RadarIngest(SensorIngest):
    """Object lists of the configured radars (`radar/<name>`)."""

    kind = "radar"

    def __init__(self, bus, radars: list[str], rate_hz: float = 20.0, wait_s: float = 2.0):
        super().__init__(bus, radars, radar_stream.KEY, radar_stream.decode_scan, radar_stream.RadarStreamError,
                         rate_hz, wait_s)
