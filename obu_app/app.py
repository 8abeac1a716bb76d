"""The ev's OBU app as a process: bus, time protocol, its GNSS fixes and the V2X air in; signed SRMs out.

1. read the configuration and the station's credentials (ConfigError: exit 2);
2. open the bus the master names, subscribe to its vehicle's GNSS fixes
   (gnss/<vehicle>) and to what its station hears (v2x/rx/<station>), join;
3. lockstep: per tick, the inputs stamped up to the tick in time order
   (fixes -> its pose; MAP, SPaT, SSM verified and decoded), `EvsCore.step`,
   the SRMs it answers signed under PSID_SRM and published on
   v2x/tx/<station> at the tick, an "evsp" trace record per SRM, ack;
   realtime: the same on the master's clock;
4. at the end: one JSON summary line on stdout.

Only `bridges` of the project is imported (tests/test_boundaries.py).
"""
from __future__ import annotations

import json
import logging
import math
import signal
import sys
import threading
import time
import traceback
from collections import Counter

from bridges.j2735 import J2735Error, default_codec
from bridges.j2735.map import MapData
from bridges.j2735.signal_request import SSM_ID, Ssm
from bridges.j2735.spat import Spat
from bridges.security import (PSID_SPAT_MAP, PSID_SRM, PSID_SSM, SecurityFormatError, Signer, VerificationError,
                              Verifier, load_certificate, load_credentials, time64_us)
from bridges.security import oer
from bridges.security.oer import PROTOCOL_VERSION
from bridges.sensor_stream import GNSS_KEY, SensorStreamError, decode_fix
from bridges.timesync.errors import TimeSyncError
from bridges.timesync.exits import EXIT_CONFIG, EXIT_ERROR, EXIT_OK, SESSION_ERRORS, session_end
from bridges.timesync.participant import Participant, bus_from_env
from bridges.v2x import ENCODE, EPOCH, SEND, SIGN, rx_key, stamp_ns, trace_key, tx_key, unix_time
from obu_app.config import ConfigError, ObuConfig
from obu_app.core import EvsCore, Pose

log = logging.getLogger("obu_app")
SPAT_ID, MAP_ID = 19, 18
_PSIDS = {SPAT_ID: PSID_SPAT_MAP, MAP_ID: PSID_SPAT_MAP, SSM_ID: PSID_SSM}


class Terminated(Exception):
    pass


class ObuApp:
    def __init__(self, cfg: ObuConfig):
        self.cfg = cfg
        self.name, self.station = cfg.app.name, cfg.station
        self.signer, self.verifier = self._keys()
        self.codec = default_codec()
        self.core = EvsCore(cfg.evsp)
        self.pose: Pose | None = None
        self.heard: Counter = Counter()
        self.rejected: Counter = Counter()
        self.published = 0
        self.ticks = 0
        self.bus = self.part = None
        self.exit_reason = ""
        self._inbox: list = []
        self._lock = threading.Lock()
        self._order = 0
        self._announced = False

    def _keys(self):
        sec = self.cfg.security
        if sec.mode == "unsecured":
            return None, Verifier([], allow_unsecured=True, max_age_s=sec.max_age_s)
        pki = self.cfg.path(sec.pki_dir or ".")
        name = sec.credential or self.station
        try:
            signer = Signer(load_credentials(pki, name))
        except SecurityFormatError as exc:
            raise ConfigError([f"security.pki_dir: cannot load the credentials {name!r} from {str(pki)!r}: "
                               f"{exc.reason}"]) from None
        if PSID_SRM not in signer.credentials.certificate.psids:
            raise ConfigError([f"security.credential: certificate {name!r} may not sign SRMs (PSID {PSID_SRM:#x}); "
                               f"issue it with `v2i pki init DIR --station {name}:{PSID_SRM:#x}`"])
        anchor = self.cfg.path(sec.trust_anchor) if sec.trust_anchor else pki / "v2i-scenario-ca.cert"
        try:
            verifier = Verifier([load_certificate(anchor)], max_age_s=sec.max_age_s)
        except (SecurityFormatError, OSError) as exc:
            raise ConfigError([f"security.trust_anchor: cannot load {str(anchor)!r}: {exc}"]) from None
        return signer, verifier

    # -- inputs -------------------------------------------------------------------------------------------
    def _on(self, kind: str):
        def put(msg) -> None:
            with self._lock:
                self._order += 1
                self._inbox.append((float(msg.t_sim), 0 if kind == "gnss" else 1, self._order, kind,
                                    bytes(msg.payload)))
        return put

    def _take(self, t: float | None):
        with self._lock:
            if t is None:
                items, self._inbox = self._inbox, []
            else:
                items = [i for i in self._inbox if i[0] <= t + 1e-9]
                self._inbox = [i for i in self._inbox if i[0] > t + 1e-9]
        return sorted(items, key=lambda i: i[:3])

    def _feed(self, items) -> None:
        for t, _, _, kind, payload in items:
            if kind == "gnss":
                try:
                    fix = decode_fix(payload)
                except SensorStreamError:
                    self.rejected["gnss"] += 1
                    continue
                heading = (90.0 - math.degrees(fix.heading)) % 360.0   # rad CCW from east -> deg CW from north
                self.pose = Pose(fix.x, fix.y, heading, fix.speed)
            else:
                self._heard(payload, t)

    def _heard(self, payload: bytes, t: float) -> None:
        try:
            v = self.verifier.verify(payload, time64_us(unix_time(t, self.epoch)))
            frame = self.codec.decode(v.payload)
        except VerificationError as exc:
            self.rejected[exc.reason.value] += 1
            return
        except J2735Error:
            self.rejected["undecodable"] += 1
            return
        want = _PSIDS.get(frame.message_id)
        if want is None:
            return  # BSMs and the like: not for this app
        if v.secured and v.psid != want:
            self.rejected["psid-mismatch"] += 1
            return
        try:
            if frame.message_id == MAP_ID:
                for g in MapData.from_asn1(frame.message).intersections:
                    self.core.on_map(g)
            elif frame.message_id == SPAT_ID:
                self.core.on_spat(Spat.from_asn1(frame.message))
            else:
                self.core.on_ssm(Ssm.from_asn1(frame.message))
        except (J2735Error, KeyError, TypeError, ValueError):
            self.rejected["undecodable"] += 1
            return
        self.heard[{MAP_ID: "map", SPAT_ID: "spat", SSM_ID: "ssm"}[frame.message_id]] += 1

    # -- output -------------------------------------------------------------------------------------------
    def _step(self, t: float) -> None:
        if not self._announced:   # who the ev is, for the run's metrics, also when it only listens
            self._announced = True
            self._trace({"kind": "obu", "t": t, "vehicle": self.cfg.app.vehicle, "requests": self.cfg.evsp.enabled})
        if self.pose is None:
            return
        before = self.core.ssm_status
        for kind, srm in self.core.step(t, self.pose):
            payload = srm.encode()
            if self.signer is not None:
                frame = self.signer.sign(payload, PSID_SRM, time64_us(unix_time(t, self.epoch)))
            else:
                frame = oer.encode("Ieee1609Dot2Data", {"protocolVersion": PROTOCOL_VERSION,
                                                        "content": ("unsecuredData", payload)})
            stamps = {ENCODE: stamp_ns(t), SIGN: stamp_ns(t), SEND: stamp_ns(t)}
            try:
                self.bus.publish(tx_key(self.station), frame, t, stamps=stamps)
                self.published += 1
            except Exception as exc:
                log.warning("SRM not published: %s", exc)
            self._trace({"kind": "srm_sent", "t": t, "srm": kind, "vehicle": self.cfg.app.vehicle,
                         "lane": self.core.lane.lane_id,
                         "signal_group": self.core.lane.signal_group,
                         "to_stop_line_m": round(self.core.lane.to_stop_line_m, 3)})
        if self.core.ssm_status != before:
            self._trace({"kind": "ssm_heard", "t": t, "status": self.core.ssm_status})

    def _trace(self, rec: dict) -> None:
        rec = {"record": "evsp", **rec}
        try:
            self.bus.publish(trace_key(self.name), json.dumps(rec, separators=(",", ":")).encode(), rec["t"])
        except Exception as exc:
            log.debug("trace record not published: %s", exc)

    # -- running ------------------------------------------------------------------------------------------
    def run(self) -> int:
        cfg, code = self.cfg, EXIT_OK
        try:
            self.bus = bus_from_env(self.name, transport=cfg.bus.transport, prefix=cfg.bus.prefix,
                                    connect=",".join(cfg.bus.connect) or None)
        except (TimeSyncError, ValueError, OSError) as exc:
            print(f"obu_app: bus: {exc}", file=sys.stderr)
            return EXIT_CONFIG
        previous = signal.signal(signal.SIGTERM, self._on_sigterm)
        subs = []
        try:
            subs = [self.bus.subscribe(GNSS_KEY.format(cfg.app.vehicle), self._on("gnss")),
                    self.bus.subscribe(rx_key(self.station), self._on("v2x"))]
            self.part = Participant(self.bus, self.name, cfg.app.role,
                                    publishes=[tx_key(self.station), trace_key(self.name)])
            welcome = self.part.join(timeout=cfg.app.join_timeout_s)
            epoch = self.part.world.get(EPOCH)
            self.epoch = float(epoch) if epoch is not None else time.time()
            self.core.epoch_unix_s = self.epoch
            if welcome.mode == "lockstep":
                for tick in self.part.ticks():
                    c0 = time.perf_counter()
                    self._feed(self._take(tick.t))
                    self._step(tick.t)
                    self.part.ack(tick, time.perf_counter() - c0)
                    self.ticks += 1
            else:
                while True:
                    tick = self.part.next_tick(timeout=0.02)
                    if tick is None and self.part.ended is not None:
                        break
                    try:
                        now = self.part.sim_time_now()
                    except TimeSyncError:
                        continue
                    self._feed(self._take(None))
                    self._step(now)
                    self.ticks += tick is not None
            self.exit_reason = "the run ended"
        except SESSION_ERRORS as exc:
            print(f"obu_app: {exc}", file=sys.stderr)
            code, self.exit_reason = session_end(exc)
        except (Terminated, KeyboardInterrupt):
            self.exit_reason = "terminated by signal"
        except Exception as exc:
            traceback.print_exc()
            code, self.exit_reason = EXIT_ERROR, f"internal error: {type(exc).__name__}: {exc}"
        finally:
            signal.signal(signal.SIGTERM, previous)
            print(json.dumps(self.summary()), flush=True)
            for s in subs:
                try:
                    s.close()
                except Exception:
                    pass
            for thing in (self.part, self.bus):
                try:
                    thing is not None and thing.close()
                except Exception as exc:
                    log.debug("closing: %s", exc)
        return code

    def _on_sigterm(self, signum, frame):
        raise Terminated()

    def summary(self) -> dict:
        c = self.core
        return {"app": "obu_app", "name": self.name, "station": self.station, "exit": self.exit_reason,
                "ticks": self.ticks, "published": self.published, "state": c.state,
                "lane": None if c.lane is None else c.lane.lane_id,
                "signal_group": None if c.lane is None else c.lane.signal_group,
                "srm_sent": dict(c.sent), "first_request_t": c.t_first_request, "cancel_t": c.t_cancelled,
                "ssm_status": c.ssm_status, "signal_state": c.signal_state, "heard": dict(self.heard),
                "rejected": dict(self.rejected)}
