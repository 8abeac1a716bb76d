"""The SignalDriver model (fmus/driver/model.py) closed with the VehicleDynamics model, without an FMU.

A driver eastbound on the y = -1.75 lane toward a stop line at x = -4.5 (the box of a 7 m road starts at
-3.5), at 13.9 m/s (50 km/h); the signal is a function of time. What a driver at a signal does: holds its
speed on green, stops at the line (not past it, not metres short) for a red it can stop for, without
braking harder than needed, stands until green and pulls away; on yellow it stops if that needs no more
than b_yellow and goes on otherwise; a red it cannot stop for it runs.
"""
from __future__ import annotations

import pytest

from fmus.driver.model import DriverParams, SignalDriver
from fmus.vehicle.model import VehicleModel, VehicleParams

LINE_X = -4.5
DT = 0.01


def drive(signal_at, x0: float, v0: float = 13.9, seconds: float = 20.0, **params):
    p = DriverParams(v_desired=13.9, stop_x=LINE_X, stop_y=-1.75, travel_yaw=0.0, **params)
    driver = SignalDriver(p)
    car = VehicleModel(VehicleParams(), x0=x0, y0=-1.75, v0=v0)
    rows = []
    for k in range(int(seconds / DT)):
        t = k * DT
        a = driver.command(signal_at(t), car.x, car.y, car.v)
        car.step(DT, a, 0.0, False)
        rows.append((t, car.x + p.front, car.v, car.a, a, driver.holding))
    return rows


def first_past(rows, x):
    return next((t for t, front, *_ in rows if front > x), None)


def test_green_holds_the_speed():
    rows = drive(lambda t: 6, x0=-150.0, seconds=8.0)
    assert all(abs(v - 13.9) < 0.3 for _, _, v, *_ in rows)
    assert not any(h for *_, h in rows)


def test_a_red_it_can_stop_for_ends_at_the_line_then_green_pulls_away():
    rows = drive(lambda t: 3 if t < 14.0 else 6, x0=-120.0)
    stopped = [(t, front) for t, front, v, *_ in rows if v < 0.05]
    assert stopped, "never stopped"
    stop_front = stopped[0][1]
    assert LINE_X - 1.0 - 0.5 <= stop_front <= LINE_X - 1.0 + 0.3  # the front 1 m short of the line (stop_gap)
    # the stop is driven at about b_comfort (2.5 m/s^2), not at the driver's limit
    assert -3.5 < min(r[3] for r in rows) < -2.0
    assert first_past(rows, LINE_X) > 14.0  # nobody crosses before green
    assert rows[-1][2] > 5.0  # pulling away after green


def test_yellow_far_out_stops_close_in_goes_on():
    far = drive(lambda t: 7 if t < 3.0 else 3, x0=-60.0)  # 13.9 m/s, ~52 m out: a stop needs ~1.9 m/s^2
    assert first_past(far, LINE_X) is None
    near = drive(lambda t: 7 if t < 3.0 else 3, x0=-25.0)  # ~17 m out: a stop needs ~5.7 m/s^2 > b_yellow
    crossed = first_past(near, LINE_X)
    assert crossed is not None and crossed < 3.0  # through within the yellow
    assert min(r[3] for r in near) > -0.5  # no braking


def test_a_red_it_cannot_stop_for_it_runs_and_one_it_can_it_stops_for():
    runs = drive(lambda t: 3, x0=-15.0, seconds=3.0)  # ~7 m out at 13.9 m/s: 14 m/s^2 needed
    assert first_past(runs, LINE_X) is not None
    stops = drive(lambda t: 3, x0=-30.0, seconds=6.0)  # ~22 m: 4.5 m/s^2, under b_max
    assert first_past(stops, LINE_X) is None


@pytest.mark.parametrize("bad, key", [({"b_yellow": 10.0}, "b_comfort <= b_yellow <= b_max"),
                                      ({"a_max": 0.0}, "a_max"), ({"front": -1.0}, "front"),
                                      ({"stop_x": float("nan")}, "stop_x")])
def test_bad_parameters_are_named(bad, key):
    with pytest.raises(ValueError, match=key):
        SignalDriver(DriverParams(**bad))
