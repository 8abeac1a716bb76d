"""master.run.collision: footprints, first contact, min gap, TTC and PET against hand-computed geometry."""
from __future__ import annotations

import math

import numpy as np
import pytest

from master.run.collision import Body, CollisionCheck

CAR = Body("car", 4.5, 1.8, 0.95)


def drive(check, tracks, t_end, dt=0.01):
    """tracks: name -> f(t) -> (x, y, yaw, v); feeds the check every dt."""
    contacts = []
    for k in range(round(t_end / dt) + 1):
        t = k * dt
        contacts += check.update(t, {n: f(t) for n, f in tracks.items()})
    return contacts


def test_footprint_is_placed_from_the_rear_axle():
    c = CAR.corners(10.0, 5.0, math.pi / 2)  # heading north
    assert np.allclose(c.min(axis=0), [10.0 - 0.9, 5.0 - 0.95]) and np.allclose(c.max(axis=0), [10.9, 5.0 + 3.55])
    assert CAR.footprint(0, 0, 0).area == pytest.approx(4.5 * 1.8)


def test_bad_bodies_are_refused():
    with pytest.raises(ValueError, match="rear_overhang"):
        CollisionCheck({"x": Body("x", 4.0, 1.8, 4.0)})


def test_crossing_cars_touch_at_the_computed_time_with_their_relative_speed():
    # a drives north along x = 0 at 10 m/s, rear axle from y = -30; b drives east along y = 0 at 10 m/s from x = -30.
    # a's body spans x in [-0.9, 0.9]; b's front bumper reaches x = -0.9 when its rear axle is at -0.9 - 3.55;
    # a's body covers y = -0.9 (b's near side) from when its front (rear axle + 3.55) passes -0.9.
    a = lambda t: (0.0, -30.0 + 10 * t, math.pi / 2, 10.0)
    b = lambda t: (-30.0 + 10 * t, 0.0, 0.0, 10.0)
    check = CollisionCheck({"a": CAR, "b": Body("b", 4.5, 1.8, 0.95)})
    contacts = drive(check, {"a": a, "b": b}, 4.0)
    t_a = (-0.9 - 3.55 + 30) / 10  # a's front reaches b's lane edge
    t_b = (-0.9 - 3.55 + 30) / 10  # b's front reaches a's lane edge: the same by symmetry
    assert len(contacts) == 1 and contacts[0].t == pytest.approx(max(t_a, t_b), abs=0.011)
    assert contacts[0].relative_speed_mps == pytest.approx(10 * math.sqrt(2))
    m = check.metrics()
    assert m["collision"] and m["first_collision_s"] == contacts[0].t and m["min_gap_m"] == 0.0
    # at t = 0 both fronts are 25.55 m from the other lane at 10 m/s: TTC 2.555 s, found at the next 0.05 s sample
    assert m["min_ttc_s"] == 0.0 and m["pairs"]["a-b"]["min_ttc_s"] == 0.0
    fresh = CollisionCheck({"a": CAR, "b": Body("b", 4.5, 1.8, 0.95)})
    assert 2.555 <= fresh.ttc(a(0), b(0), "a", "b") < 2.555 + 0.05
    assert fresh.ttc(a(0), (-30.0, 0.0, math.pi, 10.0), "a", "b") is None  # b driving away: never


def test_parallel_lanes_never_touch_and_the_gap_is_the_lane_spacing_minus_width():
    a = lambda t: (-50 + 10 * t, -1.75, 0.0, 10.0)
    b = lambda t: (50 - 10 * t, 1.75, math.pi, 10.0)
    check = CollisionCheck({"a": CAR, "b": CAR})
    assert drive(check, {"a": a, "b": b}, 10.0) == []
    m = check.metrics()
    assert not m["collision"] and m["first_collision_s"] is None
    assert m["min_gap_m"] == pytest.approx(3.5 - 1.8)
    assert m["min_ttc_s"] is None and m["pet_s"] is None  # parallel paths: no conflict zone


def test_post_encroachment_time_of_a_vehicle_that_waits():
    # b crosses the junction eastward at 10 m/s; a waits south of it and goes north 2 s after b has left.
    b = lambda t: (-30.0 + 10 * t, 0.0, 0.0, 10.0)
    t_go = 6.0
    a = lambda t: (0.0, -8.0 + (0.0 if t < t_go else 10 * (t - t_go)), math.pi / 2, 0.0 if t < t_go else 10.0)
    check = CollisionCheck({"a": CAR, "b": CAR})
    assert drive(check, {"a": a, "b": b}, 9.0) == []
    # the zone is a's lane x in [-0.9, 0.9] crossed with b's lane y in [-0.9, 0.9]; b's rear leaves it when
    # its rear bumper (rear axle - 0.95) passes x = 0.9; a's front enters when rear axle + 3.55 reaches -0.9
    b_out = (0.9 + 0.95 + 30) / 10
    a_in = t_go + (-0.9 - 3.55 + 8.0) / 10
    assert check.metrics()["pet_s"] == pytest.approx(a_in - b_out, abs=0.021)
    assert check.metrics()["min_gap_m"] > 0


def test_post_encroachment_time_of_a_vehicle_following_another_is_its_time_gap():
    """Same lane, same way, 15.5 m from the leader's rear bumper to the follower's front at 10 m/s: every point
    of the lane the two share is left by the leader 1.55 s before the follower reaches it. Judged over the
    shared stretch as one zone (leader out of its far end, follower into its near end) it read as both in
    the zone at once."""
    a = lambda t: (-20.0 + 10 * t, 0.0, 0.0, 10.0)  # leader: rear bumper at rear axle - 0.95
    b = lambda t: (-40.0 + 10 * t, 0.0, 0.0, 10.0)  # follower: front bumper at rear axle + 3.55
    check = CollisionCheck({"a": CAR, "b": CAR})
    assert drive(check, {"a": a, "b": b}, 6.0) == []
    gap_m = (-20.0 - 0.95) - (-40.0 + 3.55)
    assert check.metrics()["pet_s"] == pytest.approx(gap_m / 10.0, abs=0.021)
    assert check.metrics()["min_gap_m"] == pytest.approx(gap_m)




def test_a_pair_that_touched_has_a_post_encroachment_time_of_at_most_zero():
    """b's corner comes down on a's side at 45 degrees and touches it at the last sample (a run that stops at
    first contact, as the case study's does): the swept areas meet in a point, a zone of no area, yet both
    covered that point at once."""
    a_pose = (0.0, 0.0, 0.0, 0.0)  # standing: x in [-0.95, 3.55], y in [-0.9, 0.9]
    yaw = -3 * math.pi / 4
    corner = CAR.corners(0.0, 0.0, yaw)
    low = corner[np.argmin(corner[:, 1])]  # b's lowest corner, relative to its rear axle
    end = (1.0 - low[0], 0.9 - 1e-9 - low[1])  # rear axle where that corner just meets a's side at x = 1.0
    b = lambda t: (end[0] - 5.0 * (1.0 - t) * math.cos(yaw), end[1] - 5.0 * (1.0 - t) * math.sin(yaw), yaw, 5.0)
    check = CollisionCheck({"a": CAR, "b": CAR})
    contacts = drive(check, {"a": lambda t: a_pose, "b": b}, 1.0)
    assert [c.t for c in contacts] == [pytest.approx(1.0)]
    assert check.metrics()["pet_s"] is not None and check.metrics()["pet_s"] <= 0.0
