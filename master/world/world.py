"""`World`: the scene with its cameras, lidar and radars; `WorldParticipant`: the world in the master's loop."""
from __future__ import annotations

import math
from typing import Any

from bridges.radar_stream import RadarScan
from master.hooks import Hook, Outcome, RunContext
from master.stats import percentiles
from master.world.camera import Camera
from master.world.gnss import Fix, Gnss
from master.world.layout import WorldLayout
from master.world.lidar import Lidar, Scan, hits_by_vehicle
from master.world.los import line_of_sight
from master.world.radar import Radar, targets
from master.world.scene import Scene
from master.world.signals import state_name


class World:
    """Scene, cameras, lidar and radars over one private pybullet DIRECT client. Close it (or use `with`).

    The radars need no pybullet: they see the vehicles' poses and the buildings' boxes (master/world/radar.py).
    """

    def __init__(self, layout: WorldLayout, renderer: str | None = None):
        """`renderer`: "auto", "tiny" or "egl"; None: V2I_RENDERER, else the layout's `renderer`."""
        self.layout = layout
        self.scene = Scene(layout, renderer)
        c = self.scene.client
        try:
            self.cameras = {s.name: Camera(s, c, self.scene.renderer) for s in layout.cameras}
            if self.cameras and self.scene.renderer_name == "egl":
                # pybullet's EGL renderer draws its first two frames unlike every later one (26k pixels of a
                # 640x480 frame differ, by up to 61 levels): drawn and dropped here, so that every frame
                # a run or a dataset keeps is drawn alike, whichever process draws it
                next(iter(self.cameras.values())).warm_up(2)
            self.lidars = {v.name: Lidar(v, v.lidar, c, self.scene.vehicle_ids[v.name])
                           for v in layout.vehicles.values() if v.lidar is not None}
            self.radars = {n: Radar(s, self._clear) for n, s in layout.radars.items()}
        except Exception:
            self.scene.close()
            raise

    def pose_vehicle(self, name: str, x: float, y: float, yaw: float, v: float = 0.0) -> None:
        self.scene.pose_vehicle(name, x, y, yaw, v)

    def set_signal(self, name: str, state: int) -> bool:
        """Show J2735 MovementPhaseState `state` on signal head `name` (True if the lamps changed)."""
        return self.scene.set_signal(name, state)

    def scan(self, name: str, t: float = 0.0) -> Scan:
        x, y, yaw, _ = self.scene.poses[name]
        return self.lidars[name].scan((x, y, yaw), t)

    def radar_scan(self, name: str, t: float = 0.0) -> RadarScan:
        """Radar `name`'s scan of the vehicles as posed now."""
        return self.radars[name].scan(t, targets(self.scene.poses, self.layout.vehicles))

    def _clear(self, p, q) -> bool:
        return not line_of_sight(p, q, self.layout.buildings)[0]

    def hits_by_vehicle(self, scan: Scan) -> dict[str, int]:
        """Rays of `scan` that hit each vehicle, by name (the carrier never hits itself)."""
        return hits_by_vehicle(scan, self.scene.vehicle_ids)

    def line_of_sight(self, p, q) -> tuple[bool, int, float]:
        return line_of_sight(p, q, self.layout.buildings)

    def close(self) -> None:
        self.scene.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class Schedule:
    """Sample times start + n / rate_hz. A sample is taken at the first step end at
    or after its time; slots a long step skipped are not taken late (no backlog)."""

    def __init__(self, start: float, rate_hz: float):
        self.start, self.rate, self.n = start, rate_hz, 0

    def due(self, t: float) -> bool:
        if t + 1e-9 < self.start + self.n / self.rate:
            return False
        self.n = max(self.n + 1, math.floor((t - self.start) * self.rate + 1e-9) + 1)
        return True


class WorldParticipant(Hook):
    """The world in the master's loop. After each step it poses the vehicle bodies from
    their FMUs' outputs, sets the signal heads from their controllers' state_k outputs,
    and, at each sensor's rate, renders the cameras, scans the lidars (keeping which
    vehicles each scan hit), scans the radars (keeping when each vehicle was reported,
    from the radar's truth: the scans themselves name no vehicle) and takes GNSS fixes.
    Stores no images: counts and times.

    `sensors=False` leaves cameras, lidars, radars and GNSS out (a snapshot needs only the poses).

    With `workers` (the run's `[world] sensor_processes`), cameras and lidars take their samples in
    worker processes (master/world/sensor_worker.py), each on its own core beside the loop. In
    lockstep the step waits for every sample of its time and hands them to the listeners in the same
    order and with the same contents as if taken here, so an app sees the same bytes. In realtime the
    loop hands the world of a sample time over and steps on; the sample reaches the listeners when its
    worker is done, stamped with the run clock's time at which it was taken (`capture_stamp`), as a
    camera's frame arrives after its exposure. A sample that falls due while the sensor's previous one is
    still being taken is dropped (counted), as a camera drops frames it cannot read out.
    """

    def __init__(self, layout: WorldLayout, start: float, sensors: bool = True, workers: bool = False):
        self.layout, self.start, self.sensors = layout, start, sensors
        self.workers_wanted = workers and sensors
        self.world: World | None = None
        self._getters: list[tuple[str, Any]] = []
        self._signal_getters: list[tuple[Any, list[str]]] = []  # (get state_k values, head per value)
        self._schedules: dict[tuple[str, str], Schedule] = {}
        self.gnss: dict[str, Gnss] = {}
        self.fixes: dict[str, list[Fix]] = {}
        self._gnss_err2: dict[str, list[float]] = {}
        self.scans: dict[str, list[tuple[float, dict[str, int]]]] = {}  # lidar -> (t, rays per vehicle hit)
        self.signal_log: list[tuple[float, str, int]] = []  # (t, head, new state)
        self.radar_log: dict[str, list[tuple[float, list[str]]]] = {}  # radar -> (t, vehicles reported)
        # called as listener(kind, name, t, data) for each camera Frame, lidar Scan, radar RadarScan and GNSS Fix
        self.listeners: list[Any] = []
        # the camera's body-id pass: only ground truth needs it (a hook that records it sets this)
        self.segmentation = False
        self.realtime = False
        self._stamp = lambda t: t  # the run clock's time now, given the step's time (RunContext.stamp_time)
        self.capture_stamp: dict[tuple[str, str], float] = {}  # (kind, name) -> stamp of the sample being handed out
        self._workers: dict[str, Any] = {}  # "camera" / "lidar" -> SensorWorker
        self._in_flight: dict[str, list[tuple[str, float, float]]] = {}  # kind -> [(name, t, stamp)] in order
        self.dropped: dict[tuple[str, str], int] = {}
        self._renderer_used: str | None = None  # the cameras' renderer, where a worker draws them
        self._worker_kinds: list[str] = []

    name = "world"

    def open(self, ctx: RunContext) -> dict[str, Any]:
        """The loop's world hook: the scene, posed from the run's FMUs; the run's other hooks see it as ctx.world."""
        self.realtime = ctx.mode == "realtime"
        self._stamp = ctx.stamp_time
        meta = self.attach(ctx.fmus, ctx.t0)
        ctx.world = self.world
        return meta

    def _start_workers(self) -> None:
        from master.world import renderer
        from master.world.sensor_worker import SensorWorker

        kinds = [k for k, present in (("camera", self.layout.cameras),
                                      ("lidar", any(v.lidar for v in self.layout.vehicles.values()))) if present]
        try:
            for kind in kinds:
                self._workers[kind] = SensorWorker(kind, self.layout, renderer.choose(self.layout.renderer))
                self._in_flight[kind] = []
            for worker in self._workers.values():
                worker.wait_ready()
                if worker.vehicle_ids != self.world.scene.vehicle_ids:
                    raise RuntimeError(f"{worker.kind} worker: its scene's body ids differ from the master's "
                                       f"({worker.vehicle_ids} vs {self.world.scene.vehicle_ids})")
            if "camera" in self._workers:
                self._renderer_used = self._workers["camera"].renderer_name
            self._worker_kinds = sorted(self._workers)
        except Exception:
            self._close_workers()
            raise

    def attach(self, fmus: dict[str, Any], t: float) -> dict[str, Any]:
        """Build the scene and pose it from `fmus` at t (also for tools that step FMUs themselves)."""
        # with workers the cameras are drawn there: the master's own scene needs no OpenGL context
        self.world = World(self.layout, renderer="tiny" if self.workers_wanted and self.layout.cameras else None)
        if self.workers_wanted:
            self._start_workers()
        for name in self.layout.vehicles:
            fmu = fmus[name]
            outs = [v for v in ("x", "y", "yaw", "v") if v in fmu.variables]
            get = fmu.accessor(fmu.access_key(outs[0]), [fmu.variables[n].valueReference for n in outs], setter=False)
            self._getters.append((name, get))
        by_instance: dict[str, list] = {}
        for sig in self.layout.signals:
            by_instance.setdefault(sig.instance, []).append(sig)
        for inst, heads in by_instance.items():
            fmu = fmus[inst]
            names = [f"state_{h.signal_group}" for h in heads]
            get = fmu.accessor(fmu.access_key(names[0]), [fmu.variables[n].valueReference for n in names],
                               setter=False)
            self._signal_getters.append((get, [h.name for h in heads]))
        if self.sensors:
            w = self.world
            self._schedules = {("camera", n): Schedule(self.start, c.spec.rate_hz) for n, c in w.cameras.items()}
            self._schedules.update({("lidar", n): Schedule(self.start, l.spec.rate_hz) for n, l in w.lidars.items()})
            self.scans = {n: [] for n in w.lidars}
            self._schedules.update({("radar", n): Schedule(self.start, r.spec.rate_hz) for n, r in w.radars.items()})
            self.radar_log = {n: [] for n in w.radars}
            for v in self.layout.vehicles.values():
                if v.gnss is not None:
                    self.gnss[v.name] = Gnss(v.gnss, v.name)
                    self.fixes[v.name], self._gnss_err2[v.name] = [], []
                    self._schedules[("gnss", v.name)] = Schedule(self.start, v.gnss.rate_hz)
        self.after_step(-1, t)
        if self.realtime:  # the samples of the start, as in lockstep, before the clock runs: the first step
            self._deliver_finished(wait=True)  # waited for them (60 ms, the run's first nine steps late)
        return self.metadata()

    def after_step(self, k: int, t_next: float) -> None:
        w = self.world
        for name, get in self._getters:
            vals = get()
            w.pose_vehicle(name, vals[0], vals[1], vals[2], vals[3] if len(vals) > 3 else 0.0)
        for get, heads in self._signal_getters:
            for head, state in zip(heads, get()):
                if w.set_signal(head, int(state)):
                    self.signal_log.append((t_next, head, int(state)))
        if self.realtime:
            self._deliver_finished(wait=False)
        due = [key for key, schedule in self._schedules.items() if schedule.due(t_next)]
        if not due:
            return
        stamp = self._stamp(t_next)
        if self._workers:
            self._hand_over([key for key in due if key[0] in self._workers], t_next, stamp)
            if not self.realtime:
                self._deliver_finished(wait=True)  # in the order the samples were due, as taken here
        for kind, name in due:
            if kind in self._workers:
                continue
            if kind == "camera":
                data = w.cameras[name].render(t_next, segmentation=self.segmentation)
            elif kind == "lidar":
                data = w.scan(name, t_next)
            elif kind == "radar":
                data = w.radar_scan(name, t_next)
                self.radar_log[name].append((t_next, list(w.radars[name].reported)))
            else:
                data = self._take_fix(name, t_next)
            self._hand_out(kind, name, t_next, stamp, data)

    def _hand_over(self, keys: list[tuple[str, str]], t: float, stamp: float) -> None:
        """Give the world of time t to the workers for these samples (realtime: drop a busy sensor's)."""
        from master.world.sensor_worker import Job

        if not keys:
            return
        scene = self.world.scene
        poses, signals = dict(scene.poses), dict(scene.signal_states)
        for kind, name in keys:
            if self.realtime and any(n == name for n, _, _ in self._in_flight[kind]):
                self.dropped[(kind, name)] = self.dropped.get((kind, name), 0) + 1
                continue
            self._workers[kind].submit(Job(kind, name, t, poses, signals, self.segmentation))
            self._in_flight[kind].append((name, t, stamp))

    def _deliver_finished(self, wait: bool) -> None:
        """Hand out the workers' finished samples (all of them, waiting, when `wait`), cameras first."""
        for kind, worker in self._workers.items():
            queue = self._in_flight[kind]
            while queue and (wait or worker.ready()):
                name, t, stamp = queue.pop(0)
                data, seconds = worker.result()
                if kind == "camera":
                    cam = self.world.cameras[name]
                    cam.frame_id = data.frame_id + 1
                    cam.render_times.append(seconds)
                else:
                    self.world.lidars[name].scan_times.append(seconds)
                self._hand_out(kind, name, t, stamp, data)

    def _hand_out(self, kind: str, name: str, t: float, stamp: float, data: Any) -> None:
        if kind == "lidar":
            self.scans[name].append((t, self.world.hits_by_vehicle(data)))
        self.capture_stamp[(kind, name)] = stamp
        for listener in self.listeners:
            listener(kind, name, t, data)

    def _take_fix(self, name: str, t: float) -> None:
        x, y, yaw, v = self.world.scene.poses[name]
        fix = self.gnss[name].fix(t, x, y, self.layout.vehicles[name].height, yaw, v)
        self.fixes[name].append(fix)
        self._gnss_err2[name].append((fix.x - x) ** 2 + (fix.y - y) ** 2)
        return fix

    def lidar_metadata(self, name: str) -> dict[str, Any]:
        lidar = self.world.lidars[name]
        scans = self.scans.get(name, [])
        seen: dict[str, dict[str, Any]] = {}
        for other in self.layout.vehicles:
            if other == name:
                continue
            hit = [(t, hits[other]) for t, hits in scans if other in hits]
            seen[other] = {"first_hit_s": hit[0][0] if hit else None, "scans_hit": len(hit),
                           "max_rays": max((n for _, n in hit), default=0)}
        return {"scans": len(scans), "rate_hz": lidar.spec.rate_hz, "rays_per_scan": len(lidar.directions),
                "scan_s": percentiles(lidar.scan_times), "dropped": self.dropped.get(("lidar", name), 0),
                "vehicles": seen}

    def radar_metadata(self, name: str) -> dict[str, Any]:
        radar = self.world.radars[name]
        log = self.radar_log.get(name, [])
        seen: dict[str, dict[str, Any]] = {}
        for vehicle in self.layout.vehicles:
            times = [t for t, names in log if vehicle in names]
            seen[vehicle] = {"first_report_s": times[0] if times else None,
                             "last_report_s": times[-1] if times else None, "scans_reported": len(times)}
        return {"scans": len(log), "rate_hz": radar.spec.rate_hz,
                "objects_reported": sum(len(names) for _, names in log),
                "scan_s": percentiles(radar.scan_times), "vehicles": seen}

    def metadata(self) -> dict[str, Any]:
        w = self.world
        if w is None:
            return {}
        poses = w.scene.poses
        return {
            "vehicles": list(self.layout.vehicles),
            "buildings": [b.name for b in self.layout.buildings],
            "poses": {n: [x, y, yaw] for n, (x, y, yaw, _) in poses.items()},  # last rear-axle poses
            "speeds": {n: v for n, (_, _, _, v) in poses.items()},  # last speeds (m/s)
            "sensors": self.sensors,
            "renderer": self._renderer_used or w.scene.renderer_name,
            "sensor_processes": self._worker_kinds,  # the sensor kinds taken in worker processes
            "cameras": {n: {"frames": c.frame_id, "width": c.spec.width, "height": c.spec.height,
                            "rate_hz": c.spec.rate_hz, "render_s": percentiles(c.render_times),
                            "dropped": self.dropped.get(("camera", n), 0)}
                        for n, c in w.cameras.items()},
            "lidars": {n: self.lidar_metadata(n) for n in w.lidars},
            "radars": {n: self.radar_metadata(n) for n in w.radars},
            "gnss": {n: {"fixes": len(f), "rate_hz": self.gnss[n].spec.rate_hz,
                         "error_h_rms_m": (math.sqrt(sum(self._gnss_err2[n]) / len(f)) if f else None)}
                     for n, f in self.fixes.items()},
            "signals": {s.name: {"instance": s.instance, "signal_group": s.signal_group,
                                 "state": w.scene.signal_states[s.name],
                                 "lamps": state_name(w.scene.signal_states[s.name]),
                                 "changes": sum(1 for _, h, _ in self.signal_log if h == s.name)}
                        for s in self.layout.signals},
        }

    def _close_workers(self) -> None:
        for worker in self._workers.values():
            worker.close()
        self._workers = {}

    def close(self, outcome: Outcome | None = None) -> dict[str, Any]:
        self._close_workers()  # samples still being taken are dropped with them
        meta = self.metadata()
        if self.world is not None:
            self.world.close()
            self.world = None
        return meta
