"""The time protocol on the in-process memory bus: messages, clocks, lockstep, failures, realtime."""
from __future__ import annotations

import itertools
import json
import threading
import time

import pytest

from bridges.timesync import messages as m
from bridges.timesync.clock import MIN_SLEW_RATE, SLEW_HORIZON_S, OffsetSample, TimeMapping, best_sample, \
    offset_sample, slewed
from bridges.timesync.coordinator import Coordinator, Expected
from bridges.timesync.errors import (JoinTimeout, MasterLost, ParticipantLost, ParticipantTimeout, ProtocolError,
                                     Refused, TimeSyncError)
from bridges.timesync.participant import Participant
from bridges.transport import TransportError, open_bus
from bridges.transport.memory import MemoryBus

_ids = itertools.count()
# A thread of ours that dies with an exception (a tick resending on a closed bus) fails the test it happens in,
# instead of a warning that a clean run would print.
pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")


@pytest.fixture
def prefix():
    return f"test/timesync-{next(_ids)}-{time.monotonic_ns()}"


@pytest.fixture
def buses(prefix):
    """buses(name) -> a MemoryBus on this test's prefix; all closed at the end."""
    opened = []

    def make(name):
        bus = MemoryBus(prefix=prefix, sender=name)
        opened.append(bus)
        return bus

    yield make
    for bus in opened:
        bus.close()


class App(threading.Thread):
    """A participant in a thread: acks every tick after `work(tick)`; records what it saw."""

    def __init__(self, bus, name, role="echo", work=None, **options):
        super().__init__(daemon=True)
        self.p = Participant(bus, name, role, **options)
        self.work, self.seen, self.error = work, [], None
        self.joined = threading.Event()

    def run(self):
        try:
            self.p.join(5)
            self.joined.set()
            for tick in self.p.ticks():
                self.seen.append((tick.k, tick.t))
                if self.work and self.work(tick) == "leave":
                    self.p.leave("tired")
                    return
                self.p.ack(tick)
        except Exception as exc:  # examined by the test
            self.error = exc
        finally:
            self.joined.set()


def coordinator(bus, *expected, **options):
    options.setdefault("heartbeat_s", 0.05)
    options.setdefault("heartbeat_timeout_s", 0.5)
    c = Coordinator(bus, [e if isinstance(e, Expected) else Expected(e) for e in expected], **options)
    c.start()
    return c


# -- messages ----------------------------------------------------------------------------
def test_messages_round_trip_bit_for_bit():
    t = 0.1 + 0.2  # not representable in short decimal: must survive exactly
    for msg in (m.Tick(7, t, 0.01), m.Ack("rsu1", "s", 7, 0.0123), m.Join("av", "av_app", "s", ["v2x/rx/av"]),
                m.Welcome("av", "s", True, latencies={"detect": 0.05},
                          world={"origin": {"lat": 42.0, "lon": -83.0, "alt": 260.0}}), m.Mapping(t, 123, 2.0),
                m.Pong("a", 1, 2, 3, 4), m.End("failed", "x"), m.Offset("a", "s", -250_000_000, 300_000, 8)):
        back = m.decode(m.encode(msg))
        assert back == msg and type(back) is type(msg)
    assert m.decode(m.encode(m.Tick(1, t))).t == t
    body = json.loads(m.encode(m.Tick(1, 0.5)))
    assert body["type"] == "tick" and body["v"] == list(m.PROTOCOL_VERSION) == [1, 1]


@pytest.mark.parametrize("payload, words", [
    (b"\xff\xfe", "not UTF-8 JSON"),
    (b"[1, 2]", "must be a JSON object"),
    (b'{"type": "nope", "v": [1, 0]}', "unknown time-protocol message type 'nope'"),
    (b'{"type": "tick", "v": [1, 0], "t": 1.0}', "tick: missing field 'k'"),
    (b'{"type": "tick", "v": [1, 0], "k": "3", "t": 1.0}', "field 'k' must be int"),
    (b'{"type": "tick", "v": [1, 0], "k": true, "t": 1.0}', "field 'k' must be int"),
    (b'{"type": "tick", "v": "1.0", "k": 1, "t": 1.0}', "field 'v' must be [major, minor]"),
    (b'{"type": "tick", "v": [2, 0], "k": 1, "t": 1.0}', "protocol version 2.0 is not compatible with 1.1"),
    (b'{"type": "ack", "v": [1, 0], "name": "a/b", "session": "s", "k": 1}', "not a valid key chunk"),
    (b'{"type": "tick", "v": [1, 0], "k": 1, "t": NaN}', "tick: field 't' must be a finite number, got nan"),
    (b'{"type": "map", "v": [1, 0], "t_sim0": 0.0, "wall0_ns": 5, "rtf": 0}', "map: field 'rtf' must be a finite "
                                                                               "number > 0"),
    (b'{"type": "map", "v": [1, 0], "t_sim0": 0.0, "wall0_ns": 5, "rtf": -0.5}', "got -0.5"),
    (b'{"type": "map", "v": [1, 0], "t_sim0": 0.0, "wall0_ns": 5, "rtf": Infinity}', "field 'rtf' must be a finite"),
])
def test_bad_payloads_say_what_is_wrong(payload, words):
    with pytest.raises(ProtocolError, match=None) as info:
        m.decode(payload)
    assert words in str(info.value)


def test_newer_minor_with_extra_fields_is_accepted():
    body = {"type": "tick", "v": [1, 7], "k": 3, "t": 0.5, "future": {"x": 1}}
    assert m.decode(json.dumps(body).encode()) == m.Tick(3, 0.5)


# -- clocks -------------------------------------------------------------------------------------
def test_offset_sample_recovers_offset_and_rtt():
    offset, up, down, busy = 250_000_000, 3_000, 1_000, 500  # master ahead by 250 ms
    t1 = 10_000_000
    t2 = t1 + up + offset
    t3 = t2 + busy
    t4 = t3 - offset + down
    s = offset_sample(t1, t2, t3, t4)
    assert s.rtt_ns == up + down
    assert abs(s.offset_ns - offset) <= s.rtt_ns // 2  # the asymmetry bound
    assert best_sample([OffsetSample(5, 9_000), s, OffsetSample(9, 10_000)]) is s
    with pytest.raises(ValueError, match="no offset samples"):
        best_sample([])


def test_time_mapping_round_trips():
    mp = TimeMapping(t_sim0=2.0, wall0_ns=1_000_000_000, rtf=0.5)
    assert mp.sim_time(3_000_000_000) == pytest.approx(3.0)
    assert mp.master_ns(3.0) == 3_000_000_000


def test_a_schedule_ahead_is_stepped_to():
    now = 5_000_000_000
    ahead = TimeMapping(3.2, now, 1.0)
    assert slewed(TimeMapping(3.0, now, 1.0), ahead, now) is ahead
    assert slewed(None, ahead, now) is ahead


@pytest.mark.parametrize("back_s", [0.01, 0.1, 0.5, 3.0])
def test_a_schedule_that_moved_back_is_slewed_to_and_met(back_s):
    """A loop that slipped moves its schedule back by the overrun; the run clock slows instead of stepping
    (a receiver date-checks signed messages on it), and meets the schedule within the horizon when that keeps
    it above the minimum rate."""
    now, rtf = 7_000_000_000, 1.0
    current = TimeMapping(4.0, now - 1_000_000_000, rtf)  # 5.0 s now
    schedule = TimeMapping(5.0 - back_s, now, rtf)
    s = slewed(current, schedule, now)
    assert s.sim_time(now) == pytest.approx(current.sim_time(now))  # continuous: no step
    assert MIN_SLEW_RATE * rtf <= s.rtf < rtf  # slower, never standing still
    meet_s = back_s / (rtf - s.rtf)
    assert meet_s == pytest.approx(max(SLEW_HORIZON_S, back_s / (rtf * (1 - MIN_SLEW_RATE))))
    met = now + round(meet_s * 1e9)
    assert s.sim_time(met) == pytest.approx(schedule.sim_time(met))


def test_the_participants_realtime_clock_never_goes_back(buses):
    """A new mapping that arrives a bus delay late (or a refreshed offset) could put the clock back a little:
    read through the participant, it holds instead."""
    c = coordinator(buses("master"), "rt", mode="realtime")
    wall = [time.time_ns()]
    p = Participant(buses("rt"), "rt", "x", auto_offset=False, clock_ns=lambda: wall[0])
    p.join(5)
    now = wall[0]
    p.mapping = TimeMapping(10.0, now, 1.0)
    assert p.sim_time_now() == 10.0
    p.mapping = TimeMapping(9.0, now, 1.0)  # a second back
    wall[0] += 500_000_000
    assert p.sim_time_now() == 10.0  # held: the new mapping reads 9.5
    wall[0] += 600_000_000
    assert p.sim_time_now() == pytest.approx(10.1)  # and runs again once it has passed
    c.close()
    p.close()


def test_the_realtime_clock_never_goes_back_across_threads(buses):
    """Two threads read the clock at once: one whose reading of the mapping (10 s) is slow, one that reads
    20 s meanwhile. Without a lock the slow one then stored its 10 s over the 20 s, and a later reading of
    15 s went back from 20 s; read-max-write is one step, so the second thread waits for the first."""
    import threading

    c = coordinator(buses("master"), "rt", mode="realtime")
    p = Participant(buses("rt"), "rt", "x", auto_offset=False)
    p.join(5)
    first_in, release = threading.Event(), threading.Event()

    class Mapping:  # what the master's mapping reads, scripted per call
        readings = iter([10.0, 20.0, 15.0])

        def sim_time(self, ns):
            value = next(self.readings)
            if value == 10.0:
                first_in.set()
                release.wait(0.5)  # held until the other thread has read (or, with the lock, gave up waiting)
            return value

    p.mapping = Mapping()
    slow = threading.Thread(target=p.sim_time_now)
    slow.start()
    assert first_in.wait(5)
    newer = p.sim_time_now()
    release.set()
    slow.join(5)
    assert newer == 20.0
    assert p.sim_time_now() == 20.0  # the 15 s reading is held at 20 s: the clock never went back
    c.close()
    p.close()


# -- memory bus ------------------------------------------------------------------------------------
def test_memory_bus_delivery_isolation_and_bounds(buses, prefix):
    a, b = buses("a"), buses("b")
    other = MemoryBus(prefix=prefix + "-other", sender="o")
    try:
        q = b.subscribe("data/*")
        latest = b.subscribe("data/x", latest_only=True)
        small = b.subscribe("data/**", maxlen=2)
        stranger = other.subscribe("**")
        seqs = [a.publish("data/x", bytes([i]), t_sim=i * 0.1, stamps={"t0": i}) for i in range(3)]
        assert seqs == sorted(seqs) and len(set(seqs)) == 3
        got = [q.recv(timeout=1) for _ in range(3)]
        assert [g.payload for g in got] == [b"\x00", b"\x01", b"\x02"]
        assert got[1].sender == "a" and got[1].key == "data/x" and got[1].t_sim == 0.1 and got[1].stamps == {"t0": 1}
        assert latest.recv(timeout=1).payload == b"\x02" and latest.recv(timeout=0.05) is None
        assert b.stats()["dropped_queue_full"] == 1 and small.recv(timeout=1).payload == b"\x01"
        assert stranger.recv(timeout=0.05) is None  # another prefix never hears it
        with pytest.raises(TransportError):
            a.publish("data/*", b"", 0.0)
        with pytest.raises(TransportError, match="no option 'group'"):
            open_bus("memory", prefix=prefix, sender="x", group="239.1.1.1")
    finally:
        other.close()


def test_memory_bus_callback_errors_are_counted_not_fatal(buses):
    a, b = buses("a"), buses("b")
    seen, done = [], threading.Event()

    def cb(msg):
        if msg.payload == b"bad":
            raise RuntimeError("subscriber bug")
        seen.append(msg.payload)
        if msg.payload == b"last":
            done.set()

    b.subscribe("k", cb)
    for p in (b"one", b"bad", b"last"):
        a.publish("k", p, 0.0)
    assert done.wait(2)
    assert seen == [b"one", b"last"] and b.stats()["callback_errors"] == 1


# -- lockstep ---------------------------------------------------------------------------------------
def test_lockstep_every_participant_acks_every_tick(buses):
    c = coordinator(buses("master"), "a", Expected("b", sync_every=2))
    apps = [App(buses("a"), "a"), App(buses("b"), "b")]
    for app in apps:
        app.start()
    c.wait_for_participants(5)
    for k in range(50):
        c.tick(k, k * 0.01, 0.01)
    c.end("completed")
    for app in apps:
        app.join(5)
        assert app.error is None and not app.is_alive()
    assert [k for k, _ in apps[0].seen] == list(range(50))
    assert [k for k, _ in apps[1].seen] == list(range(0, 50, 2))  # sync_every = 2
    rep = c.report()
    assert rep["members"]["a"]["acks"] == 50 and rep["members"]["b"]["acks"] == 25
    assert rep["members"]["a"]["joined"] and rep["members"]["a"]["late_acks"] == 0
    assert apps[0].p.ended.status == "completed"
    c.close()


def test_tick_waits_for_the_slowest_participant(buses):
    c = coordinator(buses("master"), "fast", "slow")
    apps = [App(buses("fast"), "fast"), App(buses("slow"), "slow", work=lambda t: time.sleep(0.05))]
    for app in apps:
        app.start()
    c.wait_for_participants(5)
    t0 = time.perf_counter()
    for k in range(4):
        c.tick(k, k * 0.1)
        assert len(apps[1].seen) == k + 1
    assert time.perf_counter() - t0 >= 0.2
    c.end("completed")
    c.close()


def test_stalled_participant_ends_the_run_naming_it(buses):
    c = coordinator(buses("master"), "good", Expected("stuck", timeout_s=0.3), heartbeat_timeout_s=5.0)
    stall = threading.Event()
    apps = [App(buses("good"), "good"), App(buses("stuck"), "stuck", work=lambda t: stall.wait(5) if t.k == 2 else None)]
    for app in apps:
        app.start()
    c.wait_for_participants(5)
    c.tick(0, 0.0)
    c.tick(1, 0.1)
    t0 = time.perf_counter()
    with pytest.raises(ParticipantTimeout, match=r"participant 'stuck' did not acknowledge tick 2 \(t = 0.2 s\) "
                                                 r"within 0.3 s") as info:
        c.tick(2, 0.2)
    # it fires at its timeout: the wait wakes every 50 ms at most; 0.1 s more for a busy machine (a doubled
    # timeout, 0.6 s, fails this)
    assert 0.3 <= time.perf_counter() - t0 < 0.3 + 0.05 + 0.1
    assert info.value.name == "stuck" and c.report()["members"]["stuck"]["timeouts"] == 1
    stall.set()
    c.end("failed", str(info.value))
    c.close()


def test_crashed_participant_is_noticed_by_missing_heartbeats(buses):
    c = coordinator(buses("master"), "crashy")
    bus = buses("crashy")
    p = Participant(bus, "crashy", "echo")
    p.join(5)
    p._stop.set()  # the process "dies": no heartbeat, no leave, no ack
    bus.close()
    t0 = time.perf_counter()
    with pytest.raises(ParticipantLost, match=r"participant 'crashy' lost: no heartbeat for"):
        c.tick(0, 0.0)
    assert time.perf_counter() - t0 < 1.5  # heartbeat timeout 0.5 s, long before the 5 s ack timeout
    c.close()


def test_leaving_participant_ends_the_run_or_is_dropped_when_optional(buses):
    c = coordinator(buses("master"), "must", Expected("maybe", required=False))
    must, maybe = App(buses("must"), "must"), App(buses("maybe"), "maybe", work=lambda t: "leave" if t.k == 1 else None)
    must.start(), maybe.start()
    must.joined.wait(5), maybe.joined.wait(5)
    c.wait_for_participants(5)
    c.tick(0, 0.0)
    t0 = time.perf_counter()
    c.tick(1, 0.1)  # maybe leaves instead of acking: dropped at once, the run goes on
    assert time.perf_counter() - t0 < 1.0
    c.tick(2, 0.2)
    rep = c.report()["members"]
    assert "left the run (tired)" in rep["maybe"]["gone"] and rep["must"]["acks"] == 3
    assert c.active() == ["must"]
    must.p.leave("bye")
    with pytest.raises(ParticipantLost, match=r"participant 'must' lost: left the run \(bye\)"):
        c.tick(3, 0.3)
    c.close()


@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_a_box_that_joins_a_running_run_catches_up_and_is_waited_for(buses, mode):
    """An optional participant (a box) joining a run already ticking: the tick in progress when it joins did
    not wait for it, so the next one can arrive before it acked the first; that ack of a tick the master no
    longer waits for was once a ValueError ("ack of tick 25, but the current tick is 26") that killed the box.
    It is dropped (counted), the box goes on with the next tick, and from there the master waits for it."""
    c = coordinator(buses("master"), "early", Expected("box", required=False), mode=mode, resend_s=0.02)
    early = App(buses("early"), "early")
    early.start()
    c.wait_for_participants(5, optional=["box"]) if mode == "lockstep" else None
    first = []

    def slow_first(tick):  # the box's first step takes long (loading a detector)
        if not first:
            first.append(tick.k)
            time.sleep(0.3)

    box = App(buses("box"), "box", work=slow_first)
    k = 0
    for k in range(60):
        if k == 5:
            box.start()
        if mode == "lockstep":
            c.tick(k, k * 0.05)
        else:
            c.publish_mapping(0.0, time.time_ns(), 1.0) if k == 0 else None
            c.announce(k, k * 0.05)
        time.sleep(0.01)
    c.end("completed")
    box.join(5)
    early.join(5)
    assert box.error is None and early.error is None, (box.error, early.error)
    assert first and len(box.seen) > 10
    rep = c.report()["members"]["box"]
    if mode == "lockstep":
        ks = [k for k, _ in box.seen]
        assert ks == sorted(ks) and box.p.stale_acks >= 1  # the tick that did not wait for it
        assert rep["acks"] >= len(box.seen) - box.p.stale_acks - 1 and rep["timeouts"] == 0
    c.close()


def test_late_and_duplicate_acks_are_counted_and_ignored(buses):
    mbus = buses("master")
    c = coordinator(mbus, "a")
    bus = buses("a")
    app = App(bus, "a")
    app.start()
    c.wait_for_participants(5)
    for k in range(3):
        c.tick(k, k * 0.1)
    session = app.p.session
    for k in (0, 1, 1):  # late acks of old ticks
        bus.publish("time/ack/a", m.encode(m.Ack("a", session, k)), 0.0)
    bus.publish("time/ack/a", m.encode(m.Ack("a", session, 2)), 0.0)  # a duplicate of the current tick
    bus.publish("time/ack/a", m.encode(m.Ack("a", session, 99)), 0.0)  # a tick never sent
    bus.publish("time/ack/a", m.encode(m.Ack("a", "other-session", 2)), 0.0)
    bus.publish("time/ack/a", b"garbage", 0.0)
    bus.publish("time/ack/b", m.encode(m.Ack("a", session, 2)), 0.0)  # name and key disagree
    deadline = time.monotonic() + 2
    while time.monotonic() < deadline and sum(c.report()["protocol_errors"].values()) < 4:
        time.sleep(0.01)
    rep = c.report()
    assert rep["members"]["a"]["late_acks"] == 3 and rep["members"]["a"]["duplicate_acks"] == 1
    assert rep["members"]["a"]["acks"] == 3
    errors = " | ".join(rep["protocol_errors"])
    assert "tick 99, which was not sent yet" in errors and "old session of 'a'" in errors
    assert "not UTF-8 JSON" in errors and "does not match the key" in errors
    c.tick(3, 0.3)  # and the run goes on
    c.end("completed")
    c.close()


class DropFirstTick:
    """A bus that loses the first tick, as UDP may."""

    def __init__(self, bus):
        self.bus, self.dropped = bus, 0

    def publish(self, key, payload, t_sim, stamps=None):
        if key == m.TICK and not self.dropped:
            self.dropped = 1
            return 0
        return self.bus.publish(key, payload, t_sim, stamps)

    def __getattr__(self, name):
        return getattr(self.bus, name)


def test_a_lost_tick_is_sent_again(buses):
    c = coordinator(DropFirstTick(buses("master")), "a", resend_s=0.05)
    app = App(buses("a"), "a")
    app.start()
    c.wait_for_participants(5)
    c.tick(0, 0.0)
    assert c.resends >= 1 and c.report()["members"]["a"]["acks"] == 1
    c.end("completed")
    c.close()


# -- joining -------------------------------------------------------------------------------------------
def test_join_timeout_names_the_missing(buses):
    c = coordinator(buses("master"), "rsu1", "av1", Expected("extra", required=False))
    App(buses("av1"), "av1").start()
    with pytest.raises(JoinTimeout, match=r"participant\(s\) 'rsu1' did not join within 0.5 s"):
        c.wait_for_participants(0.5)
    c.close()


def test_incompatible_version_is_refused_naming_both_versions(buses):
    c = coordinator(buses("master"), "old")
    p = Participant(buses("old"), "old", "echo", version=(2, 0))
    with pytest.raises(Refused, match=r"protocol version 2\.0 of participant 'old' is incompatible with the "
                                      r"master's protocol version 1\.1"):
        p.join(5)
    with pytest.raises(JoinTimeout, match="'old' was refused: protocol version 2.0"):
        c.wait_for_participants(0.2)
    assert c.report()["refused"][0]["version"] == "2.0"
    c.close()


def test_refusal_fails_the_master_when_configured(buses):
    c = coordinator(buses("master"), "x", on_refused="fail")
    with pytest.raises(Refused):
        Participant(buses("x"), "x", "echo", version=(0, 9)).join(5)
    with pytest.raises(Refused, match="participant 'x' refused by the master: protocol version 0.9"):
        c.wait_for_participants(5)
    c.close()


def test_strangers_wrong_roles_and_name_thieves_are_refused(buses):
    c = coordinator(buses("master"), Expected("rsu1", role="rsu_app"))
    with pytest.raises(Refused, match=r"'ghost' is not an expected participant \(expected: rsu1\)"):
        Participant(buses("ghost"), "ghost", "rsu_app").join(5)
    with pytest.raises(Refused, match="role 'av_app' does not match the scenario's role 'rsu_app'"):
        Participant(buses("rsu1a"), "rsu1", "av_app").join(5)
    Participant(buses("rsu1b"), "rsu1", "rsu_app").join(5)
    with pytest.raises(Refused, match="the name 'rsu1' is taken by a live participant"):
        Participant(buses("rsu1c"), "rsu1", "rsu_app").join(5)
    c.wait_for_participants(1)
    c.close()


def test_participant_without_master_gets_a_clear_timeout(buses):
    with pytest.raises(JoinTimeout, match="no answer from the master"):
        Participant(buses("lonely"), "lonely", "echo").join(0.3)


def test_participant_notices_a_silent_master(buses):
    c = coordinator(buses("master"), "a", master_timeout_s=0.4)
    p = Participant(buses("a"), "a", "echo")
    p.join(5)
    c.close()  # the master dies without a word
    t0 = time.perf_counter()
    with pytest.raises(MasterLost, match="nothing from the master"):
        p.next_tick()
    assert time.perf_counter() - t0 < 2
    p.close()


# -- latency policies ------------------------------------------------------------------------------------------
def test_fixed_latency_policy_is_exact(buses):
    c = coordinator(buses("master"), Expected("rsu", latencies={"detect": 0.05, "encode": 0.002}))
    p = Participant(buses("rsu"), "rsu", "rsu_app")
    p.join(5)
    assert p.welcome.latency_policy == "fixed"
    ticking = threading.Thread(target=c.tick, args=(3, 0.3), daemon=True)
    ticking.start()
    tick = p.next_tick(5)
    assert p.output_time("detect", processing_s=9.9) == 0.3 + 0.05  # processing time ignored: reproducible
    assert p.output_time("encode", tick=tick) == 0.3 + 0.002
    with pytest.raises(ValueError, match=r"no fixed latency for stage 'track' \(configured: detect, encode\)"):
        p.output_time("track")
    p.ack(tick, 0.01)
    with pytest.raises(ValueError, match="ack of tick 2, but the current tick is 3"):
        p.ack(m.Tick(2, 0.2))
    ticking.join(5)  # the ack ended the tick (closing before it arrived left the tick resending)
    assert not ticking.is_alive() and c.report()["members"]["rsu"]["acks"] == 1
    assert c.report()["members"]["rsu"]["latencies_s"] == {"detect": 0.05, "encode": 0.002}
    c.close()
    p.close()


def test_measured_latency_policy_adds_processing_time(buses):
    c = coordinator(buses("master"), "av", latency_policy="measured")
    p = Participant(buses("av"), "av", "av_app")
    p.join(5)
    ticking = threading.Thread(target=c.tick, args=(0, 1.5), daemon=True)
    ticking.start()
    tick = p.next_tick(5)
    assert p.output_time("plan", processing_s=0.0123) == 1.5 + 0.0123
    with pytest.raises(ValueError, match="'measured' latency policy needs processing_s"):
        p.output_time("plan")
    p.ack(tick, 0.0123)
    ticking.join(5)  # the ack ends the tick: no ticking thread outlives the test and its buses
    assert not ticking.is_alive()
    rep = c.report()
    assert rep["latency_policy"] == "measured"
    assert rep["members"]["av"]["processing_s"]["max"] == pytest.approx(0.0123)
    c.close()
    p.close()


# -- realtime ---------------------------------------------------------------------------------------------------
def test_offset_estimate_with_a_skewed_clock(buses):
    """A participant whose clock runs 0.25 s ahead estimates the offset within a few ms and corrects for it."""
    c = coordinator(buses("master"), "box", mode="realtime")
    skew = 250_000_000
    p = Participant(buses("box"), "box", "box", clock_ns=lambda: time.time_ns() + skew)
    p.join(5)  # realtime: estimates and reports the offset on join
    assert p.offset is not None and abs(p.offset.offset_ns + skew) < 3_000_000
    assert abs(p.master_time_ns() - time.time_ns()) < 3_000_000
    deadline = time.monotonic() + 2
    while c.report()["members"]["box"]["clock_offset"] is None and time.monotonic() < deadline:
        time.sleep(0.01)
    recorded = c.report()["members"]["box"]["clock_offset"]
    assert recorded["offset_ns"] == p.offset.offset_ns and recorded["samples"] == 8
    # the mapping: sim time now, through the corrected clock
    with pytest.raises(TimeSyncError, match="no time mapping"):
        p.sim_time_now()
    c.publish_mapping(10.0, time.time_ns(), 2.0)
    deadline = time.monotonic() + 2
    while p.mapping is None and time.monotonic() < deadline:
        time.sleep(0.005)
    time.sleep(0.1)
    assert p.sim_time_now() == pytest.approx(10.2, abs=0.03)  # rtf 2: 0.1 wall s = 0.2 sim s
    # a mapping that would stop the run clock is refused by its receiver, which keeps the one it has
    good = p.mapping
    with pytest.raises(ValueError, match="field 'rtf' must be a finite number > 0"):
        c.publish_mapping(10.0, time.time_ns(), 0.0)  # the master cannot send one
    c.bus.publish(m.MAPPING, b'{"type": "map", "v": [1, 1], "t_sim0": 10.0, "wall0_ns": 5, "rtf": 0}', 10.0)
    deadline = time.monotonic() + 2
    while not any("rtf" in e for e in p.errors) and time.monotonic() < deadline:
        time.sleep(0.005)
    assert p.mapping is good and any("map: field 'rtf' must be a finite number > 0" in e for e in p.errors), p.errors
    assert p.output_time("detect", 0.5) == pytest.approx(p.sim_time_now(), abs=0.01)  # wall clock charges the work
    c.announce(0, 10.0)
    p.ack(p.next_tick(2))  # a no-op in realtime
    assert c.report()["members"]["box"]["acks"] == 0 and c.report()["latency_policy"] == "realtime (wall clock)"
    c.close()
    p.close()


def test_closing_the_coordinator_ends_a_tick_still_waiting(buses):
    """A tick waiting for an ack that can no longer come returns when the coordinator closes, instead of
    resending on a bus its owner closes next (an unhandled error in the ticking thread)."""
    c = coordinator(buses("master"), Expected("mute", timeout_s=30), heartbeat_timeout_s=30)
    p = Participant(buses("mute"), "mute", "x")
    p.join(5)
    errors = []

    def tick():
        try:
            c.tick(0, 0.0)
        except Exception as exc:  # noqa: BLE001 (the test asserts there is none)
            errors.append(exc)

    ticking = threading.Thread(target=tick, daemon=True)
    ticking.start()
    p.next_tick(5)  # never acked
    time.sleep(0.2)
    assert ticking.is_alive()
    c.close()
    ticking.join(2)
    assert not ticking.is_alive() and errors == []
    assert c.report()["members"]["mute"]["timeouts"] == 0
    p.close()


def test_a_closed_coordinator_publishes_nothing(buses):
    """A tick() or announce() that starts after close() (a ticking thread racing with the end of the run) returns
    without touching the bus its owner closes next: publishing there raised TransportError in that thread."""
    bus = buses("master")
    c = coordinator(bus, Expected("mute", timeout_s=30), heartbeat_timeout_s=30)
    p = Participant(buses("mute"), "mute", "x")
    p.join(5)
    c.close()
    bus.close()
    c.tick(0, 0.0)
    c.announce(1, 0.1)
    c.publish_mapping(0.0, time.time_ns(), 1.0)
    assert c.ticks == 0 and p.next_tick(0.2) is None
    p.close()


def test_realtime_app_that_fell_behind_gets_the_newest_tick(buses):
    c = coordinator(buses("master"), "slow", mode="realtime")
    p = Participant(buses("slow"), "slow", "x", auto_offset=False)
    p.join(5)
    for k in range(5):
        c.announce(k, k * 0.1)
    time.sleep(0.2)
    assert p.next_tick(2).k == 4 and p.skipped_ticks == 4
    c.close()
    p.close()


def test_a_flood_of_strangers_is_counted_in_bounded_memory(buses):
    c = coordinator(buses("master"), "a")
    evil = buses("evil")
    for i in range(300):
        evil.publish(f"time/hb/x{i}", m.encode(m.Heartbeat(f"x{i}", "s")), 0.0)
    deadline = time.monotonic() + 3
    while sum(c.report()["protocol_errors"].values()) < 300 and time.monotonic() < deadline:
        time.sleep(0.01)
    errors = c.report()["protocol_errors"]
    assert sum(errors.values()) == 300 and len(errors) <= 101
    assert errors["other reasons (too many distinct ones to list)"] == 200
    c.close()


def test_an_optional_participant_the_master_started_is_waited_for_at_the_start(buses):
    """Optional apps the master started are on their way: the run waits for them (up to the join timeout) so a
    lockstep one starts at the first tick, not mid-run; without being named, an optional one is not waited for."""
    c = coordinator(buses("master"), Expected("late", required=False))
    app = App(buses("late"), "late")
    threading.Timer(0.4, app.start).start()
    t0 = time.perf_counter()
    c.wait_for_participants(5, optional=["late"])
    assert 0.35 <= time.perf_counter() - t0 < 5 and c.members["late"].join is not None
    c.tick(0, 0.0)
    assert app.seen[:1] == [(0, 0.0)]  # it saw the first tick
    c.end("completed")
    c.close()
    app.join(5)
    assert app.error is None

    c2 = coordinator(buses("master2"), Expected("absent", required=False))
    t0 = time.perf_counter()
    c2.wait_for_participants(0.3, optional=["absent"])  # never joins: the run starts without it, no error
    assert 0.3 <= time.perf_counter() - t0 < 2
    c2.wait_for_participants(5)  # not named: not waited for
    c2.close()
