"""Commit or yield (issue 38), the pure decision at its boundary: a yield is a plan only while the vehicle
can still stop before the conflict zone; past that commit point it goes on, because standing in the zone is
the worst choice; before it, it yields comfortably unless going on clears the object by the PET margin.

The boundary is computed here from the kinematics (v^2 / 2d = room), independently of av_app's code."""
from __future__ import annotations

import math

import pytest

from av_app.planner import STOP_SLACK_M, commit_or_yield, stop_decel

V0 = 5.0  # m/s, about the case study's turn speed
ZONE = 112.5  # the zone's first station (the case study's: the cav's grown footprint touches the ev's lane)
MARGIN = 1.0  # planner.stop_margin_m
COMFORT, MAX = 3.0, 8.0  # control.decel_comfort, vehicle.max_decel
KW = dict(pet_margin=3.0, merge_gap=1.0, stop_margin=MARGIN, decel_comfort=COMFORT, max_decel=MAX)


def station_for(decel: float) -> float:
    """The station from which stopping MARGIN before the zone takes exactly `decel`."""
    return ZONE - MARGIN - V0 * V0 / (2 * decel)


def test_stop_decel_is_the_kinematic_deceleration_and_infinite_past_the_zone():
    assert stop_decel(V0, station_for(2.5), ZONE, MARGIN) == pytest.approx(2.5)
    assert stop_decel(0.0, ZONE - 0.3, ZONE, MARGIN) == 0.0  # standing outside the zone: nothing to do
    # past the stop point, what is left of the margin still counts; in the zone, nothing does
    s = ZONE - 0.5
    assert stop_decel(1.0, s, ZONE, MARGIN) == pytest.approx(1.0 / (2 * (0.5 - STOP_SLACK_M)))
    assert stop_decel(1.0, ZONE - STOP_SLACK_M + 0.01, ZONE, MARGIN) == math.inf
    assert stop_decel(0.0, ZONE + 0.1, ZONE, MARGIN) == math.inf  # standing in it: it cannot stop "before" it
    # ... unless "in it" is within the footprints' safety margins (0.4 m each): standing there is clear
    assert stop_decel(0.0, ZONE + 0.5, ZONE, MARGIN, grown=0.8) == 0.0
    assert stop_decel(0.0, ZONE + 0.9, ZONE, MARGIN, grown=0.8) == math.inf
    ch = commit_or_yield("ev", 0.0, ZONE + 0.5, ZONE, -0.3, grown=0.8, **KW)  # the cav at the line, ev passing
    assert (ch.action, ch.why) == ("yield", "comfortable_yield")


@pytest.mark.parametrize("gap", [None, -0.5, 0.5, 2.0])
def test_a_yield_just_inside_the_comfortable_commit_point_is_comfortable_unless_going_on_clears(gap):
    ch = commit_or_yield("ev", V0, station_for(COMFORT) - 0.01, ZONE, gap, **KW)
    if gap is None:  # nothing of the object on the path if it goes on
        assert (ch.action, ch.why) == ("go", "clear_ahead")
    else:
        assert (ch.action, ch.why) == ("yield", "comfortable_yield")
        assert ch.need_decel <= COMFORT
    assert commit_or_yield("ev", V0, station_for(COMFORT) - 0.01, ZONE, 3.2, **KW).why == "clear_ahead"


def test_following_an_object_that_has_passed_needs_the_pet_margin_to_be_clear():
    s = station_for(COMFORT) - 1.0  # a comfortable yield is possible
    assert commit_or_yield("ev", V0, s, ZONE, None, behind_gap=1.2, **KW).why == "comfortable_yield"
    assert commit_or_yield("ev", V0, s, ZONE, None, behind_gap=3.2, **KW).why == "clear_ahead"
    s = station_for(COMFORT) + 0.5  # past the comfortable commit point, merge_gap behind it is safe
    assert commit_or_yield("ev", V0, s, ZONE, None, behind_gap=1.2, **KW).why == "merge_ahead"
    assert commit_or_yield("ev", V0, s, ZONE, None, behind_gap=0.8, **KW).why == "hard_yield"


def test_a_slow_down_that_keeps_the_pet_margin_is_taken_before_any_stop_or_merge():
    """Where slowing to some speed lets the object pass first with the PET margin (the planner's `slow`),
    that is the give-way: before a comfortable stop, a merge at merge_gap and a hard brake; but not when going
    on clears the object by the margin anyway, nor against a decision to go that is still safe."""
    for s, gap in ((station_for(COMFORT) - 1.0, 1.5), (station_for(COMFORT) + 0.05, 1.2),
                   (station_for(COMFORT) + 0.05, 0.8)):
        ch = commit_or_yield("ev", V0, s, ZONE, gap, slow=3.5, **KW)
        assert (ch.action, ch.why, ch.cap) == ("slow", "slow_yield", 3.5)
    assert commit_or_yield("ev", V0, station_for(COMFORT) - 1.0, ZONE, 3.2, slow=3.5, **KW).why == "clear_ahead"
    assert commit_or_yield("ev", V0, station_for(COMFORT) - 1.0, ZONE, 1.5, slow=3.5, going=True,
                           **KW).why == "merge_ahead"
    # without one, the stops of before
    assert commit_or_yield("ev", V0, station_for(COMFORT) - 1.0, ZONE, 1.5, **KW).why == "comfortable_yield"
    assert commit_or_yield("ev", V0, station_for(COMFORT) + 0.05, ZONE, 0.8, **KW).why == "hard_yield"


def test_just_past_the_comfortable_commit_point_a_safe_merge_beats_a_hard_brake():
    s = station_for(COMFORT) + 0.05
    ch = commit_or_yield("ev", V0, s, ZONE, 1.2, **KW)  # the ev 1.2 s behind through the merge: enough
    assert (ch.action, ch.why) == ("go", "merge_ahead")
    ch = commit_or_yield("ev", V0, s, ZONE, 0.8, **KW)  # not enough: brake hard, but before the zone
    assert (ch.action, ch.why) == ("yield", "hard_yield") and COMFORT < ch.need_decel <= MAX
    # a merge that clears the zone but that the ev, not braking, would close on afterwards is not safe
    ch = commit_or_yield("ev", V0, s, ZONE, 1.2, follow_gap=0.1, follow_need=0.3, **KW)
    assert (ch.action, ch.why) == ("yield", "hard_yield")


def test_at_the_last_commit_point_it_never_plans_to_stop_in_the_zone():
    before, after = station_for(MAX) - 0.05, station_for(MAX) + 0.05
    assert commit_or_yield("ev", V0, before, ZONE, 0.2, **KW).why == "hard_yield"
    ch = commit_or_yield("ev", V0, after, ZONE, 0.2, **KW)  # it cannot stop before the zone any more
    assert (ch.action, ch.why) == ("go", "committed_unsafe") and ch.need_decel > MAX
    assert commit_or_yield("ev", V0, ZONE + 2.0, ZONE, 1.5, **KW).why == "merge_ahead"  # inside, merging


def test_a_decision_to_go_is_kept_while_going_on_stays_safe():
    s = station_for(COMFORT) - 1.0  # a comfortable yield would be possible again
    assert commit_or_yield("ev", V0, s, ZONE, 1.5, **KW).why == "comfortable_yield"
    assert commit_or_yield("ev", V0, s, ZONE, 1.5, going=True, **KW).why == "merge_ahead"
    assert commit_or_yield("ev", V0, s, ZONE, 0.5, going=True, **KW).why == "comfortable_yield"  # not safe now
    # past the comfortable commit point, a gap one plan's noise short of merge_gap does not undo it
    s = station_for(COMFORT) + 0.5
    assert commit_or_yield("ev", V0, s, ZONE, 0.95, **KW).why == "hard_yield"
    assert commit_or_yield("ev", V0, s, ZONE, 0.95, going=True, **KW).why == "merge_ahead"
    assert commit_or_yield("ev", V0, s, ZONE, 0.6, going=True, **KW).why == "hard_yield"


@pytest.mark.parametrize("distance, speed, safe", [(53.0, 16.667, False), (53.0, 20.8, False),
                                                    (80.0, 16.667, True), (100.0, 16.667, True)])
def test_the_rsu_coverage_a_phantom_vehicle_would_need(distance, speed, safe):
    """docs/ima-timing.md: at the cav's comfortable commit point at its turn speed, merging ahead of a
    vehicle just beyond the RSU's coverage (60 m from the pole = 53 m from the junction on the west arm) at
    60 km/h is not safe, so a phantom there would stop the cav at every crossing; from 80 m it is."""
    from pathlib import Path

    from av_app.config import load
    from av_app.fusion import FusedObject
    from av_app.lanes import LaneMap
    from av_app.planner import Planner
    from av_app.route import Route

    # the shipped config's planner and route; its trust anchor is made by a first run (v2i pki init), which
    # a fresh clone has not had, and the planner does not verify anything
    cfg = load(Path(__file__).resolve().parent.parent / "scenarios" / "apps" / "av.toml",
               {"security": {"trust_anchor": "", "allow_unsecured": True}})
    route = Route(cfg.route.waypoints, cfg.route.corner_radius)
    v = math.sqrt(cfg.route.lateral_accel_max * cfg.route.corner_radius)  # the turn speed
    s = ZONE - MARGIN - v * v / (2 * cfg.control.decel_comfort)
    x, y, yaw, _ = route.at(s)
    phantom = FusedObject("phantom", "v2x", 0.0, -distance, -1.75, 0.0, speed, 0.0, 4.5, 1.8)
    plan = Planner(cfg, route, LaneMap(7.0, 230.0)).plan(0.0, (float(x), float(y), float(yaw)), v, [phantom])
    assert (plan.decision in ("cruise", "go")) is safe, (plan.decision, plan.choices, plan.conflicts)


# -- past the last commit point with going on unsafe: a stop only clear of its way -------------------------------------------
PAST = station_for(MAX) + 0.05  # braking at the limit no longer stops before the zone


def test_a_stop_that_leaves_the_objects_corridor_free_beats_an_unsafe_go():
    ch = commit_or_yield("ev", V0, PAST, ZONE, 0.2, blocked=0.0, **KW)
    assert (ch.action, ch.why) == ("yield", "stop_clear_of_path")


@pytest.mark.parametrize("gap, blocked", [(-0.2, 0.3), (-0.2, 0.8), (0.5, 0.05)])
def test_a_stop_that_blocks_any_of_the_objects_way_is_not_taken(gap, blocked):
    """Standing in its way, the object meets the ego at its full speed; going on, at the difference of their
    speeds (the case study without the RSU: 16.7 m/s standing, 9.2 m/s going on)."""
    ch = commit_or_yield("ev", V0, PAST, ZONE, gap, blocked=blocked, **KW)
    assert (ch.action, ch.why) == ("go", "committed_unsafe")


def test_once_stopping_clear_of_it_the_cav_stands_until_going_on_is_safe():
    ch = commit_or_yield("ev", 0.0, ZONE + 1.5, ZONE, 0.3, blocked=0.2, stood=True, **KW)
    assert (ch.action, ch.why) == ("yield", "stop_clear_of_path")  # setting off toward its way never helps
    assert commit_or_yield("ev", 0.0, ZONE + 1.5, ZONE, None, behind_gap=3.5, blocked=0.2, stood=True,
                           **KW).why == "clear_ahead"  # it has passed


def _object(x, y, yaw, width=1.8, length=4.5):
    from av_app.fusion import FusedObject
    return FusedObject("ev", "lidar", 0.0, x, y, yaw, 16.7, 0.0, length, width)


def test_the_blocked_fraction_is_the_standing_footprints_share_of_the_corridor():
    from av_app.config import PlannerSection, VehicleSection
    from av_app.estimator import CollisionEstimator

    veh, pl = VehicleSection(), PlannerSection()
    est = CollisionEstimator(pl, veh)
    front = veh.length - veh.rear_overhang  # rear axle to nose
    half = 1.8 / 2 + pl.margin_m / 2  # the corridor: the ev's width and half the margin on each side
    ev = _object(-30.0, -1.75, 0.0)  # eastbound in the lane centre
    north = math.pi / 2
    assert est.blocked(ev, (1.75, -1.75 - half - 0.05 - front, north)) == 0.0  # the nose short of it
    into = 0.5
    assert est.blocked(ev, (1.75, -1.75 - half + into - front, north)) == pytest.approx(into / (2 * half))
    assert est.blocked(ev, (1.75, -4.0, north)) == 1.0  # across it
    assert est.blocked(ev, (-40.0, -1.75, 0.0)) == 0.0  # behind it in its lane: its business
    # the corridor is the lane's, not the lidar box's biased centre (0.9 m toward the sensor)
    biased = _object(-30.0, -2.65, 0.0)
    pose = (1.75, -1.75 - half + into - front, north)
    assert est.blocked(biased, pose, 0.9) == pytest.approx(into / (2 * half))
    assert est.blocked(biased, pose) > est.blocked(biased, pose, 0.9)


def test_an_object_of_no_measured_width_has_a_car_wide_corridor():
    """A lidar cluster seen end-on measures 0 m wide; the ev it stands for is not: the ego standing 0.5 m into
    the lane blocks a car-wide corridor (the ego's width), not a 0.4 m one it would seem to miss."""
    from av_app.config import PlannerSection, VehicleSection
    from av_app.estimator import CollisionEstimator

    veh, pl = VehicleSection(), PlannerSection()
    est = CollisionEstimator(pl, veh)
    front = veh.length - veh.rear_overhang
    half = veh.width / 2 + pl.margin_m / 2
    thin = _object(-30.0, -1.75, 0.0, width=0.0)
    into = 0.5
    pose = (1.75, -1.75 - half + into - front, math.pi / 2)
    assert est.blocked(thin, pose) == pytest.approx(into / (2 * half))
    assert est.blocked(thin, (1.75, -1.75 - half - 0.05 - front, math.pi / 2)) == 0.0


@pytest.mark.parametrize("x, y, yaw, shift", [
    (-30.0, -2.65, 0.0, 0.9),              # eastbound, its box biased south: the lane centre is 0.9 m left
    (-2.0, -2.65, 0.0, 0.9),               # in the junction box its heading names the road
    (30.0, 1.0, math.pi, -0.75),           # westbound north of the centre line: the centre at y = 1.75
    (1.0, -30.0, math.pi / 2, -0.75),      # northbound: the centre at x = 1.75, to its right
    (-30.0, -2.65, math.radians(60), 0.0),  # following neither road
    (-30.0, -20.0, 0.0, 0.0),              # off the roads
])
def test_the_lane_centre_shift(x, y, yaw, shift):
    from av_app.lanes import LaneMap

    assert LaneMap(7.0, 120.0).centre_shift(_object(x, y, yaw)) == pytest.approx(shift)


@pytest.mark.parametrize("edge_x, speed, slows", [(-243.4, 20.8, False), (-52.9, 20.8, True)])
def test_a_phantom_at_the_shipped_coverage_edge_costs_nothing_one_at_the_cameras_edge_stops_the_cav(
        edge_x, speed, slows):
    """The shipped av.toml puts a phantom where the RSU's radar stops seeing the west approach (250 m from the
    pole): at the cav's comfortable commit point it plans as if the road were empty. The same phantom at the
    camera's 60 m edge (x = -52.9) would make it yield at every crossing (docs/ima-timing.md)."""
    from pathlib import Path

    from av_app.config import load
    from av_app.fusion import FusedObject
    from av_app.lanes import LaneMap
    from av_app.planner import Planner
    from av_app.route import Route

    cfg = load(Path(__file__).resolve().parent.parent / "scenarios" / "apps" / "av.toml",
               {"security": {"trust_anchor": "", "allow_unsecured": True}})
    assert cfg.coverage.edges and cfg.coverage.edges[0][0] == pytest.approx(-243.4, abs=1.0)
    route = Route(cfg.route.waypoints, cfg.route.corner_radius)
    v = math.sqrt(cfg.route.lateral_accel_max * cfg.route.corner_radius)
    s = ZONE - MARGIN - v * v / (2 * cfg.control.decel_comfort)
    x, y, yaw, _ = route.at(s)
    phantom = FusedObject("phantom:0", "phantom", 0.0, edge_x, -1.75, 0.0, speed, 0.0, 4.5, 1.8)
    plan = Planner(cfg, route, LaneMap(7.0, 250.0)).plan(0.0, (float(x), float(y), float(yaw)), v, [phantom])
    assert (plan.decision not in ("cruise", "go")) is slows, (plan.decision, plan.choices)
