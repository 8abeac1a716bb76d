"""What every participant app repeats, written once: open the bus the master named, keep what arrives in a
time-ordered inbox, join, follow the master's clock (lockstep ticks or the realtime mapping), publish, trace.

    s = AppSession("hello", "hello_app", listen=[rx_key("hello")], publishes=[tx_key("hello")])
    s.open(join_timeout_s=20)                      # bus from V2I_* (the master sets them); Refused, JoinTimeout
    for step in s.steps():                         # ends when the master ends the run
        for msg in step.heard: ...                 # bus Messages with t_sim <= step.t, oldest first
        s.publish(tx_key("hello"), frame, s.output_time("send"))
        s.trace({"what": "sent"}, step.t, stamps={"send": stamp_ns(step.t)})
    s.close()

Why a helper: the RSU app, the AV app and the attacker each carry their own copy of this loop. A new app (the
guide's example, docs/writing-an-app.md) should not have to learn its fine points to be correct:

* lockstep: a step is one tick; the tick is acknowledged when the body of the loop is done (the generator
  resumes), with the body's wall time as its processing time, so the `measured` latency policy charges it.
  Frames are handed over only once the simulation reached their time, so a run repeats bit for bit;
* realtime: the master never waits, so a step is "now" on the master's clock (`Participant.sim_time_now`),
  taken every `poll_s` wall seconds, and the inbox is drained up to it;
* a publish that fails (a closed bus at the very end) is counted, never raised: the run goes on;
* trace records go to `trace/<name>` (bridges.v2x.trace_key), where the master keeps them in the run's
  trace.jsonl and its latency metrics read their stamps.

Imports only `bridges`, like every module here.
"""
from __future__ import annotations

import heapq
import itertools
import json
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Iterator

from bridges.geo import GeoOrigin
from bridges.timesync.errors import TimeSyncError
from bridges.timesync.participant import Participant, bus_from_env
from bridges.v2x import EPOCH, trace_key

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Step:
    """One step of the app: its simulation time and what was heard up to it."""

    t: float  # simulation time (s) the app works at now
    until: float  # lockstep: the next tick's time (what is due before it belongs to this step); realtime: t
    heard: list = field(default_factory=list)  # bridges.transport Messages with t_sim <= t, oldest first


class AppSession:
    """One app's session with the master: bus, inbox, join, steps, publish, trace, close."""

    def __init__(self, name: str, role: str, *, listen=(), publishes=(), bus=None, poll_s: float = 0.005):
        self.name, self.role = name, role
        self.listen, self.publishes = list(listen), list(publishes)
        self.bus, self._own_bus = bus, bus is None
        self.poll_s = poll_s
        self.part: Participant | None = None
        self.epoch_from_master = True
        self.ticks = self.heard = self.published = self.publish_errors = 0
        self._inbox: list = []
        self._order = itertools.count()
        self._lock = threading.Lock()
        self._subs: list = []
        self._t0 = time.perf_counter()

    # -- joining -----------------------------------------------------------------------------------------
    def open(self, join_timeout_s: float = 20.0, **bus_args: Any):
        """Open the bus (V2I_* unless one was given; `bus_args` as bus_from_env's), subscribe, join.

        Returns the master's Welcome; Refused / JoinTimeout (bridges.timesync.errors) when it cannot join.
        """
        if self.bus is None:
            self.bus = bus_from_env(self.name, **bus_args)
        self._subs = [self.bus.subscribe(key, self._hear) for key in self.listen]
        self.part = Participant(self.bus, self.name, self.role, publishes=self.publishes + [trace_key(self.name)])
        return self.part.join(timeout=join_timeout_s)

    @property
    def mode(self) -> str | None:
        return self.part.mode if self.part else None

    @property
    def world(self) -> dict:
        return self.part.world if self.part else {}

    @property
    def origin(self) -> GeoOrigin:
        """The scenario's geodetic origin (the default one when the master sent none)."""
        return (self.part.origin if self.part else None) or GeoOrigin()

    @property
    def epoch(self) -> float:
        """The Unix time simulation time 0 stands for (J2735 secMark, 1609.2 generation times).

        From the master's welcome; without one, this app's join time (`epoch_from_master` turns False).
        """
        epoch = self.world.get(EPOCH)
        if epoch is None:
            self.epoch_from_master = False
            epoch = self.__dict__.setdefault("_own_epoch", time.time())
        return float(epoch)

    # -- the clock ---------------------------------------------------------------------------------------
    def _hear(self, msg) -> None:
        with self._lock:
            heapq.heappush(self._inbox, (msg.t_sim, next(self._order), msg))

    def _take(self, t: float) -> list:
        out = []
        with self._lock:
            while self._inbox and self._inbox[0][0] <= t + 1e-9:
                out.append(heapq.heappop(self._inbox)[2])
        self.heard += len(out)
        return out

    def steps(self) -> Iterator[Step]:
        """The app's steps until the master ends the run (MasterLost if it goes silent)."""
        if self.part is None or self.part.welcome is None:
            raise TimeSyncError(f"app '{self.name}': open() (join) before steps()")
        welcome = self.part.welcome
        if welcome.mode == "lockstep":
            period = max(1, int(welcome.sync_every or 1))
            for tick in self.part.ticks():
                self._t0 = time.perf_counter()
                step = float(tick.step or 0.0)
                yield Step(tick.t, tick.t + step * period if step > 0 else tick.t, self._take(tick.t))
                self.part.ack(tick, time.perf_counter() - self._t0)
                self.ticks += 1
            return
        while True:
            tick = self.part.next_tick(timeout=self.poll_s)
            if tick is None and self.part.ended is not None:
                return
            try:
                now = self.part.sim_time_now()
            except TimeSyncError:
                continue  # no clock mapping from the master yet
            self._t0 = time.perf_counter()
            self.ticks += tick is not None
            yield Step(now, now, self._take(now))

    def output_time(self, stage: str) -> float:
        """Simulation time of an output of `stage` made in this step, per the run's latency policy
        (fixed: the step's time + the stage's configured latency; measured: + the wall time spent so far
        in this step; realtime: now)."""
        return self.part.output_time(stage, time.perf_counter() - self._t0)

    # -- output ------------------------------------------------------------------------------------------
    def publish(self, key: str, payload: bytes, t: float, stamps: dict[str, int] | None = None) -> int | None:
        """Publish on `key` at simulation time t; the sequence number, or None (counted) when it failed."""
        try:
            seq = self.bus.publish(key, payload, t, stamps=stamps)
        except Exception as exc:  # a closed or broken bus: count it, keep the run going
            self.publish_errors += 1
            log.warning("%s: could not publish on %s: %s", self.name, key, exc)
            return None
        self.published += 1
        return seq

    def trace(self, record: dict[str, Any], t: float, stamps: dict[str, int] | None = None) -> int | None:
        """One JSON trace record on trace/<name> at simulation time t (its stamps also under "stamps")."""
        body = dict(record, stamps=dict(stamps)) if stamps else dict(record)
        return self.publish(trace_key(self.name), json.dumps(body, separators=(",", ":")).encode(), t, stamps)

    # -- leaving -----------------------------------------------------------------------------------------
    def close(self, reason: str = "done") -> None:
        """Leave (if the run has not ended), close the subscriptions and the bus this session opened."""
        if self.part is not None:
            try:
                if self.part.welcome is not None and self.part.ended is None:
                    self.part.leave(reason)
                else:
                    self.part.close()
            except Exception as exc:  # the bus may be gone already
                log.debug("%s: leaving: %s", self.name, exc)
        for thing in self._subs + ([self.bus] if self._own_bus and self.bus is not None else []):
            try:
                thing.close()
            except Exception as exc:
                log.debug("%s: closing %r: %s", self.name, thing, exc)
        self._subs = []

    def __enter__(self) -> "AppSession":
        return self

    def __exit__(self, *exc) -> None:
        self.close("exception" if exc[0] else "done")
