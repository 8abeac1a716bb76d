"""VehicleDynamics FMU: the kinematic single-track model behind FMI 2."""
from __future__ import annotations

from fmus.slave_base import V2iSlave, Var
from fmus.vehicle.model import VehicleModel, VehicleParams

_P = VehicleParams()

# Parameters passed straight to VehicleParams (same names).
_MODEL_PARAMETERS = (
    Var("wheelbase", "parameter", "Distance front to rear axle (CommonRoad vehicle 1: 0.8839 + 1.5088 m)", "m", _P.wheelbase),
    Var("mass", "parameter", "Vehicle mass (CommonRoad vehicle 1)", "kg", _P.mass),
    Var("a_max", "parameter", "Largest traction acceleration, below v_switch", "m/s2", _P.a_max),
    Var("a_min", "parameter", "Braking limit (negative)", "m/s2", _P.a_min),
    Var("v_switch", "parameter", "Speed above which acceleration is power-limited: a_max*v_switch/|v|", "m/s", _P.v_switch),
    Var("v_max", "parameter", "Largest forward speed", "m/s", _P.v_max),
    Var("v_min", "parameter", "Largest reverse speed (negative)", "m/s", _P.v_min),
    Var("steer_max", "parameter", "Front-wheel steering angle limit (symmetric)", "rad", _P.steer_max),
    Var("steer_rate_max", "parameter", "Steering-rate limit (symmetric)", "rad/s", _P.steer_rate_max),
    Var("cd_a", "parameter", "Aerodynamic drag coefficient times frontal area", "m2", _P.cd_a),
    Var("c_rr", "parameter", "Rolling-resistance coefficient", "1", _P.c_rr),
    Var("rho_air", "parameter", "Air density", "kg/m3", _P.rho_air),
    Var("g", "parameter", "Gravitational acceleration", "m/s2", _P.g),
    Var("dt_internal", "parameter", "Largest internal integration step; longer communication steps are sub-stepped", "s", _P.dt_internal),
)
_INITIAL_STATE = (
    Var("x0", "parameter", "Initial x position of the rear axle (world frame, east)", "m", 0.0),
    Var("y0", "parameter", "Initial y position of the rear axle (world frame, north)", "m", 0.0),
    Var("yaw0", "parameter", "Initial heading, counter-clockwise from the x axis", "rad", 0.0),
    Var("v0", "parameter", "Initial speed along the heading", "m/s", 0.0),
    Var("steer0", "parameter", "Initial front-wheel steering angle", "rad", 0.0),
)
_INPUTS = (
    Var("accel_cmd", "input", "Longitudinal acceleration command; negative brakes", "m/s2", 0.0),
    Var("steer_cmd", "input", "Front-wheel steering angle command", "rad", 0.0),
    Var("reverse", "input", "Reverse gear: speed may go below zero only while true", start=False, type="Boolean"),
)
_OUTPUTS = (
    Var("x", "output", "Rear-axle x position (world frame)", "m"),
    Var("y", "output", "Rear-axle y position (world frame)", "m"),
    Var("yaw", "output", "Heading, counter-clockwise from the x axis", "rad"),
    Var("v", "output", "Speed along the heading (negative when reversing)", "m/s"),
    Var("a", "output", "Net longitudinal acceleration dv/dt (command after limits, minus road load)", "m/s2"),
    Var("steer", "output", "Actual front-wheel steering angle", "rad"),
    Var("yaw_rate", "output", "Yaw rate v*tan(steer)/wheelbase", "rad/s"),
)


class VehicleDynamics(V2iSlave):
    """Kinematic single-track vehicle with road load, CommonRoad vehicle 1 defaults."""

    DESCRIPTION = (
        "Kinematic single-track (bicycle) model with aerodynamic drag, rolling resistance, "
        "power-limited acceleration above v_switch, braking limit, steering angle and rate "
        "limits; defaults are CommonRoad vehicle 1 (Ford Escort)."
    )
    VARIABLES = _INPUTS + _INITIAL_STATE + _MODEL_PARAMETERS + _OUTPUTS

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.model: VehicleModel | None = None

    def initialize(self) -> None:
        v = self.values
        params = VehicleParams(**{p.name: v[p.name] for p in _MODEL_PARAMETERS})
        params.validate()
        self.model = VehicleModel(params, x0=v["x0"], y0=v["y0"], yaw0=v["yaw0"], v0=v["v0"], steer0=v["steer0"])
        self.model.update_outputs(v["accel_cmd"], v["steer_cmd"], v["reverse"])
        self._publish()

    def step(self, t: float, dt: float) -> None:
        v = self.values
        self.model.step(dt, v["accel_cmd"], v["steer_cmd"], v["reverse"])
        self._publish()

    def _publish(self) -> None:
        m, v = self.model, self.values
        v["x"], v["y"], v["yaw"], v["v"] = m.x, m.y, m.yaw, m.v
        v["a"], v["steer"], v["yaw_rate"] = m.a, m.steer, m.yaw_rate
