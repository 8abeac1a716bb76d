"""The controller link's answer timeout runs on the controller's clock: simulated time in lockstep.

A lockstep master that stalls in wall time (a loaded machine, a camera frame
being rendered) does not make the controller late: its answer comes at the
simulated time the RS-232 model says. A wall-clock timeout counted such stalls
as silent polls and sent a duplicate request (CI: one timeout in
test_rsu_app_spat under load). The port here is the controller model stepped by
the test, so simulated and wall time are independent.
"""
from __future__ import annotations

import time

from fmus.traffic_light.model import TrafficLightModel
from fmus.traffic_light.uart import UartConfig
from rsu_app.controller_link import ControllerLink

from test_evsp_controller_link import ModelPort, two_phase


def _link(port, timeout_s=0.2):
    link = ControllerLink("model://", opener=lambda url: port, answer_timeout_s=timeout_s)
    link.open()
    return link


def _wait_for(cond, wall_s=2.0):
    end = time.monotonic() + wall_s
    while time.monotonic() < end and not cond():
        time.sleep(0.01)
    return cond()


def test_a_stalled_lockstep_clock_is_not_a_silent_controller():
    port = ModelPort(TrafficLightModel(two_phase(), UartConfig(baud=9600)))
    link = _link(port)
    link.follow(lambda: port.t)
    link.start()
    try:
        time.sleep(0.8)  # four timeouts of wall time with the simulation standing still
        assert link.stats().get("timeouts", 0) == 0 and link.stats()["polls"] == 1
        for _ in range(100):  # one simulated second: the controller answers, the link polls on
            port.step()
            link.collect()
        assert link.stats().get("timeouts", 0) == 0 and link.stats()["answers"] >= 10
    finally:
        link.close()


def test_a_silent_controller_times_out_on_the_simulated_clock():
    port = ModelPort(TrafficLightModel(two_phase(), UartConfig(baud=9600)))  # never stepped: never answers
    link = _link(port)
    link.follow(lambda: port.t)
    link.start()
    try:
        time.sleep(0.3)
        assert link.stats().get("timeouts", 0) == 0
        port.t = 0.25  # simulated time passes without an answer
        assert _wait_for(lambda: link.stats().get("timeouts", 0) == 1)
        port.t = 0.5
        assert _wait_for(lambda: link.stats().get("timeouts", 0) == 2)
    finally:
        link.close()


def test_before_the_clock_has_a_time_nothing_times_out():
    port = ModelPort(TrafficLightModel(two_phase(), UartConfig(baud=9600)))
    now = [float("nan")]
    link = _link(port)  # the first poll went out before the app joined
    link.follow(lambda: now[0])
    link.start()
    try:
        time.sleep(0.4)
        assert link.stats().get("timeouts", 0) == 0
        now[0] = 3.0       # the first tick: the poll is dated now
        time.sleep(0.3)
        assert link.stats().get("timeouts", 0) == 0
        now[0] = 3.3
        assert _wait_for(lambda: link.stats().get("timeouts", 0) == 1)
    finally:
        link.close()


def test_on_a_real_line_the_timeout_is_wall_time():
    port = ModelPort(TrafficLightModel(two_phase(), UartConfig(baud=9600)))  # silent
    link = _link(port)
    link.start()
    try:
        assert _wait_for(lambda: link.stats().get("timeouts", 0) >= 1)
    finally:
        link.close()
