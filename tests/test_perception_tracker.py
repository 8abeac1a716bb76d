"""Kalman multi-object tracker on synthetic ground tracks with noise and missed detections."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rsu_app.perception.tracker import GroundDetection, Tracker, TrackerConfig, TrackerError

DT = 0.1


def _angle_err(a: float, b: float) -> float:
    return abs(math.remainder(a - b, math.tau))


def test_speed_and_heading_after_one_second():
    rng = np.random.default_rng(1)
    speed, heading = 15.0, math.radians(30)
    v = speed * np.array([math.cos(heading), math.sin(heading)])
    tr = Tracker()
    for k in range(11):  # t = 0 .. 1.0 s
        p = np.array([-20.0, -10.0]) + v * k * DT + rng.normal(0, 0.3, 2)
        out = tr.update(k * DT, [GroundDetection(*p)])
    assert len(out) == 1 and out[0].confirmed
    s = out[0]
    assert abs(s.speed - speed) < 1.0, s.speed
    assert _angle_err(s.heading, heading) < math.radians(5), math.degrees(s.heading)
    truth = np.array([-20.0, -10.0]) + v * 1.0
    assert np.hypot(s.x - truth[0], s.y - truth[1]) < 0.6


def test_ids_stable_through_a_crossing_with_misses():
    """Two vehicles cross the same point at the same time at right angles; 15 % of detections are
    missed, positions have 0.3 m noise. Each vehicle keeps one id from confirmation to the end."""
    rng = np.random.default_rng(7)
    va, vb = np.array([12.0, 0.0]), np.array([0.0, 10.0])  # eastbound, northbound
    a0, b0 = -va * 2.5, -vb * 2.5  # both at (0, 0) at t = 2.5 s
    tr = Tracker()
    ids: dict[str, set[int]] = {"a": set(), "b": set()}
    for k in range(51):
        t = k * DT
        truth = {"a": a0 + va * t, "b": b0 + vb * t}
        dets = [GroundDetection(*(p + rng.normal(0, 0.3, 2))) for p in truth.values() if rng.random() > 0.15]
        for s in tr.update(t, dets):
            name = min(truth, key=lambda n: np.hypot(*(truth[n] - (s.x, s.y))))
            if k > 5 and abs(t - 2.5) > 0.3:  # outside the crossing, assignment to a truth is unambiguous
                ids[name].add(s.id)
    assert len(ids["a"]) == 1 and len(ids["b"]) == 1 and ids["a"] != ids["b"], ids
    final = {s.id: s for s in tr.predict(5.0)}
    assert _angle_err(final[next(iter(ids["a"]))].heading, 0.0) < math.radians(5)
    assert _angle_err(final[next(iter(ids["b"]))].heading, math.pi / 2) < math.radians(5)


def test_birth_m_of_n_and_death():
    cfg = TrackerConfig(confirm_hits=3, confirm_window=5, max_missed=3)
    tr = Tracker(cfg)
    # a single spurious detection never becomes a track
    tr.update(0.0, [GroundDetection(50.0, 50.0)])
    for k in range(1, 6):
        assert tr.update(k * DT, []) == []
    assert tr.tracks == []  # the tentative one is gone after its window
    # a real one: hit, miss, hit, hit -> confirmed at the third hit (4th frame)
    seq = [True, False, True, True]
    confirmed_at = None
    for k, hit in enumerate(seq, start=10):
        out = tr.update(k * DT, [GroundDetection(1.0 * k * DT, 0.0)] if hit else [])
        if out and confirmed_at is None:
            confirmed_at = k
    assert confirmed_at == 13
    # coasts through max_missed missed frames, then dies
    for k in range(14, 14 + 3):
        assert len(tr.update(k * DT, [])) == 1
    assert tr.update(17 * DT, []) == []


def test_predict_between_frames_extrapolates_without_changing_state():
    tr = Tracker()
    for k in range(10):
        tr.update(k * DT, [GroundDetection(10.0 * k * DT, 5.0)])
    before = tr.predict(0.9)[0]
    mid = tr.predict(0.95)[0]
    assert mid.x == pytest.approx(before.x + before.vx * 0.05, abs=1e-9)
    assert mid.cov[0, 0] > before.cov[0, 0]  # uncertainty grows with the extrapolation
    again = tr.predict(0.9)[0]
    assert (again.x, again.y, again.vx) == (before.x, before.y, before.vx)
    with pytest.raises(TrackerError, match="backwards"):
        tr.predict(0.5)


def test_heading_held_when_stopping():
    """A vehicle heading north-east brakes to a stop and sits there with noisy detections:
    the reported heading stays the last moving one instead of following the noise."""
    rng = np.random.default_rng(3)
    tr = Tracker(min_speed=1.0)
    p, v = np.array([0.0, 0.0]), 8.0
    heading = math.radians(45)
    headings = []
    for k in range(80):
        t = k * DT
        v = max(0.0, v - 4.0 * DT) if t > 1.5 else v
        p = p + v * DT * np.array([math.cos(heading), math.sin(heading)])
        out = tr.update(t, [GroundDetection(*(p + rng.normal(0, 0.15, 2)))])
        if t > 5.0:
            headings.append(out[0].heading)
    assert out[0].speed < 1.0
    assert all(h is not None and _angle_err(h, heading) < math.radians(15) for h in headings), headings


def test_bad_input():
    tr = Tracker()
    tr.update(1.0, [])
    with pytest.raises(TrackerError, match="backwards"):
        tr.update(0.5, [])
    with pytest.raises(TrackerError, match="finite"):
        tr.update(2.0, [GroundDetection(math.nan, 0.0)])
    with pytest.raises(TrackerError, match="finite"):
        tr.update(math.nan, [])
    with pytest.raises(TrackerError, match="confirm_hits"):
        TrackerConfig(confirm_hits=6, confirm_window=5)
    assert tr.update(3.0, [(1.0, 2.0)]) == []  # plain (x, y) tuples work; not confirmed yet
