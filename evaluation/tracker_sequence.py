"""The RSU perception chain on the case-study sequence, scored against the simulator's truth.

    from evaluation.tracker_sequence import evaluate_sequence
    from rsu_app.perception import make_detector

    rep = evaluate_sequence("scenarios/ima_world.toml", make_detector("torch", threads=1))
    print(rep.table())

An evaluation tool, not part of the RSU app: it poses the simulator's world
and reads its truth (master), which the app itself never imports.

The scenario's vehicles are posed along their trajectories (both drive
straight at constant speed in the IMA case study: x0, y0, yaw0, v0 of each
VehicleDynamics instance; `trajectory` can be swapped for a recorded run's
timeseries) and the RSU camera renders at its rate (10 Hz). Two chains turn
the frames into tracks:

- `chain="app"` (default): what the RSU app runs, wired as rsu_app/app.py
  wires it. A `rsu_app.config.Settings` (default `Settings()`, the values of
  scenarios/apps/rsu.toml, chosen on the validation sequences
  tests/scenarios/rsu_tuning*.toml) gives the tracker's configuration, the
  detection zone (on the intersection the master describes to the app), the
  score threshold, the duplicate-merge radius and the border rule of
  `rsu_app.perception_stage.PerceptionStage`. Each frame goes through
  `stage.process` then `stage.apply`, and the tracks scored are
  `stage.broadcastable(stage.tracker.predict(t))`: the ones the app would send
  a BSM for. Any difference from the app would make the figures describe
  something nobody runs.
- `chain="tracker"`: the bare chain for comparison: every box the detector
  gives (at its own threshold) put on the ground by `geo.box_to_ground` and fed
  to a plain Kalman `Tracker`, every confirmed track scored.

A detector with `detect_frame(frame, world)` (a test's oracle reading the
segmentation) works with both: an adapter answers `detect(rgb)` for the
frame being processed.

Every scored track is matched to the nearest true vehicle centre (within
`match_radius`, one to one); the scores are over matched tracks confirmed
more than `min_age` ago whose vehicle is within `near_m` of the camera:
position error (m), speed error (m/s), heading error (deg), and whether the
track's class (car or emergency: the RSU must flag the emergency vehicle) is
the vehicle's `kind` in the scenario's world. Coverage says how many of the
frames in which a vehicle was visible and near had a track on it; false
track-frames are scored tracks that match no vehicle (each is 1/rate s of
ghost BSMs), also given per 10 s and per minute of sequence (duration:
frames / rate) with the position of each, so one can see why it was false.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Callable

import numpy as np

from master.scenario.loader import load_scenario
from master.world.dataset import MIN_VISIBLE_PIXELS  # fewer visible pixels is not a vehicle anyone could see
from master.world.world import World
from rsu_app.config import Settings
from rsu_app.perception.detector import Detector
from rsu_app.perception.evaluate import finite_or_none
from rsu_app.perception.geo import CameraModel, GeoError, box_to_ground, rough_ground_point
from rsu_app.perception.tracker import GroundDetection, Tracker
from rsu_app.perception_stage import PerceptionStage, tracker_config

CHAINS = ("app", "tracker")


def constant_speed(scenario) -> Callable[[str, float], tuple[float, float, float, float]]:
    """trajectory(name, t) -> (x, y, yaw, v) of the rear axle, from the instance's x0, y0, yaw0, v0."""
    def at(name: str, t: float):
        p = scenario.instances[name].parameters
        x0, y0, yaw, v = (float(p.get(k, 0.0)) for k in ("x0", "y0", "yaw0", "v0"))
        return x0 + v * t * math.cos(yaw), y0 + v * t * math.sin(yaw), yaw, v
    return at


def project_detection(det, camera: CameraModel, tracks=(), radius: float = 3.0) -> tuple[float, float]:
    """A detection's ground point (the "tracker" chain). When a track with a heading lies within `radius`
    (+ 2 m for the rough guess's error) of the rough guess, one box fit at that heading (tighter, and ~6x
    cheaper than fitting the heading too); otherwise the heading search of `box_to_ground`."""
    rx, ry = rough_ground_point(det.box, camera, det.label)
    near = [s for s in tracks if s.heading is not None and math.hypot(s.x - rx, s.y - ry) < radius + 2.0]
    if near:
        best = min(near, key=lambda s: math.hypot(s.x - rx, s.y - ry))
        gx, gy = box_to_ground(det.box, camera, det.label, heading=best.heading)
    else:
        gx, gy = box_to_ground(det.box, camera, det.label)
    return float(gx), float(gy)


class FrameDetector:
    """What the chains call `detect(rgb)` on: the wrapped detector's boxes for the frame being processed.

    A detector with `detect_frame(frame, world)` (an oracle reading the segmentation) needs the whole frame,
    which the app's stage never hands over; this adapter holds it. It also times the detector alone, so the
    report can split a frame's time into detect and project."""

    def __init__(self, detector, world):
        self.detector, self.world = detector, world
        self.frame = None
        self.seconds = 0.0
        self.name = getattr(detector, "name", "?")

    def detect(self, rgb):
        t0 = time.perf_counter()
        if hasattr(self.detector, "detect_frame"):
            out = self.detector.detect_frame(self.frame, self.world)
        else:
            out = self.detector.detect(rgb)
        self.seconds = time.perf_counter() - t0
        return out


@dataclass
class SequenceReport:
    scenario: str
    detector: str
    chain: str  # "app" (the RSU app's PerceptionStage) or "tracker" (plain tracker)
    operating_point: dict  # score threshold (None: the detector's own) and the tracker's configuration
    frames: int
    rate_hz: float
    duration_s: float  # frames / rate: each frame stands for 1/rate s of BSMs
    near_m: float
    min_age: float
    samples: int  # matched (track, frame) pairs that are scored
    position_error: dict[str, float]  # median, p90, max (m)
    speed_error: dict[str, float]  # m/s
    heading_error: dict[str, float]  # deg
    coverage: dict[str, float]  # per vehicle: share of visible-and-near frames with a scored track on it
    false_tracks: int  # scored track-frames matching no vehicle
    false_per_10s: float
    false_per_min: float
    id_switches: int  # times a vehicle's matched track id changed
    class_errors: int  # scored samples whose track label is not the vehicle's kind
    class_accuracy: dict[str, float]  # per vehicle: share of its scored samples with the right label
    ms_per_frame: dict[str, float] = field(default_factory=dict)  # detect, project, track (median)
    rows: list[dict] = field(default_factory=list, repr=False)  # per scored sample
    false_rows: list[dict] = field(default_factory=list, repr=False)  # per false track-frame

    def to_dict(self, rows: bool = False) -> dict:
        d = dataclasses.asdict(self)
        if not rows:
            d.pop("rows")
            d.pop("false_rows")
        return finite_or_none(d)

    def table(self) -> str:
        f = lambda d: " ".join(f"{k} {v:.3f}" for k, v in d.items())  # noqa: E731
        op = " ".join(f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}" for k, v in self.operating_point.items())
        lines = [
            f"sequence {self.scenario}: {self.frames} frames at {self.rate_hz:g} Hz ({self.duration_s:g} s), "
            f"detector {self.detector}, chain {self.chain}",
            f"operating point: {op}",
            f"scored: {self.samples} track-frames (tracks older than {self.min_age:g} s, vehicles within "
            f"{self.near_m:g} m of the camera)",
            f"position error (m):    {f(self.position_error)}",
            f"speed error (m/s):     {f(self.speed_error)}",
            f"heading error (deg):   {f(self.heading_error)}",
            f"coverage:              {f(self.coverage)}",
            f"class accuracy:        {f(self.class_accuracy)} ({self.class_errors} class errors)",
            f"false track-frames {self.false_tracks} ({self.false_per_10s:.2f} per 10 s, "
            f"{self.false_per_min:.1f} per min), id switches {self.id_switches}",
            f"ms per frame (median): {f(self.ms_per_frame)}",
        ]
        for r in self.false_rows:
            lines.append(f"  false: t {r['t']:.2f} s track {r['track']} ({r['label']}) at ({r['x']:.1f}, "
                         f"{r['y']:.1f}), {r['distance']:.1f} m from {r['nearest']}")
        return "\n".join(lines)


def _stats(v) -> dict[str, float]:
    a = np.abs(np.asarray(v, float))
    if a.size == 0:
        return {"median": float("nan"), "p90": float("nan"), "max": float("nan")}
    return {"median": float(np.median(a)), "p90": float(np.percentile(a, 90)), "max": float(a.max())}


class _AppChain:
    """The RSU app's PerceptionStage, built from its Settings as rsu_app/app.py builds it."""

    def __init__(self, detector: FrameDetector, settings: Settings, intersection: dict):
        self.stage = PerceptionStage.from_settings(detector, settings, intersection)
        self.detector = detector

    def step(self, frame, t: float):
        """(tracks the app would broadcast at t, seconds to detect, to project, to track)."""
        result = self.stage.process(frame, t)
        track_s = self.stage.apply([result]) if result is not None else 0.0
        detect_s = self.detector.seconds
        project_s = result.compute_s - detect_s if result is not None else 0.0
        return self.stage.broadcastable(self.stage.tracker.predict(t)), detect_s, project_s, track_s


class _TrackerChain:
    """Every box at the detector's own threshold, on the ground, into a plain Tracker; all confirmed scored."""

    def __init__(self, detector: FrameDetector, tracker: Tracker, match_radius: float):
        self.detector, self.tracker, self.match_radius = detector, tracker, match_radius

    def step(self, frame, t: float):
        dets = self.detector.detect(frame.rgb)
        t1 = time.perf_counter()
        prior = self.tracker.predict(t) if self.tracker.t is not None else []
        model = CameraModel(frame.K, frame.R_wc, frame.position)
        ground = []
        for det in dets:
            try:
                gx, gy = project_detection(det, model, prior, self.match_radius)
            except GeoError:
                continue
            ground.append(GroundDetection(float(gx), float(gy), det.label, det.score))
        t2 = time.perf_counter()
        states = self.tracker.update(t, ground)
        return states, self.detector.seconds, t2 - t1, time.perf_counter() - t2


@dataclass
class RenderedSequence:
    """A scenario's camera sequence rendered once, with the truth each frame is scored on; `score_sequence`
    runs any number of detectors and operating points over it (rendering is most of an evaluation's time)."""
    scenario: str
    camera: str
    rate_hz: float
    frames: list  # master.world.camera.Frame per time step (rgb, seg, camera model)
    truth: list[dict[str, tuple[float, float, float, float]]]  # per frame: vehicle -> centre x, y, yaw, speed
    visible: list[set[str]]  # per frame: vehicles with >= MIN_VISIBLE_PIXELS pixels in it
    kinds: dict[str, str]  # vehicle -> "car" / "emergency" (the scenario's [world.vehicles.*] kind)
    intersection: dict  # what the master describes to the app
    world: SimpleNamespace = field(repr=False)  # scene.vehicle_ids and layout.vehicles, for `detect_frame`
    background: np.ndarray | None = field(default=None, repr=False)  # the empty scene (classical detector)

    @property
    def names(self) -> list[str]:
        return list(self.kinds)


def render_sequence(scenario: str | Path, *, start: float | None = None, stop: float | None = None,
                    rate_hz: float | None = None, camera: str | None = None, trajectory: Callable | None = None,
                    size: tuple[int, int] | None = None, background: bool = False) -> RenderedSequence:
    """Render the scenario's camera at its rate from start to stop with the vehicles posed along
    `trajectory` (default `constant_speed`); see `evaluate_sequence` for the arguments. `background`: also
    render the scene without its vehicles (what a background-subtraction detector learns)."""
    sc = load_scenario(scenario)
    if sc.world is None or not sc.world.cameras:
        raise ValueError(f"{scenario}: the scenario has no [world] camera")
    cams = {c.name: c for c in sc.world.cameras}
    if camera is not None and camera not in cams:
        raise ValueError(f"{scenario}: no camera {camera!r}; cameras: {', '.join(cams)}")
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
    frames, truths, visible = [], [], []
    n_frames = int(math.floor((stop - start) * rate + 1e-9)) + 1
    empty = None
    with World(sc.world) as w:
        cam = w.cameras[spec.name]
        if background:
            for n in names:
                w.pose_vehicle(n, 5000.0, 5000.0, 0.0, 0.0)
            empty = cam.render(start).rgb.copy()
        for k in range(n_frames):
            t = start + k / rate
            truth = {}
            for n in names:
                x, y, yaw, v = traj(n, t)
                w.pose_vehicle(n, x, y, yaw, v)
                d = sc.world.vehicles[n].centre_offset
                truth[n] = (x + d * math.cos(yaw), y + d * math.sin(yaw), yaw, v)
            frame = cam.render(t)
            frames.append(frame)
            truths.append(truth)
            visible.append({n for n in names
                            if np.count_nonzero(frame.seg == w.scene.vehicle_ids[n]) >= MIN_VISIBLE_PIXELS})
        world = SimpleNamespace(scene=SimpleNamespace(vehicle_ids=dict(w.scene.vehicle_ids)),
                                layout=SimpleNamespace(vehicles=dict(w.layout.vehicles)))
    return RenderedSequence(str(scenario), spec.name, rate, frames, truths, visible,
                            {n: sc.world.vehicles[n].kind for n in names}, sc.world.describe()["intersection"],
                            world, empty)


def evaluate_sequence(scenario: str | Path, detector: Detector, *, chain: str = "app",
                      settings: Settings | None = None, start: float | None = None, stop: float | None = None,
                      rate_hz: float | None = None, camera: str | None = None, near_m: float = 60.0,
                      min_age: float = 1.0, match_radius: float = 3.0, trajectory: Callable | None = None,
                      tracker: Tracker | None = None, size: tuple[int, int] | None = None) -> SequenceReport:
    """Render, detect, track and score the scenario's camera sequence (see the module docstring).

    `settings` (default `Settings()`) is the app's operating point; the "tracker" chain takes only its
    tracker section, or `tracker` when given (the "app" chain builds its tracker from the settings, as the
    app does, and refuses `tracker`). start/stop default to the scenario's [time]; rate_hz to the camera's;
    `size` (W, H) renders smaller frames for quick checks (the intrinsics follow)."""
    _check_chain(chain, tracker)
    seq = render_sequence(scenario, start=start, stop=stop, rate_hz=rate_hz, camera=camera, trajectory=trajectory,
                          size=size)
    return score_sequence(seq, detector, chain=chain, settings=settings, near_m=near_m, min_age=min_age,
                          match_radius=match_radius, tracker=tracker)


def _check_chain(chain: str, tracker) -> None:
    if chain not in CHAINS:
        raise ValueError(f"chain must be one of {', '.join(CHAINS)}, got {chain!r}")
    if chain == "app" and tracker is not None:
        raise ValueError("the app chain builds its tracker from `settings.tracker`, as the app does: "
                         "pass settings, not tracker (or chain='tracker')")


def score_sequence(seq: RenderedSequence, detector: Detector, *, chain: str = "app",
                   settings: Settings | None = None, near_m: float = 60.0, min_age: float = 1.0,
                   match_radius: float = 3.0, tracker: Tracker | None = None) -> SequenceReport:
    """Detect, track and score a rendered sequence (see the module docstring and `evaluate_sequence`)."""
    _check_chain(chain, tracker)
    settings = settings or Settings()
    names, kinds = seq.names, seq.kinds
    born: dict[int, float] = {}
    last_match: dict[str, int] = {}
    pos_err, spd_err, hdg_err, rows, false_rows = [], [], [], [], []
    seen = {n: 0 for n in names}
    covered = {n: 0 for n in names}
    labelled = {n: [0, 0] for n in names}  # scored samples, right label
    id_switches = 0
    t_det, t_proj, t_trk = [], [], []
    n_frames, rate = len(seq.frames), seq.rate_hz
    source = FrameDetector(detector, seq.world)
    if chain == "app":
        runner = _AppChain(source, settings, seq.intersection)
        tcfg = runner.stage.tracker.cfg
        op = {"score_threshold": settings.detector.score_threshold}
    else:
        runner = _TrackerChain(source, tracker or Tracker(tracker_config(settings)), match_radius)
        tcfg = runner.tracker.cfg
        op = {"score_threshold": None}
    op.update(confirm_hits=tcfg.confirm_hits, confirm_window=tcfg.confirm_window, max_missed=tcfg.max_missed,
              gate=tcfg.gate, meas_std=tcfg.meas_std, accel_std=tcfg.accel_std, motion=tcfg.motion)
    if chain == "app":
        p = settings.perception
        op.update(max_range_m=p.max_range_m, track_range_m=p.track_range_m, on_road_only=p.on_road_only,
                  merge_radius_m=p.merge_radius_m, border_px=p.border_px, ground_covariance=p.ground_covariance)
    for k, (frame, truth, vis) in enumerate(zip(seq.frames, seq.truth, seq.visible)):
        t = frame.t
        source.frame = frame
        view = SimpleNamespace(camera=seq.camera, frame_id=k, t=t, rgb=frame.rgb, K=frame.K, R_wc=frame.R_wc,
                               position=frame.position)
        states, det_s, proj_s, trk_s = runner.step(view, t)
        t_det.append(det_s), t_proj.append(proj_s), t_trk.append(trk_s)
        cam_xy = np.asarray(frame.position)[:2]
        near_set = {n for n in vis if math.hypot(truth[n][0] - cam_xy[0], truth[n][1] - cam_xy[1]) <= near_m}
        # match scored tracks to vehicles: nearest first, one to one
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
            he = (float("nan") if s.heading is None
                  else math.degrees(abs(math.remainder(s.heading - tyaw, math.tau))))
            pos_err.append(dist), spd_err.append(s.speed - tv), hdg_err.append(he)
            labelled[n][0] += 1
            labelled[n][1] += s.label == kinds[n]
            rows.append({"t": round(t, 3), "vehicle": n, "track": s.id, "x": s.x, "y": s.y, "true_x": tx,
                         "true_y": ty, "position_error": dist, "speed": s.speed, "true_speed": tv,
                         "heading_error_deg": he, "range": math.hypot(tx - cam_xy[0], ty - cam_xy[1]),
                         "label": s.label, "kind": kinds[n]})
        for i, s in enumerate(states):
            born.setdefault(s.id, t)
            if i not in used_s:
                near_n = min(names, key=lambda n: math.hypot(s.x - truth[n][0], s.y - truth[n][1]))
                false_rows.append({"t": round(t, 3), "track": s.id, "x": s.x, "y": s.y, "label": s.label,
                                   "nearest": near_n,
                                   "distance": math.hypot(s.x - truth[near_n][0], s.y - truth[near_n][1])})
        for n in near_set:
            seen[n] += 1
            covered[n] += n in used_n
    ms = lambda v: float(np.median(v) * 1000) if v else float("nan")  # noqa: E731
    duration = n_frames / rate
    false_tracks = len(false_rows)
    return SequenceReport(
        scenario=seq.scenario, detector=getattr(detector, "name", "?"), chain=chain, operating_point=op,
        frames=n_frames, rate_hz=rate, duration_s=duration, near_m=near_m, min_age=min_age, samples=len(pos_err),
        position_error=_stats(pos_err), speed_error=_stats(spd_err),
        heading_error=_stats([h for h in hdg_err if math.isfinite(h)]),
        coverage={n: (covered[n] / seen[n] if seen[n] else float("nan")) for n in names},
        false_tracks=false_tracks, false_per_10s=false_tracks / duration * 10.0,
        false_per_min=false_tracks / duration * 60.0, id_switches=id_switches,
        class_errors=sum(a - b for a, b in labelled.values()),
        class_accuracy={n: (b / a if a else float("nan")) for n, (a, b) in labelled.items()},
        ms_per_frame={"detect": ms(t_det), "project": ms(t_proj), "track": ms(t_trk)}, rows=rows,
        false_rows=false_rows)
