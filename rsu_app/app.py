"""The RSU app as a process: bus, time protocol, camera and controller in; V2X frames out. The thin shell.

Everything that decides what is sent and when lives in `RsuCore` (simulated
time, no I/O); this module wires it to the world:

1. check the configuration, load the detector (and warm it up) and the
   station's credentials: any problem is a `ConfigError` (exit 2);
2. open the bus (`bridges.timesync.participant.bus_from_env`) and, when the
   scenario has a controller link, open it and send the first poll;
3. join the master; the join reply gives the run's mode and latency policy,
   the geodetic origin, the Unix time of simulation time 0, the intersection
   and its signal heads;
4. lockstep: per tick, the frames due (waiting, bounded, for a frame that is
   due), the controller answers that arrived, `core.step(t)` up to the next
   step's end (what is due before it is handed over now, so the master puts
   it on the air at its stamp: `RsuCore`), publish (the V2X frames, then the
   frames' "detections" trace records on trace/<name> when
   `app.trace_detections`), ack; realtime: the same on the simulation time
   read off the master's clock;
5. at the end (the master ends the run, or SIGTERM): the JSON summary on stdout.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import secrets
import signal
import sys
import time
import traceback

import numpy as np

from bridges.geo import GeoOrigin
import threading
from pathlib import Path

from bridges.security import (PSID_SPAT_MAP, PSID_SSM, PSID_SURROGATE_BSM, SecurityFormatError, Verifier,
                              load_certificate)
from bridges.timesync.errors import TimeSyncError
from bridges.timesync.exits import EXIT_CONFIG, EXIT_ERROR, EXIT_OK, SESSION_ERRORS, session_end
from bridges.timesync.participant import Participant, bus_from_env
from bridges.v2x import EPOCH, rx_key, trace_key, tx_key
from rsu_app.bsm_stage import BsmStage
from rsu_app.camera import CameraIngest, RadarIngest
from rsu_app.config import ConfigError, Settings
from rsu_app.controller_link import ControllerLink, serial_env
from rsu_app.core import RsuCore
from rsu_app.envelope import Envelope
from rsu_app.health import Health, clean, percentiles_ms
from rsu_app.intersection_map import intersection_geometry
from rsu_app.perception_stage import PerceptionStage
from rsu_app.sdsm_stage import SdsmStage
from rsu_app.priority import PriorityCore, ingress_lanes
from rsu_app.priority_stage import PriorityStage
from rsu_app.spat_stage import MapStage, SpatStage
from rsu_app.timing import LatencyModel

log = logging.getLogger("rsu_app")

DEFAULT_SIGNAL_GROUPS = [2, 4, 6, 8]


class Terminated(Exception):
    """SIGTERM: finish with the summary."""


def make_rsu_detector(settings: Settings):
    """The configured detector, warmed up; ConfigError naming detector.* when it cannot be built."""
    from rsu_app.perception import DetectorError, make_detector

    d = settings.detector
    try:
        import cv2

        cv2.setNumThreads(d.threads)
    except ImportError:  # OpenCV is a dependency; only the classical backend needs it for sure
        pass
    if d.backend == "classical":
        options = {"background": d.background} if d.background else {}
    else:
        options = {"threads": d.threads, "score_threshold": d.score_threshold}
        if d.weights:
            options["weights"] = d.weights
        if d.compile:
            options["compile"] = True
    try:
        detector = make_detector(d.backend, **options)
        detector.detect(np.zeros((48, 64, 3), np.uint8))  # first inference builds the graph: not in a frame's time
    except DetectorError as exc:
        key = "detector.weights" if d.weights and "weights" in str(exc) else "detector.backend"
        raise ConfigError([(key, str(exc))]) from None
    return detector


def j2735_codec():
    """The J2735 codec, compiled now: before joining, not on the first MAP or BSM of the run.

    Compiling the ASN.1 takes about a second of CPU; in a realtime run the first message's stage took
    it from the run's first second, beside the master's loop and the other app. ConfigError naming
    the ASN.1 folder's variable when a user's files cannot be compiled."""
    from bridges.j2735 import J2735Error, default_codec
    from bridges.j2735.codec import ASN1_DIR_ENV

    try:
        return default_codec()
    except J2735Error as exc:
        raise ConfigError([(ASN1_DIR_ENV, str(exc))]) from None


def session_salt(station: str, seed: int | None, lockstep: bool) -> bytes:
    """The per-session salt of the temporary ids: from the seed (lockstep default 0: runs repeat), else random."""
    if seed is None and not lockstep:
        return secrets.token_bytes(16)
    return hashlib.sha256(f"v2i-rsu-salt:{station}:{seed or 0}".encode()).digest()[:16]


class RsuApp:
    def __init__(self, settings: Settings, environ=os.environ):
        self.s = settings
        self.environ = environ
        self.name = settings.name or "rsu"
        self.station = settings.station or self.name
        self.serial_url = settings.spat.url or environ.get(serial_env(settings.spat.serial)) or None
        messages = settings.v2x.messages
        psids = [PSID_SURROGATE_BSM] if settings.camera.names and "surrogate_bsm" in messages else []
        if settings.camera.names and "sdsm" in messages:
            psids.append(settings.v2x.sdsm_psid)
        if self.serial_url or settings.map.enabled:
            psids.append(PSID_SPAT_MAP)
        if settings.priority.enabled:
            psids.append(PSID_SSM)
        self.envelope = Envelope.load(settings.security.mode, settings.security.pki_dir,
                                      settings.security.credential or self.station, psids,
                                      settings.security.certificate_interval_s)
        self.detector = make_rsu_detector(settings) if settings.camera.names else None
        self.codec = j2735_codec()
        self.bus = self.part = self.ingest = self.radar_ingest = self.link = self.core = None
        self.welcome = None
        self.t_sim = float("nan")
        self.ticks = 0
        self.published = 0
        self.publish_errors = 0
        self.traces_detections = self.detector is not None and settings.app.trace_detections
        self.trace_records = 0
        self.trace_errors = 0
        self.notes: list[str] = []
        self.srm_verifier = self._srm_verifier() if settings.priority.enabled else None
        self._heard: list[tuple[bytes, float]] = []   # V2X frames heard (payload, arrival), for the priority stage
        self._heard_lock = threading.Lock()
        self.ended = None
        self.exit_reason = ""

    def _srm_verifier(self) -> Verifier:
        """The 1609.2 checks of the SRMs: the scenario CA (`priority.trust_anchor`); ConfigError when unusable."""
        p, sec = self.s.priority, self.s.security
        path = Path(p.trust_anchor) if p.trust_anchor else Path(sec.pki_dir or ".") / "v2i-scenario-ca.cert"
        anchors = []
        if sec.mode != "unsecured" or p.trust_anchor:
            try:
                anchors.append(load_certificate(path))
            except (SecurityFormatError, OSError) as exc:
                raise ConfigError([("priority.trust_anchor", f"cannot load the CA certificate {str(path)!r}: "
                                                            f"{getattr(exc, 'reason', exc)}")]) from None
        return Verifier(anchors, max_age_s=p.max_age_s, allow_unsecured=sec.mode == "unsecured")

    def _on_heard(self, msg) -> None:
        with self._heard_lock:
            self._heard.append((bytes(msg.payload), float(msg.t_sim)))

    def _take_heard(self, t: float | None) -> list[tuple[bytes, float]]:
        with self._heard_lock:
            if t is None:
                out, self._heard = self._heard, []
            else:
                out = [h for h in self._heard if h[1] <= t + 1e-9]
                self._heard = [h for h in self._heard if h[1] > t + 1e-9]
        return sorted(out, key=lambda h: h[1])

    # -- set-up once joined ---------------------------------------------------------------------------
    def _build_core(self, world: dict) -> RsuCore:
        w, s = self.welcome, self.s
        origin = self.part.origin
        if origin is None:
            origin = GeoOrigin()
            self.notes.append("the master sent no geodetic origin: using bridges.geo's default")
        epoch = world.get(EPOCH)
        if epoch is None:
            epoch = time.time()
            self.notes.append("the master sent no epoch_unix_s: simulation time 0 = this app's start")
        self.origin, self.epoch = origin, float(epoch)
        lockstep = w.mode == "lockstep"
        self.latency = LatencyModel(w.mode, w.latency_policy, w.latencies, self.s.inference_s())
        self.salt = session_salt(self.station, s.seed, lockstep)
        perception = bsm = sdsm = spat = map_stage = None
        if self.detector is not None:
            perception = PerceptionStage.from_settings(self.detector, s, world.get("intersection"))
            if "surrogate_bsm" in s.v2x.messages:
                bsm = BsmStage(self.station, origin, epoch, self.salt, self.envelope, self.latency)
            if "sdsm" in s.v2x.messages:
                sdsm = SdsmStage(self.station, origin, epoch, self.salt, self.envelope, self.latency,
                                 s.v2x.sdsm_psid)
        if self.serial_url:
            groups = s.spat.signal_groups or sorted({int(h["signal_group"]) for h in world.get("signals") or ()
                                                     if "signal_group" in h}) or DEFAULT_SIGNAL_GROUPS
            spat = SpatStage(self.station, epoch, self.envelope, self.latency, intersection_id=s.spat.intersection_id,
                             signal_groups=groups, baud=s.spat.baud, max_age_s=s.spat.max_age_s)
        if s.map.enabled:
            try:
                geometry = intersection_geometry(world, origin, s.spat.intersection_id, s.map.revision,
                                                 s.map.stop_line_offset_m)
                map_stage = MapStage(self.station, epoch, self.envelope, self.latency, geometry, s.map.revision)
            except ValueError as exc:
                self.notes.append(f"no MAP: {exc}")
                log.info("no MAP: %s", exc)
        priority = None
        if s.priority.enabled:
            if map_stage is None or spat is None:
                self.notes.append("priority: no SRMs served (needs the controller link and the MAP)")
            else:
                core = PriorityCore(s.spat.intersection_id, ingress_lanes(map_stage.geometry),
                                    set(s.priority.preempt_groups), expire_s=s.priority.expire_s)
                priority = PriorityStage(core, self.srm_verifier, self.station, epoch, self.envelope, self.latency)
        return RsuCore(self.latency, perception, bsm, spat, map_stage, bsm_rate_hz=s.timing.bsm_rate_hz,
                       spat_rate_hz=s.spat.rate_hz, map_rate_hz=s.map.rate_hz, realtime=not lockstep,
                       trace_detections=self.traces_detections, sdsm=sdsm, priority=priority,
                       ssm_rate_hz=s.priority.ssm_rate_hz, bsm_follows=s.timing.bsm_follows)

    # -- running ------------------------------------------------------------------------------------------
    def run(self) -> int:
        s = self.s
        try:
            self.bus = bus_from_env(self.name, transport=s.bus.transport, prefix=s.bus.prefix,
                                    connect=",".join(s.bus.connect) or None, environ=self.environ)
        except (TimeSyncError, ValueError, OSError) as exc:
            print(f"rsu_app: bus: {exc}", file=sys.stderr)
            return EXIT_CONFIG
        except Exception as exc:  # TransportError (unknown option, port taken...)
            print(f"rsu_app: bus: cannot open it: {exc}", file=sys.stderr)
            return EXIT_CONFIG
        code = EXIT_OK
        previous = signal.signal(signal.SIGTERM, self._on_sigterm)
        try:
            if self.detector is not None:
                self.ingest = CameraIngest(self.bus, s.camera.names, s.camera.rate_hz, s.camera.wait_s)
                if s.radar.names:
                    self.radar_ingest = RadarIngest(self.bus, s.radar.names, s.radar.rate_hz, s.radar.wait_s)
            if self.serial_url:
                self.link = ControllerLink(self.serial_url, s.spat.controller, s.spat.baud, s.spat.poll,
                                           s.spat.answer_timeout_s)
                self.link.open()
            if s.priority.enabled:
                self._heard_sub = self.bus.subscribe(rx_key(self.station), self._on_heard)
            publishes = [tx_key(self.station)] + ([trace_key(self.name)]
                                                  if self.traces_detections or s.priority.enabled else [])
            self.part = Participant(self.bus, self.name, s.role, publishes=publishes)
            self.welcome = self.part.join(timeout=s.bus.join_timeout_s)
            if self.link is not None:
                if self.welcome.mode == "lockstep":
                    self.link.follow(lambda: self.t_sim)  # the controller's answers come at simulated times
                self.link.start()
            self.core = self._build_core(self.part.world)
            self.health = Health(self, s.health.stats_every_s)
            if self.welcome.mode == "lockstep":
                self._lockstep()
            else:
                self._realtime()
            self.ended = self.part.ended.status if self.part.ended else None
            self.exit_reason = f"the run ended ({self.ended})"
        except SESSION_ERRORS as exc:
            print(f"rsu_app: {exc}", file=sys.stderr)
            code, self.exit_reason = session_end(exc)
        except (Terminated, KeyboardInterrupt):
            self.exit_reason = "terminated by signal"
            if self.part is not None and self.part.welcome is not None and self.part.ended is None:
                try:
                    self.part.leave("terminated by signal")  # the master hears it now, not at its timeout
                except Exception as exc:  # the bus may be gone
                    log.debug("leave: %s", exc)
        except Exception as exc:  # a bug of ours: say so with the traceback, still summarise
            traceback.print_exc()
            code, self.exit_reason = EXIT_ERROR, f"internal error: {type(exc).__name__}: {exc}"
        finally:
            signal.signal(signal.SIGTERM, previous)
            summary = self.summary()
            self._close()
            print(json.dumps(clean(summary)), flush=True)
        return code

    def _on_sigterm(self, signum, frame):
        raise Terminated()

    def _lockstep(self) -> None:
        for tick in self.part.ticks():
            c0 = time.perf_counter()
            self.t_sim = tick.t
            frames = self._samples(tick.t, wait=True)
            statuses = [(a.status, a.wire_bytes) for a in self.link.collect()] if self.link is not None else []
            acks = self.link.collect_preempt() if self.link is not None else []
            self._publish(self.core.step(tick.t, frames, statuses, self._horizon(tick), srms=self._take_heard(tick.t),
                                         acks=acks))
            self._trace(self.core.take_records())
            self._priority_out()
            self.part.ack(tick, time.perf_counter() - c0)
            self.ticks += 1
            self.health.maybe_report()

    def _samples(self, t: float, wait: bool) -> list:
        """Camera frames and radar scans of time <= t, in time order. `wait` (lockstep): wait for those due at
        t; else (realtime) every sample that came, the newest per sensor."""
        out = []
        for ingest in (self.ingest, self.radar_ingest):
            if ingest is not None:
                got = ingest.collect(t, wait=wait)
                out += got if wait else ingest.newest_only(got)
        return sorted(out, key=lambda f: (f.t, f.sensor))

    def _horizon(self, tick) -> float | None:
        """Lockstep: the earliest simulation time an input still to come may have (`RsuCore.step` works ahead
        up to it, so what is due before the master's next step reaches the air at its stamp). Camera frames are
        samples of the master's steps, each taken at the first tick at or after it: the next one is at t + step
        or later. Statuses are dated by their tick: the next one is sync_every steps on. None without a step."""
        step = float(getattr(tick, "step", 0.0) or 0.0)
        if not step > 0:
            return None
        if self.ingest is not None or (self.core is not None and self.core.priority is not None):  # every step
            return tick.t + step
        return tick.t + step * max(1, int(getattr(self.welcome, "sync_every", 1) or 1))

    def _realtime(self) -> None:
        while True:
            tick = self.part.next_tick(timeout=0.02)
            if tick is None and self.part.ended is not None:
                return
            try:
                now = self.part.sim_time_now()
            except TimeSyncError:
                continue  # no time mapping from the master yet
            # a stage's wall seconds are charged as rtf simulated seconds, and the rtf comes with the mapping
            # (the join does not carry it): without it a run at RTF 0.3 stamped encode and sign 3.3x too long,
            # so a BSM's send stamp ran ahead of the run clock and its air stage read up to -2 ms. It is read
            # as each stage ends: a first MAP encode of 0.6 s charged at the rate the step began with, while
            # the clock slewed at 0.1 after the master's first slip, was stamped 0.5 s ahead of the clock
            self.latency.rate_source = lambda: self.part.mapping.rtf
            self.t_sim = now
            frames = self._samples(float("inf"), wait=False)
            statuses = [(a.status, a.wire_bytes) for a in self.link.collect()] if self.link is not None else []
            acks = self.link.collect_preempt() if self.link is not None else []
            self._publish(self.core.step(now, frames, statuses, srms=self._take_heard(None), acks=acks))
            self._trace(self.core.take_records())
            self._priority_out()
            self.ticks += tick is not None
            self.health.maybe_report()

    def _publish(self, transmissions) -> None:
        for tx in transmissions:
            try:
                self.bus.publish(tx.key, tx.payload, tx.t_sim, stamps=tx.stamps)
                self.published += 1
            except Exception as exc:  # a closed or broken bus: count, keep the run going
                self.publish_errors += 1
                log.warning("could not publish on %s: %s", tx.key, exc)

    def _priority_out(self) -> None:
        """The preemption calls the core decided go to the controller link; its records to trace/<name>."""
        for _, on in self.core.take_preempt_calls():
            if self.link is not None:
                self.link.set_preempt(on)
        for rec in self.core.take_priority_records():
            rec = {"record": "evsp", **rec}
            try:
                self.bus.publish(trace_key(self.name), json.dumps(rec, separators=(",", ":")).encode(), rec["t"])
                self.trace_records += 1
            except Exception as exc:
                self.trace_errors += 1
                log.debug("evsp trace record not published: %s", exc)

    def _trace(self, records) -> None:
        """Publish the frames' trace records on trace/<name>, each at its detect_end (when its detections were
        known). A record that cannot go out is counted: the trace is for the report, the RSU keeps working."""
        for rec in records:
            try:
                self.bus.publish(trace_key(self.name), json.dumps(rec, separators=(",", ":")).encode(),
                                 rec["detect_end"])
                self.trace_records += 1
            except Exception as exc:
                self.trace_errors += 1
                log.debug("trace record not published: %s", exc)

    def _close(self) -> None:
        for thing in (self.link, self.ingest, self.radar_ingest, self.part):
            if thing is not None:
                try:
                    thing.close()
                except Exception as exc:
                    log.debug("closing %r: %s", thing, exc)
        if self.bus is not None:
            try:
                self.bus.close()
            except Exception as exc:
                log.debug("closing the bus: %s", exc)

    # -- health --------------------------------------------------------------------------------------------
    def snapshot(self) -> dict:
        core = self.core
        p = core.perception if core else None
        b = core.bsm if core else None
        stage2 = [] if b is None else [e + g for e, g in zip(b.encode_s, b.sign_s)]
        return {
            "name": self.name, "station": self.station, "t_sim": self.t_sim,
            "camera": self.ingest.stats() if self.ingest else {"received": 0, "bad": 0, "late": 0},
            "frames_dropped_busy": core.counters.frames_dropped_busy if core else 0,
            "detections": p.detections if p else 0,
            "confirmed_tracks": len([t for t in p.tracker.tracks if t.confirmed]) if p else 0,
            "bsm_sent": b.sent if b else 0,
            "sdsm_sent": core.sdsm.sent if core and core.sdsm else 0,
            "spat_sent": core.spat.sent if core and core.spat else 0,
            "map_sent": core.map.sent if core and core.map else 0,
            "stage1": {"compute_ms": percentiles_ms(p.compute_s if p else []),
                       "charged_ms": percentiles_ms(core.counters.stage1_charged_s if core else [])},
            "stage2": {"compute_ms": percentiles_ms(stage2)},
        }

    def summary(self) -> dict:
        out = {"app": "rsu_app", "name": self.name, "station": self.station, "exit": self.exit_reason,
               "end": self.ended, "ticks": self.ticks, "published": self.published,
               "publish_errors": self.publish_errors, "notes": self.notes,
               "trace": {"detections": self.traces_detections, "records": self.trace_records,
                         "publish_errors": self.trace_errors}}
        if self.welcome is not None:
            out.update(mode=self.welcome.mode, latency_policy=self.welcome.latency_policy)
        if self.core is None:
            return out
        core, snap = self.core, self.snapshot()
        out.update(snap)
        out["epoch_unix_s"] = self.epoch
        out["origin"] = self.origin.to_dict()
        out["latency"] = self.latency.describe()
        out["hardware"] = self.s.timing.hardware
        out["frames"] = {"processed": core.counters.frames - core.counters.frames_dropped_busy,
                         "dropped_busy": core.counters.frames_dropped_busy,
                         "refused": core.counters.frames_refused}
        out["slots_skipped_late"] = core.counters.slots_skipped
        if self.radar_ingest is not None:
            out["radar"] = {**self.radar_ingest.stats(), "scans": core.counters.radar_scans}
        p, b = core.perception, core.bsm
        if p is not None:
            out["detector"] = {"backend": self.s.detector.backend, "threads": self.s.detector.threads,
                               "score_threshold": self.s.detector.score_threshold}
            out["tracker"] = {"confirmed_ever": len(core.tracks_seen), "late_updates": p.late_updates,
                              "rejected_detections": dict(p.rejected), "detector_errors": p.detector_errors}
        if b is not None:
            out["bsm_by_track"] = {b.bsm_id(tid): n for tid, n in sorted(b.sent_by_track.items())}
        if core.sdsm is not None:
            sd = core.sdsm
            out["sdsm"] = {"sent": sd.sent, "objects_sent": sd.objects_sent, "objects_dropped": sd.objects_dropped,
                           "psid": sd.psid, "source_id": sd.source_id.hex(),
                           "compute_ms": percentiles_ms([e + g for e, g in zip(sd.encode_s, sd.sign_s)])}
        if core.spat is not None:
            sp = core.spat
            out["spat"] = {"sent": sp.sent, "statuses": sp.statuses, "suppressed_stale": sp.suppressed_stale,
                           "signal_groups": sp.signal_groups}
        if self.link is not None:
            out["controller_link"] = self.link.stats()
        if core.priority is not None:
            pc = core.priority.core
            out["priority"] = {"srms": core.priority.srms, "ssm_sent": core.priority.sent,
                               "rejections": dict(pc.rejections), "answered_rejected": dict(pc.answered_rejected),
                               "cancellations": pc.cancellations, "expired": pc.expired,
                               "other_messages": {str(k): v for k, v in core.priority.other_messages.items()}}
        if core.map is not None:
            out["map"] = {"sent": core.map.sent, "lanes": len(core.map.geometry.lanes)}
        out["bus"] = self.bus.stats() if self.bus is not None else None
        if self.part is not None:
            out["time_protocol_errors"] = dict(self.part.errors)
        return out
