"""bridges.app_session: the join + clock loop + inbox + publish/trace an app gets from one helper.

On the in-process memory bus, against the master's own Coordinator: in lockstep a step hands over exactly what
arrived up to its tick (oldest first, later frames wait for their tick), is acknowledged only when the loop body
is done (so the measured policy charges the body's time), and output times follow the latency policy; in
realtime a step is "now" on the master's published clock mapping; a publish on a closed bus is counted, not raised.
"""
from __future__ import annotations

import itertools
import json
import threading
import time

import pytest

from bridges.app_session import AppSession
from bridges.timesync.coordinator import Coordinator, Expected
from bridges.timesync.errors import TimeSyncError
from bridges.transport.memory import MemoryBus
from bridges.v2x import EPOCH, rx_key, trace_key, tx_key

_ids = itertools.count()


@pytest.fixture
def buses():
    prefix = f"test/app-session-{next(_ids)}-{time.monotonic_ns()}"
    opened = []

    def make(name):
        opened.append(MemoryBus(prefix=prefix, sender=name))
        return opened[-1]

    yield make
    for bus in opened:
        bus.close()


def master(bus, *expected, **options):
    c = Coordinator(bus, list(expected), heartbeat_s=0.05, heartbeat_timeout_s=2.0, **options)
    c.start()
    return c


def collect(bus, key):
    got = []
    bus.subscribe(key, got.append)
    return got


def wait_for(predicate, timeout=3.0):
    deadline = time.monotonic() + timeout
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.005)
    return predicate()


def test_steps_before_joining_say_so(buses):
    s = AppSession("app", "hello_app", bus=buses("app"))
    with pytest.raises(TimeSyncError, match="open\\(\\) \\(join\\) before steps\\(\\)"):
        next(s.steps())


def test_lockstep_hands_over_what_arrived_up_to_each_tick_and_acks_after_the_body(buses):
    mbus = buses("master")
    c = master(mbus, Expected("app", latencies={"send": 0.002}), latency_policy="fixed",
               world={EPOCH: 1_700_000_000.0})
    sent, traced = collect(mbus, tx_key("app")), collect(mbus, trace_key("app"))
    s = AppSession("app", "hello_app", listen=[rx_key("app")], publishes=[tx_key("app")], bus=buses("app"))
    seen, acked_during_body = [], []

    def app():
        for step in s.steps():
            seen.append((step.t, step.until, [(m.t_sim, m.payload) for m in step.heard]))
            acked_during_body.append(c.report()["members"]["app"]["acks"])
            t = s.output_time("send")
            s.publish(tx_key("app"), b"frame", t)
            s.trace({"what": "sent"}, step.t, stamps={"send": round(t * 1e9)})

    assert s.open(join_timeout_s=5).mode == "lockstep"
    assert s.epoch == 1_700_000_000.0 and s.epoch_from_master
    worker = threading.Thread(target=app, daemon=True)
    worker.start()
    c.wait_for_participants(5)
    # heard out of order: 0.15 before 0.05; the 0.25 one is due after the last tick
    for t, data in ((0.15, b"b"), (0.05, b"a"), (0.25, b"c")):
        mbus.publish(rx_key("app"), data, t)
    assert wait_for(lambda: s.heard == 0 and len(s._inbox) == 3)
    for k in range(3):
        c.tick(k, k * 0.1, 0.1)
    c.end("completed")
    worker.join(5)
    assert not worker.is_alive()
    assert seen == [(0.0, 0.1, []), (0.1, 0.2, [(0.05, b"a")]), (0.2, pytest.approx(0.3), [(0.15, b"b")])]
    assert acked_during_body == [0, 1, 2]  # each tick acked after its body, not before
    assert s.ticks == 3 and s.heard == 2
    assert wait_for(lambda: len(sent) == 3 and len(traced) == 3)
    assert [m.t_sim for m in sent] == pytest.approx([0.002, 0.102, 0.202])  # tick + the fixed latency
    assert json.loads(traced[1].payload) == {"what": "sent", "stamps": {"send": 102_000_000}}
    assert traced[1].stamps == {"send": 102_000_000}
    s.close()
    c.close()


def test_measured_policy_charges_the_body_and_a_closed_bus_is_counted(buses):
    mbus = buses("master")
    c = master(mbus, Expected("app"), latency_policy="measured")
    s = AppSession("app", "hello_app", bus=buses("app"))
    times = []

    def app():
        for step in s.steps():
            time.sleep(0.03)
            times.append((step.t, s.output_time("plan")))

    s.open(join_timeout_s=5)
    assert s.epoch > 0 and not s.epoch_from_master  # no epoch in the welcome: this app's join time
    worker = threading.Thread(target=app, daemon=True)
    worker.start()
    c.wait_for_participants(5)
    c.tick(0, 1.0, 0.1)
    c.end("completed")
    worker.join(5)
    (t, out), = times
    assert t == 1.0 and 1.03 <= out < 1.5
    assert c.report()["members"]["app"]["processing_s"]["max"] >= 0.03
    s.bus.close()
    assert s.publish("v2x/tx/app", b"late", 2.0) is None and s.publish_errors == 1 and s.published == 0
    s.close()
    c.close()


def test_realtime_steps_follow_the_masters_clock(buses):
    mbus = buses("master")
    c = master(mbus, Expected("app"), mode="realtime")
    s = AppSession("app", "hello_app", listen=[rx_key("app")], bus=buses("app"), poll_s=0.002)
    steps = []

    def app():
        for step in s.steps():
            steps.append((time.time_ns(), step.t, [m.payload for m in step.heard]))

    assert s.open(join_timeout_s=5).mode == "realtime"
    worker = threading.Thread(target=app, daemon=True)
    worker.start()
    c.wait_for_participants(5)
    wall0 = time.time_ns()
    c.publish_mapping(5.0, wall0, 1.0)
    mbus.publish(rx_key("app"), b"now", 5.0)
    mbus.publish(rx_key("app"), b"later", 1e6)  # far in the future: never handed over
    time.sleep(0.2)
    c.end("completed")
    worker.join(5)
    assert not worker.is_alive() and len(steps) > 10
    for wall, t, _ in steps:  # each step is the master's sim time at that wall instant (same clock here)
        assert t == pytest.approx(5.0 + (wall - wall0) / 1e9, abs=0.01)
    assert [p for _, _, heard in steps for p in heard] == [b"now"]
    s.close()
    c.close()
