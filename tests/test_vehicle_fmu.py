"""The VehicleDynamics FMU stepped by fmpy: anchors V2, V3, V5 through FMI, not only the Python model."""
from __future__ import annotations

import math

import numpy as np
import pytest
from fmpy import simulate_fmu

NO_ROAD_LOAD = {"cd_a": 0.0, "c_rr": 0.0}


def simulate(fmu, stop, step, **start_values):
    return simulate_fmu(str(fmu), stop_time=stop, step_size=step, output_interval=step,
                        start_values=start_values, output=["x", "y", "yaw", "v", "a", "steer", "yaw_rate"])


def test_V2_kinematic_yaw_rate(vehicle_fmu):
    """ANCHORS V2: v = 10 m/s, delta = 0.05 rad, l = 2.3927 m -> 0.2091 rad/s."""
    r = simulate(vehicle_fmu, 2.0, 0.01, v0=10.0, steer0=0.05, steer_cmd=0.05, **NO_ROAD_LOAD)
    assert r["yaw_rate"][0] == pytest.approx(0.2091, abs=5e-5)
    assert r["yaw_rate"][-1] == pytest.approx(0.2091, abs=5e-5)
    assert r["yaw"][-1] - r["yaw"][0] == pytest.approx(0.2091 * 2.0, abs=1e-4)


def test_V3_power_limited_acceleration(vehicle_fmu):
    """ANCHORS V3: CommonRoad acceleration limit 5.468 m/s2 at 10 m/s, 2.734 m/s2 at 20 m/s."""
    at10 = simulate(vehicle_fmu, 0.01, 0.01, v0=10.0, accel_cmd=50.0, **NO_ROAD_LOAD)
    at20 = simulate(vehicle_fmu, 0.01, 0.01, v0=20.0, accel_cmd=50.0, **NO_ROAD_LOAD)
    assert at10["a"][0] == pytest.approx(5.468, abs=1e-3)
    assert at20["a"][0] == pytest.approx(2.734, abs=1e-3)


def test_V3_constant_power_curve_with_large_communication_steps(vehicle_fmu):
    """Sub-stepping: 0.5 s communication steps follow v^2 = v0^2 + 2 a_max v_switch t (V3)."""
    r = simulate(vehicle_fmu, 5.0, 0.5, v0=10.0, accel_cmd=50.0, **NO_ROAD_LOAD)
    expected = np.sqrt(10.0 ** 2 + 2 * 11.5 * 4.755 * r["time"])
    np.testing.assert_allclose(r["v"], expected, atol=1e-6)


def test_V5_coast_down(vehicle_fmu):
    """ANCHORS V5: 100 km/h, 1500 kg, CdA 0.66 m2, Crr 0.012, air 1.2 kg/m3 -> 0.321 m/s2."""
    r = simulate(vehicle_fmu, 0.01, 0.01, v0=100 / 3.6, mass=1500.0, cd_a=0.66, c_rr=0.012, rho_air=1.2, accel_cmd=0.0)
    assert r["a"][0] == pytest.approx(-0.321, abs=1e-3)


def test_communication_step_does_not_change_the_trajectory(vehicle_fmu):
    """A turning, braking manoeuvre at 1 s communication steps matches 10 ms steps."""
    kwargs = dict(v0=15.0, steer_cmd=0.2, accel_cmd=-2.0)
    coarse = simulate(vehicle_fmu, 4.0, 1.0, **kwargs)
    fine = simulate(vehicle_fmu, 4.0, 0.01, **kwargs)
    for name in ("x", "y", "yaw", "v"):
        assert coarse[name][-1] == pytest.approx(fine[name][-1], abs=1e-6), name


def test_braking_stops_without_reversing(vehicle_fmu):
    r = simulate(vehicle_fmu, 5.0, 0.1, v0=5.0, accel_cmd=-3.0)
    assert r["v"].min() == 0.0 and r["v"][-1] == 0.0
    stop_x = r["x"][-1]
    assert stop_x == pytest.approx(r["x"][np.argmax(r["v"] == 0.0)])  # stays put once stopped


def test_reverse_gear_drives_backwards(vehicle_fmu):
    r = simulate(vehicle_fmu, 2.0, 0.1, accel_cmd=-1.0, reverse=True)
    assert r["v"][-1] < -1.0 and r["x"][-1] < 0.0


def test_initial_pose_parameters(vehicle_fmu):
    r = simulate(vehicle_fmu, 1.0, 0.1, x0=3.0, y0=-4.0, yaw0=math.pi / 2, v0=2.0, **NO_ROAD_LOAD)
    assert (r["x"][0], r["y"][0], r["yaw"][0]) == pytest.approx((3.0, -4.0, math.pi / 2))
    assert r["y"][-1] == pytest.approx(-2.0, abs=1e-9) and r["x"][-1] == pytest.approx(3.0, abs=1e-9)


def test_invalid_parameter_fails_initialisation_with_the_field_name(vehicle_fmu):
    from fmpy.fmi1 import FMICallException

    messages = []
    with pytest.raises(FMICallException, match="fmi2ExitInitializationMode"):
        simulate_fmu(str(vehicle_fmu), stop_time=0.1, start_values={"mass": -5.0},
                     logger=lambda *args: messages.append(args[-1].decode()), debug_logging=True)
    assert any("mass" in m for m in messages), messages
