"""The whole RSU perception chain on the case-study sequence, scored against the simulator's truth.

    from evaluation.tracker_sequence import evaluate_sequence
    from rsu_app.perception import make_detector

    rep = evaluate_sequence("scenarios/ima_world.toml", make_detector("torch"))
    print(rep.table())

An evaluation tool, not part of the RSU app: it poses the simulator's world
and reads its truth (master), which the app itself never imports.

The scenario's vehicles are posed along their trajectories (both drive
straight at constant speed in the IMA case study: x0, y0, yaw0, v0 of each
VehicleDynamics instance; `trajectory` can be swapped for a recorded run's
timeseries), the RSU camera renders at its rate (10 Hz), the detector finds
the vehicles, `geo.box_to_ground` puts each box on the ground (with the
heading of the track it is about to join when there is one, else fitted),
and the Kalman tracker follows them. Every confirmed track is matched to
the nearest true vehicle centre (within `match_radius`); the scores are
over matched tracks confirmed more than `min_age` ago whose vehicle is within `near_m`
of the camera: position error (m), speed error (m/s), heading error (deg).
Coverage says how many of the frames in which a vehicle was visible and
near had a confirmed track on it; false tracks are confirmed tracks that
match no vehicle.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from master.scenario import load_scenario
from master.world.dataset import MIN_VISIBLE_PIXELS  # fewer visible pixels is not a vehicle anyone could see
from master.world.world import World
from rsu_app.perception.detector import Detector
from rsu_app.perception.geo import CameraModel, GeoError, box_to_ground, rough_ground_point
from rsu_app.perception.tracker import GroundDetection, Tracker


def constant_speed(scenario) -> Callable[[str, float], tuple[float, float, float, float]]:
    """trajectory(name, t) -> (x, y, yaw, v) of the rear axle, from the instance's x0, y0, yaw0, v0."""
    def at(name: str, t: float):
        p = scenario.instances[name].parameters
        x0, y0, yaw, v = (float(p.get(k, 0.0)) for k in ("x0", "y0", "yaw0", "v0"))
        return x0 + v * t * math.cos(yaw), y0 + v * t * math.sin(yaw), yaw, v
    return at


def project_detection(det, camera: CameraModel, tracks=(), radius: float = 3.0) -> tuple[float, float]:
    """A detection's ground point. When a track with a heading lies within `radius` (+ 2 m for the rough
    guess's error) of the rough guess, one box fit at that heading (tighter, and ~6x cheaper than
    fitting the heading too); otherwise the heading search of `box_to_ground`."""
    rx, ry = rough_ground_point(det.box, camera, det.label)
    near = [s for s in tracks if s.heading is not None and math.hypot(s.x - rx, s.y - ry) < radius + 2.0]
    if near:
        best = min(near, key=lambda s: math.hypot(s.x - rx, s.y - ry))
        gx, gy = box_to_ground(det.box, camera, det.label, heading=best.heading)
    else:
        gx, gy = box_to_ground(det.box, camera, det.label)
    return float(gx), float(gy)


@dataclass
class SequenceReport:
    scenario: str
    detector: str
    frames: int
    rate_hz: float
    near_m: float
    min_age: float
    samples: int  # matched (track, frame) pairs that are scored
    position_error: dict[str, float]  # median, p90, max (m)
    speed_error: dict[str, float]  # m/s
    heading_error: dict[str, float]  # deg
    coverage: dict[str, float]  # per vehicle: share of visible-and-near frames with a confirmed track on it
    false_tracks: int  # confirmed track-frames matching no vehicle
    id_switches: int  # times a vehicle's matched track id changed
    ms_per_frame: dict[str, float] = field(default_factory=dict)  # detect, project, track (median)
    rows: list[dict] = field(default_factory=list, repr=False)  # per scored sample

    def to_dict(self, rows: bool = False) -> dict:
        d = dataclasses.asdict(self)
        if not rows:
            d.pop("rows")
        return _clean(d)

    def table(self) -> str:
        f = lambda d: " ".join(f"{k} {v:.3f}" for k, v in d.items())  # noqa: E731
        return "\n".join([
            f"sequence {self.scenario}: {self.frames} frames at {self.rate_hz:g} Hz, detector {self.detector}",
            f"scored: {self.samples} track-frames (tracks older than {self.min_age:g} s, vehicles within "
            f"{self.near_m:g} m of the camera)",
            f"position error (m):    {f(self.position_error)}",
            f"speed error (m/s):     {f(self.speed_error)}",
            f"heading error (deg):   {f(self.heading_error)}",
            f"coverage:              {f(self.coverage)}",
            f"false track-frames {self.false_tracks}, id switches {self.id_switches}",
            f"ms per frame (median): {f(self.ms_per_frame)}",
        ])


def _clean(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_clean(v) for v in x]
    return x


def _stats(v) -> dict[str, float]:
    a = np.abs(np.asarray(v, float))
    if a.size == 0:
        return {"median": float("nan"), "p90": float("nan"), "max": float("nan")}
    return {"median": float(np.median(a)), "p90": float(np.percentile(a, 90)), "max": float(a.max())}


def evaluate_sequence(scenario: str | Path, detector: Detector, *, start: float | None = None,
                      stop: float | None = None, rate_hz: float | None = None, camera: str | None = None,
                      near_m: float = 60.0, min_age: float = 1.0, match_radius: float = 3.0,
                      trajectory: Callable | None = None, tracker: Tracker | None = None,
                      size: tuple[int, int] | None = None) -> SequenceReport:
    """Render, detect, project, track and score the scenario's camera sequence (see the module docstring).

    start/stop default to the scenario's [time]; rate_hz to the camera's; `size` (W, H) renders smaller
    frames for quick checks (the intrinsics follow)."""
    sc = load_scenario(scenario)
    if sc.world is None or not sc.world.cameras:
        raise ValueError(f"{scenario}: the scenario has no [world] camera")
    cams = {c.name: c for c in sc.world.cameras}
    spec = cams[camera] if camera else sc.world.cameras[0]
    if size is not None:
        spec = dataclasses.replace(spec, width=int(size[0]), height=int(size[1]))
    sc.world.cameras = [spec]
    start = sc.time.start if start is None else float(start)
    stop = sc.time.stop if stop is None else float(stop)
    rate = float(rate_hz or spec.rate_hz or 10.0)
    if not stop > start or rate <= 0:
        raise ValueError(f"need stop > start and rate_hz > 0, got {start}, {stop}, {rate}")
    traj = trajectory or constant_speed(sc)
    names = [n for n in sc.world.vehicles]
    tracker = tracker or Tracker()
    born: dict[int, float] = {}
    last_match: dict[str, int] = {}
    pos_err, spd_err, hdg_err, rows = [], [], [], []
    seen = {n: 0 for n in names}
    covered = {n: 0 for n in names}
    false_tracks = id_switches = 0
    t_det, t_proj, t_trk = [], [], []
    n_frames = int(math.floor((stop - start) * rate + 1e-9)) + 1
    with World(sc.world) as w:
        cam = w.cameras[spec.name]
        model = CameraModel(cam.K, cam.R_wc, cam.position)
        for k in range(n_frames):
            t = start + k / rate
            truth = {}
            for n in names:
                x, y, yaw, v = traj(n, t)
                w.pose_vehicle(n, x, y, yaw, v)
                d = sc.world.vehicles[n].centre_offset
                truth[n] = (x + d * math.cos(yaw), y + d * math.sin(yaw), yaw, v)
            frame = cam.render(t)
            t0 = time.perf_counter()
            # a detector with detect_frame (e.g. a test's oracle reading the segmentation) gets the whole frame
            dets = detector.detect_frame(frame, w) if hasattr(detector, "detect_frame") else detector.detect(frame.rgb)
            t1 = time.perf_counter()
            prior = tracker.predict(t) if tracker.t is not None else []
            ground = []
            for det in dets:
                try:
                    gx, gy = project_detection(det, model, prior, match_radius)
                except GeoError:
                    continue
                ground.append(GroundDetection(float(gx), float(gy), det.label, det.score))
            t2 = time.perf_counter()
            states = tracker.update(t, ground)
            t3 = time.perf_counter()
            t_det.append(t1 - t0), t_proj.append(t2 - t1), t_trk.append(t3 - t2)
            # visible (enough pixels) and near vehicles
            vis = {n for n in names if np.count_nonzero(frame.seg == w.scene.vehicle_ids[n]) >= MIN_VISIBLE_PIXELS}
            cam_xy = model.position[:2]
            near_set = {n for n in vis if math.hypot(truth[n][0] - cam_xy[0], truth[n][1] - cam_xy[1]) <= near_m}
            # match confirmed tracks to vehicles: nearest first, one to one
            pairs = sorted((math.hypot(s.x - truth[n][0], s.y - truth[n][1]), i, n)
                           for i, s in enumerate(states) for n in names)
            used_s, used_n = set(), set()
            for dist, i, n in pairs:
                if dist > match_radius or i in used_s or n in used_n:
                    continue
                used_s.add(i), used_n.add(n)
                s = states[i]
                born.setdefault(s.id, t)
                if n in last_match and last_match[n] != s.id:
                    id_switches += 1
                last_match[n] = s.id
                if n not in near_set or t - born[s.id] < min_age - 1e-9:
                    continue
                tx, ty, tyaw, tv = truth[n]
                he = float("nan") if s.heading is None else math.degrees(abs(math.remainder(s.heading - tyaw, math.tau)))
                pos_err.append(dist), spd_err.append(s.speed - tv), hdg_err.append(he)
                rows.append({"t": round(t, 3), "vehicle": n, "track": s.id, "x": s.x, "y": s.y, "true_x": tx,
                             "true_y": ty, "position_error": dist, "speed": s.speed, "true_speed": tv,
                             "heading_error_deg": he, "range": math.hypot(tx - cam_xy[0], ty - cam_xy[1])})
            for i, s in enumerate(states):
                born.setdefault(s.id, t)
                if i not in used_s:
                    false_tracks += 1
            for n in near_set:
                seen[n] += 1
                covered[n] += n in used_n
    ms = lambda v: float(np.median(v) * 1000) if v else float("nan")  # noqa: E731
    return SequenceReport(
        str(scenario), getattr(detector, "name", "?"), n_frames, rate, near_m, min_age, len(pos_err),
        _stats(pos_err), _stats(spd_err), _stats([h for h in hdg_err if math.isfinite(h)]),
        {n: (covered[n] / seen[n] if seen[n] else float("nan")) for n in names}, false_tracks, id_switches,
        {"detect": ms(t_det), "project": ms(t_proj), "track": ms(t_trk)}, rows)
