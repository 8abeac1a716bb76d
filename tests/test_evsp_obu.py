"""The ev's OBU logic (obu_app.core), without bus: from the RSU's MAP it finds its lane, approach and signal group;
it asks when its ETA to the stop line falls below the horizon, renews at the SRM rate, cancels once through; it
reads its request's SSM status and its group's SPaT state. The SRMs it sends are the ones the RSU's
PriorityCore grants (issue 39)."""
from __future__ import annotations

import pytest

from bridges.geo import GeoOrigin
from bridges.j2735.signal_request import Srm, Ssm
from bridges.j2735.spat import IntersectionSignals, Movement, Spat
from obu_app.core import DONE, EvsConfig, EvsCore, Pose, locate
from rsu_app.intersection_map import intersection_geometry
from rsu_app.priority import PriorityCore, ingress_lanes

WORLD = {"intersection": {"road_width": 7.0, "lane_width": 3.5, "arm_length": 120.0, "sidewalk_width": 2.0},
         "signals": [{"name": "nb", "x": 5.0, "y": 5.0, "yaw": 270.0, "signal_group": 2},
                     {"name": "eb", "x": 5.0, "y": -5.0, "yaw": 180.0, "signal_group": 8}]}
STOP_X = -(3.5 + 1.0)       # the west arm's stop line: road half width + 1 m
GEOMETRY = intersection_geometry(WORLD, GeoOrigin(), 1201, 1, 1.0)


def eastbound(x: float, speed: float = 13.89) -> Pose:
    return Pose(x, -1.75, 90.0, speed)


def test_the_ev_finds_its_lane_approach_and_group_from_the_map():
    on = locate(GEOMETRY, eastbound(-100.0))
    assert (on.lane_id, on.approach, on.signal_group) == (21, 2, 8)
    assert on.to_stop_line_m == pytest.approx(-100.0 * -1 + STOP_X)
    assert locate(GEOMETRY, Pose(-100.0, -1.75, 270.0, 10.0)) is None   # westbound on the egress lane
    assert locate(GEOMETRY, Pose(-100.0, -30.0, 90.0, 10.0)) is None    # off the road


def run(horizon=8.0, speed=13.89, x0=-150.0, dt=0.1, until=20.0):
    core = EvsCore(EvsConfig(horizon_s=horizon), GEOMETRY)
    out, x, t = [], x0, 0.0
    while t < until and core.state != DONE:
        for kind, srm in core.step(t, eastbound(x, speed)):
            out.append((round(t, 3), kind, Srm.decode(srm.encode())))
        x += speed * dt
        t = round(t + dt, 6)
    return core, out


def test_it_asks_below_the_horizon_renews_at_the_rate_and_cancels_once_through():
    core, out = run()
    kinds = [k for _, k, _ in out]
    t_first = out[0][0]
    eta_first = (STOP_X - (-150.0 + 13.89 * t_first)) / 13.89   # the ev's ETA when it first asked
    assert kinds[0] == "request" and 8.0 - 0.1 <= eta_first <= 8.0 + 1e-6
    updates = [t for t, k, _ in out if k == "update"]
    assert all(b - a == pytest.approx(1.0) for a, b in zip([t_first] + updates, updates))
    assert kinds[-3:] == ["cancel"] * 3 and core.state == DONE
    t_cancel = next(t for t, k, _ in out if k == "cancel")
    # the first cancel comes once the ev is through_m past the stop line
    assert -150.0 + 13.89 * t_cancel - STOP_X >= core.cfg.through_m
    first = out[0][2]
    req = first.requests[0]
    assert first.requestor.role == "emergency" and req.inbound.id == 21 and req.intersection_id == 1201
    assert out[1][2].requests[0].request_type == "priorityRequestUpdate"
    assert out[-1][2].requests[0].request_type == "priorityCancellation"


def test_the_rsu_grants_what_the_ev_asks_and_the_ev_reads_it_from_the_ssm():
    rsu = PriorityCore(1201, ingress_lanes(GEOMETRY), {4, 8})
    core = EvsCore(EvsConfig(horizon_s=8.0), GEOMETRY)
    t, x = 0.0, -150.0
    while core.t_first_request is None:
        for _, srm in core.step(t, eastbound(x)):
            rsu.on_srm(srm, t)
        t, x = t + 0.1, x + 1.389
    assert rsu.step(t).preempt is True
    rsu.on_preempt_sent(True, t)
    rsu.on_controller(1 << 7, True, t + 5)
    core.on_ssm(Ssm.decode(rsu.ssm().encode()))
    assert core.ssm_status == "granted"
    core.on_spat(Spat([IntersectionSignals(1201, movements=[Movement(8, "protected-Movement-Allowed")])]))
    assert core.signal_state == "protected-Movement-Allowed"


def test_a_stopped_ev_far_away_does_not_ask_and_bad_settings_are_named():
    core, out = run(speed=0.0, until=3.0)
    assert out == [] and core.state == "idle"
    with pytest.raises(ValueError, match="evsp.horizon_s"):
        EvsConfig(horizon_s=-1.0).validate()
    with pytest.raises(ValueError, match="evsp.request_id"):
        EvsConfig(request_id=300).validate()
