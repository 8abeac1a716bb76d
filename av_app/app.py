"""The AV app as a process: bus, time protocol, CAN, and the core's inputs in time order.

Lockstep (the deterministic mode). The master publishes everything of time t
(AV_Status on CAN, GNSS fixes, lidar scans, V2X frames arriving by t) before
its tick of t, on different channels. At each tick the app:

1. waits, bounded by `app.sensor_wait_s`, for any AV_Status, GNSS fix or lidar
   scan that is due by t (their rates are known) but not here yet;
2. hands every input stamped <= t to the core, in (time, kind, sequence)
   order: statuses and fixes first, then scans, then V2X frames;
3. answers the AV_Status of time t with exactly one AV_Command echoing its
   counter (the gateway applies it at t + one step), and publishes the trace
   record of each V2X frame that command is the first to use;
4. acknowledges the tick.

So a command for status t depends only on data stamped <= t. With the
participant ticking at least as often as the status (`sync_every` x step <= the
status period; sync_every = 1 is the natural choice) this is exact; with
sparser ticks, statuses between ticks are answered as they come from the data
of the last tick (reproducibility is then lost, and the summary says so).

Realtime: nothing waits; each AV_Status is answered as it arrives, stamped with
the simulation time read off the master's clock mapping.
"""
from __future__ import annotations

import json
import logging
import math
import sys
import threading
import time
from typing import Any

from bridges.geo import GeoOrigin
from bridges.sensor_stream import GNSS_KEY, LIDAR_KEY, SensorStreamError, decode_fix, decode_scan
from bridges.security import Verifier, load_certificate
from bridges.security.oer import SecurityFormatError
from bridges.timesync.errors import JoinTimeout, MasterLost, Refused, TimeSyncError
from bridges.timesync.exits import (EXIT_CONFIG, EXIT_ERROR, EXIT_MASTER_LOST, EXIT_NO_MASTER, EXIT_OK,
                                    EXIT_REFUSED)
from bridges.timesync.participant import Participant, bus_from_env
from bridges.v2x import EPOCH, rx_key, trace_key

from av_app.can_driver import CanDriver
from av_app.config import AvConfig, ConfigError
from av_app.core import AvCore
from av_app.obu import Obu
from av_app.timing import StageClock

log = logging.getLogger("av_app")

_ORDER = {"gnss": 1, "lidar": 2, "v2x": 3}  # statuses are 0: fed first at each time


class Due:
    """Samples of a stream at start + n / rate: which one is due at a tick, has it arrived?"""

    def __init__(self, rate_hz: float, start: float):
        self.rate, self.start = rate_hz, start
        self.seen = False  # the stream exists (only a stream seen once is waited for)
        self.next_n = 0
        self.misses = 0
        self.late = 0

    def got(self, t: float) -> None:
        if self.rate <= 0:
            return
        self.seen = True
        self.misses = 0
        n = math.floor((t - self.start) * self.rate + 1e-6) + 1
        self.next_n = max(self.next_n, n)

    def waiting(self, t: float) -> bool:
        """Is a sample due by t that has not arrived?"""
        if self.rate <= 0 or not self.seen or self.misses >= 3:
            return False
        return self.start + self.next_n / self.rate <= t + 1e-6

    def give_up(self, t: float) -> None:
        self.late += 1
        self.misses += 1
        self.next_n = math.floor((t - self.start) * self.rate + 1e-6) + 1


class AvApp:
    def __init__(self, cfg: AvConfig):
        self.cfg = cfg
        self.name = cfg.app.name
        self.bus = None
        self.part: Participant | None = None
        self.can: CanDriver | None = None
        self.core: AvCore | None = None
        self._inbox: list[tuple[float, int, int, str, Any]] = []
        self._lock = threading.Condition()
        self._order = 0
        self._subs = []
        self.summary: dict[str, Any] = {"name": self.name}
        self.statuses_between_ticks = 0
        self._last_stats = time.monotonic()
        self._hb_n = -1
        path = cfg.path(cfg.app.plan_log)
        self._plan_log = open(path, "w", buffering=1) if path is not None else None

    # -- set-up ---------------------------------------------------------------------------------------------
    def _verifier(self) -> Verifier | None:
        sec = self.cfg.security
        anchors = []
        path = self.cfg.path(sec.trust_anchor)
        if path is not None:
            try:
                anchors.append(load_certificate(path))
            except SecurityFormatError as exc:
                raise ConfigError([f"security.trust_anchor: {exc}"]) from None
        try:
            return Verifier(anchors, max_age_s=sec.max_age_s, max_future_s=sec.max_future_s,
                            allow_unsecured=sec.allow_unsecured)
        except ValueError as exc:
            raise ConfigError([f"security.trust_anchor: {exc}"]) from None

    def _on(self, kind: str):
        def put(msg) -> None:
            with self._lock:
                self._order += 1
                self._inbox.append((msg.t_sim, _ORDER[kind], self._order, kind, msg))
                self._lock.notify_all()
        return put

    def open(self) -> None:
        cfg = self.cfg
        verifier = self._verifier()
        try:
            self.can = CanDriver(cfg.can, cfg.path(cfg.can.dbc))
        except ValueError as exc:  # a bad DBC or bus setting
            raise ConfigError([f"can: {exc}"]) from None
        try:
            self.bus = bus_from_env(self.name, transport=cfg.bus.transport or None, prefix=cfg.bus.prefix or None,
                                    connect=",".join(cfg.bus.connect) or None)
        except TimeSyncError as exc:
            raise ConfigError([f"bus: {exc}"]) from None
        self._subs = [self.bus.subscribe(rx_key(cfg.app.station), self._on("v2x")),
                      self.bus.subscribe(GNSS_KEY.format(cfg.app.vehicle), self._on("gnss"))]
        if cfg.perception.enabled:
            self._subs.append(self.bus.subscribe(LIDAR_KEY.format(cfg.app.vehicle), self._on("lidar")))
        self.part = Participant(self.bus, self.name, cfg.app.role, publishes=[trace_key(self.name)])
        welcome = self.part.join(timeout=cfg.app.join_timeout_s)
        world = self.part.world
        origin = self.part.origin or GeoOrigin()
        epoch = world.get(EPOCH)
        if epoch is None:
            epoch = time.time()
            log.warning("%s: the master sent no %s; dating messages from the join time", self.name, EPOCH)
        policy = welcome.latency_policy if welcome.mode == "lockstep" else "realtime"
        # realtime: the master's clock mapping comes with its first step; work done before it (a first lidar
        # scan) counts at its input's own time (the fallback the clock is given, here minus infinity)
        clock = StageClock(policy, welcome.latencies, cfg.latency, now=lambda: self._now(float("-inf")))
        self.core = AvCore(cfg, Obu(cfg.obu, origin, epoch, verifier), clock, world)
        self.summary.update(mode=welcome.mode, latency=clock.describe(), sync_every=welcome.sync_every,
                            origin=origin.to_dict(), station=cfg.app.station, vehicle=cfg.app.vehicle)
        log.info("%s joined: %s, latency %s, station %s", self.name, welcome.mode, clock.describe(),
                 cfg.app.station)

    # -- inputs ---------------------------------------------------------------------------------------------------
    def _take(self, t: float | None) -> list[tuple[float, int, int, str, Any]]:
        """Inbox items stamped <= t (all when t is None), in time order."""
        with self._lock:
            if t is None:
                items, self._inbox = self._inbox, []
            else:
                items = [i for i in self._inbox if i[0] <= t + 1e-9]
                self._inbox = [i for i in self._inbox if i[0] > t + 1e-9]
        items.sort(key=lambda i: i[:3])
        return items

    def _feed(self, items, realtime: bool = False) -> None:
        core = self.core
        for t_sim, _, _, kind, msg in items:
            if kind == "gnss":
                try:
                    fix = decode_fix(msg.payload)
                except SensorStreamError as exc:
                    core.health.garbage["gnss"] += 1
                    log.debug("bad GNSS fix: %s", exc)
                    continue
                core.on_gnss(fix)
            elif kind == "lidar":
                try:
                    scan = decode_scan(msg.payload)  # its per-point labels are ground truth: never read
                except SensorStreamError as exc:
                    core.health.garbage["lidar"] += 1
                    log.debug("bad lidar scan: %s", exc)
                    continue
                core.on_lidar(scan.t, scan.points)
            elif kind == "v2x":
                t_rx = self._now(t_sim) if realtime else None
                core.on_v2x(msg.payload, msg.t_sim, msg.stamps, t_receive=t_rx)

    def _send(self, echo: int):
        def send(accel, steer, mode) -> int:
            return self.can.send_command(accel, steer, mode, echo)
        return send

    def _answer(self, t: float, echo: int) -> None:
        records = self.core.command(t, self._send(echo))
        if self._plan_log is not None:
            self._plan_log.write(json.dumps(self.core.plan_record(t), separators=(",", ":")) + "\n")
        for rec in records:
            try:
                self.bus.publish(trace_key(self.name), json.dumps(rec, separators=(",", ":")).encode(),
                                 AvCore.record_time(rec), stamps=rec["stamps"])
            except Exception as exc:  # a trace that cannot go out is counted, the vehicle keeps driving
                self.core.health.garbage["trace_publish"] += 1
                log.debug("trace record not published: %s", exc)
        self.core.health.counts["trace_records"] += len(records)

    def _heartbeat(self, t: float) -> None:
        hz = self.cfg.can.heartbeat_hz
        if hz <= 0:
            return
        n = math.floor(t * hz + 1e-6)
        if n != self._hb_n:
            self._hb_n = n
            self.can.send_heartbeat(self.core.app_state(t))

    def _stats(self, t: float | None) -> None:
        every = self.cfg.app.stats_every_s
        if every > 0 and time.monotonic() - self._last_stats >= every:
            self._last_stats = time.monotonic()
            print(self.core.health.line(self.name, round(t, 3) if t is not None else None, self.core.obu, self.can),
                  file=sys.stderr, flush=True)

    # -- the loops --------------------------------------------------------------------------------------------
    def run(self) -> int:
        self.open()
        w = self.part.welcome
        try:
            if w.mode == "lockstep":
                self._lockstep()
            else:
                self._realtime()
        finally:
            self.summary["end"] = self.part.ended.status if self.part.ended else None
        return EXIT_OK

    def _wait_due(self, t: float, dues: dict[str, Due], status_due: Due, statuses: list) -> None:
        deadline = time.monotonic() + self.cfg.app.sensor_wait_s
        while True:
            if status_due.waiting(t) and not statuses:
                got = self.can.poll(timeout=0.002)
                statuses.extend(got)
                if got:
                    status_due.got(t)
            missing = [k for k, d in dues.items() if d.waiting(t)]
            if not missing and not (status_due.waiting(t) and not statuses):
                return
            if time.monotonic() >= deadline:
                for k in missing:
                    dues[k].give_up(t)
                    self.core.health.counts[f"late_{k}"] += 1
                if status_due.waiting(t) and not statuses:
                    status_due.give_up(t)
                    self.core.health.counts["late_status"] += 1
                return
            with self._lock:
                for k in missing:  # anything that arrived meanwhile counts
                    for item in self._inbox:
                        if item[3] == k and item[0] <= t + 1e-9:
                            dues[k].got(item[0])
                if [k for k, d in dues.items() if d.waiting(t)]:
                    self._lock.wait(0.002)

    def _lockstep(self) -> None:
        part, core, cfg = self.part, self.core, self.cfg
        ticks_ok = None  # does every status fall on a tick? decided at the first tick
        dues: dict[str, Due] = {}
        status_due: Due | None = None
        last_t = None
        while True:
            tick = part.next_tick(timeout=0.005)
            if tick is None:
                if part.ended is not None:
                    break
                if ticks_ok is False:  # sparse ticks: answer statuses as they come, from the last tick's data
                    for st in self.can.poll(0.0):
                        self.statuses_between_ticks += 1
                        core.on_status(last_t or 0.0, st.status.speed, st.status.yaw_rate)
                        self._answer(last_t or 0.0, st.status.counter)
                continue
            w0 = time.perf_counter()
            t = tick.t
            if ticks_ok is None:
                tick_period = part.welcome.sync_every * tick.step
                ticks_ok = tick_period <= 1.0 / cfg.can.status_rate_hz + 1e-9
                if not ticks_ok:
                    log.warning("%s: ticks every %g s are sparser than AV_Status (every %g s): statuses are "
                                "answered between ticks; this run is not reproducible", self.name, tick_period,
                                1.0 / cfg.can.status_rate_hz)
                self.summary["statuses_on_ticks"] = ticks_ok
                dues = {"gnss": Due(cfg.ego.gnss_rate_hz, t), "lidar": Due(cfg.perception.rate_hz, t)}
                if not cfg.perception.enabled:
                    dues.pop("lidar")
                status_due = Due(cfg.can.status_rate_hz, t)
            with self._lock:
                for item in self._inbox:
                    if item[3] in dues and item[0] <= t + 1e-9:
                        dues[item[3]].got(item[0])
            statuses = self.can.poll(0.0)
            if statuses:
                status_due.got(t)
            if ticks_ok:
                self._wait_due(t, dues, status_due, statuses)
            items = self._take(t)
            for k in {i[3] for i in items}:
                if k in dues:
                    for i in items:
                        if i[3] == k:
                            dues[k].got(i[0])
            # the status of time t first (the ego filter advances to t), then sensors and frames <= t
            for st in statuses:
                core.on_status(t, st.status.speed, st.status.yaw_rate)
            self._feed(items)
            for st in statuses:  # one command per status (normally exactly one)
                self._answer(t, st.status.counter)
            if len(statuses) > 1:
                core.health.counts["statuses_stacked"] += len(statuses) - 1
            self._heartbeat(t)
            self._stats(t)
            last_t = t
            part.ack(tick, time.perf_counter() - w0)

    def _now(self, fallback: float = 0.0) -> float:
        """Simulation time now (realtime runs); before the master's first clock mapping, `fallback`."""
        return self.part.sim_time_now() if self.part.mapping is not None else fallback

    def _realtime(self) -> None:
        part, core = self.part, self.core
        t = 0.0
        while part.ended is None:
            part.next_tick(timeout=0.0)  # keeps the master-lost check; ticks carry nothing else here
            statuses = self.can.poll(timeout=0.005)
            self._feed(self._take(None), realtime=True)
            for st in statuses:
                t = max(t, self._now(t))
                core.on_status(t, st.status.speed, st.status.yaw_rate)
                self._answer(t, st.status.counter)
            t = max(t, self._now(t))
            self._heartbeat(t)
            self._stats(t)

    # -- the end ---------------------------------------------------------------------------------------------
    def close(self) -> dict[str, Any]:
        core, can = self.core, self.can
        if core is not None:
            s = self.summary
            s["obu"] = {"received": core.obu.received, "accepted": dict(core.obu.accepted),
                        "rejected": dict(core.obu.rejected)}
            s.update(core.health.summary())
            s["ego"] = {"fixes": core.ego.fixes, "statuses": core.ego.statuses, "rejected": core.ego.rejected,
                        "resets": core.ego.resets}
            s["lidar"] = {"scans": core.tracker.scans, "tracks": len(core.tracker.tracks)}
            s["statuses_between_ticks"] = self.statuses_between_ticks
        if can is not None:
            self.summary["can"] = {"sent": dict(can.sent), "rejected": dict(can.rejected),
                                   "ignored": dict(can.ignored), "send_errors": can.send_errors,
                                   "counter_gaps": can.checker.counter_gaps}
            can.close()
        if self.part is not None:
            self.summary["protocol_errors"] = dict(self.part.errors)
            if self.bus is not None:
                self.summary["bus"] = {k: v for k, v in self.bus.stats().items() if v}
            try:
                self.part.close()
            except Exception:
                pass
        if self._plan_log is not None:
            self._plan_log.close()
        for sub in self._subs:
            try:
                sub.close()
            except Exception:
                pass
        if self.bus is not None:
            try:
                self.bus.close()
            except Exception:
                pass
        return self.summary


def run_app(cfg: AvConfig) -> int:
    app = AvApp(cfg)
    code = EXIT_OK
    try:
        code = app.run()
    except ConfigError as exc:
        for p in exc.problems:
            print(f"{exc.source}: {p}", file=sys.stderr)
        code = EXIT_CONFIG
    except Refused as exc:
        print(exc, file=sys.stderr)
        app.summary["refused"] = exc.reason
        code = EXIT_REFUSED
    except JoinTimeout as exc:
        print(exc, file=sys.stderr)
        code = EXIT_NO_MASTER
    except MasterLost as exc:
        print(exc, file=sys.stderr)
        code = EXIT_MASTER_LOST
    except KeyboardInterrupt:
        code = EXIT_ERROR
    except Exception as exc:  # a bug: say it, keep the summary
        log.exception("av_app failed")
        app.summary["crash"] = f"{type(exc).__name__}: {exc}"
        code = EXIT_ERROR
    finally:
        summary = app.close()
        summary["exit_code"] = code
        print(json.dumps(summary, default=str), flush=True)
    return code


__all__ = ["AvApp", "run_app", "Due"]
