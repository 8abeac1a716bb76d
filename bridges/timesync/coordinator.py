"""The master side of the time protocol: admit participants, tick, wait for acks, notice who left.

The master owns simulation time (DESIGN §3). In lockstep, `tick(k, t)`
publishes the tick and returns once every active participant due at k has
acknowledged it; a silent one raises ParticipantTimeout naming it, one that
left or stopped sending heartbeats raises ParticipantLost (or is dropped
when optional). The tick is re-sent every `resend_s` while acks are missing,
so a datagram lost on UDP costs a resend, not the run. In realtime,
`announce` publishes ticks without waiting and `check` only looks for the lost.

Messages from the network are handled on the transport's threads; a bad one
is counted with its reason (`report()["protocol_errors"]`) and never raises.
"""
from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

from bridges.timesync import messages as m
from bridges.timesync.errors import (JoinTimeout, ParticipantLost, ParticipantTimeout, ProtocolError, Refused,
                                     TimeSyncError)

log = logging.getLogger(__name__)
LATENCY_POLICIES = ("fixed", "measured")
MAX_REASONS = 100  # distinct protocol-error reasons / refusals kept: a flood must not grow the record without end


@dataclass
class Expected:
    """A participant the scenario expects."""

    name: str
    role: str | None = None  # None: any role
    required: bool = True
    timeout_s: float = 5.0  # wall seconds to acknowledge a tick
    sync_every: int = 1  # ticks at steps k with k % sync_every == 0
    latencies: dict = field(default_factory=dict)  # stage -> simulated seconds (fixed policy)


@dataclass
class _Member:
    spec: Expected
    join: m.Join | None = None
    joined_after_s: float | None = None
    joined_at_ns: int | None = None
    active: bool = False
    gone: str | None = None  # why it is no longer active
    last_seen: float = 0.0  # monotonic
    acks: int = 0
    late_acks: int = 0
    duplicate_acks: int = 0
    timeouts: int = 0
    heartbeats: int = 0
    processing_s_max: float = 0.0
    processing_s_sum: float = 0.0
    processing_n: int = 0
    offset: dict | None = None


class Coordinator:
    def __init__(self, bus, expected: list[Expected], *, mode: str = "lockstep", latency_policy: str = "fixed",
                 heartbeat_s: float = 0.5, heartbeat_timeout_s: float = 3.0, resend_s: float = 0.25,
                 master_timeout_s: float = 10.0, on_refused: str = "wait",
                 clock_ns: Callable[[], int] = time.time_ns, poll: Callable[[], None] | None = None,
                 world: dict[str, Any] | None = None):
        """`world`: what the join reply tells every app of the scenario's world (geodetic origin, ...)."""
        if latency_policy not in LATENCY_POLICIES:
            raise ValueError(f"latency policy must be one of {LATENCY_POLICIES}, got {latency_policy!r}")
        self.bus, self.mode, self.latency_policy = bus, mode, latency_policy
        self.heartbeat_s, self.heartbeat_timeout_s, self.resend_s = heartbeat_s, heartbeat_timeout_s, resend_s
        self.master_timeout_s, self.on_refused, self.clock_ns = master_timeout_s, on_refused, clock_ns
        self.poll = poll or (lambda: None)
        self.world = dict(world or {})
        self.members = {e.name: _Member(e) for e in expected}
        self.refused: list[dict[str, Any]] = []
        self.protocol_errors: Counter = Counter()
        self.ticks = self.resends = 0
        self._cond = threading.Condition()
        self._k, self._t = -1, 0.0
        self._waiting: set[str] = set()
        self._fatal: TimeSyncError | None = None
        self._stop = threading.Event()
        self._closed = False  # close() ends a tick() still waiting: nobody is left to ack it
        self._opened = time.monotonic()
        self._subs: list = []
        self._beat: threading.Thread | None = None

    # -- life cycle ---------------------------------------------------------------
    def start(self) -> None:
        handlers = {m.JOIN: self._on_join, m.ACK: self._on_ack, m.HEARTBEAT: self._on_heartbeat,
                    m.LEAVE: self._on_leave, m.PING: self._on_ping, m.OFFSET: self._on_offset}
        for base, handler in handlers.items():
            self._subs.append(self.bus.subscribe(f"{base}/*", self._guard(handler)))
        self._opened = time.monotonic()
        self._beat = threading.Thread(target=self._beats, name="timesync-beat", daemon=True)
        self._beat.start()

    def wait_for_participants(self, timeout_s: float, optional: Iterable[str] = ()) -> None:
        """Block until every required participant joined (JoinTimeout names the missing ones) and the optional
        ones named in `optional` joined or the timeout passed: apps the master started are on their way, and
        one that joins a lockstep run already ticking starts at a tick of its own, not at the run's first."""
        deadline = time.monotonic() + timeout_s
        optional = [n for n in optional if n in self.members]
        with self._cond:
            while True:
                self._check_heartbeats(time.monotonic())
                missing = [n for n, s in self.members.items() if s.spec.required and s.join is None]
                late = [n for n in optional if self.members[n].join is None]
                if not missing and not late:
                    return
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(min(left, 0.1))
                self._cond.release()
                try:
                    self.poll()
                finally:
                    self._cond.acquire()
        if not missing:
            return  # only optional ones are late: the run starts without them
        refusals = "".join(f"; '{r['name']}' was refused: {r['reason']}" for r in self.refused)
        raise JoinTimeout(missing, timeout_s, refusals)

    def tick(self, k: int, t: float, step: float = 0.0) -> None:
        """Lockstep sync point: publish tick k and wait for the acks of every participant due at k."""
        with self._cond:
            self._raise_fatal()
            if self._closed:  # a ticking thread racing with close(): the bus is about to close, nobody can ack
                return
            self._k, self._t = k, t
            self._waiting = {n for n, s in self.members.items() if s.active and k % s.spec.sync_every == 0}
            if not self._waiting:
                return
        payload = m.encode(m.Tick(k, t, step))
        self.ticks += 1
        started = time.monotonic()
        last_send = started
        if not self._publish(m.TICK, payload, t):
            return
        with self._cond:
            while True:
                self._raise_fatal()  # before the exit test: a lost participant leaves the waiting set
                if not self._waiting or self._closed:
                    return
                now = time.monotonic()
                for name in sorted(self._waiting):
                    member = self.members[name]
                    if now - started > member.spec.timeout_s:
                        member.timeouts += 1
                        self._fail_or_drop(member, ParticipantTimeout(name, k, t, member.spec.timeout_s))
                self._check_heartbeats(now)
                if not self._waiting:
                    continue
                if now - last_send >= self.resend_s:
                    self.bus.publish(m.TICK, payload, t)
                    self.resends += 1
                    last_send = now
                self._cond.wait(min(self.resend_s, 0.05))
                if self._waiting:
                    self._cond.release()
                    try:
                        self.poll()
                    finally:
                        self._cond.acquire()

    def announce(self, k: int, t: float, step: float = 0.0) -> None:
        """Realtime sync point: publish the tick, never wait (nothing once closed)."""
        with self._cond:
            if self._closed:
                return
            self._k, self._t = k, t
        self.ticks += 1
        self._publish(m.TICK, m.encode(m.Tick(k, t, step)), t)

    def publish_mapping(self, t_sim0: float, wall0_ns: int, rtf: float) -> None:
        self._publish(m.MAPPING, m.encode(m.Mapping(t_sim0, wall0_ns, rtf)), t_sim0)

    def _publish(self, key: str, payload: bytes, t: float) -> bool:
        """Publish unless closed; False when closed (before, or while publishing: the bus closed under us).
        Outside the lock, as before: the transport's threads take it to deliver what they receive."""
        if self._closed:
            return False
        try:
            self.bus.publish(key, payload, t)
        except Exception:
            if self._closed:  # lost the race with close(): its owner closes the bus next, nothing to tell
                return False
            raise
        return True

    def check(self) -> None:
        """Raise for a required participant that left or fell silent (realtime runs call this each step)."""
        with self._cond:
            self._raise_fatal()
            self._check_heartbeats(time.monotonic())
        self.poll()

    def end(self, status: str, reason: str = "") -> None:
        """Tell everyone the run is over (three times: datagrams get lost) and stop the heartbeat."""
        payload = m.encode(m.End(status, reason or ""))
        for _ in range(3):
            try:
                self.bus.publish(m.END, payload, self._t)
            except Exception as exc:  # the bus died with the run: nothing left to tell
                log.debug("end not published: %s", exc)
                break
        self._stop.set()

    def close(self) -> None:
        """Stop the heartbeat and the subscriptions. A tick() still waiting (in another thread) returns: its
        acks can no longer arrive, and resending on a bus about to close would only raise there. A tick(),
        announce() or publish_mapping() after close() publishes nothing."""
        self._stop.set()
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        if self._beat is not None:
            self._beat.join(timeout=2.0)
        for sub in self._subs:
            try:
                sub.close()
            except Exception as exc:
                log.debug("closing a subscription: %s", exc)
        self._subs = []

    def lose(self, name: str, reason: str) -> None:
        """Outside knowledge that a participant is gone (its process exited): fail or drop it."""
        with self._cond:
            member = self.members.get(name)
            if member is not None and member.gone is None:
                self._fail_or_drop(member, ParticipantLost(name, reason))
                self._cond.notify_all()

    def active(self) -> list[str]:
        return [n for n, s in self.members.items() if s.active]

    # -- record -------------------------------------------------------------------
    def report(self) -> dict[str, Any]:
        members = {}
        for name, s in self.members.items():
            j = s.join
            members[name] = {
                "role": j.role if j else s.spec.role, "required": s.spec.required, "timeout_s": s.spec.timeout_s,
                "sync_every": s.spec.sync_every, "joined": j is not None, "joined_after_s": s.joined_after_s,
                "joined_at_ns": s.joined_at_ns, "version": m.version_text(j.version) if j else None,
                "publishes": list(j.publishes) if j else [], "pid": j.pid if j else None, "host": j.host if j else None,
                "acks": s.acks, "late_acks": s.late_acks, "duplicate_acks": s.duplicate_acks, "timeouts": s.timeouts,
                "heartbeats": s.heartbeats, "gone": s.gone, "clock_offset": s.offset,
                "processing_s": ({"mean": s.processing_s_sum / s.processing_n, "max": s.processing_s_max,
                                  "n": s.processing_n} if s.processing_n else None),
                **({"latencies_s": dict(s.spec.latencies)} if self.latency_policy == "fixed" else {}),
            }
        return {"protocol_version": m.version_text(m.PROTOCOL_VERSION), "mode": self.mode,
                "latency_policy": self.latency_policy if self.mode == "lockstep" else "realtime (wall clock)",
                "ticks": self.ticks, "tick_resends": self.resends, "members": members, "refused": list(self.refused),
                "protocol_errors": dict(self.protocol_errors)}

    # -- handlers (transport threads) -----------------------------------------------------
    def _guard(self, handler):
        def on_message(msg):
            try:
                body = m.decode(msg.payload)
                if getattr(body, "name", None) != m.name_of(msg.key):
                    raise ProtocolError(f"{body.TYPE}: name {getattr(body, 'name', None)!r} does not match "
                                        f"the key {msg.key!r}")
                handler(body)
            except ProtocolError as exc:
                self._error(str(exc))
            except Exception as exc:  # a bug of ours must not kill the transport thread silently
                log.exception("time protocol handler failed on %s", msg.key)
                self._error(f"internal: {type(exc).__name__}: {exc}")
        return on_message

    def _error(self, reason: str) -> None:
        with self._cond:
            self._count(reason)
        log.warning("time protocol: ignored a message: %s", reason)

    def _count(self, reason: str) -> None:
        """Count a protocol error by reason (hold self._cond)."""
        reason = reason[:160]
        if reason not in self.protocol_errors and len(self.protocol_errors) >= MAX_REASONS:
            reason = "other reasons (too many distinct ones to list)"
        self.protocol_errors[reason] += 1

    def _on_join(self, join: m.Join) -> None:
        theirs = m.version_text(join.version)
        ours = m.version_text(m.PROTOCOL_VERSION)
        with self._cond:
            member = self.members.get(join.name)
            reason = None
            if not m.compatible(join.version):
                reason = (f"protocol version {theirs} of participant '{join.name}' is incompatible with the master's "
                          f"protocol version {ours} (major versions differ)")
            elif member is None:
                reason = f"'{join.name}' is not an expected participant (expected: {', '.join(self.members) or 'none'})"
            elif member.spec.role is not None and join.role != member.spec.role:
                reason = f"role {join.role!r} does not match the scenario's role {member.spec.role!r} for '{join.name}'"
            elif member.join is not None and member.join.session != join.session and member.active:
                reason = f"the name '{join.name}' is taken by a live participant (pid {member.join.pid} on {member.join.host})"
            if reason is not None:
                if not any(r["session"] == join.session for r in self.refused) and len(self.refused) < MAX_REASONS:
                    self.refused.append({"name": join.name, "session": join.session, "role": join.role,
                                         "version": theirs, "reason": reason})
                    log.error("refused participant '%s': %s", join.name, reason)
                    if self.on_refused == "fail":
                        self._fatal = Refused(join.name, reason)
                        self._cond.notify_all()
                welcome = m.Welcome(join.name, join.session, False, reason)
            else:
                if member.join is None or member.join.session != join.session:
                    member.join, member.active, member.gone = join, True, None
                    member.joined_after_s = time.monotonic() - self._opened
                    member.joined_at_ns = self.clock_ns()
                    log.info("participant '%s' (%s) joined", join.name, join.role)
                member.last_seen = time.monotonic()
                spec = member.spec
                welcome = m.Welcome(join.name, join.session, True, "", list(m.PROTOCOL_VERSION), self.mode,
                                    self.latency_policy, dict(spec.latencies), spec.sync_every, self.heartbeat_s,
                                    self.master_timeout_s, dict(self.world))
                self._cond.notify_all()
        self.bus.publish(m.key(m.WELCOME, join.name), m.encode(welcome), self._t)

    def _member(self, name: str, session: str) -> _Member | None:
        """The member a message belongs to, or None (counted) for strangers and stale sessions."""
        member = self.members.get(name)
        if member is None or member.join is None:
            self._count(f"message from '{name}', which has not joined")
            return None
        if member.join.session != session:
            self._count(f"message from an old session of '{name}'")
            return None
        member.last_seen = time.monotonic()
        return member

    def _on_ack(self, ack: m.Ack) -> None:
        with self._cond:
            member = self._member(ack.name, ack.session)
            if member is None:
                return
            if ack.k < self._k:
                member.late_acks += 1
            elif ack.k > self._k:
                self._count(f"ack from '{ack.name}' for tick {ack.k}, which was not sent yet")
            elif ack.name in self._waiting:
                self._waiting.discard(ack.name)
                member.acks += 1
                if ack.processing_s >= 0:
                    member.processing_n += 1
                    member.processing_s_sum += ack.processing_s
                    member.processing_s_max = max(member.processing_s_max, ack.processing_s)
                if not self._waiting:
                    self._cond.notify_all()
            else:
                member.duplicate_acks += 1

    def _on_heartbeat(self, hb: m.Heartbeat) -> None:
        with self._cond:
            member = self._member(hb.name, hb.session)
            if member is not None:
                member.heartbeats += 1

    def _on_leave(self, leave: m.Leave) -> None:
        with self._cond:
            member = self._member(leave.name, leave.session)
            if member is not None and member.gone is None:
                self._fail_or_drop(member, ParticipantLost(leave.name, f"left the run ({leave.reason or 'no reason'})"))
                self._cond.notify_all()

    def _on_ping(self, ping: m.Ping) -> None:
        t2 = self.clock_ns()
        with self._cond:
            member = self.members.get(ping.name)
            if member is not None:
                member.last_seen = time.monotonic()
        pong = m.Pong(ping.name, ping.id, ping.t1_ns, t2, self.clock_ns())
        self.bus.publish(m.key(m.PONG, ping.name), m.encode(pong), self._t)

    def _on_offset(self, offset: m.Offset) -> None:
        with self._cond:
            member = self._member(offset.name, offset.session)
            if member is not None:
                member.offset = {"offset_ns": offset.offset_ns, "rtt_ns": offset.rtt_ns, "samples": offset.samples}
                log.info("participant '%s': clock offset %.3f ms (rtt %.3f ms)", offset.name,
                         offset.offset_ns / 1e6, offset.rtt_ns / 1e6)

    # -- helpers (hold self._cond) ------------------------------------------------------------
    def _fail_or_drop(self, member: _Member, error: TimeSyncError) -> None:
        member.active = False
        member.gone = str(error)
        self._waiting.discard(member.spec.name)
        if member.spec.required:
            if self._fatal is None:
                self._fatal = error
        else:
            log.warning("dropped optional participant: %s", error)

    def _check_heartbeats(self, now: float) -> None:
        for member in self.members.values():
            if member.active and now - member.last_seen > self.heartbeat_timeout_s:
                self._fail_or_drop(member, ParticipantLost(
                    member.spec.name, f"no heartbeat for {now - member.last_seen:.1f} s "
                                      f"(limit {self.heartbeat_timeout_s:g} s)"))
        self._raise_fatal()

    def _raise_fatal(self) -> None:
        if self._fatal is not None:
            raise self._fatal

    def _beats(self) -> None:
        n = 0
        while not self._stop.wait(self.heartbeat_s):
            n += 1
            try:
                self.bus.publish(m.BEAT, m.encode(m.Beat(n)), self._t)
            except Exception as exc:  # bus closed: the run is over
                log.debug("beat not sent: %s", exc)
                return
