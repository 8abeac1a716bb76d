"""Stage 2, the deployments' way: confirmed tracks -> one SAE J3224 Sensor Data Sharing Message per slot.

Where the surrogate-BSM stage (bsm_stage.py) sends one BSM per track, this
stage sends one SDSM per slot (10 Hz) with every broadcastable track, signed
under the configured PSID (`[v2x] sdsm_psid`; deployments differ). Per object:

* objectID: the track id modulo 65536 (stable for the track's life);
* objType: "vehicle" for the detector's vehicle classes (car, emergency),
  "vru" for persons and cyclists, else "unknown"; objTypeCfd: the score (in
  percent) of the track's latest detector box;
* the position as offsets east and north from the reference point, which is
  the MAP's (the scenario's origin, rsu_app/intersection_map.py), so they are
  the world's x and y;
* measurementTime: the time of the camera frame that last updated the track,
  relative to the message's timestamp (the slot's time); position and speed
  are the tracker's estimate at that frame time (the constant-velocity
  prediction to the slot, taken back), so a receiver predicts forward from
  when the object was seen;
* confidences from the tracker's covariance, each bound read as J2735's
  95 % level: position 2.45 sigma of the major axis (the 95 % radius of a 2-D
  Gaussian), speed and heading 1.96 sigma along and across the velocity;
  time to the millisecond the frame times carry;
* detVeh: the class's typical length, width and height (`geo.VEHICLE_SIZE`),
  as the surrogate BSM does, and its J2735 BasicVehicleClass where the
  detector's class names one (car: 10, passenger vehicle; emergency: 60, an
  emergency vehicle of unknown type) with the box's score as its confidence:
  the SDSM has no siren or lightbar flags, so this is how a receiver learns
  that the vehicle is an emergency one.

The message's trace stamps are those of its oldest frame (the E2E latency of
the message is that of its stalest object). At most 256 objects fit: the
tracks beyond (by id) are counted in `objects_dropped`.
"""
from __future__ import annotations

import hashlib
import math
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from bridges.geo import GeoOrigin
from bridges.j2735.sdsm import (HEADING_CONFIDENCE, MAX_OBJECTS, MEASUREMENT_TIME, POSITION_CONFIDENCE,
                                SPEED_CONFIDENCE, DateTime, DetectedObject, Sdsm, VehicleDetails)
from bridges.v2x import tx_key, unix_time
from rsu_app.bsm_stage import Transmission, sign_encoded
from rsu_app.perception.geo import VEHICLE_SIZE
from rsu_app.perception.tracker import TrackState
from rsu_app.perception_stage import TrackStamps, covariance_ellipse

OBJECT_TYPES = {"car": "vehicle", "emergency": "vehicle", "truck": "vehicle", "bus": "vehicle",
                "person": "vru", "pedestrian": "vru", "bicycle": "vru", "cyclist": "vru"}
POSITION_95 = 2.4477   # sqrt(chi2(2 dof, 0.95)): the 95 % radius of a 2-D Gaussian in sigmas
ONE_D_95 = 1.96
VEHICLE_CLASSES = {"car": 10, "emergency": 60}  # J2735 BasicVehicleClass: passenger-Vehicle, emergency-TypeUnknown
TIME_CONFIDENCE = "time-000-001"  # frame times are exact in the simulation; the wire carries milliseconds
MIN_HEADING_SPEED = 0.5  # m/s: below, a heading's confidence from the velocity covariance means nothing


@dataclass(frozen=True)
class Reference:
    """The point the objects' offsets are from: (lat, lon) deg, elevation m, and its world x, y (m)."""

    latitude: float
    longitude: float
    elevation: float
    x: float = 0.0
    y: float = 0.0

    @classmethod
    def of_origin(cls, origin: GeoOrigin) -> "Reference":
        lat, lon, h = origin.to_geodetic(0.0, 0.0, 0.0)
        return cls(float(lat), float(lon), float(h))


def sdsm_source_id(station: str, session_salt: bytes) -> bytes:
    """The SDSM's sourceID (a TemporaryID): stable for the RSU session, unlinkable across sessions."""
    return hashlib.sha256(b"sdsm:" + station.encode() + session_salt).digest()[:4]


def speed_heading_sigmas(s: TrackState) -> tuple[float | None, float | None]:
    """1-sigma of the speed (m/s) and the heading (deg) from the velocity covariance; None when unknown."""
    cov = np.asarray(s.cov, float)
    if cov.shape != (4, 4) or not np.all(np.isfinite(cov)):
        return None, None
    v = cov[2:, 2:]
    speed = math.hypot(s.vx, s.vy)
    if speed < MIN_HEADING_SPEED:
        return math.sqrt(max(float(np.trace(v)) / 2.0, 0.0)), None
    along = np.array([s.vx, s.vy]) / speed
    across = np.array([-along[1], along[0]])
    sigma_speed = math.sqrt(max(float(along @ v @ along), 0.0))
    sigma_heading = math.degrees(math.sqrt(max(float(across @ v @ across), 0.0)) / speed)
    return sigma_speed, sigma_heading


class SdsmStage:
    def __init__(self, station: str, origin: GeoOrigin, epoch_unix_s: float, salt: bytes, envelope, latency,
                 psid: int, reference: Reference | None = None):
        self.key = tx_key(station)
        self.epoch, self.envelope, self.latency, self.psid = float(epoch_unix_s), envelope, latency, int(psid)
        self.reference = reference or Reference.of_origin(origin)
        self.source_id = sdsm_source_id(station, bytes(salt))
        self.msg_count = 0
        self.scores: dict[int, float] = {}    # track id -> score of its latest detector box
        self.sent = 0
        self.objects_sent = 0
        self.objects_dropped = 0
        self.encode_s: deque[float] = deque(maxlen=20000)
        self.sign_s: deque[float] = deque(maxlen=20000)

    def observe(self, results) -> None:
        """Remember each track's latest box score (objTypeCfd) from applied frame results."""
        for r in results:
            for outcome in r.objects:
                track = r.track_of(outcome)
                if track is not None:
                    self.scores[track] = float(outcome.score)

    def detected_object(self, s: TrackState, t: float, frame_t: float | None) -> DetectedObject:
        back = 0.0
        if frame_t is not None and 0.0 <= t - frame_t <= MEASUREMENT_TIME.high * MEASUREMENT_TIME.step:
            back = t - frame_t
        major, _, _ = covariance_ellipse(s.cov)
        sigma_speed, sigma_heading = speed_heading_sigmas(s)
        heading = None if s.heading is None else (90.0 - math.degrees(s.heading)) % 360.0
        score = self.scores.get(s.id)
        length, width, height = VEHICLE_SIZE.get(s.label, VEHICLE_SIZE["car"])[:3]
        kind = OBJECT_TYPES.get(s.label, "unknown")
        return DetectedObject(
            object_id=s.id % 65536, object_type=kind,
            type_confidence=0 if score is None else min(100, max(0, round(100 * score))),
            measurement_time=-back, time_confidence=TIME_CONFIDENCE,
            offset_x=s.x - s.vx * back - self.reference.x, offset_y=s.y - s.vy * back - self.reference.y,
            position_confidence=POSITION_CONFIDENCE.name_for(POSITION_95 * major),
            speed=min(float(s.speed), 163.8), heading=heading,
            speed_confidence=SPEED_CONFIDENCE.name_for(None if sigma_speed is None else ONE_D_95 * sigma_speed),
            heading_confidence=HEADING_CONFIDENCE.name_for(
                None if sigma_heading is None or heading is None else ONE_D_95 * sigma_heading),
            details=VehicleDetails(width=width, length=length, height=height,
                                   vehicle_class=VEHICLE_CLASSES.get(s.label),
                                   class_confidence=None if s.label not in VEHICLE_CLASSES or score is None
                                   else min(100, max(0, round(100 * score)))) if kind == "vehicle" else None)

    def sdsm(self, states: list[TrackState], t: float, stamps: dict[int, TrackStamps]) -> Sdsm:
        chosen = sorted(states, key=lambda s: s.id)[:MAX_OBJECTS]
        self.objects_dropped += len(states) - len(chosen)
        objects = [self.detected_object(s, t, stamps[s.id].frame if s.id in stamps else None) for s in chosen]
        message = Sdsm(self.source_id, objects, latitude=self.reference.latitude,
                       longitude=self.reference.longitude, elevation=self.reference.elevation,
                       timestamp=DateTime.from_unix(unix_time(t, self.epoch)), msg_count=self.msg_count,
                       equipment_type="rsu")
        self.msg_count = (self.msg_count + 1) % 128
        return message

    def send(self, states: list[TrackState], t: float, stamps: dict[int, TrackStamps], start: float | None = None
             ) -> list[Transmission]:
        """The slot's SDSM (none without tracks), its stages starting at `start` (default t: after the slot's
        other messages when one CPU does them in turn)."""
        if not states:
            return []
        start = t if start is None else start
        c0 = time.perf_counter()
        message = self.sdsm(states, t, stamps)
        signed = sign_encoded(message.encode(), c0, start, self.psid, self.envelope, self.latency, self.epoch)
        marks = signed.marks()
        seen = [stamps[s.id] for s in states if s.id in stamps]
        if seen:
            oldest = min(seen, key=lambda st: st.frame)
            marks = {**oldest.marks(), **marks}
        self.encode_s.append(signed.encode_s)
        self.sign_s.append(signed.sign_s)
        self.sent += 1
        self.objects_sent += len(message.objects)
        return [Transmission(self.key, signed.frame, signed.t_sign, marks, "sdsm", self.source_id.hex(),
                             signed.compute_s())]
