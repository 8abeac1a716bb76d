"""Kalman multi-object tracker on synthetic ground tracks with noise and missed detections.

The last tests hold the filter to its documented noise model and gate: the posterior of a static target
against the least-squares value, the mean NEES against 2, and the association gate against the chi-square
99.9 % quantile (13.82): each fails when R is the standard deviation instead of the variance, or the gate
is ten times too wide."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rsu_app.perception.tracker import GroundDetection, Tracker, TrackerConfig, TrackerError, TrackState

DT = 0.1


def _angle_err(a: float, b: float) -> float:
    return abs(math.remainder(a - b, math.tau))


@pytest.mark.parametrize("motion", ["cv", "ctrv"])
def test_speed_and_heading_after_one_second(motion):
    rng = np.random.default_rng(1)
    speed, heading = 15.0, math.radians(30)
    v = speed * np.array([math.cos(heading), math.sin(heading)])
    tr = Tracker(motion=motion)
    for k in range(11):  # t = 0 .. 1.0 s
        p = np.array([-20.0, -10.0]) + v * k * DT + rng.normal(0, 0.3, 2)
        out = tr.update(k * DT, [GroundDetection(*p)])
    assert len(out) == 1 and out[0].confirmed
    s = out[0]
    assert abs(s.speed - speed) < 1.0, s.speed
    assert _angle_err(s.heading, heading) < math.radians(5), math.degrees(s.heading)
    truth = np.array([-20.0, -10.0]) + v * 1.0
    assert np.hypot(s.x - truth[0], s.y - truth[1]) < 0.6
    if motion == "cv":
        assert s.yaw_rate is None
    else:  # 0.6 s after the switch from CV the yaw rate is known to ~0.05-0.1 rad/s (measured 0.08 here)
        assert abs(s.yaw_rate) < 0.15, s.yaw_rate


@pytest.mark.parametrize("motion", ["cv", "ctrv"])
def test_ids_stable_through_a_crossing_with_misses(motion):
    """Two vehicles cross the same point at the same time at right angles; 15 % of detections are
    missed, positions have 0.3 m noise. Each vehicle keeps one id from confirmation to the end."""
    rng = np.random.default_rng(7)
    va, vb = np.array([12.0, 0.0]), np.array([0.0, 10.0])  # eastbound, northbound
    a0, b0 = -va * 2.5, -vb * 2.5  # both at (0, 0) at t = 2.5 s
    tr = Tracker(motion=motion)
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


# --- constant turn rate and velocity (CTRV) ---------------------------------------------------------
TURN_SPEED, TURN_RATE = 8.0, 0.35  # m/s, rad/s: 80 degrees in 4 s, a tight urban turn (2.8 m/s^2 lateral)
TURN_YAW0 = 2.6  # rad: the heading crosses +-pi 1.5 s in, so the filter's yaw wrapping is exercised


def _turn_truth(t: float) -> tuple[np.ndarray, float]:
    """Starts at the origin heading TURN_YAW0 and turns left."""
    yaw = TURN_YAW0 + TURN_RATE * t
    r = TURN_SPEED / TURN_RATE
    return r * np.array([math.sin(yaw) - math.sin(TURN_YAW0), math.cos(TURN_YAW0) - math.cos(yaw)]), yaw


def _turn_detections(seed: int) -> list[tuple[float, np.ndarray]]:
    rng = np.random.default_rng(seed)
    return [(k * DT, _turn_truth(k * DT)[0] + rng.normal(0, 0.3, 2)) for k in range(41)]


def _track_turn(motion: str, dets) -> tuple[float, float, TrackState]:
    """Median heading error (deg) and position error (m) after the first second, and the last state."""
    tr = Tracker(motion=motion)
    head, pos = [], []
    for t, z in dets:
        (s,) = tr.update(t, [GroundDetection(*z)]) or (None,)
        if t > 1.0 + 1e-9:
            p, yaw = _turn_truth(t)
            head.append(math.degrees(_angle_err(s.heading, yaw)))
            pos.append(math.hypot(s.x - p[0], s.y - p[1]))
    return float(np.median(head)), float(np.median(pos)), s


def test_ctrv_follows_a_turn_better_than_cv():
    """CV lags a turn (measured here: 12.8 deg median heading error, 0.42 m position error); CTRV models
    it (1.4 deg, 0.23 m). Over 40 seeds CTRV's median heading error was 0.9-4.3 deg (median 1.8) against
    CV's 11.9-13.7, so 5 deg separates them with margin; its final yaw-rate error was < 0.06 rad/s."""
    dets = _turn_detections(seed=5)
    cv_head, cv_pos, _ = _track_turn("cv", dets)
    ct_head, ct_pos, s = _track_turn("ctrv", dets)
    assert ct_head < cv_head and ct_pos < cv_pos, (ct_head, cv_head, ct_pos, cv_pos)
    assert ct_head < 5.0, ct_head
    assert abs(s.yaw_rate - TURN_RATE) < 0.1, s.yaw_rate


def test_ctrv_predicts_across_a_gap_without_changing_state():
    """The camera drops out for 0.8 s mid-turn: CTRV's extrapolation follows the arc (measured 0.44 m
    off vs CV's 2.8 m here; over 40 seeds median 0.54 vs 2.99 m), and predicting changes nothing a later
    update would see."""
    dets = _turn_detections(seed=5)
    before = [(t, z) for t, z in dets if t <= 2.0 + 1e-9]
    after = [(t, z) for t, z in dets if t >= 2.8 - 1e-9]
    truth, _ = _turn_truth(after[0][0])
    err = {}
    for motion in ("cv", "ctrv"):
        tr = Tracker(motion=motion)
        for t, z in before:
            tr.update(t, [GroundDetection(*z)])
        (s,) = tr.predict(after[0][0])
        err[motion] = math.hypot(s.x - truth[0], s.y - truth[1])
    assert err["ctrv"] < err["cv"], err
    assert err["ctrv"] < 1.0, err
    # without noise the extrapolation must follow the arc, not its tangent: 0.8 s at 8 m/s and 0.35 rad/s
    # bends v w T^2 / 2 ~ 0.9 m off the tangent (measured: 0.18 m off with the arc, 0.65 m with the chord)
    tr = Tracker(motion="ctrv")
    for t, _ in before:
        tr.update(t, [GroundDetection(*_turn_truth(t)[0])])
    (s,) = tr.predict(after[0][0])
    assert math.hypot(s.x - truth[0], s.y - truth[1]) < 0.3

    probed, plain = Tracker(motion="ctrv"), Tracker(motion="ctrv")
    for t, z in before:
        probed.update(t, [GroundDetection(*z)])
        plain.update(t, [GroundDetection(*z)])
    (a,), (b,) = probed.predict(2.8), probed.predict(2.8)
    assert a.yaw_rate is not None and a == b and np.array_equal(a.cov, b.cov)
    probed.predict(2.5)
    for t, z in after:
        (p,), (q,) = probed.update(t, [GroundDetection(*z)]), plain.update(t, [GroundDetection(*z)])
        assert p == q and np.array_equal(p.cov, q.cov)


@pytest.mark.parametrize("key, value", [("motion", "ctra"), ("turn_accel_std", 0.0)])
def test_bad_motion_config(key, value):
    with pytest.raises(TrackerError, match=key) as e:
        TrackerConfig(**{key: value})
    assert str(value) in str(e.value)
    if key == "motion":
        assert "'cv'" in str(e.value) and "'ctrv'" in str(e.value)


# --- the filter's noise model and the gate, as strict as the documented numbers --------------------------
def test_posterior_of_a_static_target_is_the_least_squares_one():
    """With (almost) no process noise, N updates of a target at rest at times 0, dt, .. (N-1) dt are a
    straight-line fit; its variance at the last time is meas_std^2 (4N - 2) / (N (N + 1)) for the position
    and 12 meas_std^2 / (N (N^2 - 1) dt^2) for the speed, per axis. The filter must reach them: R is the
    variance meas_std^2 (a filter built with R = meas_std * I is 1 / meas_std times off, 43 % at 0.7 m).
    Measured: within 1e-5 relative at N = 50."""
    n = 50
    for sigma in (0.3, 2.0):  # either side of 1 m, where a standard deviation and a variance are equal
        tr = Tracker(meas_std=sigma, accel_std=1e-6)
        for k in range(n):
            (s,) = tr.update(k * DT, [GroundDetection(5.0, -3.0)]) or (None,)
        position_var = sigma ** 2 * (4 * n - 2) / (n * (n + 1))
        speed_var = 12 * sigma ** 2 / (n * (n * n - 1) * DT ** 2)
        assert s.cov[0, 0] == pytest.approx(position_var, rel=1e-3), (sigma, s.cov[0, 0], position_var)
        assert s.cov[1, 1] == pytest.approx(position_var, rel=1e-3), (sigma, s.cov[1, 1], position_var)
        assert s.cov[2, 2] == pytest.approx(speed_var, rel=1e-3), (sigma, s.cov[2, 2], speed_var)


def _mean_nees(motion: str, sigma: float, runs: int = 40, steps: int = 40, accel_std: float = 3.0) -> float:
    """Mean normalised estimation error squared of the position (e^T P^-1 e, 2 dof) over Monte Carlo runs of
    the filter's own model: white acceleration of accel_std (piecewise constant per frame), white measurement
    noise of sigma per axis. A consistent filter averages 2."""
    rng = np.random.default_rng(11)
    values = []
    for _ in range(runs):
        tr = Tracker(motion=motion, meas_std=sigma, accel_std=accel_std, confirm_hits=1, confirm_window=1,
                     gate=1e3)  # wide: a 0.1 % outlier must not start a second track in this test
        p, v = np.array([0.0, 0.0]), np.array([8.0, 3.0])
        for k in range(steps):
            if k:
                a = rng.normal(0, accel_std, 2)
                p, v = p + v * DT + a * DT * DT / 2, v + a * DT
            (s,) = tr.update(k * DT, [GroundDetection(*(p + rng.normal(0, sigma, 2)))])
            if k >= 10:  # past the start, where the velocity prior still dominates
                e = p - (s.x, s.y)
                values.append(float(e @ np.linalg.solve(s.cov[:2, :2], e)))
    return float(np.mean(values))


@pytest.mark.parametrize("motion", ["cv", "ctrv"])
def test_filter_is_consistent_with_its_measurement_noise(motion):
    """Measured mean NEES (ideal 2) at 0.3 and 2 m: cv 2.04 and 2.12, ctrv 2.04 and 2.10 (1.78-1.95 over 100
    runs of another seed); with R = meas_std * I instead of meas_std^2 * I: cv 0.90 and 3.89, ctrv 0.81 and
    3.91, outside [1.5, 2.5] either way."""
    for sigma in (0.3, 2.0):
        nees = _mean_nees(motion, sigma)
        assert 1.5 <= nees <= 2.5, (motion, sigma, nees)


def _at_mahalanobis(tr: Tracker, track_id: int, t: float, d2: float, direction) -> np.ndarray:
    """The point at Mahalanobis^2 d2 from track track_id's position predicted to t, in the given direction,
    with the innovation covariance S = predicted P + meas_std^2 I that the association uses."""
    (pred,) = [s for s in tr.predict(t, include_tentative=True) if s.id == track_id]
    S = pred.cov[:2, :2] + tr.cfg.meas_std ** 2 * np.eye(2)
    u = np.asarray(direction, float) / np.hypot(*direction)
    offset = u * math.sqrt(d2 / (u @ np.linalg.solve(S, u)))
    assert float(offset @ np.linalg.solve(S, offset)) == pytest.approx(d2)
    return np.array([pred.x, pred.y]) + offset


def _static_track(n: int = 20) -> Tracker:
    tr = Tracker()  # the app's defaults: meas_std 0.7 m, gate 13.82 (chi-square 2 dof, 99.9 %)
    for k in range(n):
        tr.update(k * DT, [GroundDetection(10.0, 20.0)])
    assert len(tr.tracks) == 1 and tr.tracks[0].confirmed
    return tr


@pytest.mark.parametrize("d2, joins", [(12.0, True), (16.0, False), (100.0, False)])
def test_gate_at_the_chi_square_quantile(d2, joins):
    """A detection at Mahalanobis^2 d2 (innovation covariance S = predicted P + meas_std^2 I) from the only
    track updates it inside the 13.82 gate and starts a new track beyond it: 16 and 100 lie inside a gate
    ten times too wide (138.2); 16 also lies inside the correct gate were S built with R = meas_std * I."""
    tr = _static_track()
    t = 20 * DT
    (pred,) = tr.predict(t)
    z = _at_mahalanobis(tr, pred.id, t, d2, direction=(1.0, 1.0))
    tr.update(t, [GroundDetection(*z)])
    (track_id,) = tr.last_assignment
    if joins:
        assert track_id == pred.id and len(tr.tracks) == 1, (d2, tr.last_assignment)
    else:
        assert track_id != pred.id and len(tr.tracks) == 2, (d2, tr.last_assignment)
        old = next(x for x in tr.tracks if x.id == pred.id)
        assert old.missed == 1


# --- matching cascade: confirmed tracks choose first ------------------------------------------------------
def _east_track(n: int = 20, speed: float = 10.0) -> tuple[Tracker, int]:
    """A confirmed track on a target driving east along y = 0 from the origin, detected without noise."""
    tr = Tracker()  # the app's defaults
    for k in range(n):
        tr.update(k * DT, [GroundDetection(speed * k * DT, 0.0)])
    ((track_id, confirmed),) = [(x.id, x.confirmed) for x in tr.tracks]
    assert confirmed
    return tr, track_id


@pytest.mark.parametrize("noisy_frames", [2, 5])
def test_an_outlier_beyond_the_gate_does_not_take_over_a_confirmed_track(noisy_frames):
    """One detection at Mahalanobis^2 16 (beyond the 13.82 gate, 1 in 3,000 under the noise model) starts a
    tentative track beside a confirmed one; the next detections sit 1.9 m to the same side (d^2 = 5 from the
    confirmed track's prediction at the first of them, as a box that shifts for a few frames), then back on
    the true path. The confirmed track must get every one of them and the outlier's track must never be
    confirmed. A single assignment over all tracks gave the shifted ones to the young track, which sits on
    them and pays less d^2 than its larger ln|S| costs: with 2 such frames it was confirmed beside the real
    one (a duplicate vehicle broadcast), with 5 it took every later detection too and the real track coasted
    out (an id switch)."""
    tr, real = _east_track()
    sideways = (0.0, 1.0)
    t = 20 * DT
    tr.update(t, [GroundDetection(*_at_mahalanobis(tr, real, t, 16.0, sideways))])
    (outlier,) = tr.last_assignment
    assert outlier != real and len(tr.tracks) == 2  # the gate did its job: a new tentative track
    (pred,) = tr.predict(21 * DT)  # the confirmed track alone
    shift = _at_mahalanobis(tr, real, 21 * DT, 5.0, sideways) - (pred.x, pred.y)
    assert 1.5 < shift[1] < 2.5 and abs(shift[0]) < 1e-9
    assignments, confirmed = [], set()
    for k in range(21, 36):
        t = k * DT
        z = np.array([10.0 * t, 0.0]) + (shift if k < 21 + noisy_frames else 0.0)
        confirmed |= {s.id for s in tr.update(t, [GroundDetection(*z)])}
        assignments += tr.last_assignment
    assert assignments == [real] * 15, assignments
    assert confirmed == {real}, confirmed
    assert [x.id for x in tr.tracks] == [real]  # the outlier's track died in its window


def test_new_vehicles_beside_a_confirmed_track_start_and_confirm_their_own_tracks():
    """The second stage of the cascade: detections a confirmed track did not take go to the tentative ones.
    A vehicle appears far away (30 m north, driving north) and another in the next lane 4 m beside the
    confirmed track (outside its gate, overtaking); their detections come first and last in each frame, the
    confirmed track's in the middle, so a mix-up of detection indices between the stages shows."""
    tr, real = _east_track()
    truth = {"far": lambda t: (0.0, 30.0 + 8.0 * (t - 2.0)),
             "real": lambda t: (10.0 * t, 0.0),
             "beside": lambda t: (20.0 + 12.0 * (t - 2.0), -4.0)}
    tr.update(2.0, [GroundDetection(*f(2.0)) for f in truth.values()])
    far, first, beside = tr.last_assignment
    assert first == real and len({far, real, beside}) == 3 and len(tr.tracks) == 3
    for k in range(21, 31):
        t = k * DT
        out = tr.update(t, [GroundDetection(*f(t)) for f in truth.values()])
        assert tr.last_assignment == [far, real, beside], (k, tr.last_assignment)
        # confirmed at their third hit (confirm_hits = 3), the real track throughout
        expected = {real} if k < 22 else {far, real, beside}
        assert {s.id for s in out} == expected, (k, [s.id for s in out])
    final = {s.id: s for s in tr.predict(3.0)}
    for name, tid in (("far", far), ("real", real), ("beside", beside)):
        assert math.hypot(final[tid].x - truth[name](3.0)[0], final[tid].y - truth[name](3.0)[1]) < 0.5


# --- a covariance per detection ------------------------------------------------------------------------------
ANISO = (9.0, 0.0, 0.04)  # var_x, cov_xy, var_y: 3 m along x (a viewing ray), 0.2 m across it


def _aniso_nees(use_cov: bool, runs: int = 30, seed: int = 5) -> tuple[float, float]:
    """Mean NEES of a CV track on a vehicle driving east at 15 m/s, detected with 3 m noise along x and 0.2 m
    across, when its detections carry that covariance (or not: the tracker's meas_std 0.7 m on each axis);
    and the mean ratio of the track's position std along x to along y."""
    rng = np.random.default_rng(seed)
    L = np.linalg.cholesky(np.array([[ANISO[0], ANISO[1]], [ANISO[1], ANISO[2]]]))
    values, ratios = [], []
    for _ in range(runs):
        tr = Tracker(init_speed_std=20.0, gate=1e3)  # wide: without the covariance most points lie beyond 13.82
        for k in range(40):
            truth = np.array([-80.0 + 15.0 * k * DT, -1.75])
            z = truth + L @ rng.standard_normal(2)
            (s,) = tr.update(k * DT, [GroundDetection(*z, cov=ANISO if use_cov else None)]) or (None,)
            if s is not None and k >= 15:
                e = np.array([s.x, s.y]) - truth
                values.append(float(e @ np.linalg.solve(s.cov[:2, :2], e)))
                ratios.append(math.sqrt(s.cov[0, 0] / s.cov[1, 1]))
    return float(np.mean(values)), float(np.mean(ratios))


def test_a_detection_covariance_weighs_each_direction_by_what_it_is_worth():
    """A far vehicle's ground point is uncertain along the viewing ray, precise across it. With each detection's
    covariance the track is consistent (NEES ~2, ideal 2) and knows its position is far surer across the ray;
    with one figure for both axes the same detections leave it overconfident along the ray."""
    with_cov, ratio = _aniso_nees(True)
    without, flat = _aniso_nees(False)
    assert 1.5 <= with_cov <= 2.6, with_cov
    assert ratio > 4.0 and flat == pytest.approx(1.0, abs=0.05), (ratio, flat)
    assert without > 2 * with_cov, (without, with_cov)


@pytest.mark.parametrize("offset, joins", [((4.0, 0.0), True), ((0.0, 1.5), False)])
def test_the_gate_uses_each_detection_s_covariance(offset, joins):
    """A confirmed static track and a detection 4 m off along its uncertain axis (3 m std) joins it; one
    1.5 m off across it (0.2 m std) does not, though the second is nearer."""
    tr = Tracker()
    for k in range(20):
        tr.update(k * DT, [GroundDetection(10.0, 20.0, cov=ANISO)])
    (track_id,) = [x.id for x in tr.tracks]
    tr.update(20 * DT, [GroundDetection(10.0 + offset[0], 20.0 + offset[1], cov=ANISO)])
    assert (tr.last_assignment == [track_id]) == joins, (offset, tr.last_assignment)


@pytest.mark.parametrize("cov", [(1.0, 2.0, 1.0), (-1.0, 0.0, 1.0), (math.nan, 0.0, 1.0), ("a", 0, 1)])
def test_a_bad_detection_covariance_is_refused(cov):
    tr = Tracker()
    with pytest.raises(TrackerError, match="covariance"):
        tr.update(0.0, [GroundDetection(0.0, 0.0, cov=cov)])
    assert tr.tracks == [] and tr.last_assignment == []
