"""Stage 1: a camera frame -> vehicles on the ground -> tracks, with the times the chain needs.

`PerceptionStage.process(frame)` runs the detector on the frame, keeps the
boxes above the score threshold, places each on the ground through the
frame's camera model (`geo.ground_fix`, at the heading of the nearest known
track when there is one: a tighter and cheaper fit), with the covariance of
that fit (a far vehicle's point is uncertain along the viewing ray, a box cut
by the border in the direction it was cut: the tracker weighs each point by
it), and drops ground points outside the detection zone (beyond
`track_range_m`, or off the roads of the intersection). It returns a
`FrameResult` and leaves the tracker alone: the tracker learns of a frame's detections only when they are *ready* in simulated
time (`apply`), so a BSM sent before then cannot know them.

Two rules keep the tracker from inventing vehicles (every false track is a
ghost BSM a vehicle may brake for): detections of one frame closer than
`merge_radius_m` on the ground are one vehicle (the detector sometimes boxes
the front and the whole of a long vehicle), the best-scored kept; and a box cut
by the image border (within `border_px`, or a tenth of its extent: the
detector's box of a vehicle leaving the picture often stops short of it;
`geo.cut_edges`), whose ground point is the least reliable, may update a track
near it but never start one. A box near a track whose predicted outline
(`geo.outline`, the class's typical size at the track's position and heading)
reaches past the border is fitted as cut on those sides even where it stops
short of the border: a vehicle mostly out of the picture gets a box well
inside it (a car leaving under the case study's pole: 55 px short), and fitting
that box's edge as where the car ends put it 2-4 m off.

A confirmed track whose predicted position has left every camera's view and
that no detection updated in the last frame (or one outside the detection
zone: beyond `max_range_m`) is not broadcast (`broadcastable`);
beyond `max_range_m` its positions are not good enough to send, and out of view
nothing can confirm it any more, and coasting on a straight line after a
vehicle turned out of sight is how a real track becomes a ghost.

`apply(result)` folds the detections into the tracker at the frame's time and
remembers, per track, the stamps of the last camera frame that updated it: the
BSMs of a track carry those (FRAME, DETECT_START, DETECT_END), so the run's
latency chain stays the camera's, as the seed paper measured it. A track last
updated by a radar scan carries none (a radar scan is no camera frame, and an
older frame's stamps would read as a stale chain).

A roadside radar (`process_radar`) adds what a camera cannot: vehicles far
out on an approach (advance detection), each as a ground point with the
covariance of its range and azimuth accuracies, voting for a configured class
with a small weight (a radar does not tell an ambulance from a car: the
camera names it once it is near). Each scan states the radar's coverage,
which does three things: its objects start tracks there (not the camera's
range limits), a track there may be broadcast, and, once any radar is known,
a frame's silence counts as a miss only for tracks its sensor could have
seen (`sees`): a vehicle 150 m out is not missed by every camera frame, and a
vehicle under the pole is not missed by a radar pointed down the road.
Without a radar every frame misses every unmatched track, as before.

Each `FrameResult` also keeps every box above the threshold with what became of
it (its ground detection, or why it was rejected) and, once applied, the track
each detection updated or started: `detection_record` turns that into the
frame's "detections" trace record (the report draws it on the camera clip).
Nothing of it feeds back into tracking or the BSMs.
"""
from __future__ import annotations

import logging
import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from bridges.geo import GeoError
from bridges.v2x import DETECT_END, DETECT_START, FRAME, stamp_ns
from rsu_app.perception.detector import Detection, DetectorError
from rsu_app.perception.geo import (BoxNoise, CameraModel, box_to_ground, cut_edges, ground_fix, leaving_edges, outline,
                                    rough_ground_point)
from rsu_app.perception.tracker import (GroundDetection, Tracker, TrackerConfig, TrackerError, TrackState,
                                        positive_definite)

log = logging.getLogger(__name__)
HEADING_RADIUS = 3.0  # m: a track this close to a detection's rough ground point lends it its heading
CAMERA, RADAR = "camera", "radar"  # FrameResult.kind
DETECTIONS = "detections"  # the kind of a frame's trace record (master/report/page.py draws these on the clip)


@dataclass
class BoxOutcome:
    """One detector box above the threshold and what stage 1 made of it, kept for the frame's trace record."""

    box: tuple[float, float, float, float]  # pixels (u0, v0, u1, v1), as the detector gave it
    label: str
    score: float
    detection: int | None = None  # index of its ground detection in FrameResult.detections; None: rejected
    rejected: str | None = None   # why it did not reach the tracker


@dataclass
class FrameResult:
    camera: str                   # the sensor's name (a camera's, or a radar's when `kind` is RADAR)
    frame_id: int
    t: float                      # the frame's simulation time (FRAME)
    detections: list[GroundDetection]
    boxes: int                    # detector boxes above the threshold
    compute_s: float              # wall seconds: detect + project
    detect_start: float = 0.0     # simulation times, set by the core
    detect_end: float = 0.0
    rejected: dict[str, int] = field(default_factory=dict)
    objects: list[BoxOutcome] = field(default_factory=list)  # every box above the threshold
    tracks: list[int | None] = field(default_factory=list)   # per detection, once applied: its track's id
    broadcast: frozenset[int] = frozenset()  # of those tracks, the ones worth a BSM (confirmed, in the zone and in
                                             # view: `broadcastable`) once the tracker learned them
    kind: str = "camera"          # CAMERA or RADAR

    def track_of(self, outcome: BoxOutcome) -> int | None:
        """The id of the track a box's detection updated or started; None when rejected or not yet applied."""
        if outcome.detection is None or outcome.detection >= len(self.tracks):
            return None
        return self.tracks[outcome.detection]


@dataclass
class TrackStamps:
    """When the camera frame that last updated a track was taken, and when its detection started and ended."""

    frame: float
    detect_start: float
    detect_end: float

    def marks(self) -> dict[str, int]:
        """The frame's trace stamps (bridges.v2x) that a message about this track carries before its own."""
        return {FRAME: stamp_ns(self.frame), DETECT_START: stamp_ns(self.detect_start),
                DETECT_END: stamp_ns(self.detect_end)}


class DetectionZone:
    """Where a ground point may be a vehicle: near the camera and (when the intersection is known) on a road.

    Two ranges: a track is broadcast only within `max_range_m`, where box-based positions are good enough
    to send; ground points count out to `track_range_m` (default the same), so that a vehicle arriving
    from afar enters `max_range_m` with its track already confirmed and settled instead of starting one
    there (tracker.confirm_hits detections of a 60 km/h vehicle, 1.7 m each, without a BSM)."""

    def __init__(self, max_range_m: float, intersection: dict | None, on_road_only: bool, margin_m: float,
                 track_range_m: float | None = None):
        self.max_range_m = max_range_m
        self.track_range_m = max(max_range_m, track_range_m if track_range_m is not None else max_range_m)
        self.half_road = None
        self.arm = None
        if on_road_only and intersection:
            try:
                self.half_road = float(intersection["road_width"]) / 2 + margin_m
                self.arm = float(intersection["arm_length"])
            except (KeyError, TypeError, ValueError):
                log.warning("the master's intersection description %r has no road_width/arm_length: every ground "
                            "point counts as on the road", intersection)

    def on_road(self, x: float, y: float) -> bool:
        """Whether (x, y) is on a road of the intersection (always, when its roads are not known)."""
        if self.half_road is None:
            return True
        on_x_road = abs(y) <= self.half_road and abs(x) <= self.arm
        on_y_road = abs(x) <= self.half_road and abs(y) <= self.arm
        return on_x_road or on_y_road

    def reason_to_reject(self, x: float, y: float, camera_xy, tracking: bool = False) -> str | None:
        """Why (x, y) is outside the zone, or None: for a ground point to track (`tracking`, out to
        track_range_m) or for a track to broadcast (out to max_range_m)."""
        limit, name = (self.track_range_m, "track_range_m") if tracking else (self.max_range_m, "max_range_m")
        if math.hypot(x - camera_xy[0], y - camera_xy[1]) > limit:
            return f"beyond {name}"
        return None if self.on_road(x, y) else "off the road"


def box_noise(settings) -> BoxNoise:
    """The box noise of the app's settings (`rsu_app.config.Settings`): what its ground covariances assume."""
    p = settings.perception
    return BoxNoise(edge_px=p.box_edge_px, edge_rel=p.box_edge_rel, cut_edge_rel=p.box_cut_edge_rel,
                    size_rel=p.size_rel)


def tracker_config(settings) -> TrackerConfig:
    """The tracker configuration of the app's settings (`rsu_app.config.Settings`)."""
    t = settings.tracker
    return TrackerConfig(accel_std=t.accel_std, meas_std=t.meas_std, init_speed_std=t.init_speed_std, gate=t.gate,
                         confirm_hits=t.confirm_hits, confirm_window=t.confirm_window, max_missed=t.max_missed,
                         motion=t.motion)


class PerceptionStage:
    @classmethod
    def from_settings(cls, detector, settings, intersection: dict | None) -> "PerceptionStage":
        """Stage 1 as the app wires it from its settings (`rsu_app.config.Settings`) and the intersection the
        master describes; one place, so that tools scoring the app's chain run exactly what it runs."""
        s, p = settings, settings.perception
        zone = DetectionZone(p.max_range_m, intersection, p.on_road_only, p.road_margin_m, p.track_range_m)
        return cls(detector, Tracker(tracker_config(s)), zone, s.detector.score_threshold, p.merge_radius_m,
                   p.border_px, box_noise(s) if p.ground_covariance else None, radar_label=s.radar.label,
                   radar_score=s.radar.score)

    def __init__(self, detector, tracker: Tracker, zone: DetectionZone, score_threshold: float,
                 merge_radius_m: float = 2.5, border_px: float = 2.0, noise: BoxNoise | None = None,
                 radar_label: str = "car", radar_score: float = 0.0):
        """`noise`: each ground point carries the covariance `geo.ground_fix` gives under it; None: the points
        carry none and the tracker counts each as its `meas_std`. `radar_label`/`radar_score`: the class a
        radar object votes for, and how much."""
        self.radar_label, self.radar_score = radar_label, radar_score
        self.radars: dict = {}  # radar -> its last scan (bridges.radar_stream.RadarScan): where it sees
        self.detector, self.tracker, self.zone = detector, tracker, zone
        self.score_threshold = score_threshold
        self.merge_radius_m, self.border_px = merge_radius_m, border_px
        self.noise = noise
        self.track_stamps: dict[int, TrackStamps] = {}
        self.detections = 0
        self.rejected: dict[str, int] = {}
        self.detector_errors = 0
        self.late_updates = 0
        self.compute_s: deque[float] = deque(maxlen=20000)  # wall seconds per processed frame (detect + project)
        self.views: dict[str, tuple[CameraModel, int, int]] = {}  # camera -> (model, width, height), last seen
        self.suppressed_out_of_view = 0

    def _ground(self, det: Detection, camera: CameraModel, prior: list[TrackState],
                size: tuple[int, int]) -> tuple[float, float, tuple[float, float, float] | None]:
        """The box's ground point and, with `noise`, its covariance (var_x, cov_xy, var_y); the heading of
        the nearest track with one (tighter, and ~6x cheaper than searching the heading too), and the sides
        on which that track's predicted outline leaves the picture (see the module docstring)."""
        rx, ry = rough_ground_point(det.box, camera, det.label)
        near = [s for s in prior if s.heading is not None and math.hypot(s.x - rx, s.y - ry) < HEADING_RADIUS + 2.0]
        track = min(near, key=lambda s: math.hypot(s.x - rx, s.y - ry)) if near else None
        heading, cut = None, None
        if track is not None:
            heading = track.heading
            predicted = outline(track.x, track.y, track.heading, camera, det.label)
            cut = leaving_edges(predicted, *size) if predicted is not None else None
        border = max(self.border_px, 1.0)
        if self.noise is None:
            gx, gy = box_to_ground(det.box, camera, det.label, heading=heading, border_px=border, cut=cut)
            return float(gx), float(gy), None
        (gx, gy), C = ground_fix(det.box, camera, det.label, heading=heading, noise=self.noise, border_px=border,
                                 cut=cut)
        cov = (float(C[0, 0]), float(C[0, 1]), float(C[1, 1]))
        if not positive_definite(cov):  # the tracker would refuse the frame's every box with it
            raise ValueError(f"the ground fit's covariance is not finite and positive definite: {cov}")
        return float(gx), float(gy), cov

    def process(self, frame, t_now: float) -> FrameResult | None:
        """Detect and project one frame (the tracker's prior is its state at `t_now`); None for a frame the
        detector refuses (counted)."""
        c0 = time.perf_counter()
        try:
            boxes = [d for d in self.detector.detect(frame.rgb) if d.score >= self.score_threshold]
        except DetectorError as exc:
            self.detector_errors += 1
            log.warning("camera %s frame %d: the detector refused it: %s", frame.camera, frame.frame_id, exc)
            return None
        try:
            camera = CameraModel(frame.K, frame.R_wc, frame.position)
        except GeoError as exc:
            self.detector_errors += 1
            log.warning("camera %s frame %d: unusable camera model: %s", frame.camera, frame.frame_id, exc)
            return None
        prior = self.tracker.predict(max(t_now, self.tracker.t)) if self.tracker.t is not None else []
        known = self.tracker.predict(max(t_now, self.tracker.t), include_tentative=True) if prior or \
            self.tracker.tracks else []
        height, width = frame.rgb.shape[:2]
        self.views[frame.camera] = (camera, width, height)
        ground, rejected, objects = [], {}, []
        for det in sorted(boxes, key=lambda d: -d.score):
            outcome = BoxOutcome(tuple(float(c) for c in det.box), str(det.label), float(det.score))
            placed = self._place(det, camera, prior, known, ground, (width, height))
            if isinstance(placed, str):
                outcome.rejected = placed
                rejected[placed] = rejected.get(placed, 0) + 1
            else:
                outcome.detection = len(ground)
                ground.append(placed)
            objects.append(outcome)
        for k, v in rejected.items():
            self.rejected[k] = self.rejected.get(k, 0) + v
        compute = time.perf_counter() - c0
        self.compute_s.append(compute)
        return FrameResult(frame.camera, frame.frame_id, float(frame.t), ground, len(boxes), compute,
                           rejected=rejected, objects=objects)

    def _place(self, det: Detection, camera: CameraModel, prior: list[TrackState], known: list[TrackState],
               ground: list[GroundDetection], size: tuple[int, int]) -> GroundDetection | str:
        """One box on the ground as a detection for the tracker, or the reason it is not one (the zone, the
        duplicate and the border rules, against the frame's better-scored boxes already in `ground`)."""
        try:
            gx, gy, cov = self._ground(det, camera, prior, size)
        except (GeoError, ValueError, np.linalg.LinAlgError) as exc:
            log.debug("box %s: no ground point: %s", det.box, exc)
            return "no ground point"
        why = self.zone.reason_to_reject(gx, gy, camera.position[:2], tracking=True)
        if why:
            return why
        if any(math.hypot(gx - g.x, gy - g.y) < self.merge_radius_m for g in ground):
            return "duplicate of a better box"
        cut = self.border_px >= 0 and bool(cut_edges(det.box, *size, self.border_px).any())
        if cut and not any(math.hypot(gx - s.x, gy - s.y) < HEADING_RADIUS + 2.0 for s in known):
            return "cut by the image border, no track near"
        return GroundDetection(gx, gy, det.label, float(det.score), cov)

    def process_radar(self, scan, t_now: float) -> FrameResult:
        """One radar scan's objects as ground detections (those off the road rejected, counted)."""
        c0 = time.perf_counter()
        self.radars[scan.radar] = scan
        ground, rejected = [], {}
        for obj in scan.objects:
            gx, gy = scan.ground_point(obj)
            if not self.zone.on_road(gx, gy):
                rejected["off the road"] = rejected.get("off the road", 0) + 1
                continue
            ground.append(GroundDetection(gx, gy, self.radar_label, self.radar_score, scan.ground_covariance(obj)))
        for k, v in rejected.items():
            self.rejected[k] = self.rejected.get(k, 0) + v
        compute = time.perf_counter() - c0
        return FrameResult(scan.radar, scan.scan_id, float(scan.t), ground, len(scan.objects), compute,
                           rejected=rejected, kind=RADAR)

    def _covers(self, sensor: str, x: float, y: float) -> bool:
        """Whether `sensor` (a camera or radar seen so far) could detect a vehicle at (x, y)."""
        if sensor in self.radars:
            return self.radars[sensor].covers(x, y)
        view = self.views.get(sensor)
        if view is None:
            return False
        camera = view[0]
        return (math.hypot(x - camera.position[0], y - camera.position[1]) <= self.zone.track_range_m
                and self._in_camera(view, x, y))

    def sees(self, results: list[FrameResult]):
        """The tracker's `sees` for one batch of results: None while no radar is known (every frame sees
        everything, as a camera-only RSU always did); else a point is seen when a sensor of the batch covers it,
        or when no sensor does (a track out of every sensor's coverage still misses, and ends)."""
        if not self.radars:
            return None
        batch = {r.camera for r in results}
        every = set(self.views) | set(self.radars)

        def sees(x: float, y: float) -> bool:
            return any(self._covers(n, x, y) for n in batch) or not any(self._covers(n, x, y) for n in every)
        return sees

    def in_radar_coverage(self, x: float, y: float) -> bool:
        return any(scan.covers(x, y) for scan in self.radars.values())

    @staticmethod
    def _in_camera(view, x: float, y: float, height_m: float = 0.75) -> bool:
        camera, width, height = view
        uv, depth = camera.project([[x, y, height_m]])
        u, v = uv[0]
        return bool(depth[0] > 0.5 and 0 <= u < width and 0 <= v < height)

    def in_view(self, x: float, y: float, height_m: float = 0.75) -> bool:
        """Whether a ground point (at a vehicle's mid height) projects inside some camera's image."""
        return any(self._in_camera(view, x, y, height_m) for view in self.views.values())

    def broadcastable(self, states: list[TrackState]) -> list[TrackState]:
        """The confirmed tracks worth a BSM: in the detection zone and still in a camera's view: their centre
        in a picture, or a detection in the last frame (a vehicle leaving the picture is seen until its
        last pixels go, long after its centre has left)."""
        out = []
        for s in states:
            if not self._worth_sending(s):
                self.suppressed_out_of_view += 1
                continue
            out.append(s)
        return out

    def _worth_sending(self, s: TrackState) -> bool:
        """`broadcastable`'s test for one confirmed track (without its count); True before any frame told
        the stage its cameras."""
        if not self.views and not self.radars:
            return True
        if self.radars and self.in_radar_coverage(s.x, s.y) and self.zone.on_road(s.x, s.y):
            return True  # a radar watches it: its silence there would end the track
        zone_ok = any(self.zone.reason_to_reject(s.x, s.y, cam.position[:2]) is None
                      for cam, _, _ in self.views.values())
        return zone_ok and (s.missed == 0 or self.in_view(s.x, s.y))

    def apply(self, results: list[FrameResult]) -> float:
        """Fold the detections of frames of one instant into the tracker; returns the wall seconds it took."""
        c0 = time.perf_counter()
        t = results[0].t
        if self.tracker.t is not None and t < self.tracker.t:
            self.late_updates += 1  # frames of several cameras with different latencies: keep time monotonic
            t = self.tracker.t
        dets = [d for r in results for d in r.detections]
        try:
            states = self.tracker.update(t, dets, sees=self.sees(results))
        except TrackerError as exc:
            log.warning("tracker refused the detections of t = %.3f: %s", t, exc)
            return time.perf_counter() - c0
        self.detections += len(dets)
        note_tracks(results, self.tracker.last_assignment, {s.id for s in states if self._worth_sending(s)})
        for r in results:  # the stamps of the camera frame that last updated each track (the paper's chain)
            for tid in r.tracks:
                if r.kind == CAMERA:
                    self.track_stamps[tid] = TrackStamps(r.t, r.detect_start, r.detect_end)
                else:  # a radar sample is no camera frame: its BSMs carry no FRAME stamps, and no older ones
                    self.track_stamps.pop(tid, None)
        alive = {tr.id for tr in self.tracker.tracks}
        for tid in [k for k in self.track_stamps if k not in alive]:
            del self.track_stamps[tid]
        return time.perf_counter() - c0


def note_tracks(results: list[FrameResult], assignment: list[int], broadcast: set[int]) -> None:
    """Hand each frame its share of the tracker's association (its detections came in `results` order), so
    its trace record can say which box became which track, and whether that track is broadcast (a confirmed
    track beyond `max_range_m`, started there by `track_range_m`, is not: no BSM carries its id)."""
    start = 0
    for r in results:
        r.tracks = list(assignment[start:start + len(r.detections)])
        r.broadcast = frozenset(tid for tid in r.tracks if tid in broadcast)
        start += len(r.detections)


def detection_record(result: FrameResult, bsm_id: Callable[[int], str] | None = None) -> dict:
    """The frame's "detections" trace record: every box above the threshold, in the frame's pixels, with its
    label, score, track and the temporary id the BSMs of that track carry (`bsm_id(track)`; None while the
    track is not broadcast: not confirmed, beyond the broadcast range or out of view). Times are plain float
    seconds, never under "stamps": the master's latency metrics read the stamps of trace records, and a
    record of boxes is no message."""
    objects = []
    for o in result.objects:
        track = result.track_of(o)
        broadcast = bsm_id is not None and track is not None and track in result.broadcast
        objects.append({"box": list(o.box), "label": o.label, "score": o.score, "track": track,
                        "bsm_id": bsm_id(track) if broadcast else None, "rejected": o.rejected})
    return {"kind": DETECTIONS, "camera": result.camera, "frame_id": int(result.frame_id), "t": float(result.t),
            "detect_start": float(result.detect_start), "detect_end": float(result.detect_end), "objects": objects}


def covariance_ellipse(cov: np.ndarray) -> tuple[float, float, float]:
    """(semi-major, semi-minor (m, 1 sigma), orientation of the major axis (deg clockwise from north, 0..180))
    of a 2x2 position covariance in (east, north)."""
    c = np.asarray(cov, float)[:2, :2]
    c = (c + c.T) / 2
    w, v = np.linalg.eigh(c)
    w = np.clip(w, 0.0, None)
    major = v[:, 1]
    orientation = math.degrees(math.atan2(major[0], major[1])) % 180.0
    return float(math.sqrt(w[1])), float(math.sqrt(w[0])), orientation
