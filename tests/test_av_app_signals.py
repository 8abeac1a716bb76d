"""AV app: stop at a red signal of its approach from the RSU's MAP and SPaT (signed frames through the OBU).

The MAP is the one the RSU app generates from the world (rsu_app.intersection_map): approach 1 (the south
arm, northbound) has its stop line 1 m before the crossing road, under the signal head facing south.
"""
from __future__ import annotations

import math
import time
from datetime import datetime, timedelta, timezone

import pytest

from bridges.geo import GeoOrigin
from bridges.j2735.map import MapData
from bridges.j2735.spat import IntersectionSignals, Movement, Spat
from bridges.security import PSID_SPAT_MAP, ScenarioCA, Signer, Verifier, time64_us
from bridges.sensor_stream import GnssFix
from bridges.v2x import unix_time
from av_app.config import build
from av_app.core import AvCore
from av_app.obu import Obu
from av_app.timing import StageClock
from rsu_app.intersection_map import intersection_geometry

ORIGIN = GeoOrigin()
EPOCH = time.time() + 60.0
WORLD = {"intersection": {"road_width": 7.0, "lane_width": 3.5, "arm_length": 120.0, "sidewalk_width": 2.0},
         "signals": [{"name": "nb", "x": 5.0, "y": 5.0, "yaw": 270.0, "signal_group": 2},
                     {"name": "eb", "x": 5.0, "y": -5.0, "yaw": 180.0, "signal_group": 8}]}
STOP_LINE_Y = -(3.5 + 1.0)


@pytest.fixture(scope="module")
def rsu():
    # valid from an hour ago: EPOCH is fixed when the module is collected, which in a full run can be
    # minutes before this fixture runs, and a certificate must already be valid at the frames' times
    start = datetime.now(timezone.utc) - timedelta(hours=1)
    ca = ScenarioCA.create(start=start)
    return ca, Signer(ca.issue("rsu", [PSID_SPAT_MAP], start=start), 0.0)


def core(rsu, **tables):
    cfg = build({"security": {"allow_unsecured": True}, "perception": {"enabled": False}, **tables})
    return AvCore(cfg, Obu(cfg.obu, ORIGIN, EPOCH, Verifier([rsu[0].certificate])),
                  StageClock("fixed", {}, cfg.latency), WORLD)


def send_map(c, rsu, t, right_group=None):
    g = intersection_geometry(WORLD, ORIGIN, 7, 1, 1.0)
    if right_group is not None:  # the right turn from the south arm under a signal group of its own
        lane = g.lane(11)
        for conn in lane.connections:
            if conn.maneuvers == frozenset({"right"}):
                conn.signal_group = right_group
    frame = MapData([g], revision=1).encode()
    assert c.on_v2x(rsu[1].sign(frame, PSID_SPAT_MAP, time64_us(unix_time(t, EPOCH))), t) is not None


def send_spat(c, rsu, t, states: dict[int, str]):
    spat = Spat([IntersectionSignals(7, movements=[Movement(g, s) for g, s in states.items()])]).encode()
    assert c.on_v2x(rsu[1].sign(spat, PSID_SPAT_MAP, time64_us(unix_time(t, EPOCH))), t) is not None


def ego_at(c, t, y, v):
    c.on_gnss(GnssFix(t, 1.75, y, 1.5, math.pi / 2, v))
    c.on_status(t, v, 0.0)


def plan(c, t):
    c.command(t, lambda a, s, m: 0)
    return c.last_plan


def test_red_for_its_approach_stops_it_with_the_bumper_before_the_stop_line(rsu):
    c = core(rsu)
    ego_at(c, 0.0, -40.0, 8.333)
    send_map(c, rsu, 0.0)
    send_spat(c, rsu, 0.0, {2: "stop-And-Remain", 8: "protected-Movement-Allowed"})
    p = plan(c, 0.02)
    assert p.decision == "stop_red" and p.cause == "signal group 2"
    stop = [st for st in p.stops if st.reason == "red"][0]
    front = stop.s - 120.0 + (4.5 - 0.95)  # route station -> y of the front bumper (the route starts at y = -120)
    assert STOP_LINE_Y - 0.8 < front < STOP_LINE_Y
    assert c.signals.last == {"intersection": 7, "lane": 11, "group": 2, "state": "stop-And-Remain"}


def test_green_or_no_spat_or_a_stale_one_do_not_stop_it(rsu):
    c = core(rsu)
    ego_at(c, 0.0, -40.0, 8.333)
    send_map(c, rsu, 0.0)
    assert plan(c, 0.02).decision == "cruise"  # a MAP but no SPaT yet
    send_spat(c, rsu, 0.04, {2: "protected-Movement-Allowed"})
    assert plan(c, 0.06).decision == "cruise"
    send_spat(c, rsu, 0.08, {2: "stop-And-Remain"})
    assert plan(c, 0.10).decision == "stop_red"
    ego_at(c, 1.5, -40.0 + 1.5 * 8.333, 8.333)
    assert plan(c, 1.5).decision == "cruise"  # that SPaT is 1.4 s old by now (signals.max_age_s = 1)


def test_yellow_stops_it_when_it_comfortably_can_and_not_in_the_dilemma_zone(rsu):
    """Straight on through the junction (no turn to slow for): 40 m out it stops; 10 m before the stop
    line at 30 km/h it would need 5.4 m/s^2, so it goes on."""
    straight = {"route": {"waypoints": [[1.75, -120.0], [1.75, 120.0]]}}
    far, near = core(rsu, **straight), core(rsu, **straight)
    for c, y in ((far, -40.0), (near, -15.0)):
        ego_at(c, 0.0, y, 8.333)
        send_map(c, rsu, 0.0)
        send_spat(c, rsu, 0.0, {2: "protected-clearance"})
    assert plan(far, 0.02).decision == "stop_red"
    assert plan(near, 0.02).decision == "cruise"


def test_the_signal_group_of_the_movement_it_makes_counts(rsu):
    """Its route turns right: the right-turn connection's own group rules, not the straight-on one's."""
    c = core(rsu)
    ego_at(c, 0.0, -40.0, 8.333)
    send_map(c, rsu, 0.0, right_group=12)
    send_spat(c, rsu, 0.0, {2: "stop-And-Remain", 12: "protected-Movement-Allowed"})
    assert plan(c, 0.02).decision == "cruise"
    send_spat(c, rsu, 0.04, {2: "protected-Movement-Allowed", 12: "stop-And-Remain"})
    p = plan(c, 0.06)
    assert p.decision == "stop_red" and p.cause == "signal group 12"


def test_closed_loop_it_waits_at_red_and_goes_on_green(rsu):
    from fmus.vehicle.model import VehicleModel, VehicleParams

    c = core(rsu)
    car = VehicleModel(VehicleParams(), x0=1.75, y0=-40.0, yaw0=math.pi / 2, v0=8.333)
    send_map(c, rsu, 0.0)
    accel = steer = 0.0
    log = []
    for k in range(1200):
        t = round(k * 0.01, 10)
        if k % 10 == 0:
            c.on_gnss(GnssFix(t, car.x, car.y, 1.5, car.yaw, car.v))
            green = t >= 9.0
            send_spat(c, rsu, t, {2: "protected-Movement-Allowed" if green else "stop-And-Remain"})
        if k % 2 == 0:
            c.on_status(t, car.v, car.yaw_rate)
            sent = []
            c.command(t, lambda a, s, m: sent.append((a, s)) or 0)
            accel, steer = sent[0]
            log.append((t, car.y + math.sin(car.yaw) * (4.5 - 0.95), car.v, c.last_plan.decision))
        car.step(0.01, accel, steer)
    waiting = [(t, front, v) for t, front, v, d in log if 7.0 < t < 9.0]
    assert all(v < 0.05 for _, _, v in waiting)  # standing at the red light
    assert all(STOP_LINE_Y - 1.0 < front < STOP_LINE_Y for _, front, _ in waiting)
    assert log[-1][2] > 2.0 and log[-1][1] > STOP_LINE_Y  # green: through the junction
