"""Tests of the plain-Python vehicle model (fmus/vehicle/model.py).

Anchors:
  V2  kinematic yaw rate v*tan(delta)/l (CommonRoad KS model): v = 10 m/s,
      delta = 0.05 rad, l = 2.3927 m -> 0.2091 rad/s.
  V3  power-limited acceleration a_max*v_switch/v (CommonRoad acceleration
      constraints, vehicle 1): 5.468 m/s^2 at 10 m/s, 2.734 m/s^2 at 20 m/s.
  V5  coast-down at 100 km/h, m = 1500 kg, cd_a = 0.66, c_rr = 0.012,
      rho = 1.2: 0.5*1.2*0.66*27.78^2/1500 + 0.012*9.81 = 0.321 m/s^2.
"""
import math

import pytest

from fmus.vehicle.model import VehicleModel, VehicleParams

NO_LOAD = dict(cd_a=0.0, c_rr=0.0)


def run(model, dt, n, accel_cmd, steer_cmd, reverse=False):
    for _ in range(n):
        model.step(dt, accel_cmd, steer_cmd, reverse)
    return model


def state(m):
    return (m.x, m.y, m.yaw, m.v, m.steer)


# ----------------------------------------------------------------- anchors
def test_V2_yaw_rate_anchor():
    m = VehicleModel(VehicleParams(**NO_LOAD), v0=10.0, steer0=0.05)
    m.update_outputs(0.0, 0.05)
    assert m.yaw_rate == pytest.approx(0.2091, abs=5e-5), "V2 anchor"
    assert m.yaw_rate == pytest.approx(10.0 * math.tan(0.05) / 2.3927, rel=1e-12)
    run(m, 0.1, 20, 0.0, 0.05)
    assert m.v == pytest.approx(10.0, abs=1e-12)
    assert m.yaw == pytest.approx(0.2091 * 2.0, abs=1e-4), "V2 anchor: yaw after 2 s"
    assert m.yaw == pytest.approx(2.0 * 10.0 * math.tan(0.05) / 2.3927, rel=1e-12)
    assert m.yaw_rate == pytest.approx(0.2091, abs=5e-5)


def test_V2_yaw_through_rate_limited_steering_matches_closed_form():
    # steer(t) = 0.4 t until 0.05 rad (t_s = 0.125 s), then constant:
    # yaw(t) = v/l * ( -ln(cos(0.4 t_s))/0.4 + tan(0.05) (t - t_s) )
    p = VehicleParams(**NO_LOAD)
    m = VehicleModel(p, v0=10.0)
    run(m, 0.1, 20, 0.0, 0.05)
    t_s = 0.05 / 0.4
    expected = 10.0 / p.wheelbase * (-math.log(math.cos(0.05)) / 0.4 + math.tan(0.05) * (2.0 - t_s))
    assert m.steer == 0.05
    assert m.yaw == pytest.approx(expected, abs=1e-11), "V2: yaw over time"
    assert m.yaw_rate == pytest.approx(0.2091, abs=5e-5), "V2"


def test_V3_power_limited_acceleration_limit():
    m = VehicleModel()
    assert m.accel_limit(10.0) == pytest.approx(5.468, abs=5e-4), "V3 at 10 m/s"
    assert m.accel_limit(20.0) == pytest.approx(2.734, abs=5e-4), "V3 at 20 m/s"
    assert m.accel_limit(-10.0) == m.accel_limit(10.0)
    assert m.accel_limit(3.0) == 11.5
    assert m.accel_limit(4.755) == 11.5


def test_V3_constant_power_speed_curve():
    m = VehicleModel(VehicleParams(**NO_LOAD), v0=10.0)
    k = 11.5 * 4.755
    for i in range(1, 51):
        m.step(0.1, 1e6, 0.0)
        t = 0.1 * i
        assert m.v == pytest.approx(math.sqrt(100.0 + 2.0 * k * t), abs=1e-3), f"V3 curve at t={t}"
    assert m.v == pytest.approx(math.sqrt(100.0 + 2.0 * k * 5.0), abs=1e-9)
    x_exact = ((100.0 + 2.0 * k * 5.0) ** 1.5 - 1000.0) / (3.0 * k)
    assert m.x == pytest.approx(x_exact, abs=1e-6)
    assert m.a == pytest.approx(k / m.v, rel=1e-12)


def test_V3_power_limit_kink_crossed_from_standstill():
    # a = a_max up to v_switch (t1 = v_switch/a_max), then constant power.
    m = VehicleModel(VehicleParams(**NO_LOAD))
    m.step(2.0, 100.0, 0.0)
    t1 = 4.755 / 11.5
    v_exact = math.sqrt(4.755 ** 2 + 2.0 * 11.5 * 4.755 * (2.0 - t1))
    assert m.v == pytest.approx(v_exact, abs=1e-9), "V3"


def test_V5_coast_down_deceleration():
    m = VehicleModel(VehicleParams(mass=1500.0, cd_a=0.66, c_rr=0.012, rho_air=1.2), v0=100.0 / 3.6)
    m.update_outputs(0.0, 0.0)
    assert m.a == pytest.approx(-0.321, abs=1e-3), "V5 coast-down"
    assert m.road_load(100.0 / 3.6) == pytest.approx(0.321, abs=1e-3), "V5"
    v_before = m.v
    m.step(0.01, 0.0, 0.0)
    assert (m.v - v_before) / 0.01 == pytest.approx(-0.321, abs=1e-3), "V5 over a step"


# -------------------------------------------------------------- longitudinal
def test_road_load_zero_at_rest_and_symmetric():
    m = VehicleModel()
    assert m.road_load(0.0) == 0.0
    assert m.road_load(5.0) == m.road_load(-5.0) > 0.0
    assert m.road_load(1e-6) == pytest.approx(0.012 * 9.81, rel=1e-6)


def test_braking_stops_exactly_at_zero_and_stays():
    m = VehicleModel(v0=20.0)
    speeds, xs = [], []
    for _ in range(100):
        m.step(0.1, -5.0, 0.0)
        speeds.append(m.v)
        xs.append(m.x)
    assert min(speeds) >= 0.0, "no creeping backwards"
    assert speeds[-1] == 0.0 and m.a == 0.0
    stop = speeds.index(0.0)
    assert all(v == 0.0 for v in speeds[stop:]), "no oscillation around 0"
    assert all(x == xs[stop] for x in xs[stop:])


def test_braking_distance_matches_analytic():
    m = VehicleModel(VehicleParams(**NO_LOAD), v0=17.3)
    run(m, 1.0, 10, -4.1, 0.0)
    assert m.v == 0.0
    assert m.x == pytest.approx(17.3 ** 2 / (2 * 4.1), abs=1e-9)


def test_brake_command_clipped_to_a_min():
    m = VehicleModel(VehicleParams(**NO_LOAD), v0=20.0)
    m.update_outputs(-100.0, 0.0)
    assert m.a == -11.5
    assert m.net_accel(20.0, 100.0) == pytest.approx(11.5 * 4.755 / 20.0, rel=1e-12)


def test_standstill_is_held_by_brakes_and_rolling_resistance():
    m = VehicleModel()
    assert m.net_accel(0.0, -5.0) == 0.0
    assert m.net_accel(0.0, 0.1) == 0.0  # below c_rr*g = 0.1177: rolling resistance holds
    assert m.net_accel(0.0, 1.0) == pytest.approx(1.0 - 0.012 * 9.81)
    run(m, 0.1, 10, -5.0, 0.0)
    assert (m.x, m.v, m.a) == (0.0, 0.0, 0.0)
    run(m, 0.1, 10, 0.1, 0.0)
    assert (m.x, m.v, m.a) == (0.0, 0.0, 0.0)
    run(m, 0.1, 10, 1.0, 0.0)
    assert m.v > 0.0 and m.x > 0.0


def test_small_traction_below_road_load_coasts_to_stop_not_backwards():
    m = VehicleModel(v0=2.0)
    run(m, 0.5, 60, 0.05, 0.0)
    assert m.v == 0.0 and m.a == 0.0


def test_forward_speed_capped_at_v_max():
    m = VehicleModel(VehicleParams(v_max=20.0, **NO_LOAD))
    for _ in range(20):
        m.step(0.5, 50.0, 0.0)
        assert m.v <= 20.0
    assert m.v == 20.0 and m.a == 0.0


def test_reverse_gear_drives_backwards_and_brakes_to_zero():
    m = VehicleModel(VehicleParams(**NO_LOAD))
    run(m, 0.01, 100, -2.0, 0.0, reverse=True)
    assert m.v == pytest.approx(-2.0, abs=1e-12)
    assert m.x == pytest.approx(-1.0, abs=1e-12)
    assert m.a == -2.0
    speeds = []
    for _ in range(100):
        m.step(0.01, 3.0, 0.0, True)
        speeds.append(m.v)
    assert max(speeds) <= 0.0, "reverse gear never goes forwards"
    assert speeds[-1] == 0.0 and m.a == 0.0
    assert m.x == pytest.approx(-1.0 - 4.0 / 6.0, abs=1e-9)


def test_reverse_gear_with_road_load_and_speed_limit():
    m = VehicleModel()
    m.step(1.0, -2.0, 0.0, True)
    assert -2.0 < m.v < -(2.0 - 0.012 * 9.81) + 1e-3
    run(m, 1.0, 30, -20.0, 0.0, reverse=True)
    assert m.v == m.params.v_min == -13.9, "reverse speed capped at v_min (CommonRoad vehicle 1)"
    m2 = VehicleModel()
    run(m2, 0.1, 10, 2.0, 0.0, reverse=True)  # positive command in reverse only brakes
    assert (m2.v, m2.x) == (0.0, 0.0)


def test_forward_gear_never_goes_below_zero_when_braking_from_rest():
    m = VehicleModel()
    for _ in range(50):
        m.step(0.1, -11.5, 0.3)
        assert m.v == 0.0 and m.x == 0.0 and m.y == 0.0 and m.yaw == 0.0


# ------------------------------------------------------------------ steering
def test_steering_rate_limit():
    m = VehicleModel(v0=5.0)
    m.step(0.1, 0.0, 0.5)
    assert m.steer == pytest.approx(0.04, abs=1e-12)
    for _ in range(200):
        m.step(0.03, 0.0, 0.5)
        assert m.steer <= 0.5
    assert m.steer == 0.5, "settles exactly, no overshoot"


def test_steering_rate_limit_exact_within_coarse_substep():
    m = VehicleModel(VehicleParams(dt_internal=0.5))
    m.step(0.05, 0.0, -0.3)
    assert m.steer == pytest.approx(-0.02, abs=1e-15)
    m.step(1.0, 0.0, -0.3)
    assert m.steer == -0.3


def test_steering_angle_clipped():
    m = VehicleModel()
    m.step(5.0, 0.0, 2.0)
    assert m.steer == 0.910
    m.step(10.0, 0.0, -2.0)
    assert m.steer == -0.910


# --------------------------------------------------------------- integration
@pytest.mark.parametrize("splits", [
    [0.01] * 100,
    [0.001] * 1000,
    [0.37, 0.63],
    [1.0 / 3.0] * 3,
    [0.25, 0.001, 0.5, 0.249],
])
def test_step_size_independence_smooth(splits):
    # Crosses the power-limit kink (v_switch) and the steering settling instant.
    def sim(parts):
        m = VehicleModel(v0=3.0)
        for d in parts:
            m.step(d, 3.0, 0.3)
        return state(m)

    ref = sim([1.0])
    assert sum(splits) == pytest.approx(1.0, abs=1e-12)
    for a, b in zip(ref, sim(splits)):
        assert a == pytest.approx(b, abs=1e-6)


@pytest.mark.parametrize("splits", [[0.01] * 200, [0.001] * 2000, [0.37, 0.63, 1.0], [0.7] * 2 + [0.6]])
def test_step_size_independence_stopping(splits):
    def sim(parts):
        m = VehicleModel(v0=8.0)
        for d in parts:
            m.step(d, -5.0, 0.2)
        return state(m)

    ref = sim([2.0])
    assert ref[3] == 0.0
    for a, b in zip(ref, sim(splits)):
        assert a == pytest.approx(b, abs=1e-3)


def test_coarse_internal_step_close_to_fine():
    def sim(dt_internal):
        m = VehicleModel(VehicleParams(dt_internal=dt_internal), v0=3.0)
        m.step(1.0, 3.0, 0.3)
        m.step(1.0, -6.0, -0.2)
        return state(m)

    for a, b in zip(sim(0.001), sim(0.02)):
        assert a == pytest.approx(b, abs=1e-6)


def test_straight_constant_speed_is_exact():
    m = VehicleModel(VehicleParams(**NO_LOAD), v0=15.0)
    run(m, 1.0, 10, 0.0, 0.0)
    assert m.x == pytest.approx(150.0, abs=1e-9)
    assert (m.y, m.yaw, m.v) == (0.0, 0.0, 15.0)


def test_cruise_command_equal_to_road_load_holds_speed():
    m = VehicleModel(v0=15.0, yaw0=math.pi / 2)
    cmd = m.road_load(15.0)
    run(m, 0.1, 100, cmd, 0.0)
    assert m.v == pytest.approx(15.0, abs=1e-9)
    assert m.y == pytest.approx(150.0, abs=1e-6)
    assert m.x == pytest.approx(0.0, abs=1e-9)


def test_steady_circle_closes_after_one_period():
    p = VehicleParams(**NO_LOAD)
    m = VehicleModel(p, x0=3.0, y0=-4.0, yaw0=0.3, v0=10.0, steer0=0.05)
    period = 2.0 * math.pi / m.yaw_rate
    n = int(period / 0.1)
    run(m, 0.1, n, 0.0, 0.05)
    m.step(period - n * 0.1, 0.0, 0.05)
    assert m.x == pytest.approx(3.0, abs=1e-6)
    assert m.y == pytest.approx(-4.0, abs=1e-6)
    assert m.yaw == pytest.approx(0.3 + 2.0 * math.pi, abs=1e-9)


def test_circle_radius_matches_kinematic_geometry():
    # Rear axle moves on a circle of radius l / tan(delta) (KS model).
    p = VehicleParams(**NO_LOAD)
    m = VehicleModel(p, v0=10.0, steer0=0.2)
    r = p.wheelbase / math.tan(0.2)
    for _ in range(50):
        m.step(0.1, 0.0, 0.2)
        assert math.hypot(m.x, m.y - r) == pytest.approx(r, abs=1e-9)


def test_update_outputs_does_not_advance_time():
    m = VehicleModel(v0=10.0, steer0=0.1)
    before = state(m)
    m.update_outputs(2.0, -0.5)
    assert state(m) == before
    assert m.a == pytest.approx(2.0 - m.road_load(10.0), rel=1e-12)
    assert m.yaw_rate == pytest.approx(10.0 * math.tan(0.1) / 2.3927, rel=1e-12)
    m.step(0.0, 2.0, -0.5)
    assert state(m) == before


# ---------------------------------------------------------------- validation
@pytest.mark.parametrize("field,value", [
    ("wheelbase", 0.0), ("mass", -1.0), ("dt_internal", 0.0), ("a_max", 0.0),
    ("a_min", 0.0), ("v_switch", 0.0), ("steer_max", 0.0), ("steer_max", 2.0),
    ("steer_rate_max", -0.1), ("cd_a", -0.1), ("c_rr", -0.01), ("v_max", 0.0),
    ("v_min", 1.0), ("mass", float("nan")), ("cd_a", float("inf")), ("g", float("-inf")),
])
def test_invalid_params_rejected_with_field_name(field, value):
    p = VehicleParams(**{field: value})
    with pytest.raises(ValueError, match=field):
        p.validate()
    with pytest.raises(ValueError, match=field):
        VehicleModel(p)


def test_default_params_valid():
    VehicleParams().validate()


@pytest.mark.parametrize("name", ["dt", "accel_cmd", "steer_cmd"])
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_nonfinite_step_inputs_rejected(name, bad):
    m = VehicleModel()
    args = dict(dt=0.1, accel_cmd=0.0, steer_cmd=0.0)
    args[name] = bad
    with pytest.raises(ValueError, match=name):
        m.step(**args)


def test_negative_dt_rejected():
    with pytest.raises(ValueError, match="dt"):
        VehicleModel().step(-0.1, 0.0, 0.0)


def test_nonfinite_update_outputs_inputs_rejected():
    m = VehicleModel()
    with pytest.raises(ValueError, match="accel_cmd"):
        m.update_outputs(float("nan"), 0.0)
    with pytest.raises(ValueError, match="steer_cmd"):
        m.update_outputs(0.0, float("inf"))


def test_invalid_initial_state_rejected():
    with pytest.raises(ValueError, match="v0"):
        VehicleModel(v0=float("nan"))
    with pytest.raises(ValueError, match="steer0"):
        VehicleModel(steer0=1.5)
    with pytest.raises(ValueError, match="v0"):
        VehicleModel(v0=100.0)
