"""The app side of the time protocol: join the master, follow its ticks, acknowledge them.

    p = Participant(bus, "rsu1", "rsu_app", publishes=["v2x/tx/rsu1"])
    p.join(timeout=10)                      # Refused / JoinTimeout on failure
    for tick in p.ticks():                  # ends when the master ends the run
        ...work for simulation time tick.t...
        t_out = p.output_time("detect", processing_s)   # per the run's latency policy
        bus.publish("v2x/tx/rsu1", frame, t_out)
        p.ack(tick)
    p.leave()

In realtime runs `ack` is a no-op (the master never waits), `sim_time_now()`
follows the master's published mapping through the estimated clock offset, and
`master_time_ns()` gives timestamps on the master's clock. Heartbeats go out
from a thread; nothing from the master for `master_timeout_s` raises MasterLost
from `ticks()`, so an orphaned app never hangs.
"""
from __future__ import annotations

import json
import logging
import os
import queue
import socket
import threading
import time
import uuid
from collections import Counter
from typing import Callable, Iterator

from bridges.timesync import lifeline
from bridges.timesync import messages as m
from bridges.timesync.clock import OffsetSample, TimeMapping, best_sample, offset_sample
from bridges.timesync.errors import JoinTimeout, MasterLost, ProtocolError, Refused, TimeSyncError

log = logging.getLogger(__name__)
_END = object()  # sentinel in the tick queue


def bus_from_env(sender: str, *, transport: str | None = None, prefix: str | None = None,
                 connect: str | None = None, environ=os.environ):
    """The bus the master told us to use: V2I_BUS, V2I_PREFIX, V2I_CONNECT (comma-separated endpoints)
    and V2I_BUS_OPTIONS (a JSON object of further transport options); arguments win over the environment."""
    transport = transport or environ.get("V2I_BUS")
    prefix = prefix or environ.get("V2I_PREFIX")
    if not transport or not prefix:
        raise TimeSyncError("no bus configured: set V2I_BUS and V2I_PREFIX (the master sets them for the "
                            "participants it starts) or pass the transport and prefix explicitly")
    try:
        options = json.loads(environ.get("V2I_BUS_OPTIONS") or "{}")
    except ValueError as exc:
        raise TimeSyncError(f"V2I_BUS_OPTIONS is not a JSON object: {exc}") from None
    if not isinstance(options, dict):
        raise TimeSyncError(f"V2I_BUS_OPTIONS must be a JSON object, got {type(options).__name__}")
    connect = connect or environ.get("V2I_CONNECT")
    if connect:
        options["connect"] = [c.strip() for c in connect.split(",") if c.strip()]
    from bridges.transport import open_bus

    return open_bus(transport, prefix=prefix, sender=sender, **options)


class Participant:
    def __init__(self, bus, name: str, role: str, publishes=(), *, clock_ns: Callable[[], int] = time.time_ns,
                 version=m.PROTOCOL_VERSION, auto_offset: bool = True):
        if not m.NAME.match(name):
            raise ValueError(f"participant name {name!r} must be letters, digits, _ or - (at most 64)")
        self.bus, self.name, self.role, self.publishes = bus, name, role, list(publishes)
        self.clock_ns, self.version, self.auto_offset = clock_ns, list(version), auto_offset
        self.session = uuid.uuid4().hex[:12]
        self.welcome: m.Welcome | None = None
        self.ended: m.End | None = None
        self.mapping: TimeMapping | None = None
        self._last_sim_time = float("-inf")  # realtime: sim_time_now() never returns less than it did
        self.offset: OffsetSample | None = None
        self.tick: m.Tick | None = None  # the tick being worked on (last delivered)
        self.errors: Counter = Counter()  # bad payloads, by reason; never raised from a callback
        self.skipped_ticks = 0  # realtime: ticks passed over because the app was busy
        self.stale_acks = 0  # lockstep: acks not sent, a newer tick having come (a late join's first tick)
        self._lock = threading.Lock()
        self._clock_lock = threading.Lock()  # sim_time_now's read-max-write of _last_sim_time, across threads
        self._ticks: queue.Queue = queue.Queue()
        self._welcomes: queue.Queue = queue.Queue()
        self._pongs: queue.Queue = queue.Queue()
        self._early_tick: m.Tick | None = None
        self._delivered_k = -1
        self._acked: m.Ack | None = None
        self._last_master = time.monotonic()
        self._stop = threading.Event()
        self._hb_thread: threading.Thread | None = None
        self._ping_id = 0
        self._subs = [bus.subscribe(k, self._on_message) for k in (
            m.key(m.WELCOME, name), m.TICK, m.END, m.MAPPING, m.BEAT, m.key(m.PONG, name))]

    # -- joining -------------------------------------------------------------
    def join(self, timeout: float = 10.0, retry_s: float = 0.25) -> m.Welcome:
        """Register with the master (repeating the request until answered); Refused says why not."""
        lifeline.arm()  # started by the master: die with it (no orphan after a kill -9 of the master)
        join = m.Join(self.name, self.role, self.session, self.publishes, self.version, os.getpid(),
                      socket.gethostname())
        deadline = time.monotonic() + timeout
        while True:
            self.bus.publish(m.key(m.JOIN, self.name), m.encode(join), 0.0)
            try:
                welcome = self._welcomes.get(timeout=max(0.0, min(retry_s, deadline - time.monotonic())))
            except queue.Empty:
                if time.monotonic() >= deadline:
                    raise JoinTimeout([self.name], timeout, ": no answer from the master (is it running, "
                                                            "same transport and prefix?)") from None
                continue
            if not welcome.accepted:
                raise Refused(self.name, welcome.reason)
            break
        with self._lock:
            self.welcome = welcome
            early, self._early_tick = self._early_tick, None
        self._hb_thread = threading.Thread(target=self._heartbeats, name=f"hb-{self.name}", daemon=True)
        self._hb_thread.start()
        if early is not None:
            self._accept_tick(early)
        if self.auto_offset and welcome.mode == "realtime":
            try:
                self.estimate_offset()
            except TimeSyncError as exc:
                log.warning("%s: clock offset not estimated: %s", self.name, exc)
        return welcome

    @property
    def mode(self) -> str | None:
        return self.welcome.mode if self.welcome else None

    @property
    def world(self) -> dict:
        """What the master told us of the scenario's world in its welcome (empty before joining)."""
        return dict(self.welcome.world) if self.welcome else {}

    @property
    def origin(self):
        """The scenario's geodetic origin (bridges.geo.GeoOrigin) from the welcome; None if the master sent none."""
        from bridges.geo import GeoOrigin

        d = self.world.get("origin")
        return GeoOrigin.from_dict(d) if d is not None else None

    # -- ticks ------------------------------------------------------------------
    def next_tick(self, timeout: float | None = None) -> m.Tick | None:
        """The next tick, or None when the run ended (or on timeout); MasterLost if the master went silent."""
        if self.welcome is None:
            raise TimeSyncError(f"participant '{self.name}' has not joined")
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            wait = 0.2 if deadline is None else max(0.0, min(0.2, deadline - time.monotonic()))
            try:
                item = self._ticks.get(timeout=wait)
            except queue.Empty:
                silent = time.monotonic() - self._last_master
                if silent > self.welcome.master_timeout_s:
                    raise MasterLost(f"participant '{self.name}': nothing from the master for {silent:.1f} s "
                                     f"(limit {self.welcome.master_timeout_s:g} s)") from None
                if deadline is not None and time.monotonic() >= deadline:
                    return None
                continue
            if item is _END:
                self._ticks.put(_END)  # stays ended for every later call
                return None
            if self.welcome.mode == "realtime":  # running free: an app that fell behind gets the newest tick
                item = self._newest(item)
            self.tick = item
            return item

    def _newest(self, tick: m.Tick) -> m.Tick:
        while True:
            try:
                nxt = self._ticks.get_nowait()
            except queue.Empty:
                return tick
            if nxt is _END:
                self._ticks.put(_END)
                return tick
            self.skipped_ticks += 1
            tick = nxt

    def ticks(self) -> Iterator[m.Tick]:
        while (tick := self.next_tick()) is not None:
            yield tick

    def ack(self, tick: m.Tick, processing_s: float | None = None) -> None:
        """Done with everything up to `tick` (lockstep); a no-op in realtime runs."""
        if self.mode != "lockstep" or self.ended is not None:
            return
        if self.tick is not None and tick.k == self.tick.k < self._delivered_k:
            # a newer tick came while this one was worked on: the master did not wait for this ack (the tick
            # was in progress when we joined), so there is nobody to send it to. A box that joins a running
            # run meets this with its first tick; the next one is waited for.
            with self._lock:
                self.stale_acks += 1
            return
        if tick.k != self._delivered_k:
            raise ValueError(f"participant '{self.name}': ack of tick {tick.k}, but the current tick is "
                             f"{self._delivered_k} (acknowledge each tick once, in order)")
        ack = m.Ack(self.name, self.session, tick.k, -1.0 if processing_s is None else float(processing_s))
        with self._lock:
            self._acked = ack
        self.bus.publish(m.key(m.ACK, self.name), m.encode(ack), tick.t)

    def run(self, work: Callable[[m.Tick], float | None]) -> None:
        """Callback style: `work(tick)` for every tick (may return its processing seconds), then ack."""
        for tick in self.ticks():
            self.ack(tick, work(tick))

    # -- time -------------------------------------------------------------------
    def output_time(self, stage: str, processing_s: float | None = None, tick: m.Tick | None = None) -> float:
        """Simulation time of an output produced for `tick` (default: the current one), per the latency policy.

        fixed: tick.t + the configured latency of `stage`; measured: tick.t + processing_s;
        realtime runs: the simulation time now (the wall clock already charged the work).
        """
        w = self.welcome
        if w is None:
            raise TimeSyncError(f"participant '{self.name}' has not joined")
        if w.mode == "realtime":
            return self.sim_time_now()
        tick = tick or self.tick
        if tick is None:
            raise TimeSyncError(f"participant '{self.name}': no tick yet, so no output time")
        if w.latency_policy == "fixed":
            if stage not in w.latencies:
                configured = ", ".join(sorted(w.latencies)) or "none"
                raise ValueError(f"participant '{self.name}': no fixed latency for stage {stage!r} (configured: "
                                 f"{configured}); set it in [participants.{self.name}.latencies]")
            return tick.t + float(w.latencies[stage])
        if processing_s is None:
            raise ValueError(f"participant '{self.name}': the 'measured' latency policy needs processing_s "
                             f"for stage {stage!r}")
        return tick.t + float(processing_s)

    def master_time_ns(self) -> int:
        """Now on the master's clock (local clock + estimated offset)."""
        return self.clock_ns() + (self.offset.offset_ns if self.offset else 0)

    def sim_time_now(self) -> float:
        """Simulation time now: from the mapping in realtime runs, the current tick's time in lockstep."""
        if self.mode == "realtime":
            if self.mapping is None:
                raise TimeSyncError(f"participant '{self.name}': no time mapping from the master yet")
            # the master's mapping only slews forward, but a new one arrives a bus delay late and the
            # offset estimate is refreshed: read through both, the clock still never goes back
            # under a lock of its own: the app's tick thread and its stages (camera ingest, the latency
            # model) read the clock at once, and an unguarded read-max-write let a thread that read the
            # mapping first store its older time after another had returned a newer one
            with self._clock_lock:
                now = max(self._last_sim_time, self.mapping.sim_time(self.master_time_ns()))
                self._last_sim_time = now
            return now
        if self.tick is None:
            raise TimeSyncError(f"participant '{self.name}': no tick yet")
        return self.tick.t

    def estimate_offset(self, exchanges: int = 8, timeout: float = 1.0) -> OffsetSample:
        """Ping/pong with the master, keep the minimum-RTT sample, report it; returns it."""
        samples = []
        for _ in range(exchanges):
            with self._lock:
                self._ping_id += 1
                ping_id = self._ping_id
            t1 = self.clock_ns()
            self.bus.publish(m.key(m.PING, self.name), m.encode(m.Ping(self.name, ping_id, t1)), 0.0)
            deadline = time.monotonic() + timeout
            while (left := deadline - time.monotonic()) > 0:
                try:
                    pong, t4 = self._pongs.get(timeout=left)
                except queue.Empty:
                    break
                if pong.id == ping_id and pong.t1_ns == t1:
                    samples.append(offset_sample(pong.t1_ns, pong.t2_ns, pong.t3_ns, t4))
                    break
                self.errors["stale pong"] += 1
        if not samples:
            raise TimeSyncError(f"participant '{self.name}': no pong from the master in {exchanges} pings")
        self.offset = best_sample(samples)
        report = m.Offset(self.name, self.session, self.offset.offset_ns, self.offset.rtt_ns, len(samples))
        self.bus.publish(m.key(m.OFFSET, self.name), m.encode(report), 0.0)
        return self.offset

    # -- leaving ------------------------------------------------------------------
    def leave(self, reason: str = "done") -> None:
        """Tell the master we go (it ends the run unless we are optional) and stop heartbeats."""
        if self.welcome is not None and self.ended is None and not self._stop.is_set():
            self.bus.publish(m.key(m.LEAVE, self.name), m.encode(m.Leave(self.name, self.session, reason)), 0.0)
        self.close()

    def close(self) -> None:
        self._stop.set()
        if self._hb_thread is not None and self._hb_thread is not threading.current_thread():
            self._hb_thread.join(timeout=2.0)
        for sub in self._subs:
            try:
                sub.close()
            except Exception as exc:  # closing twice or a bus already gone
                log.debug("%s: closing a subscription: %s", self.name, exc)
        self._subs = []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.leave("exception" if exc[0] else "done")

    # -- internals ------------------------------------------------------------------
    def _heartbeats(self) -> None:
        n = 0
        period = self.welcome.heartbeat_s
        while not self._stop.wait(period):
            n += 1
            try:
                self.bus.publish(m.key(m.HEARTBEAT, self.name), m.encode(m.Heartbeat(self.name, self.session, n)), 0.0)
            except Exception as exc:  # bus closed under us: stop quietly
                log.debug("%s: heartbeat not sent: %s", self.name, exc)
                return

    def _on_message(self, msg) -> None:
        t4 = self.clock_ns()
        try:
            body = m.decode(msg.payload)
        except ProtocolError as exc:
            self.errors[str(exc)[:120]] += 1
            log.warning("%s: ignored a bad message on %s: %s", self.name, msg.key, exc)
            return
        self._last_master = time.monotonic()
        if isinstance(body, m.Tick):
            with self._lock:
                if self.welcome is None:
                    self._early_tick = body  # the tick may overtake our welcome
                    return
            self._accept_tick(body)
        elif isinstance(body, m.Welcome):
            if body.session == self.session and body.name == self.name and self.welcome is None:
                self._welcomes.put(body)
        elif isinstance(body, m.Pong):
            self._pongs.put((body, t4))
        elif isinstance(body, m.Mapping):
            self.mapping = TimeMapping(body.t_sim0, body.wall0_ns, body.rtf)
        elif isinstance(body, m.End):
            if self.ended is None:
                self.ended = body
                self._stop.set()
                self._ticks.put(_END)

    def _accept_tick(self, tick: m.Tick) -> None:
        w = self.welcome
        if tick.k % max(1, w.sync_every):
            return
        with self._lock:
            acked = self._acked
            if acked is not None and tick.k == acked.k:  # the master repeats a tick when our ack got lost
                resend = True
            elif tick.k <= self._delivered_k:
                return  # already being worked on
            else:
                resend = False
                self._delivered_k = tick.k
        if resend:
            self.bus.publish(m.key(m.ACK, self.name), m.encode(acked), tick.t)
        else:
            self._ticks.put(tick)
