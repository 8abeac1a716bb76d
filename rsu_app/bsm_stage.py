"""Stage 2: confirmed tracks -> surrogate BSMs (J2945/8 style), encoded, signed, stamped.

One BSM per confirmed track per slot (10 Hz, J2945/1), from the track as the
tracker knows it at the slot's time, predicted to that time:

* temporary id: `surrogate_temporary_id(track id, salt)`, stable for the
  track's life, unlinkable across RSU sessions (the salt is per session);
* msgCnt: per track, 0, 1, ... 127, 0, ...;
* secMark: milliseconds within the UTC minute of the slot's time
  (`bridges.v2x.unix_time(t, epoch)`);
* position: the track's ground point through the scenario's origin to WGS-84
  (`GeoOrigin.to_geodetic`), elevation of the ground there;
* speed, heading (deg clockwise from north), yaw rate (deg/s, clockwise positive
  as in SAE J670's vehicle axes; 0 unless the CTRV filter estimates it);
* size: the detector class's typical length and width (`geo.VEHICLE_SIZE`);
* position accuracy: the 1-sigma ellipse of the track's position covariance;
* the emergency-vehicle extension (response type "emergency") when the
  detector's class says so; siren and lightbar are not seen by a camera, so
  they are "unavailable".

Signed under PSID 0x7F (`PSID_SURROGATE_BSM`), never the BSM's 0x20, with a
1609.2 generation time of the moment signing starts.
"""
from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field

from bridges.geo import GeoOrigin
from bridges.j2735.bsm import EmergencyInfo, surrogate_bsm, surrogate_temporary_id
from bridges.security import PSID_SURROGATE_BSM, time64_us
from bridges.v2x import ENCODE, SEND, SIGN, stamp_ns, tx_key, unix_time
from rsu_app.perception.geo import VEHICLE_SIZE
from rsu_app.perception.tracker import TrackState
from rsu_app.perception_stage import TrackStamps, covariance_ellipse
from rsu_app.timing import ENCODE as ENCODE_STAGE
from rsu_app.timing import SIGN as SIGN_STAGE

MAX_SEMI_AXIS = 12.7  # m: SemiMajorAxisAccuracy's largest value (254 = ">= 12.7 m")


@dataclass
class Transmission:
    """One frame for the air: published on `key` with `t_sim` (= the SEND stamp) and the trace stamps."""

    key: str
    payload: bytes
    t_sim: float
    stamps: dict[str, int]
    kind: str                   # "bsm", "spat", "map"
    object_id: str = ""         # BSM: the temporary id (hex)
    compute_s: dict[str, float] = field(default_factory=dict)  # wall seconds per stage


@dataclass(frozen=True)
class Signed:
    """A message encoded and signed: the 1609.2 frame, the simulated times its encode and sign stages
    ended, and the wall seconds each took."""

    frame: bytes
    t_encode: float
    t_sign: float
    encode_s: float
    sign_s: float

    def marks(self) -> dict[str, int]:
        """The trace stamps of its stages (it is sent as it is signed)."""
        return {ENCODE: stamp_ns(self.t_encode), SIGN: stamp_ns(self.t_sign), SEND: stamp_ns(self.t_sign)}

    def compute_s(self) -> dict[str, float]:
        return {"encode": self.encode_s, "sign": self.sign_s}


def sign_encoded(payload: bytes, c0: float, start: float, psid: int, envelope, latency, epoch_unix_s: float
                 ) -> Signed:
    """Sign `payload`, whose building and encoding began at perf_counter `c0`: the encode stage is charged
    from `start` (per the latency policy), the signature carries the time it ended as its generation time,
    and the sign stage follows it. Every message the RSU sends goes through here, so each is stamped alike."""
    c1 = time.perf_counter()
    t_encode = start + latency.stage(ENCODE_STAGE, c1 - c0)
    frame = envelope.wrap(payload, psid, time64_us(unix_time(t_encode, epoch_unix_s)))
    c2 = time.perf_counter()
    return Signed(frame, t_encode, t_encode + latency.stage(SIGN_STAGE, c2 - c1), c1 - c0, c2 - c1)


def sec_mark_ms(t_sim: float, epoch_unix_s: float) -> int:
    """Milliseconds within the UTC minute of simulation time t_sim (J2735 DSecond; no leap seconds here).

    Counted in whole milliseconds: the run's epoch rounded to its millisecond plus t_sim's millisecond.
    Flooring the float Unix time epoch + t_sim instead made the value depend on where the epoch (the
    wall clock when the run began) falls within its millisecond, and on the float rounding of a 1e9 s
    sum, so a BSM's measurement time moved by 1 ms from run to run and lockstep runs did not repeat.
    """
    return (round(epoch_unix_s * 1000.0) + math.floor(t_sim * 1000.0 + 1e-6)) % 60000


def minute_of_year(unix_s: float) -> int:
    """J2735 MinuteOfTheYear of a Unix time (UTC)."""
    import datetime as dt

    moment = dt.datetime.fromtimestamp(unix_s, dt.timezone.utc)
    start = dt.datetime(moment.year, 1, 1, tzinfo=dt.timezone.utc)
    return int((moment - start).total_seconds() // 60)


class BsmStage:
    def __init__(self, station: str, origin: GeoOrigin, epoch_unix_s: float, salt: bytes, envelope, latency):
        self.key = tx_key(station)
        self.origin, self.epoch, self.salt = origin, float(epoch_unix_s), bytes(salt)
        self.envelope, self.latency = envelope, latency
        self.msg_counts: dict[int, int] = {}
        self.sent = 0
        self.sent_by_track: dict[int, int] = {}
        self.encode_s: deque[float] = deque(maxlen=20000)  # wall seconds, for the health stats
        self.sign_s: deque[float] = deque(maxlen=20000)

    def bsm_id(self, track_id: int) -> str:
        """The temporary id (hex) the BSMs of track `track_id` carry."""
        return surrogate_temporary_id(track_id, self.salt).hex()

    def bsm(self, s: TrackState, t: float):
        lat, lon, h = self.origin.to_geodetic(s.x, s.y, 0.0)
        length, width = VEHICLE_SIZE.get(s.label, VEHICLE_SIZE["car"])[:2]
        major, minor, orientation = covariance_ellipse(s.cov)
        heading = None if s.heading is None else (90.0 - math.degrees(s.heading)) % 360.0
        count = self.msg_counts.get(s.id, -1) + 1
        self.msg_counts[s.id] = count % 128
        return surrogate_bsm(
            s.id, self.salt, msg_count=count % 128, sec_mark_ms=sec_mark_ms(t, self.epoch),
            latitude=float(lat), longitude=float(lon), elevation=float(h), speed=float(s.speed), heading=heading,
            yaw_rate=0.0 if s.yaw_rate is None else round(-math.degrees(s.yaw_rate), 2), transmission="unavailable",
            width=width, length=length, semi_major=min(major, MAX_SEMI_AXIS), semi_minor=min(minor, MAX_SEMI_AXIS),
            orientation=orientation,
            emergency=EmergencyInfo(response_type="emergency") if s.label == "emergency" else None)

    def send(self, states: list[TrackState], t: float, stamps: dict[int, TrackStamps], sequential: bool
             ) -> list[Transmission]:
        """BSMs for `states` (predicted to t). `sequential`: the stages of one slot's BSMs follow each other
        (measured and realtime policies: one CPU does them in turn); else each starts at t (fixed policy)."""
        out, cursor = [], t
        for s in sorted(states, key=lambda s: s.id):
            start = cursor if sequential else t
            c0 = time.perf_counter()
            bsm = self.bsm(s, t)
            signed = sign_encoded(bsm.encode(), c0, start, PSID_SURROGATE_BSM, self.envelope, self.latency,
                                  self.epoch)
            cursor = signed.t_sign
            st = stamps.get(s.id)
            marks = signed.marks()
            if st is not None:
                marks = {**st.marks(), **marks}
            out.append(Transmission(self.key, signed.frame, signed.t_sign, marks, "bsm", bsm.temporary_id.hex(),
                                    signed.compute_s()))
            self.encode_s.append(signed.encode_s)
            self.sign_s.append(signed.sign_s)
            self.sent += 1
            self.sent_by_track[s.id] = self.sent_by_track.get(s.id, 0) + 1
        return out
