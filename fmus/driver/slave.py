"""SignalDriver FMU: the thin FMI 2 wrapper of fmus.driver.model (a driver at a signalised approach).

Connect the controller's ``state_<group>`` of the head the driver faces to
``signal`` and its vehicle's ``x``, ``y``, ``v`` to the inputs of the same
names; ``accel_cmd`` drives the vehicle (``VehicleDynamics.accel_cmd``).
"""
from __future__ import annotations

from fmus.driver.model import DriverParams, SignalDriver as DriverModel
from fmus.slave_base import V2iSlave, Var

_P = DriverParams()

_PARAMETERS = (
    Var("v_desired", "parameter", "Speed the driver holds on green", "m/s", _P.v_desired),
    Var("a_max", "parameter", "Largest acceleration (pulling away, speeding up)", "m/s2", _P.a_max),
    Var("b_comfort", "parameter", "Deceleration at which a planned stop begins", "m/s2", _P.b_comfort),
    Var("b_yellow", "parameter", "Largest deceleration the driver stops at for a yellow (else goes on)", "m/s2",
        _P.b_yellow),
    Var("b_max", "parameter", "Largest deceleration the driver stops at for a red (else runs it)", "m/s2", _P.b_max),
    Var("k_speed", "parameter", "Gain of the speed controller", "1/s", _P.k_speed),
    Var("stop_gap", "parameter", "Where the front bumper stops short of the stop line", "m", _P.stop_gap),
    Var("front", "parameter", "Rear axle to front bumper", "m", _P.front),
    Var("stop_x", "parameter", "x of a point on the stop line (world frame)", "m", _P.stop_x),
    Var("stop_y", "parameter", "y of a point on the stop line (world frame)", "m", _P.stop_y),
    Var("travel_yaw", "parameter", "Direction of travel of the lane, counter-clockwise from the x axis", "rad",
        _P.travel_yaw),
)
_INPUTS = (
    Var("signal", "input", "J2735 MovementPhaseState of the head facing the driver (3 red, 5/6 green, 7/8 "
        "yellow, 1 dark)", start=6, type="Integer"),
    Var("x", "input", "Vehicle's rear-axle x", "m", 0.0),
    Var("y", "input", "Vehicle's rear-axle y", "m", 0.0),
    Var("v", "input", "Vehicle's speed", "m/s", 0.0),
)
_OUTPUTS = (
    Var("accel_cmd", "output", "Acceleration command to the vehicle", "m/s2"),
    Var("holding", "output", "True while stopping or standing for the signal", type="Boolean"),
)


class SignalDriver(V2iSlave):
    """A driver who holds a speed on green and stops for red (and for a yellow it can stop for)."""

    DESCRIPTION = ("Human driver at a signalised approach: speed hold on green, the dilemma-zone rule on "
                   "yellow, a stop for red at the line, standing until green.")
    VARIABLES = _INPUTS + _PARAMETERS + _OUTPUTS

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.driver: DriverModel | None = None

    def initialize(self) -> None:
        v = self.values
        self.driver = DriverModel(DriverParams(**{p.name: v[p.name] for p in _PARAMETERS}))
        self._decide()

    def step(self, t: float, dt: float) -> None:
        self._decide()

    def _decide(self) -> None:
        v = self.values
        v["accel_cmd"] = self.driver.command(v["signal"], v["x"], v["y"], v["v"])
        v["holding"] = self.driver.holding
