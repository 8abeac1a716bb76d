"""The RSU in simulated time: a small discrete-event core, no bus, no threads (tested in-process).

`RsuCore.step(t, frames, statuses, horizon)` is called once per tick of the
master (lockstep) or per loop turn (realtime) with the camera frames and
controller statuses that arrived by t, and returns the frames to transmit.
Inside, every happening is an event at its own simulation time, processed in
time order up to t (lockstep: up to the horizon, below), so what the RSU sends
and when depends only on simulation times and data stamped <= t (lockstep +
`fixed` latencies repeat bit for bit):

    FRAME  at the frame's time (a camera frame or a radar scan: the same path, each sensor
           with its own gate and stage latency): if the camera's detector is free (BusyGate),
           detect + project now, and schedule READY at frame time + stage-1
           latency (the detector is busy until then); else drop the frame.
    READY  the tracker learns the detections (at the frame's time). The first
           READY starts the BSM clock.
    BSM    every 1/bsm_rate_hz from the first READY: one BSM per confirmed track,
           predicted to the slot's time, then encode + sign (stage 2). With
           `bsm_follows` (sensor names) the slots follow those sensors' detections
           instead: a READY of one of them opens a slot at once unless its frame
           was taken less than the period (less FOLLOW_EARLY of it) after the frame
           that opened the last one (a camera faster than the BSM rate: one frame
           a period), no sooner than FOLLOW_MIN_GAP of a period after the last
           slot. Without such a READY the clock takes over: a slot the period
           plus FOLLOW_WAIT of it after a slot a detection opened (its detector's
           time per frame varies), then every period (the tracks of a sensor that
           stopped are still broadcast). A free-running clock's phase is fixed by
           the first READY of any sensor, so it leaves a camera's detection
           waiting up to a period (half of one on average) for its slot.
    STATUS a controller status arrived.
    SPAT / MAP  at their rates from the run's start.

At equal times READY comes before STATUS, FRAME and the slots, so a slot sees
every detection ready by its time and a frame's projection sees the tracks
known at its time.

Working ahead of the tick (lockstep, `horizon`). The master runs the step
[t, t + h) after the answers to its tick of t, and the air puts a frame on at
its t_sim only if that is not before the step: one stamped before t goes out
at t, counted late. So what is due between two ticks (off the tick grid:
`measured` latencies, a hardware profile's inference time, a SPaT or MAP rate
that is no multiple of the tick) must be handed over at the tick before it.
`step` therefore also processes, at their own times and in the same order, the
events before `horizon` (less AHEAD_MARGIN): the earliest simulation time an
input not handed over yet may have. This changes nothing but the tick:

* after t the queue holds only READY (of frames already taken), BSM, SPaT and
  MAP events; FRAME and STATUS events are pushed at times <= t;
* an input still to come makes no event before its own time: a status is
  dated by the tick at which it arrives, a frame is processed at its time or
  later, and its READY is later still;
* camera frames are samples of the master's steps, each handed over at the
  first tick at or after its time: at the tick of t every frame not handed
  over yet has a time >= t + the master's step (`Tick.step`).

Hence an event before the horizon sees, processed now, exactly what it would
see processed at a later tick (every READY by a slot's time, READY before a
slot of the same time, no frame or status after it), and gives the same bytes
and stamps; the master puts the frame on the air at its stamp. The app passes
t + step (t + sync_every x step without a camera: statuses only). With a tick
every step that is the next tick and nothing reaches the air late. With
`sync_every` > 1, frames of (t, t + h) come only at the next tick and may still
change a slot there, so what is due in [t + step, t + h) waits for that tick,
as without a horizon, and still reaches the air late (use sync_every = 1).
Work done ahead counts as done (`self.t`): a frame that comes after its own
tick (the camera ingest gave up waiting for it) is processed at the latest time
already done, never before it. Realtime ignores the horizon.

With `trace_detections`, each READY also leaves one "detections" trace record
per frame it makes known (`perception_stage.detection_record`: boxes, labels,
scores, tracks, BSM ids) in `records`, which the app drains with
`take_records()` and publishes on trace/<app> at the record's detect_end.
Building them reads the tracker and the BSM ids only: nothing sent changes.
"""
from __future__ import annotations

import heapq
import itertools
import logging
from collections import deque
from dataclasses import dataclass, field

from bridges import ab3418
from rsu_app.bsm_stage import BsmStage, Transmission
from rsu_app.camera import EPS, BusyGate
from bridges.radar_stream import RadarScan
from rsu_app.perception_stage import RADAR as RADAR_KIND
from rsu_app.perception_stage import FrameResult, PerceptionStage, detection_record
from rsu_app.timing import DETECT, RADAR, LatencyModel

log = logging.getLogger(__name__)
READY, STATUS, FRAME, BSM, SPAT, MAP, ACK, SRM, SSM = range(9)
# s: how far before the horizon work ahead stops. Only float noise separates the horizon (t + step) from the
# time of the master's next frame; anything this close to it is done at the next tick, as without a horizon.
AHEAD_MARGIN = 1e-9
# Slots that follow a sensor's detections, in shares of the BSM period. EARLY: a frame taken this much less than
# a period after the one that opened the last slot still opens one (frames are taken on the loop's steps); below
# a half, so a sensor faster than the BSM rate gives one slot a period (a 30 Hz camera: every third frame).
# WAIT: the clock waits this much more than a period for the next detection before it sends the tracks as
# known: the detector's time per frame varies (60-130 ms for 10 Hz frames on llvmpipe at RTF 1), and a clock
# slot just before a detection sends the tracks again only for the detection to follow it.
FOLLOW_EARLY = 0.25
FOLLOW_WAIT = 0.5
# No two slots closer than this share of a period: a detection ready just after the clock's slot (its sensor
# drops frames, or its detector was slow) waits for the rest of it, not a whole period, and the channel never
# carries a track's BSMs twice in a few milliseconds.
FOLLOW_MIN_GAP = 0.5


@dataclass
class CoreCounters:
    frames: int = 0
    radar_scans: int = 0
    frames_dropped_busy: int = 0
    frames_refused: int = 0
    bsm_slots: int = 0
    slots_skipped: int = 0  # realtime: BSM/SPaT/MAP slots the loop was too late for
    stage1_charged_s: deque = field(default_factory=lambda: deque(maxlen=20000))  # simulated s per frame


class RsuCore:
    def __init__(self, latency: LatencyModel, perception: PerceptionStage | None = None,
                 bsm: BsmStage | None = None, spat=None, map_stage=None, *, t0: float | None = None,
                 bsm_rate_hz: float = 10.0, spat_rate_hz: float = 10.0, map_rate_hz: float = 1.0,
                 realtime: bool = False, trace_detections: bool = False, sdsm=None, priority=None,
                 ssm_rate_hz: float = 10.0, bsm_follows=()):
        self.latency, self.perception, self.bsm, self.spat, self.map = latency, perception, bsm, spat, map_stage
        self.sdsm = sdsm  # SdsmStage: one SDSM per slot with every track (beside or instead of the BSMs)
        self.priority = priority  # rsu_app.priority_stage.PriorityStage: SRMs in, preemption calls and SSMs out
        self.preempt_calls: list[tuple[float, bool]] = []  # (t, on) for the controller link, drained by the app
        self.priority_records: list[dict] = []  # EVSP trace records ("srm", "preempt", "status"), by the app
        self.realtime = realtime
        self.trace_detections = trace_detections
        self.records: list[dict] = []  # trace records not yet taken by the app, in detect_end order
        self.bsm_period = 1.0 / bsm_rate_hz
        self.gates: dict[str, BusyGate] = {}
        self.counters = CoreCounters()
        self._events: list = []
        self._order = itertools.count()
        self._bsm_start: float | None = None
        self.bsm_follows = frozenset(bsm_follows)  # sensor names whose detections open a BSM slot at once
        self._last_slot: float | None = None  # following: when the last slot ran
        self._last_followed: float | None = None  # following: the frame time of the last detection that opened one
        self._slot_gen = 0  # following: the number of the one slot event still valid (a newer one cancels it)
        self._pending_ready: dict[float, list[FrameResult]] = {}
        self.t = float("-inf")  # events up to here are done
        self.tracks_seen: set[int] = set()
        self._periods = [(kind, 1.0 / rate) for kind, stage, rate in ((SPAT, spat, spat_rate_hz),
                                                                      (MAP, map_stage, map_rate_hz),
                                                                      (SSM, priority, ssm_rate_hz)) if stage]
        if t0 is not None:
            self._start_clocks(t0)

    def _start_clocks(self, t0: float) -> None:
        """SPaT and MAP slots run from t0 (default: the first step, i.e. the run's first tick)."""
        for kind, period in self._periods:
            self._push(t0, kind, (t0, period, 0))
        self._periods = []

    def _push(self, t: float, kind: int, payload) -> None:
        heapq.heappush(self._events, (t, kind, next(self._order), payload))

    # -- the one entry point ---------------------------------------------------------------------------
    def step(self, t: float, frames=(), statuses=(), horizon: float | None = None, srms=(),
             acks=()) -> list[Transmission]:
        """Everything up to simulation time t. `frames`: camera frames of time <= t (realtime: processed
        now); `statuses`: (status, wire_bytes) answers of the controller that arrived by t. `horizon`
        (lockstep; ignored in realtime): no input still to come has a time before it, so the events before it
        are processed now too, at their own times (see the module's docstring)."""
        if self._periods:
            self._start_clocks(t)
        for status, wire_bytes in statuses:
            self._push(t, STATUS, (status, wire_bytes))
        for ack in acks:  # SetPreempt acknowledgements (rsu_app.controller_link.PreemptAck), dated by the tick
            self._push(t, ACK, ack)
        for payload, t_arrival in srms:  # frames heard on the air: at their arrival, never before done work
            when = max(t_arrival, t) if self.realtime else min(max(t_arrival, self.t), t)
            self._push(when, SRM, payload)
        for frame in frames:
            when = max(frame.t, t) if self.realtime else min(max(frame.t, self.t), t)  # never before done work
            self._push(when, FRAME, frame)
        until = t + EPS
        if horizon is not None and not self.realtime:
            until = max(until, horizon - AHEAD_MARGIN)
        done = max(self.t, t)
        out: list[Transmission] = []
        while self._events and self._events[0][0] <= until:
            when, kind, _, payload = heapq.heappop(self._events)
            if when > t + EPS:
                done = max(done, when)  # ahead of the tick
            base = max(when, t) if self.realtime else when  # realtime: late work happens now
            if kind == READY:
                self._ready(when, payload)
            elif kind == STATUS:
                self.spat.on_status(payload[0], payload[1], when) if self.spat is not None else None
                if self.priority is not None:
                    self._priority_status(when, *payload)
            elif kind == ACK:
                self._priority_ack(when, payload)
            elif kind == SRM:
                self._priority_srm(when, payload)
            elif kind == FRAME:
                self._frame(when, payload)
            elif kind == BSM and self.bsm_follows:
                gen, opened = payload
                ready = self._followed_ready_by(base) if gen == self._slot_gen else None
                if ready is not None and ready > when:
                    # realtime: the loop comes late to the clock's slot (the detector held it) and the detection
                    # it waited for is ready by now: it goes first, and opens a slot or lets this one run
                    self._push(ready, BSM, payload)
                elif gen == self._slot_gen:  # else a slot opened by a detection took its place
                    self.counters.bsm_slots += 1
                    out += self._bsm_slot(base)
                    self._last_slot = base
                    self._slot_gen += 1
                    wait = self.bsm_period * (1.0 + FOLLOW_WAIT if opened else 1.0)
                    self._push(base + wait, BSM, (self._slot_gen, False))
            elif kind == BSM:
                start, n = payload
                self.counters.bsm_slots += 1
                out += self._bsm_slot(base)
                n = self._next_slot(start, self.bsm_period, n, t)
                self._push(start + n * self.bsm_period, BSM, (start, n))
            elif kind in (SPAT, MAP, SSM):
                start, period, n = payload
                stage = {SPAT: self.spat, MAP: self.map, SSM: self.priority}[kind]
                if kind == SSM:
                    self._priority_events(base, self.priority.core.step(base))
                tx = stage.send(base)
                if tx is not None:
                    out.append(tx)
                n = self._next_slot(start, period, n, t)
                self._push(start + n * period, kind, (start, period, n))
        self.t = done
        return out

    # -- signal preemption (EVSP) ------------------------------------------------------------------------------
    def _priority_srm(self, when: float, payload: bytes) -> None:
        if self.priority is None:
            return
        srm = self.priority.receive(payload, when)
        if srm is not None:
            self.priority_records.append({"kind": "srm", "t": when, "vehicle": str(srm.requestor.vehicle_id),
                                          "types": [r.request_type for r in srm.requests]})
            self._priority_events(when, self.priority.core.step(when))

    def _priority_events(self, when: float, events) -> None:
        if events.preempt is not None:
            self.preempt_calls.append((when, events.preempt))
            self.priority_records.append({"kind": "preempt_call", "t": when, "on": events.preempt})
        for r, status in events.changes:
            self.priority_records.append({"kind": "status", "t": when, "vehicle": str(r.vehicle_id),
                                          "request": r.request_id, "status": status, "reason": r.reason,
                                          "signal_group": r.signal_group})

    def _priority_ack(self, when: float, ack) -> None:
        if self.priority is None:
            return
        baud = self.spat.baud if self.spat is not None else None
        wire = None if not baud else (ack.request_bytes + ack.answer_bytes) * 10 / baud
        self.priority_records.append({"kind": "preempt_ack", "t": when, "on": ack.on, "ok": ack.ok,
                                      "request_bytes": ack.request_bytes, "answer_bytes": ack.answer_bytes,
                                      "wire_s": wire})
        if ack.ok:
            self.priority.core.on_preempt_sent(ack.on, when)
            self._priority_events(when, self.priority.core.step(when))

    def _priority_status(self, when: float, status, wire_bytes: int) -> None:
        t_status = self.spat.t_status if self.spat is not None else when
        self.priority.core.on_controller(status.greens, bool(status.status & ab3418.STATUS_PREEMPT), t_status)
        self._priority_events(when, self.priority.core.step(when))

    def take_preempt_calls(self) -> list[tuple[float, bool]]:
        calls, self.preempt_calls = self.preempt_calls, []
        return calls

    def take_priority_records(self) -> list[dict]:
        records, self.priority_records = self.priority_records, []
        return records

    def take_records(self) -> list[dict]:
        """The trace records made since the last call (the app publishes them; nobody else keeps them)."""
        records, self.records = self.records, []
        return records

    def _next_slot(self, start: float, period: float, n: int, t: float) -> int:
        """The next slot's number. Realtime: a loop that fell behind skips the slots it missed (one late
        message per kind, never a burst of stale ones); lockstep never falls behind."""
        n += 1
        if self.realtime and start + n * period <= t + EPS:
            skip = int((t + EPS - start) / period) + 1 - n
            self.counters.slots_skipped += skip
            n += skip
        return n

    # -- stage 1 ------------------------------------------------------------------------------------------
    def _frame(self, when: float, frame) -> None:
        radar = isinstance(frame, RadarScan)
        if radar:
            self.counters.radar_scans += 1
        else:
            self.counters.frames += 1
        if self.perception is None:
            return
        sensor = frame.radar if radar else frame.camera
        gate = self.gates.setdefault(sensor, BusyGate())
        if not gate.offer(when):
            self.counters.frames_dropped_busy += 1
            log.debug("%s sample of t = %.3f dropped: its stage 1 is busy until %.3f", sensor, frame.t,
                      gate.busy_until)
            return
        result = self.perception.process_radar(frame, when) if radar else self.perception.process(frame, when)
        if result is None:
            self.counters.frames_refused += 1
            return
        latency = self.latency.stage(RADAR if radar else DETECT, result.compute_s)
        gate.occupy(when, latency)
        result.detect_start, result.detect_end = when, when + latency
        if not radar:
            self.counters.stage1_charged_s.append(latency)
        ready = when + latency
        # frames of one instant whose detections are ready together update the tracker once
        batch = self._pending_ready.get(ready)
        if batch is None:
            self._pending_ready[ready] = [result]
            self._push(ready, READY, ready)
        else:
            batch.append(result)

    def _ready(self, when: float, key: float) -> None:
        results = self._pending_ready.pop(key, [])
        if not results:
            return
        by_time: dict[float, list[FrameResult]] = {}
        for r in results:
            by_time.setdefault(r.t, []).append(r)
        for _, group in sorted(by_time.items()):
            self.perception.apply(group)
        if self.trace_detections:  # boxes on a camera's clip: a radar's objects have none
            self.records += [detection_record(r, self._bsm_id) for r in results if r.kind != RADAR_KIND]
        if self.sdsm is not None:
            self.sdsm.observe(results)
        if self.bsm is None and self.sdsm is None:
            return
        if self.bsm_follows:
            followed = [r.t for r in results if r.camera in self.bsm_follows]
            # the rate is kept on the frames' own times, which are regular, not on when their detections are
            # ready, which varies with the detector's time per frame
            opens = bool(followed) and (self._last_followed is None or max(followed) >= self._last_followed
                                        + self.bsm_period * (1.0 - FOLLOW_EARLY) - EPS)
            if opens or self._last_slot is None:
                if opens:
                    self._last_followed = max(followed)
                at = when if self._last_slot is None else max(when, self._last_slot
                                                              + self.bsm_period * FOLLOW_MIN_GAP)
                self._slot_gen += 1  # the pending slot of the clock gives way to this one
                self._push(at, BSM, (self._slot_gen, opens))
                self._last_slot = at
        elif self._bsm_start is None:
            self._bsm_start = when
            self._push(when, BSM, (when, 0))

    def _followed_ready_by(self, t: float) -> float | None:
        """The time of the earliest READY still queued for t or before that brings a followed sensor's detections."""
        times = [when for when, kind, _, key in self._events if kind == READY and when <= t + EPS
                 and any(r.camera in self.bsm_follows for r in self._pending_ready.get(key, ()))]
        return min(times, default=None)

    def _bsm_id(self, track_id: int) -> str | None:
        """The temporary id the BSMs of a track carry (None without a BSM stage: nothing is broadcast)."""
        return self.bsm.bsm_id(track_id) if self.bsm is not None else None

    # -- stage 2 ------------------------------------------------------------------------------------------
    def _bsm_slot(self, t: float) -> list[Transmission]:
        tracker = self.perception.tracker
        if tracker.t is None:
            return []
        states = self.perception.broadcastable(tracker.predict(max(t, tracker.t)))
        self.tracks_seen.update(s.id for s in states)
        sequential = self.latency.policy != "fixed"
        out = [] if self.bsm is None else self.bsm.send(states, t, self.perception.track_stamps, sequential)
        if self.sdsm is not None:
            start = out[-1].t_sim if out and sequential else t  # one CPU: after the slot's BSMs
            out += self.sdsm.send(states, t, self.perception.track_stamps, start)
        return out
